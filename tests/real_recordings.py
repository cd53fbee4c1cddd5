"""Bags as real AUVs record them, written with rosbags for the reader's tests: vendor messages,
housekeeping topics, mixed clocks, surface GPS. ``Recording(fmt)`` (fmt: ros1 | sqlite3 | mcap)
builds messages with the right type store and writes them as that format; ``dive(...)`` is the
vehicle's motion of the all-traits acceptance bag."""

from __future__ import annotations

import sqlite3
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from rosbags.typesys import get_types_from_msg
from scipy.spatial.transform import Rotation

from semslam.mission.config import ReaderConfig
from semslam.mission.conversions import Encoder
from semslam.mission.geodesy import Geodetic, to_geodetic

FORMATS = ("mcap", "sqlite3", "ros1")
NAMES = {"mcap": "rec.mcap", "sqlite3": "rec_ros2", "ros1": "rec.bag"}
S = 1_000_000_000
NO = np.array([-1.0] + [0.0] * 8)  # REP 145: "this quantity is absent"

# Types no standard store knows: an acoustic modem's raw frames (no sensor reads it).
MODEM_MSG = "std_msgs/Header header\nuint8[] payload\nstring peer\n"
TF_MSG = "geometry_msgs/TransformStamped[] transforms\n"
HOUSEKEEPING = {
    "/battery": "sensor_msgs/msg/BatteryState",
    "/leak": "std_msgs/msg/Bool",
    "/diagnostics": "diagnostic_msgs/msg/DiagnosticArray",
    "/controller/wrench": "geometry_msgs/msg/WrenchStamped",
    "/modem/raw": "acme_msgs/msg/ModemRaw",
    "/tf": "tf2_msgs/msg/TFMessage",
    "/rosout": "rcl_interfaces/msg/Log",  # ROS 1: rosgraph_msgs/msg/Log
}


class Recording:
    """Messages of one bag format, collected per topic and written at once."""

    def __init__(self, fmt: str):
        from semslam.mission.typestore import typestore

        assert fmt in FORMATS
        self.fmt = fmt
        self.ros1 = fmt == "ros1"
        from rosbags.typesys import Stores, get_typestore

        self.store = get_typestore(Stores.ROS1_NOETIC if self.ros1 else Stores.ROS2_HUMBLE)
        ours = typestore(1 if self.ros1 else 2)
        vendor = {k: v for k, v in ours.fielddefs.items() if k not in self.store.fielddefs}
        self.store.register(vendor)
        extra = get_types_from_msg(MODEM_MSG, "acme_msgs/msg/ModemRaw")
        if "tf2_msgs/msg/TFMessage" not in self.store.fielddefs:
            extra.update(get_types_from_msg(TF_MSG, "tf2_msgs/msg/TFMessage"))
        self.store.register(extra)
        self.T = self.store.types
        self.pieces = Encoder(self.store, 1 if self.ros1 else 2, ReaderConfig())
        self.topics: dict[str, tuple[str, list]] = {}
        self.raw: dict[str, tuple[str, list]] = {}  # topic → (msgtype, [(t, bytes)]), written as they are

    # -- writing -------------------------------------------------------------------------------
    def add(self, topic: str, msgtype: str, t_receive: int, msg) -> None:
        self.topics.setdefault(topic, (msgtype, []))[1].append((int(t_receive), msg))

    def add_raw(self, topic: str, msgtype: str, t_receive: int, data: bytes) -> None:
        self.raw.setdefault(topic, (msgtype, []))[1].append((int(t_receive), data))

    def write(self, directory: Path, forget_definitions: tuple[str, ...] = ()) -> Path:
        """The bag in ``directory``; ``forget_definitions``: message types whose definitions a
        Humble-era sqlite3 bag would not hold (deleted after writing)."""
        path = Path(directory) / NAMES[self.fmt]
        items = []
        for topic, (msgtype, msgs) in self.topics.items():
            items += [(t, topic, msgtype, self._ser(m, msgtype)) for t, m in msgs]
        for topic, (msgtype, msgs) in self.raw.items():
            items += [(t, topic, msgtype, data) for t, data in msgs]
        items.sort(key=lambda x: x[0])
        if self.ros1:
            from rosbags.rosbag1 import Writer

            writer = Writer(path)
        else:
            from rosbags.rosbag2 import StoragePlugin, Writer

            plugin = StoragePlugin.MCAP if self.fmt == "mcap" else StoragePlugin.SQLITE3
            writer = Writer(path.with_suffix("") if self.fmt == "mcap" else path, version=9, storage_plugin=plugin)
        with writer:
            conns = {}
            for topic in sorted({x[1] for x in items} | set(self.topics)):
                msgtype = (self.topics.get(topic) or self.raw[topic])[0]
                conns[topic] = writer.add_connection(topic, msgtype, typestore=self.store)
            for t, topic, _, data in items:
                writer.write(conns[topic], t, data)
        if self.fmt == "mcap":
            (src,) = path.with_suffix("").glob("*.mcap")
            src.rename(path)
            for f in path.with_suffix("").iterdir():
                f.unlink()
            path.with_suffix("").rmdir()
        if forget_definitions:
            assert self.fmt == "sqlite3"
            with sqlite3.connect(next(path.glob("*.db3"))) as db:
                for t in forget_definitions:
                    db.execute("DELETE FROM message_definitions WHERE topic_type = ?", (t,))
        return path

    def _ser(self, msg, msgtype):
        return self.store.serialize_ros1(msg, msgtype) if self.ros1 else self.store.serialize_cdr(msg, msgtype)

    # -- message pieces (the writer's) ---------------------------------------------------------
    def header(self, t: int, frame: str = "base_link"):
        return self.pieces.header(t, frame)

    def vec3(self, v):
        return self.pieces.vec3(v)

    def quat(self, q):
        return self.pieces.quat(q)

    def point(self, p):
        return self.pieces.point(p)

    # -- sensor messages -----------------------------------------------------------------------
    def imu(self, t, q, ocov=None, rate=(0.0, 0.0, 0.0), no_orientation=False):
        return self.T["sensor_msgs/msg/Imu"](
            header=self.header(t, "ahrs"),
            orientation=self.quat(q),
            orientation_covariance=NO.copy() if no_orientation else np.asarray(ocov, float).reshape(9).copy(),
            angular_velocity=self.vec3(rate),
            angular_velocity_covariance=np.diag([1e-6] * 3).reshape(9),
            linear_acceleration=self.vec3((0, 0, 9.8)),
            linear_acceleration_covariance=np.diag([1e-3] * 3).reshape(9),
        )

    def pressure(self, t, pa, variance=25.0):
        return self.T["sensor_msgs/msg/FluidPressure"](
            header=self.header(t, "pressure"), fluid_pressure=float(pa), variance=float(variance)
        )

    def twist(self, t, v, cov=1e-4):
        c = np.zeros(36)
        c[0] = c[7] = c[14] = cov
        tw = self.T["geometry_msgs/msg/Twist"](linear=self.vec3(v), angular=self.vec3((0, 0, 0)))
        return self.T["geometry_msgs/msg/TwistWithCovarianceStamped"](
            header=self.header(t, "dvl"), twist=self.T["geometry_msgs/msg/TwistWithCovariance"](twist=tw, covariance=c)
        )

    def waterlinked_dvl(self, t, v, valid=True, beams=(True,) * 4, fom=0.002, cov=None, altitude=4.0):
        """dvl_msgs/DVL (ROS 2) or waterlinked_a50_ros_driver/DVL (ROS 1), as the drivers fill them."""
        pkg = "waterlinked_a50_ros_driver" if self.ros1 else "dvl_msgs"
        Beam = self.T[f"{pkg}/msg/DVLBeam"]
        beam_msgs = [
            Beam(id=k, velocity=0.1, distance=altitude * 1.15 if ok else -1.0, rssi=-30.0, nsd=-90.0, valid=ok)
            for k, ok in enumerate(beams)
        ]
        fields = dict(
            header=self.header(t, "dvl"),
            time=100.0,
            velocity=self.vec3(v),
            fom=float(fom),
            altitude=float(altitude if valid else -1.0),
            beams=beam_msgs,
            velocity_valid=bool(valid),
            status=0,
            form="json_v3.1",
        )
        if not self.ros1:
            given = np.zeros(0) if cov is None else np.asarray(cov, float).reshape(9)
            fields.update(covariance=given, time_of_validity=t // 1000, time_of_transmission=t // 1000 + 5000)
        return self.T[f"{pkg}/msg/DVL"](**fields)

    def uuv_dvl(self, t, v, cov, beam_ranges=(4.0,) * 4, altitude=4.0):
        Beam, pose = self.T["uuv_sensor_ros_plugins_msgs/msg/DVLBeam"], self.pose_stamped(t)
        beams = [
            Beam(range=r, range_covariance=0.01, velocity=0.1, velocity_covariance=0.01, pose=pose) for r in beam_ranges
        ]
        return self.T["uuv_sensor_ros_plugins_msgs/msg/DVL"](
            header=self.header(t, "dvl"),
            velocity=self.vec3(v),
            velocity_covariance=np.asarray(cov, float).reshape(9),
            altitude=float(altitude),
            beams=beams,
        )

    def pose_stamped(self, t):
        return self.T["geometry_msgs/msg/PoseStamped"](
            header=self.header(t),
            pose=self.T["geometry_msgs/msg/Pose"](position=self.point((0, 0, 0)), orientation=self.quat((0, 0, 0, 1))),
        )

    def navsatfix(self, t, where: Geodetic | None, cov_enu=None, cov_type=2, status=0):
        lat, lon, alt = (
            (np.nan, np.nan, np.nan) if where is None else (where.latitude_deg, where.longitude_deg, where.altitude_m)
        )
        return self.T["sensor_msgs/msg/NavSatFix"](
            header=self.header(t, "gps"),
            status=self.T["sensor_msgs/msg/NavSatStatus"](status=status, service=1),
            latitude=float(lat),
            longitude=float(lon),
            altitude=float(alt),
            position_covariance=np.zeros(9) if cov_enu is None else np.asarray(cov_enu, float).reshape(9),
            position_covariance_type=int(cov_type),
        )

    def gpsfix(self, t, where: Geodetic, err_horz=0.0, err_vert=0.0, status=0):
        GPSStatus = self.T["gps_msgs/msg/GPSStatus"]
        empty = np.zeros(0, np.int32)
        st = GPSStatus(
            header=self.header(t, "gps"),
            satellites_used=8,
            satellite_used_prn=empty,
            satellites_visible=10,
            satellite_visible_prn=empty,
            satellite_visible_z=empty,
            satellite_visible_azimuth=empty,
            satellite_visible_snr=empty,
            status=status,
            motion_source=0,
            orientation_source=0,
            position_source=1,
        )
        zeros = {k: 0.0 for k in "track speed climb pitch roll dip time gdop pdop hdop vdop tdop err".split()}
        zeros.update({k: 0.0 for k in "err_track err_speed err_climb err_time err_pitch err_roll err_dip".split()})
        return self.T["gps_msgs/msg/GPSFix"](
            header=self.header(t, "gps"),
            status=st,
            latitude=where.latitude_deg,
            longitude=where.longitude_deg,
            altitude=where.altitude_m,
            err_horz=float(err_horz),
            err_vert=float(err_vert),
            position_covariance=np.zeros(9),
            position_covariance_type=0,
            **zeros,
        )

    def odometry(self, t, p, q):
        T = self.T
        return T["nav_msgs/msg/Odometry"](
            header=self.header(t, "odom"),
            child_frame_id="base_link",
            pose=T["geometry_msgs/msg/PoseWithCovariance"](
                pose=T["geometry_msgs/msg/Pose"](position=self.point(p), orientation=self.quat(q)),
                covariance=np.zeros(36),
            ),
            twist=T["geometry_msgs/msg/TwistWithCovariance"](
                twist=T["geometry_msgs/msg/Twist"](linear=self.vec3((0, 0, 0)), angular=self.vec3((0, 0, 0))),
                covariance=np.zeros(36),
            ),
        )

    def pointcloud2(self, t, points, rgb=None, height=1, packed="rgb", rgb_datatype=7):
        """An unorganised (or organised: height > 1) little-endian cloud with float32 x, y, z and
        optionally PCL's packed colour ``packed`` (rgb / rgba) of datatype FLOAT32 (7) or UINT32 (6)."""
        n = len(points)
        names, formats = ["x", "y", "z"], ["<f4"] * 3
        if rgb is not None:
            names.append(packed)
            formats.append("<u4")
        rec = np.zeros(n, np.dtype({"names": names, "formats": formats}))
        rec["x"], rec["y"], rec["z"] = points[:, 0], points[:, 1], points[:, 2]
        datatypes = [7, 7, 7]
        if rgb is not None:
            c = np.asarray(rgb, np.uint32)
            rec[packed] = (0xFF << 24) | (c[:, 0] << 16) | (c[:, 1] << 8) | c[:, 2]
            datatypes.append(rgb_datatype)
        PF = self.T["sensor_msgs/msg/PointField"]
        step = 4 * len(names)
        return self.T["sensor_msgs/msg/PointCloud2"](
            header=self.header(t, "laser"),
            height=height,
            width=n // height,
            fields=[
                PF(name=nm, offset=4 * k, datatype=dt, count=1) for k, (nm, dt) in enumerate(zip(names, datatypes))
            ],
            is_bigendian=False,
            point_step=step,
            row_step=step * (n // height),
            data=rec.view(np.uint8).reshape(-1),
            is_dense=bool(np.isfinite(points).all()),
        )

    # -- housekeeping --------------------------------------------------------------------------
    def blank(self, msgtype: str, t: int = 0, **values):
        """A message of ``msgtype`` with every field zero / empty (a header stamped t), except ``values``."""
        from rosbags.typesys.base import Nodetype

        numeric = {"bool": bool, "string": str}

        def zero(desc):
            kind, rest = desc
            if kind == Nodetype.BASE:
                name = rest[0]
                return numeric.get(name, float if name.startswith("float") else int)()
            if kind == Nodetype.NAME:
                return self.header(t) if rest == "std_msgs/msg/Header" else self.blank(rest, t)
            inner, n = rest
            if inner[0] == Nodetype.BASE and inner[1][0] not in ("string",):
                dtype = {"bool": bool, "byte": np.uint8, "char": np.uint8}.get(inner[1][0], inner[1][0])
                return np.zeros(n if kind == Nodetype.ARRAY else 0, dtype=dtype)
            return [zero(inner) for _ in range(n if kind == Nodetype.ARRAY else 0)]

        fields = {name: zero(desc) for name, desc in self.store.fielddefs[msgtype][1]}
        fields.update(values)
        return self.T[msgtype](**fields)


# ----------------------------------------------------------------------------------------------
# The vehicle of the acceptance bag: at the surface, a dive, a straight leg with a turn, back up
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Dive:
    seconds: float = 60.0
    surface_s: float = 10.0  # at the surface first, and again for the last surface_s
    depth_m: float = 3.0
    speed_m_s: float = 0.5
    t0_vehicle: int = 1_700_000_000 * S  # the vehicle's clock (header stamps)
    receive_offset: int = 3 * 86400 * S + 123_456_789  # the recorder's clock, days ahead
    datum: Geodetic = Geodetic(41.38, 2.17, 50.0)
    p_atm: float = 101_000.0
    rho: float = 1025.0

    def depth(self, t: float) -> float:
        """Depth (m) at t s: 0 at the surface, down and up at 0.3 m/s."""
        down = max(0.0, t - self.surface_s) * 0.3
        up = max(0.0, self.seconds - self.surface_s - t) * 0.3
        return float(min(self.depth_m, down, up))

    def yaw(self, t: float) -> float:
        return 0.3 + 0.01 * t

    def velocity_body(self, t: float) -> np.ndarray:
        return np.array([self.speed_m_s, 0.0, 0.0])

    def position(self, t: float) -> np.ndarray:
        """NED position: the integral of the body velocity at yaw(t) (closed form for yaw = a + b t)."""
        a, b, v = 0.3, 0.01, self.speed_m_s
        n = v / b * (np.sin(a + b * t) - np.sin(a))
        e = -v / b * (np.cos(a + b * t) - np.cos(a))
        return np.array([n, e, self.depth(t)])

    def orientation(self, t: float) -> np.ndarray:
        return Rotation.from_euler("ZYX", [self.yaw(t), 0.0, 0.0]).as_quat()

    def stamp(self, t: float) -> int:
        return self.t0_vehicle + int(round(t * 1e9))

    def at_surface(self, t: float) -> bool:
        return self.depth(t) < 0.2

    def geodetic(self, t: float) -> Geodetic:
        p = self.position(t)
        return Geodetic(*to_geodetic(np.array([p[0], p[1], -0.3]), self.datum))  # the antenna, 0.3 m up


def all_traits(fmt: str, dive: Dive = Dive(), seed: int = 0) -> Recording:
    """The acceptance recording: zero-stamped AHRS, the recorder's clock days off, a housing
    pressure sensor beside the depth sensor, a Water Linked DVL beside its twist, a raw IMU, the
    vehicle's own Odometry, NavSatFix with NO_FIX while submerged, housekeeping topics and an
    unknown message type."""
    rng = np.random.default_rng(seed)
    rec = Recording(fmt)
    latency = lambda: int(rng.uniform(2e6, 20e6))  # noqa: E731  recorder latency, 2–20 ms
    R = lambda t: dive.stamp(t) + dive.receive_offset + latency()  # noqa: E731  receive time

    def times(rate):
        return np.arange(0.0, dive.seconds, 1.0 / rate)

    for t in times(20):
        q = dive.orientation(t)
        rec.add("/ahrs/data", "sensor_msgs/msg/Imu", R(t), rec.imu(0, q, np.diag([1e-4, 1e-4, 4e-4]), (0, 0, 0.01)))
    for t in times(50):
        rec.add("/imu/data_raw", "sensor_msgs/msg/Imu", R(t), rec.imu(dive.stamp(t), (0, 0, 0, 1), no_orientation=True))
    rho_g = dive.rho * 9.80665
    for t in times(10):
        p = dive.p_atm + rho_g * dive.depth(t) + rng.normal(0, 0.01 * rho_g)
        rec.add("/pressure", "sensor_msgs/msg/FluidPressure", R(t), rec.pressure(dive.stamp(t), p))
    for t in times(1):
        rec.add("/housing/pressure", "sensor_msgs/msg/FluidPressure", R(t), rec.pressure(dive.stamp(t), 98_000.0))
    for t in times(5):
        v = dive.velocity_body(t) + rng.normal(0, 0.005, 3)
        locked = dive.depth(t) > 0.5
        rec.add(
            "/dvl/data",
            "dvl_msgs/msg/DVL" if not rec.ros1 else "waterlinked_a50_ros_driver/msg/DVL",
            R(t),
            rec.waterlinked_dvl(
                dive.stamp(t),
                v if locked else (0, 0, 0),
                valid=locked,
                cov=np.diag([2.5e-5] * 3) if not rec.ros1 else None,
                fom=0.005,
            ),
        )
        if locked:
            rec.add(
                "/dvl/twist", "geometry_msgs/msg/TwistWithCovarianceStamped", R(t), rec.twist(dive.stamp(t), v, 2.5e-5)
            )
    for t in times(1):
        surface = dive.at_surface(t)
        where = dive.geodetic(t) if surface else None
        msg = rec.navsatfix(dive.stamp(t), where, np.diag([1.0, 1.0, 4.0]), 2, 0 if surface else -1)
        rec.add("/gps/fix", "sensor_msgs/msg/NavSatFix", R(t), msg)
    for t in times(10):
        rec.add(
            "/odometry/filtered",
            "nav_msgs/msg/Odometry",
            R(t),
            rec.odometry(dive.stamp(t), dive.position(t), dive.orientation(t)),
        )
    for t in times(1):
        for topic, msgtype in HOUSEKEEPING.items():
            msgtype = msgtype.replace("rcl_interfaces/msg/Log", "rosgraph_msgs/msg/Log") if rec.ros1 else msgtype
            rec.add(topic, msgtype, R(t), rec.blank(msgtype, dive.stamp(t)))
    return rec
