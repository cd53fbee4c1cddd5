"""ROS messages ↔ semslam measurements, for ROS 1 and ROS 2 alike (rosbags message objects).

Mapping (reader ← → writer):

====================================================  ==============  =====================
message type                                          measurement     sensor kind
====================================================  ==============  =====================
``sensor_msgs/PointCloud2``                           PointCloud      laser
``sensor_msgs/Imu``                                   Attitude        ahrs
``sensor_msgs/FluidPressure``                         Depth           depth
``cola2_msgs/DVL`` (written) / ``geometry_msgs/
TwistWithCovarianceStamped``, ``uuv_sensor_ros_
plugins_msgs/DVL``, ``dvl_msgs/DVL``, ``waterlinked_
a50_ros_driver/DVL`` (read only)                      DvlVelocity     dvl
``sensor_msgs/NavSatFix`` (written) / ``gps_msgs/
GPSFix``, ``gps_common/GPSFix`` (read only)           GpsFix          gps
``nav_msgs/Odometry``                                 GroundTruthPose ground_truth
``sensor_msgs/LaserScan``                             SonarSwath      sonar
====================================================  ==============  =====================

Conventions worth knowing:

* Stamps are the messages' header stamps, integer ns (the reader may replace them by the receive
  time, see ``semslam.mission.stamps``).
* **DVL validity**, per vendor: ``semslam.mission.dvl_messages``. The writer writes every DVL as
  ``cola2_msgs/DVL``; semslam does not model per-beam ranges and velocities, so beams carry only
  their validity (range = altitude or 0, velocity 0; -1 markers when invalid). Unknown altitude is
  written as -1 and read back as ``None``.
* **GPS**: ``semslam.mission.gps_messages`` (NED about the datum, NO_FIX dropped, covariance).
* **Imu** (REP 145): ``orientation_covariance[0] == -1`` means no orientation — such a message is
  no AHRS reading and is dropped (counted); the angular rate is kept unless
  ``angular_velocity_covariance[0] == -1``. An all-zero orientation covariance is unknown:
  ``reader.unknown_covariance.ahrs_rad`` is assumed.
* **FluidPressure** → depth = (p − p_atm) / (ρ g), variance / (ρ g)², constants from ReaderConfig
  (p_atm as resolved for the mission when ``auto``); a variance of 0 is unknown:
  ``reader.unknown_covariance.depth_m`` is assumed.
* **PointCloud2**: ``semslam.mission.pointcloud2`` (any layout, intensity, PCL's packed colour;
  invalid points removed, the cloud kept).
* **LaserScan** (REP 117): a beam whose range is not finite or outside [range_min, range_max] is
  not a return and is removed. The writer puts the returns back on a uniform angle grid (it finds
  the grid's increment from the beam angles) with +inf for the beams without a return.
* Every assumption (a covariance left unknown) is noted per sensor in the ``DecodeContext`` and
  reported by ``semslam info``.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from semslam.mission.codec_base import (
    DecodeContext,
    MalformedMessage,
    Unencodable,
    Unusable,
    normalize_msgtype,
    short_msgtype,
    stamp_ns,
    unknown_covariance,
)
from semslam.mission.config import ReaderConfig, writing_atmosphere_pa
from semslam.mission.dvl_messages import decode_twist, decode_uuv_dvl, decode_waterlinked_dvl
from semslam.mission.geodesy import Geodetic
from semslam.mission.gps_messages import decode_gps_fix, encode_navsatfix
from semslam.mission.measurements import (
    Attitude,
    Depth,
    DvlVelocity,
    GpsFix,
    GroundTruthPose,
    Measurement,
    PointCloud,
    SonarSwath,
)
from semslam.mission.pointcloud2 import FLOAT32, decode_pointcloud2_arrays, pointcloud2_fields, valid_points

__all__ = [
    "CODECS",
    "KIND_OF",
    "MSGTYPE_OF",
    "ROS1_FAST",
    "Codec",
    "DecodeContext",
    "Encoder",
    "MalformedMessage",
    "Ros1Fast",
    "Unencodable",
    "Unusable",
    "normalize_msgtype",
    "short_msgtype",
    "stamp_ns",
    "uniform_grid",
]


# ----------------------------------------------------------------------------------------------
# Decoding: message object → measurement (MalformedMessage: broken; Unusable: nothing to use)
# ----------------------------------------------------------------------------------------------

Decoder = Callable[[object, str, DecodeContext], Measurement]


def _decode_pointcloud2(msg, sensor: str, ctx: DecodeContext) -> PointCloud:
    points, intensity, rgb = valid_points(*decode_pointcloud2_arrays(msg))
    return PointCloud(stamp_ns(msg.header), sensor, points=points, intensity=intensity, rgb=rgb)


def _decode_imu(msg, sensor: str, ctx: DecodeContext) -> Attitude:
    q, w = msg.orientation, msg.angular_velocity
    return _imu_attitude(
        stamp_ns(msg.header),
        sensor,
        (q.x, q.y, q.z, q.w),
        msg.orientation_covariance,
        (w.x, w.y, w.z),
        msg.angular_velocity_covariance[0],
        ctx,
    )


def _imu_attitude(
    stamp: int, sensor: str, orientation, orientation_cov, rate, rate_cov_00: float, ctx: DecodeContext
) -> Attitude:
    """The AHRS reading of an Imu message's numbers (REP 145: a covariance starting with −1 means
    the quantity is absent, all zeros that it is unknown), whether rosbags or the ROS 1 fast path
    read them."""
    ocov = np.asarray(orientation_cov, dtype=float).reshape(3, 3)
    if ocov[0, 0] == -1.0:
        raise Unusable("orientation_covariance", "-1: no orientation in this Imu message (REP 145)")
    if unknown_covariance(ocov):
        sigma = ctx.cfg.unknown_covariance.ahrs_rad
        ctx.note(sensor, f"orientation covariance unknown: σ {sigma:g} rad assumed")
        ocov = np.eye(3) * sigma**2
    return Attitude(
        stamp, sensor, orientation=orientation, covariance=ocov, angular_rate=rate if rate_cov_00 != -1.0 else None
    )


def _decode_fluid_pressure(msg, sensor: str, ctx: DecodeContext) -> Depth:
    cfg = ctx.cfg
    rho_g = cfg.water_density_kg_m3 * cfg.gravity_m_s2
    variance = msg.variance / rho_g**2
    if variance == 0:
        sigma = cfg.unknown_covariance.depth_m
        ctx.note(sensor, f"variance unknown (0): σ {sigma:g} m assumed")
        variance = sigma**2
    return Depth(
        stamp_ns(msg.header),
        sensor,
        depth=(msg.fluid_pressure - ctx.atmospheric_pressure_pa) / rho_g,
        variance=variance,
    )


def _decode_odometry(msg, sensor: str, ctx: DecodeContext) -> GroundTruthPose:
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


def _build_odometry(stamp: int, v: tuple, sensor: str, ctx: DecodeContext) -> GroundTruthPose:
    return GroundTruthPose(stamp, sensor, position=v[0:3], orientation=v[3:7])


def _parse_imu_ros1(raw):
    head = _ros1_header(raw)
    if head is None or head[1] + _IMU_BODY.size != len(raw):
        return None
    return head[0], _IMU_BODY.unpack_from(raw, head[1])


def _build_imu(stamp: int, v: tuple, sensor: str, ctx: DecodeContext) -> Attitude:
    return _imu_attitude(stamp, sensor, v[0:4], v[4:13], v[13:16], v[16], ctx)


@dataclass(frozen=True)
class Ros1Fast:
    """A message type's fast path: ``parse(raw) -> (header stamp, values) | None`` and
    ``build(stamp, values, sensor, ctx) -> Measurement`` (may raise as the decoder does)."""

    parse: Callable[[object], tuple[int, tuple] | None]
    build: Callable[[int, tuple, str, DecodeContext], Measurement]


ROS1_FAST: dict[str, Ros1Fast] = {
    "nav_msgs/msg/Odometry": Ros1Fast(_parse_odometry_ros1, _build_odometry),
    "sensor_msgs/msg/Imu": Ros1Fast(_parse_imu_ros1, _build_imu),
}


def _decode_laserscan(msg, sensor: str, ctx: DecodeContext) -> SonarSwath:
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
        Codec("geometry_msgs/msg/TwistWithCovarianceStamped", "dvl", decode_twist),
        Codec("cola2_msgs/msg/DVL", "dvl", decode_uuv_dvl),
        Codec("uuv_sensor_ros_plugins_msgs/msg/DVL", "dvl", decode_uuv_dvl),
        Codec("dvl_msgs/msg/DVL", "dvl", decode_waterlinked_dvl),
        Codec("waterlinked_a50_ros_driver/msg/DVL", "dvl", decode_waterlinked_dvl),
        Codec("sensor_msgs/msg/NavSatFix", "gps", decode_gps_fix),
        Codec("gps_msgs/msg/GPSFix", "gps", decode_gps_fix),
        Codec("gps_common/msg/GPSFix", "gps", decode_gps_fix),
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
    GpsFix: "sensor_msgs/msg/NavSatFix",
    GroundTruthPose: "nav_msgs/msg/Odometry",
    SonarSwath: "sensor_msgs/msg/LaserScan",
}
KIND_OF: dict[type[Measurement], str] = {
    PointCloud: "laser",
    Attitude: "ahrs",
    Depth: "depth",
    DvlVelocity: "dvl",
    GpsFix: "gps",
    GroundTruthPose: "ground_truth",
    SonarSwath: "sonar",
}


class Encoder:
    """Builds message objects of one type store (ROS 1 or ROS 2 flavour)."""

    def __init__(self, store, ros_version: int, cfg: ReaderConfig, datum: Geodetic | None = None):
        self.T = store.types
        self.ros1 = ros_version == 1
        self.cfg = cfg
        self.datum = datum  # of the GPS fixes' local NED frame
        self.atmospheric_pressure_pa = writing_atmosphere_pa(cfg)

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
        fields, step, data = pointcloud2_fields(m.points, m.intensity, m.rgb)
        PF = self.T["sensor_msgs/msg/PointField"]
        return self.T["sensor_msgs/msg/PointCloud2"](
            header=self.header(m.stamp, frame_id),
            height=1,
            width=len(m.points),
            fields=[PF(name=n, offset=off, datatype=FLOAT32, count=1) for n, off in fields],
            is_bigendian=False,
            point_step=step,
            row_step=step * len(m.points),
            data=data,
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
            fluid_pressure=m.depth * rho_g + self.atmospheric_pressure_pa,
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

    def _GpsFix(self, m: GpsFix, frame_id: str):
        if self.datum is None:
            raise Unencodable("a GPS fix needs the mission's datum (MissionMetadata.datum) to be written")
        return encode_navsatfix(self.T, self.header(m.stamp, frame_id), m, self.datum)

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
