"""ROS messages ↔ semslam measurements, for ROS 1 and ROS 2 alike (rosbags message objects).

Mapping (reader ← → writer):

====================================================  ==============  =====================
message type                                          measurement     sensor kind
====================================================  ==============  =====================
``sensor_msgs/PointCloud2``                           PointCloud      laser
``sensor_msgs/Imu``                                   Attitude        ahrs
``sensor_msgs/FluidPressure``                         Depth           depth
``cola2_msgs/DVL`` (written) / ``geometry_msgs/
TwistWithCovarianceStamped`` (read only)              DvlVelocity     dvl
``nav_msgs/Odometry``                                 GroundTruthPose ground_truth
``sensor_msgs/LaserScan``                             SonarSwath      sonar
====================================================  ==============  =====================

Conventions worth knowing:

* Stamps are the messages' header stamps, integer ns.
* **DVL validity.** ``cola2_msgs/DVL``: a reading is invalid when its ``velocity_covariance`` is
  marked -1 (COLA2 / UUV Simulator convention) or when it has beams and fewer than
  ``ReaderConfig.dvl_min_valid_beams`` of them are valid; a beam is valid when its ``range`` ≥ 0,
  its ``velocity_covariance`` ≥ 0 and its velocity is finite. ``TwistWithCovarianceStamped`` has no
  beams: it is invalid when ``twist.covariance[0]`` is -1 (the same marker). An invalid reading's
  covariance carries no information and is read as NaN (so read → write → read is exact). The
  writer writes every DVL as ``cola2_msgs/DVL``; semslam does not model per-beam ranges and
  velocities, so beams carry only their validity (range = altitude or 0, velocity 0; -1 markers
  when invalid). Unknown altitude is written as -1 and read back as ``None``.
* **Imu** (REP 145): ``orientation_covariance[0] == -1`` means no orientation — such a message is
  no AHRS reading and is dropped (counted); the angular rate is kept unless
  ``angular_velocity_covariance[0] == -1``.
* **FluidPressure** → depth = (p − p_atm) / (ρ g), variance / (ρ g)², constants from ReaderConfig.
* **PointCloud2**: x, y, z (any numeric type, any order, any ``point_step``/``row_step``) and an
  optional ``intensity`` (or ``intensities``/``i``); points with a non-finite coordinate are
  invalid points in ROS (``is_dense`` false) and are removed, the cloud is kept.
* **LaserScan** (REP 117): a beam whose range is not finite or outside [range_min, range_max] is
  not a return and is removed. The writer puts the returns back on a uniform angle grid (it finds
  the grid's increment from the beam angles) with +inf for the beams without a return.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from semslam.mission.config import ReaderConfig
from semslam.mission.measurements import (
    Attitude,
    Depth,
    DvlVelocity,
    GroundTruthPose,
    Measurement,
    PointCloud,
    SonarSwath,
)


class MalformedMessage(ValueError):
    """A message that cannot be converted; ``field`` names the offending message field."""

    def __init__(self, field: str, what: str):
        super().__init__(f"field {field}: {what}")
        self.field = field
        self.what = what


class Unusable(ValueError):
    """A well-formed message that carries no measurement of its kind (dropped and counted)."""

    def __init__(self, field: str, what: str):
        super().__init__(f"field {field}: {what}")
        self.field = field


class Unencodable(ValueError):
    """A measurement that the chosen message type cannot carry."""


def normalize_msgtype(msgtype: str) -> str:
    """'sensor_msgs/PointCloud2' (ROS 1 spelling) → 'sensor_msgs/msg/PointCloud2'."""
    parts = msgtype.split("/")
    return f"{parts[0]}/msg/{parts[1]}" if len(parts) == 2 else msgtype


def short_msgtype(msgtype: str) -> str:
    """'sensor_msgs/msg/PointCloud2' → 'sensor_msgs/PointCloud2' (how people write it)."""
    return normalize_msgtype(msgtype).replace("/msg/", "/")


def stamp_ns(header) -> int:
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


# ----------------------------------------------------------------------------------------------
# Decoding: message object → measurement (MalformedMessage: broken; Unusable: nothing to use)
# ----------------------------------------------------------------------------------------------

Decoder = Callable[[object, str, ReaderConfig], Measurement]

_POINTFIELD_DTYPES = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}
_INTENSITY_NAMES = ("intensity", "intensities", "i")


def decode_pointcloud2_arrays(msg) -> tuple[np.ndarray, np.ndarray | None]:
    """x, y, z (N×3 float32) and intensity (N float32 or None) of a PointCloud2, vectorised.

    Organised clouds are flattened row by row; row padding (``row_step`` > width·point_step) is
    skipped. Invalid (non-finite) points are kept here; the caller filters them.
    """
    fields = {f.name: f for f in msg.fields}
    for axis in "xyz":
        if axis not in fields:
            raise MalformedMessage("fields", f"no '{axis}' field (have {sorted(fields)})")
    iname = next((n for n in _INTENSITY_NAMES if n in fields), None)
    wanted = ["x", "y", "z"] + ([iname] if iname else [])
    endian = ">" if msg.is_bigendian else "<"
    step, width, height = int(msg.point_step), int(msg.width), int(msg.height)
    formats = []
    for name in wanted:
        f = fields[name]
        if f.datatype not in _POINTFIELD_DTYPES:
            raise MalformedMessage(f"fields.{name}", f"unknown PointField datatype {f.datatype}")
        fmt = np.dtype(endian + _POINTFIELD_DTYPES[f.datatype])
        if f.offset + fmt.itemsize > step:
            raise MalformedMessage(f"fields.{name}", f"offset {f.offset} beyond point_step {step}")
        formats.append(fmt)
    n = width * height
    data = np.asarray(msg.data, dtype=np.uint8).reshape(-1)
    row = width * step
    if n == 0:
        return np.zeros((0, 3), np.float32), (np.zeros(0, np.float32) if iname else None)
    row_step = int(msg.row_step)
    if height > 1 and row_step > row:
        need = (height - 1) * row_step + row
        if data.size < need:
            raise MalformedMessage("data", f"{data.size} bytes, expected at least {need}")
        # Drop the padding at the end of each row: a strided view, then one contiguous copy.
        rows = np.lib.stride_tricks.as_strided(data, shape=(height, row), strides=(row_step, 1), writeable=False)
        data = np.ascontiguousarray(rows).reshape(-1)
    elif data.size < n * step:
        raise MalformedMessage("data", f"{data.size} bytes, expected {n * step} ({n} points × {step})")
    buf = data[: n * step]

    offs = [fields[a].offset for a in "xyz"]
    if (
        all(fmt == np.dtype("<f4") for fmt in formats[:3])
        and offs[1] == offs[0] + 4
        and offs[2] == offs[0] + 8
        and step % 4 == 0
        and offs[0] % 4 == 0
    ):
        # Fast path (the common layout): float32 x, y, z adjacent → one strided view, one copy.
        words = buf.view("<f4").reshape(n, step // 4)
        points = np.array(words[:, offs[0] // 4 : offs[0] // 4 + 3], dtype=np.float32)
    else:
        dtype = np.dtype({"names": ["x", "y", "z"], "formats": formats[:3], "offsets": offs, "itemsize": step})
        rec = buf.view(dtype)
        points = np.empty((n, 3), np.float32)
        for k, axis in enumerate("xyz"):
            points[:, k] = rec[axis]
    intensity = None
    if iname:
        dtype = np.dtype({"names": ["i"], "formats": [formats[3]], "offsets": [fields[iname].offset], "itemsize": step})
        intensity = buf.view(dtype)["i"].astype(np.float32)
    return points, intensity


def _decode_pointcloud2(msg, sensor: str, cfg: ReaderConfig) -> PointCloud:
    points, intensity = decode_pointcloud2_arrays(msg)
    # Cheap whole-array test first; the per-point mask only for clouds that have invalid points.
    if not (np.isfinite(points.reshape(-1)).all() and (intensity is None or np.isfinite(intensity).all())):
        ok = np.isfinite(points).all(axis=1)
        if intensity is not None:
            ok &= np.isfinite(intensity)
        points = points[ok]
        intensity = None if intensity is None else intensity[ok]
    return PointCloud(stamp_ns(msg.header), sensor, points=points, intensity=intensity)


def _decode_imu(msg, sensor: str, cfg: ReaderConfig) -> Attitude:
    q, w = msg.orientation, msg.angular_velocity
    return _imu_attitude(
        stamp_ns(msg.header),
        sensor,
        (q.x, q.y, q.z, q.w),
        msg.orientation_covariance,
        (w.x, w.y, w.z),
        msg.angular_velocity_covariance[0],
    )


def _imu_attitude(stamp: int, sensor: str, orientation, orientation_cov, rate, rate_cov_00: float) -> Attitude:
    """The AHRS reading of an Imu message's numbers (REP 145: a covariance starting with −1 means
    the quantity is absent), whether rosbags or the ROS 1 fast path read them."""
    ocov = np.asarray(orientation_cov, dtype=float).reshape(3, 3)
    if ocov[0, 0] == -1.0:
        raise Unusable("orientation_covariance", "-1: no orientation in this Imu message (REP 145)")
    return Attitude(
        stamp, sensor, orientation=orientation, covariance=ocov, angular_rate=rate if rate_cov_00 != -1.0 else None
    )


def _decode_fluid_pressure(msg, sensor: str, cfg: ReaderConfig) -> Depth:
    rho_g = cfg.water_density_kg_m3 * cfg.gravity_m_s2
    return Depth(
        stamp_ns(msg.header),
        sensor,
        depth=(msg.fluid_pressure - cfg.atmospheric_pressure_pa) / rho_g,
        variance=msg.variance / rho_g**2,
    )


_NAN33 = np.full((3, 3), np.nan)


def _decode_twist(msg, sensor: str, cfg: ReaderConfig) -> DvlVelocity:
    cov = np.asarray(msg.twist.covariance, dtype=float).reshape(6, 6)[:3, :3]
    valid = not cov[0, 0] < 0  # -1 marks an invalid reading (same convention as cola2_msgs/DVL)
    v = msg.twist.twist.linear
    return DvlVelocity(
        stamp_ns(msg.header), sensor, velocity=(v.x, v.y, v.z), covariance=cov if valid else _NAN33, valid=valid
    )


def _decode_cola2_dvl(msg, sensor: str, cfg: ReaderConfig) -> DvlVelocity:
    cov = np.asarray(msg.velocity_covariance, dtype=float).reshape(3, 3)
    marked_invalid = cov[0, 0] < 0
    beam_valid = None
    if len(msg.beams):
        beam_valid = tuple(
            bool(b.range >= 0 and b.velocity_covariance >= 0 and np.isfinite(b.velocity)) for b in msg.beams
        )
    valid = not marked_invalid and (beam_valid is None or sum(beam_valid) >= cfg.dvl_min_valid_beams)
    v = msg.velocity
    altitude = float(msg.altitude) if msg.altitude >= 0 else None  # -1 (or NaN): unknown
    return DvlVelocity(
        stamp_ns(msg.header),
        sensor,
        velocity=(v.x, v.y, v.z),
        covariance=cov if valid else _NAN33,
        valid=valid,
        beam_valid=beam_valid,
        altitude=altitude,
    )


def _decode_odometry(msg, sensor: str, cfg: ReaderConfig) -> GroundTruthPose:
    p, q = msg.pose.pose.position, msg.pose.pose.orientation
    return GroundTruthPose(stamp_ns(msg.header), sensor, position=(p.x, p.y, p.z), orientation=(q.x, q.y, q.z, q.w))


# ----------------------------------------------------------------------------------------------
# ROS 1 fast path: the most frequent messages parsed straight from their bytes
# ----------------------------------------------------------------------------------------------
# rosbags builds a message object per nested type (an Odometry: ten of them, ~43 µs); the tank
# mission's 24,501 ground-truth poses and 9800 AHRS readings took ~1.3 s of it. For these fixed
# layouts, ``parse`` reads the header stamp and the numbers the decoder uses (as rosbags would:
# little-endian, the stamp's sec int32), and ``build`` makes the same measurement as the decoder.
# ``parse`` accepts only what rosbags accepts (strings inside the message and valid UTF-8, the
# size exact) and returns None otherwise: the caller then takes the general path, whose error
# it reports as before.

_U32 = struct.Struct("<I")
_TIME = struct.Struct("<iI")
_ODOMETRY_POSE = struct.Struct("<7d")  # pose.pose: position, orientation (x, y, z, w)
_ODOMETRY_AFTER_CHILD = 8 * (7 + 36 + 6 + 36)  # pose (pose, covariance), twist (twist, covariance)
_IMU_BODY = struct.Struct("<37d")  # orientation, its covariance, angular velocity, its cov., accel., its cov.


def _ros1_string_end(raw, pos: int) -> int | None:
    """End of the ROS 1 string at ``pos`` (uint32 length, UTF-8 bytes), None if rosbags would reject it."""
    if pos + 4 > len(raw):
        return None
    end = pos + 4 + _U32.unpack_from(raw, pos)[0]
    if end > len(raw):
        return None
    try:
        bytes(raw[pos + 4 : end]).decode()
    except UnicodeDecodeError:
        return None
    return end


def _ros1_header(raw) -> tuple[int, int] | None:
    """(stamp ns, end) of the std_msgs/Header at the start of ``raw`` (seq, stamp, frame_id)."""
    if len(raw) < 12:
        return None
    sec, nanosec = _TIME.unpack_from(raw, 4)
    end = _ros1_string_end(raw, 12)
    return None if end is None else (sec * 1_000_000_000 + nanosec, end)


def _parse_odometry_ros1(raw):
    head = _ros1_header(raw)
    if head is None:
        return None
    stamp, pos = head
    pos = _ros1_string_end(raw, pos)  # child_frame_id
    if pos is None or pos + _ODOMETRY_AFTER_CHILD != len(raw):
        return None
    return stamp, _ODOMETRY_POSE.unpack_from(raw, pos)


def _build_odometry(stamp: int, v: tuple, sensor: str, cfg: ReaderConfig) -> GroundTruthPose:
    return GroundTruthPose(stamp, sensor, position=v[0:3], orientation=v[3:7])


def _parse_imu_ros1(raw):
    head = _ros1_header(raw)
    if head is None or head[1] + _IMU_BODY.size != len(raw):
        return None
    return head[0], _IMU_BODY.unpack_from(raw, head[1])


def _build_imu(stamp: int, v: tuple, sensor: str, cfg: ReaderConfig) -> Attitude:
    return _imu_attitude(stamp, sensor, v[0:4], v[4:13], v[13:16], v[16])


@dataclass(frozen=True)
class Ros1Fast:
    """A message type's fast path: ``parse(raw) -> (header stamp, values) | None`` and
    ``build(stamp, values, sensor, cfg) -> Measurement`` (may raise as the decoder does)."""

    parse: Callable[[object], tuple[int, tuple] | None]
    build: Callable[[int, tuple, str, ReaderConfig], Measurement]


ROS1_FAST: dict[str, Ros1Fast] = {
    "nav_msgs/msg/Odometry": Ros1Fast(_parse_odometry_ros1, _build_odometry),
    "sensor_msgs/msg/Imu": Ros1Fast(_parse_imu_ros1, _build_imu),
}


def _decode_laserscan(msg, sensor: str, cfg: ReaderConfig) -> SonarSwath:
    ranges = np.asarray(msg.ranges, dtype=np.float32).astype(np.float64)
    n = ranges.size
    angles = float(msg.angle_min) + np.arange(n) * float(msg.angle_increment)
    keep = np.isfinite(ranges) & (ranges >= float(msg.range_min)) & (ranges <= float(msg.range_max))
    intens = np.asarray(msg.intensities, dtype=np.float32).astype(np.float64)
    if intens.size not in (0, n):
        raise MalformedMessage("intensities", f"{intens.size} values for {n} ranges")
    return SonarSwath(
        stamp_ns(msg.header),
        sensor,
        angles=angles[keep],
        ranges=ranges[keep],
        intensities=intens[keep] if intens.size else None,
    )


@dataclass(frozen=True)
class Codec:
    msgtype: str  # normalised, e.g. 'sensor_msgs/msg/Imu'
    kind: str  # sensor kind it feeds
    decode: Decoder


CODECS: dict[str, Codec] = {
    c.msgtype: c
    for c in (
        Codec("sensor_msgs/msg/PointCloud2", "laser", _decode_pointcloud2),
        Codec("sensor_msgs/msg/Imu", "ahrs", _decode_imu),
        Codec("sensor_msgs/msg/FluidPressure", "depth", _decode_fluid_pressure),
        Codec("geometry_msgs/msg/TwistWithCovarianceStamped", "dvl", _decode_twist),
        Codec("cola2_msgs/msg/DVL", "dvl", _decode_cola2_dvl),
        Codec("nav_msgs/msg/Odometry", "ground_truth", _decode_odometry),
        Codec("sensor_msgs/msg/LaserScan", "sonar", _decode_laserscan),
    )
}


# ----------------------------------------------------------------------------------------------
# Encoding: measurement → message object of the given type store
# ----------------------------------------------------------------------------------------------

MSGTYPE_OF: dict[type[Measurement], str] = {
    PointCloud: "sensor_msgs/msg/PointCloud2",
    Attitude: "sensor_msgs/msg/Imu",
    Depth: "sensor_msgs/msg/FluidPressure",
    DvlVelocity: "cola2_msgs/msg/DVL",
    GroundTruthPose: "nav_msgs/msg/Odometry",
    SonarSwath: "sensor_msgs/msg/LaserScan",
}
KIND_OF: dict[type[Measurement], str] = {
    PointCloud: "laser",
    Attitude: "ahrs",
    Depth: "depth",
    DvlVelocity: "dvl",
    GroundTruthPose: "ground_truth",
    SonarSwath: "sonar",
}


class Encoder:
    """Builds message objects of one type store (ROS 1 or ROS 2 flavour)."""

    def __init__(self, store, ros_version: int, cfg: ReaderConfig):
        self.T = store.types
        self.ros1 = ros_version == 1
        self.cfg = cfg

    # -- small message pieces ----------------------------------------------------------------
    def header(self, stamp: int, frame_id: str):
        t = self.T["builtin_interfaces/msg/Time"](sec=stamp // 1_000_000_000, nanosec=stamp % 1_000_000_000)
        if self.ros1:
            return self.T["std_msgs/msg/Header"](seq=0, stamp=t, frame_id=frame_id)
        return self.T["std_msgs/msg/Header"](stamp=t, frame_id=frame_id)

    def vec3(self, v):
        return self.T["geometry_msgs/msg/Vector3"](x=float(v[0]), y=float(v[1]), z=float(v[2]))

    def quat(self, q):
        return self.T["geometry_msgs/msg/Quaternion"](x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3]))

    def point(self, p):
        return self.T["geometry_msgs/msg/Point"](x=float(p[0]), y=float(p[1]), z=float(p[2]))

    # -- measurements ------------------------------------------------------------------------
    def encode(self, m: Measurement, frame_id: str):
        return getattr(self, f"_{type(m).__name__}")(m, frame_id)

    def _PointCloud(self, m: PointCloud, frame_id: str):
        has_i = m.intensity is not None
        names = ["x", "y", "z"] + (["intensity"] if has_i else [])
        rec = np.empty(len(m.points), dtype=np.dtype({"names": names, "formats": ["<f4"] * len(names)}))
        rec["x"], rec["y"], rec["z"] = m.points[:, 0], m.points[:, 1], m.points[:, 2]
        if has_i:
            rec["intensity"] = m.intensity
        PF = self.T["sensor_msgs/msg/PointField"]
        step = 4 * len(names)
        return self.T["sensor_msgs/msg/PointCloud2"](
            header=self.header(m.stamp, frame_id),
            height=1,
            width=len(m.points),
            fields=[PF(name=n, offset=4 * k, datatype=7, count=1) for k, n in enumerate(names)],
            is_bigendian=False,
            point_step=step,
            row_step=step * len(m.points),
            data=rec.view(np.uint8).reshape(-1),
            is_dense=True,
        )

    def _Attitude(self, m: Attitude, frame_id: str):
        rate_unknown = m.angular_rate is None
        marker = np.zeros(9)
        marker[0] = -1.0
        return self.T["sensor_msgs/msg/Imu"](
            header=self.header(m.stamp, frame_id),
            orientation=self.quat(m.orientation),
            orientation_covariance=np.asarray(m.covariance, dtype=np.float64).reshape(9).copy(),
            angular_velocity=self.vec3(np.zeros(3) if rate_unknown else m.angular_rate),
            angular_velocity_covariance=marker.copy() if rate_unknown else np.zeros(9),
            linear_acceleration=self.vec3(np.zeros(3)),
            linear_acceleration_covariance=marker.copy(),
        )

    def _Depth(self, m: Depth, frame_id: str):
        rho_g = self.cfg.water_density_kg_m3 * self.cfg.gravity_m_s2
        return self.T["sensor_msgs/msg/FluidPressure"](
            header=self.header(m.stamp, frame_id),
            fluid_pressure=m.depth * rho_g + self.cfg.atmospheric_pressure_pa,
            variance=m.variance * rho_g**2,
        )

    def _DvlVelocity(self, m: DvlVelocity, frame_id: str):
        cov = np.asarray(m.covariance, dtype=np.float64).reshape(9).copy() if m.valid else np.full(9, -1.0)
        altitude = -1.0 if m.altitude is None else float(m.altitude)
        beams = []
        if m.beam_valid is not None:
            Beam, PoseStamped, Pose = (
                self.T["cola2_msgs/msg/DVLBeam"],
                self.T["geometry_msgs/msg/PoseStamped"],
                self.T["geometry_msgs/msg/Pose"],
            )
            for ok in m.beam_valid:
                pose = PoseStamped(
                    header=self.header(m.stamp, frame_id),
                    pose=Pose(position=self.point((0, 0, 0)), orientation=self.quat((0, 0, 0, 1))),
                )
                beams.append(
                    Beam(
                        range=max(altitude, 0.0) if ok else -1.0,
                        range_covariance=0.0 if ok else -1.0,
                        velocity=0.0,
                        velocity_covariance=0.0 if ok else -1.0,
                        pose=pose,
                    )
                )
        return self.T["cola2_msgs/msg/DVL"](
            header=self.header(m.stamp, frame_id),
            velocity=self.vec3(m.velocity),
            velocity_covariance=cov,
            altitude=altitude,
            beams=beams,
        )

    def _GroundTruthPose(self, m: GroundTruthPose, frame_id: str):
        T = self.T
        return T["nav_msgs/msg/Odometry"](
            header=self.header(m.stamp, "world_ned"),
            child_frame_id=frame_id,
            pose=T["geometry_msgs/msg/PoseWithCovariance"](
                pose=T["geometry_msgs/msg/Pose"](position=self.point(m.position), orientation=self.quat(m.orientation)),
                covariance=np.zeros(36),
            ),
            twist=T["geometry_msgs/msg/TwistWithCovariance"](
                twist=T["geometry_msgs/msg/Twist"](linear=self.vec3((0, 0, 0)), angular=self.vec3((0, 0, 0))),
                covariance=np.zeros(36),
            ),
        )

    def _SonarSwath(self, m: SonarSwath, frame_id: str):
        a0, inc, idx = uniform_grid(m.angles)
        n = int(idx[-1]) + 1 if idx.size else 0
        ranges = np.full(n, np.inf, np.float32)
        ranges[idx] = m.ranges
        intens = np.zeros(n if m.intensities is not None else 0, np.float32)
        if m.intensities is not None:
            intens[idx] = m.intensities
        finite = m.ranges[np.isfinite(m.ranges)]
        return self.T["sensor_msgs/msg/LaserScan"](
            header=self.header(m.stamp, frame_id),
            angle_min=float(a0),
            angle_max=float(np.float32(a0 + inc * max(n - 1, 0))),
            angle_increment=float(inc),
            time_increment=0.0,
            scan_time=0.0,
            range_min=float(min(0.0, finite.min())) if finite.size else 0.0,
            range_max=float(np.float32(finite.max())) if finite.size else 0.0,
            ranges=ranges,
            intensities=intens,
        )


MAX_SCAN_BEAMS = 65536
MAX_GRID_SUBDIVISION = 64


def uniform_grid(angles: np.ndarray, tol_rad: float = 1e-6) -> tuple[np.float32, np.float32, np.ndarray]:
    """(angle_min, angle_increment, beam indices) of a float32 uniform grid holding ``angles``.

    The returns of a swath are a subset of the sonar's uniform beam grid; the grid's increment is
    the smallest gap between returns divided by the smallest m = 1 … 64 that puts every return on
    the grid within ``tol_rad`` (float32 storage costs < 5e-7 rad over ±π).
    """
    a = np.asarray(angles, dtype=np.float64)
    if a.size == 0:
        return np.float32(0.0), np.float32(0.0), np.zeros(0, dtype=np.int64)
    a0 = np.float32(a[0])
    if a.size == 1:
        return a0, np.float32(0.0), np.zeros(1, dtype=np.int64)
    gaps = np.diff(a)
    if not (gaps > 0).all():
        raise Unencodable("swath beam angles must be strictly increasing to be written as a LaserScan")
    span, m = a[-1] - a[0], 1
    # m is bounded: with a fine enough grid anything "fits", which would hide an irregular swath.
    while m <= MAX_GRID_SUBDIVISION and span / (gaps.min() / m) < MAX_SCAN_BEAMS:
        inc = np.float32(gaps.min() / m)
        idx = np.rint((a - float(a0)) / float(inc)).astype(np.int64)
        if np.abs(float(a0) + idx * float(inc) - a).max() <= tol_rad:
            return a0, inc, idx
        m += 1
    raise Unencodable("swath beam angles are not on a uniform grid, which a LaserScan needs")
