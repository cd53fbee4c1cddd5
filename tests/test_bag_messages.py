"""Reading messages written by other tools: field layouts, REP conventions, COLA2 DVL beam flags."""

from __future__ import annotations

import sqlite3
from pathlib import Path

import numpy as np
import pytest

from semslam.errors import MissionError
from semslam.mission import Attitude, Depth, DvlVelocity, PointCloud, SonarSwath
from semslam.mission.bag import read_mission, write_mission
from semslam.mission.config import ReaderConfig

MSG_DIR = Path(__file__).resolve().parents[1] / "semslam" / "mission" / "msgs" / "cola2_msgs" / "msg"


def store_with_cola2(ros_version: int):
    """A fresh rosbags type store plus cola2_msgs, built here from the shipped .msg files."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC if ros_version == 1 else Stores.ROS2_HUMBLE)
    types = {}
    for name in ("DVLBeam", "DVL"):
        types.update(get_types_from_msg((MSG_DIR / f"{name}.msg").read_text(), f"cola2_msgs/msg/{name}"))
    store.register(types)
    return store


def write_raw(path: Path, ros_version: int, topics: dict[str, tuple[str, list]], store) -> Path:
    """Write messages with rosbags directly: topic → (msgtype, [(stamp ns, message)])."""
    if ros_version == 1:
        from rosbags.rosbag1 import Writer

        writer, ser = Writer(path), store.serialize_ros1
    else:
        from rosbags.rosbag2 import Writer

        writer, ser = Writer(path, version=9), store.serialize_cdr
    with writer:
        for topic, (msgtype, msgs) in topics.items():
            conn = writer.add_connection(topic, msgtype, typestore=store)
            for t, msg in msgs:
                writer.write(conn, t, ser(msg, msgtype))
    return path


def header(store, ros_version, t, frame="s"):
    T = store.types
    stamp = T["builtin_interfaces/msg/Time"](sec=t // 10**9, nanosec=t % 10**9)
    if ros_version == 1:
        return T["std_msgs/msg/Header"](seq=0, stamp=stamp, frame_id=frame)
    return T["std_msgs/msg/Header"](stamp=stamp, frame_id=frame)


def cola2_dvl(store, ros_version, t, beams, marked_invalid=False, altitude=3.0):
    T = store.types
    pose = T["geometry_msgs/msg/PoseStamped"](
        header=header(store, ros_version, t),
        pose=T["geometry_msgs/msg/Pose"](
            position=T["geometry_msgs/msg/Point"](x=0.0, y=0.0, z=0.0),
            orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
        ),
    )
    return T["cola2_msgs/msg/DVL"](
        header=header(store, ros_version, t),
        velocity=T["geometry_msgs/msg/Vector3"](x=0.5, y=-0.1, z=0.02),
        velocity_covariance=np.full(9, -1.0) if marked_invalid else np.diag([1e-4, 1e-4, 4e-4]).reshape(9),
        altitude=altitude,
        beams=[
            T["cola2_msgs/msg/DVLBeam"](range=r, range_covariance=0.0, velocity=v, velocity_covariance=vc, pose=pose)
            for r, v, vc in beams
        ],
    )


GOOD = (3.2, 0.4, 1e-4)
NO_RANGE = (-1.0, 0.0, -1.0)
NAN_VEL = (3.2, float("nan"), 1e-4)


@pytest.mark.parametrize("ros_version", [1, 2])
def test_cola2_dvl_validity_from_beam_flags(tmp_path, ros_version):
    store = store_with_cola2(ros_version)
    cases = [
        ([GOOD] * 4, False, (True,) * 4, True),
        ([GOOD, GOOD, GOOD, NO_RANGE], False, (True, True, True, False), True),  # 3 of 4 is enough
        ([GOOD, NO_RANGE, NAN_VEL, GOOD], False, (True, False, False, True), False),  # 2 of 4 is not
        ([GOOD] * 4, True, (True,) * 4, False),  # covariance marked -1: invalid whatever the beams
        ([], False, None, True),  # no beams: the covariance marker alone decides
    ]
    t0 = 10**9
    msgs = [
        (t0 + k * 200_000_000, cola2_dvl(store, ros_version, t0 + k * 200_000_000, b, inv))
        for k, (b, inv, _, _) in enumerate(cases)
    ]
    name = "dvl.bag" if ros_version == 1 else "dvl_ros2"
    path = write_raw(tmp_path / name, ros_version, {"/girona500/navigator/dvl": ("cola2_msgs/msg/DVL", msgs)}, store)

    m = read_mission(path)
    assert m.metadata.sensors["girona500/navigator/dvl"].kind == "dvl"
    out = list(m)
    assert all(isinstance(x, DvlVelocity) for x in out)
    assert [x.beam_valid for x in out] == [c[2] for c in cases]
    assert [x.valid for x in out] == [c[3] for c in cases]
    np.testing.assert_allclose(out[0].velocity, [0.5, -0.1, 0.02])
    np.testing.assert_allclose(out[0].covariance, np.diag([1e-4, 1e-4, 4e-4]))
    assert out[0].altitude == 3.0
    assert np.isnan(out[3].covariance).all()  # an invalid reading's covariance says nothing

    # the threshold is configurable
    lenient = list(read_mission(path, ReaderConfig(dvl_min_valid_beams=2)))
    assert [x.valid for x in lenient] == [True, True, True, False, True]


def test_ros2_bag_without_embedded_definitions_uses_shipped_ones(tmp_path):
    """A Humble-era sqlite3 bag stores no message definitions; cola2_msgs/DVL must still read."""
    store = store_with_cola2(2)
    msgs = [(10**9, cola2_dvl(store, 2, 10**9, [GOOD] * 4))]
    path = write_raw(tmp_path / "humble", 2, {"/dvl": ("cola2_msgs/msg/DVL", msgs)}, store)
    with sqlite3.connect(next(path.glob("*.db3"))) as db:
        db.execute("DELETE FROM message_definitions")
    (x,) = list(read_mission(path))
    assert x.valid and x.beam_valid == (True,) * 4


@pytest.mark.parametrize("ros_version", [1, 2])
def test_pointcloud2_any_layout(tmp_path, ros_version):
    """Fields out of order, float64 coordinates, uint16 intensity, padding, organised cloud, big endian."""
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC if ros_version == 1 else Stores.ROS2_HUMBLE)
    T = store.types
    rng = np.random.default_rng(1)
    h, w = 3, 5
    pts = rng.normal(size=(h * w, 3))
    pts[4] = np.nan  # an invalid point of an organised (is_dense=False) cloud
    inten = rng.integers(0, 60000, h * w).astype(np.uint16)
    msgs = []
    for k, big in enumerate((False, True)):
        e = ">" if big else "<"
        # layout: intensity u2 @0, pad, z f8 @8, x f8 @16, pad, y f8 @32; point_step 48; 16 bytes row padding
        dt = np.dtype(
            {
                "names": ["intensity", "z", "x", "y"],
                "formats": [e + "u2", e + "f8", e + "f8", e + "f8"],
                "offsets": [0, 8, 16, 32],
                "itemsize": 48,
            }
        )
        rec = np.zeros(h * w, dt)
        rec["x"], rec["y"], rec["z"], rec["intensity"] = pts[:, 0], pts[:, 1], pts[:, 2], inten
        rows = rec.view(np.uint8).reshape(h, w * 48)
        data = np.concatenate([rows, np.full((h, 16), 0xAB, np.uint8)], axis=1).reshape(-1)
        PF = T["sensor_msgs/msg/PointField"]
        t = 10**9 * (k + 1)
        msgs.append(
            (
                t,
                T["sensor_msgs/msg/PointCloud2"](
                    header=header(store, ros_version, t),
                    height=h,
                    width=w,
                    fields=[
                        PF(name="y", offset=32, datatype=8, count=1),
                        PF(name="intensity", offset=0, datatype=4, count=1),
                        PF(name="x", offset=16, datatype=8, count=1),
                        PF(name="z", offset=8, datatype=8, count=1),
                    ],
                    is_bigendian=big,
                    point_step=48,
                    row_step=w * 48 + 16,
                    data=data,
                    is_dense=False,
                ),
            )
        )
    path = write_raw(
        tmp_path / ("pc.bag" if ros_version == 1 else "pc"),
        ros_version,
        {"/cloud": ("sensor_msgs/msg/PointCloud2", msgs)},
        store,
    )
    keep = np.ones(h * w, bool)
    keep[4] = False
    for cloud in read_mission(path):
        assert isinstance(cloud, PointCloud)
        np.testing.assert_array_equal(cloud.points, pts[keep].astype(np.float32))
        np.testing.assert_array_equal(cloud.intensity, inten[keep].astype(np.float32))


def test_imu_pressure_laserscan_conventions(tmp_path):
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    T = store.types
    v3 = lambda x, y, z: T["geometry_msgs/msg/Vector3"](x=x, y=y, z=z)  # noqa: E731
    q = T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=np.sin(0.25), w=np.cos(0.25))
    ocov = np.diag([1e-4, 1e-4, 1e-3]).reshape(9)
    no = np.array([-1.0] + [0.0] * 8)
    imu = lambda t, oc, wc: T["sensor_msgs/msg/Imu"](  # noqa: E731
        header=header(store, 2, t),
        orientation=q,
        orientation_covariance=oc,
        angular_velocity=v3(0.1, 0.2, 0.3),
        angular_velocity_covariance=wc,
        linear_acceleration=v3(0, 0, 9.8),
        linear_acceleration_covariance=no,
    )
    cfg = ReaderConfig(water_density_kg_m3=1000.0, atmospheric_pressure_pa=100000.0, gravity_m_s2=10.0)
    pressure = [
        (t, T["sensor_msgs/msg/FluidPressure"](header=header(store, 2, t), fluid_pressure=p, variance=var))
        for t, p, var in [(10**9, 100000.0 + 10000.0 * 12.5, 1e4), (2 * 10**9, 100000.0, 0.0)]
    ]
    inf = np.inf
    ranges = np.array([1.0, inf, 0.05, 5.0, 50.0, np.nan, 2.5], np.float32)  # range limits [0.1, 40]
    scan = T["sensor_msgs/msg/LaserScan"](
        header=header(store, 2, 10**9),
        angle_min=-0.3,
        angle_max=0.3,
        angle_increment=0.1,
        time_increment=0.0,
        scan_time=0.0,
        range_min=0.1,
        range_max=40.0,
        ranges=ranges,
        intensities=np.arange(7, dtype=np.float32),
    )
    path = write_raw(
        tmp_path / "std",
        2,
        {
            "/imu": (
                "sensor_msgs/msg/Imu",
                [
                    (10**9, imu(10**9, ocov, np.zeros(9))),
                    (2 * 10**9, imu(2 * 10**9, ocov, no)),
                    (3 * 10**9, imu(3 * 10**9, no, np.zeros(9))),
                ],
            ),
            "/pressure": ("sensor_msgs/msg/FluidPressure", pressure),
            "/scan": ("sensor_msgs/msg/LaserScan", [(10**9, scan)]),
        },
        store,
    )
    m = read_mission(path, cfg)
    out = {s: [x for x in m if x.sensor == s] for s in ("imu", "pressure", "scan")}
    a, b = out["imu"]  # the third Imu has no orientation (REP 145): not an AHRS reading
    assert isinstance(a, Attitude)
    np.testing.assert_allclose(a.orientation, [0, 0, np.sin(0.25), np.cos(0.25)])
    np.testing.assert_allclose(a.covariance, np.diag([1e-4, 1e-4, 1e-3]))
    np.testing.assert_allclose(a.angular_rate, [0.1, 0.2, 0.3])
    assert b.angular_rate is None  # angular_velocity_covariance[0] == -1
    assert m.dropped["imu"] == 1 and m.dropped_fields["imu"] == {"orientation_covariance": 1}
    d1, d2 = out["pressure"]
    assert isinstance(d1, Depth) and d1.depth == pytest.approx(12.5) and d1.variance == pytest.approx(1e-4)
    assert d2.depth == pytest.approx(0.0)
    (s,) = out["scan"]
    assert isinstance(s, SonarSwath)
    np.testing.assert_allclose(s.angles, [-0.3, 0.0, 0.3], atol=1e-6)  # beams 0, 3, 6
    np.testing.assert_allclose(s.ranges, [1.0, 5.0, 2.5])
    np.testing.assert_allclose(s.intensities, [0.0, 3.0, 6.0])


def test_twist_dvl_validity_marker(tmp_path):
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC)
    T = store.types

    def twist(t, cov00):
        cov = np.zeros(36)
        cov[0], cov[7], cov[14] = cov00, 2e-4, 3e-4
        tw = T["geometry_msgs/msg/Twist"](
            linear=T["geometry_msgs/msg/Vector3"](x=1.0, y=0.0, z=0.0),
            angular=T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
        )
        return t, T["geometry_msgs/msg/TwistWithCovarianceStamped"](
            header=header(store, 1, t), twist=T["geometry_msgs/msg/TwistWithCovariance"](twist=tw, covariance=cov)
        )

    path = write_raw(
        tmp_path / "tw.bag",
        1,
        {"/dvl": ("geometry_msgs/msg/TwistWithCovarianceStamped", [twist(10**9, 1e-4), twist(2 * 10**9, -1.0)])},
        store,
    )
    a, b = list(read_mission(path))
    assert a.valid and not b.valid and a.beam_valid is None
    np.testing.assert_allclose(a.covariance, np.diag([1e-4, 2e-4, 3e-4]))
    # written back as cola2_msgs/DVL, validity survives
    back = list(read_mission(write_mission(read_mission(path), tmp_path / "back.bag")))
    assert [x.valid for x in back] == [True, False]


def _latency_bag(path: Path, late_s: float, clock_offset_s: float = 0.0) -> Path:
    """/fast stamped t + 50 ms recorded at once; /slow stamped t recorded ``late_s`` later.

    The recording clock runs ``clock_offset_s`` ahead of the header stamps (wall vs simulated time).
    """
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC)
    T = store.types
    fp = lambda t: T["sensor_msgs/msg/FluidPressure"](header=header(store, 1, t), fluid_pressure=101325.0, variance=1.0)  # noqa: E731
    off = int(clock_offset_s * 1e9)
    with Writer(path) as w:
        slow = w.add_connection("/slow", "sensor_msgs/msg/FluidPressure", typestore=store)
        fast = w.add_connection("/fast", "sensor_msgs/msg/FluidPressure", typestore=store)
        for k in range(40):
            t = 10**9 + k * 100_000_000
            w.write(
                fast, off + t + 1_000_000, store.serialize_ros1(fp(t + 50_000_000), "sensor_msgs/msg/FluidPressure")
            )
            w.write(slow, off + t + int(late_s * 1e9), store.serialize_ros1(fp(t), "sensor_msgs/msg/FluidPressure"))
    return path


def both_pressures(**kw) -> ReaderConfig:
    """Both depth topics of ``_latency_bag`` bound (unbound, only one depth sensor would be read)."""
    topics = {"slow": "/slow", "fast": "/fast"}
    return ReaderConfig(sensors={n: {"topic": t, "kind": "depth"} for n, t in topics.items()}, **kw)


@pytest.mark.parametrize("clock_offset_s", [0.0, 1.7e9])
def test_reorder_buffer_releases_in_header_stamp_order(tmp_path, clock_offset_s):
    """Recording time ≠ header stamp (latency differs per sensor): the stream follows header stamps."""
    path = _latency_bag(tmp_path / "lat.bag", late_s=0.5, clock_offset_s=clock_offset_s)
    stamps = [m.stamp for m in read_mission(path, both_pressures())]
    assert len(stamps) == 80 and stamps == sorted(stamps)


def test_message_later_than_reorder_window_is_an_error(tmp_path):
    path = _latency_bag(tmp_path / "lat.bag", late_s=1.0)
    with pytest.raises(
        MissionError,
        match=r"topic /slow: message stamped 1.000000 s arrived after messages "
        r"stamped more than reorder_window_s=0.5 s later",
    ):
        list(read_mission(path, both_pressures(reorder_window_s=0.5)))
    assert len(list(read_mission(path, both_pressures()))) == 80  # the default 2 s window absorbs it


def test_ros2_directory_with_mcap_storage(tmp_path, sample_mission):
    """`ros2 bag record -s mcap` makes a directory with metadata.yaml and an .mcap file."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    from semslam.mission.typestore import typestore

    store = typestore(2)
    mission = sample_mission(seconds=0.5)
    path = tmp_path / "rec"
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        conns = {}
        from semslam.mission.conversions import MSGTYPE_OF, Encoder

        enc = Encoder(store, 2, ReaderConfig())
        for m in mission:
            msgtype = MSGTYPE_OF[type(m)]
            if m.sensor not in conns:
                conns[m.sensor] = w.add_connection("/" + m.sensor, msgtype, typestore=store)
            w.write(conns[m.sensor], m.stamp, store.serialize_cdr(enc.encode(m, m.sensor), msgtype))
    assert any(path.glob("*.mcap"))
    back = read_mission(path)
    # Without a sidecar, an Odometry topic is the vehicle's navigation, never ground truth.
    assert sorted(back.metadata.sensors) == sorted(set(mission.metadata.sensors) - {"gt"})
    assert len(list(back)) == len([m for m in mission if m.sensor != "gt"])
    (gt,) = back.plan.binding.alternatives("ground_truth")
    assert gt.topic == "/gt" and "not ground truth" in gt.reason


@pytest.mark.parametrize(
    "fields, data_len, expected",
    [
        ([("x", 0), ("y", 4)], 24, "topic /cloud: field fields: no 'z' field (have ['x', 'y'])"),
        ([("x", 0), ("y", 4), ("z", 8)], 20, "topic /cloud: field data: 20 bytes, expected 24 (2 points × 12)"),
    ],
)
def test_malformed_pointcloud2_is_one_clear_error(tmp_path, fields, data_len, expected):
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC)
    T = store.types
    PF = T["sensor_msgs/msg/PointField"]
    msg = T["sensor_msgs/msg/PointCloud2"](
        header=header(store, 1, 10**9),
        height=1,
        width=2,
        fields=[PF(name=n, offset=o, datatype=7, count=1) for n, o in fields],
        is_bigendian=False,
        point_step=12,
        row_step=24,
        data=np.zeros(data_len, np.uint8),
        is_dense=True,
    )
    path = write_raw(tmp_path / "bad.bag", 1, {"/cloud": ("sensor_msgs/msg/PointCloud2", [(10**9, msg)])}, store)
    with pytest.raises(MissionError) as err:
        list(read_mission(path))
    assert str(err.value) == f"{path}: {expected} (message at t=1.000000 s)"


def test_uniform_grid_of_sparse_and_irregular_swaths():
    from semslam.mission.conversions import Unencodable, uniform_grid

    inc = float(np.float32(np.deg2rad(0.5)))
    for kept in ([0, 1, 2, 3], [0, 2, 5], [0, 17, 35], [4, 100, 101, 239]):
        angles = float(np.float32(-1.0)) + np.array(kept) * inc
        a0, step, idx = uniform_grid(angles)
        np.testing.assert_allclose(float(a0) + idx * float(step), angles, atol=1e-6)
        assert np.all(np.diff(idx) > 0)
    with pytest.raises(Unencodable, match="not on a uniform grid"):
        uniform_grid(np.array([0.0, 0.1, 0.1 * np.pi, 0.7]))


def _ros1_odometry_imu_bag(path: Path, broken: bytes | None = None) -> Path:
    """A ROS 1 bag of Odometry and Imu messages covering what their decoders distinguish (no orientation,
    no angular rate, NaN, a header stamp of 0), plus optionally one raw Odometry message ``broken``."""
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC)
    T = store.types
    v3 = lambda x, y, z: T["geometry_msgs/msg/Vector3"](x=x, y=y, z=z)  # noqa: E731
    quat = lambda a: T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=np.sin(a), w=np.cos(a) if a == a else 1.0)  # noqa: E731
    ocov, no = np.diag([1e-4, 1e-4, 1e-3]).reshape(9), np.array([-1.0] + [0.0] * 8)

    def imu(t, stamp, q, oc, wc):
        return T["sensor_msgs/msg/Imu"](
            header=header(store, 1, stamp, frame="ahrs_ü"),
            orientation=q,
            orientation_covariance=oc,
            angular_velocity=v3(0.1, -0.2, 0.3),
            angular_velocity_covariance=wc,
            linear_acceleration=v3(0, 0, 9.8),
            linear_acceleration_covariance=no,
        )

    def odom(t, x):
        pwc = T["geometry_msgs/msg/PoseWithCovariance"](
            pose=T["geometry_msgs/msg/Pose"](
                position=T["geometry_msgs/msg/Point"](x=x, y=-2.5, z=1e-3 * t / 1e9), orientation=quat(0.2)
            ),
            covariance=np.arange(36.0),
        )
        twc = T["geometry_msgs/msg/TwistWithCovariance"](
            twist=T["geometry_msgs/msg/Twist"](linear=v3(1, 2, 3), angular=v3(4, 5, 6)), covariance=np.ones(36)
        )
        return T["nav_msgs/msg/Odometry"](header=header(store, 1, t), child_frame_id="base", pose=pwc, twist=twc)

    s = 10**9
    imus = [
        (s, imu(s, s, quat(0.25), ocov, np.zeros(9))),
        (2 * s, imu(2 * s, 0, quat(0.3), ocov, no)),
        (3 * s, imu(3 * s, 3 * s, quat(0.3), no, np.zeros(9))),
        (4 * s, imu(4 * s, 4 * s, quat(np.nan), ocov, no)),
    ]
    odoms = [(t, odom(t, x)) for t, x in [(s, 0.5), (2 * s, np.inf), (3 * s, 1.0 / 3.0)]]
    with Writer(path) as writer:
        ci = writer.add_connection("/imu", "sensor_msgs/msg/Imu", typestore=store)
        co = writer.add_connection("/odom", "nav_msgs/msg/Odometry", typestore=store)
        for t, m in imus:
            writer.write(ci, t, store.serialize_ros1(m, "sensor_msgs/msg/Imu"))
        for t, m in odoms:
            writer.write(co, t, store.serialize_ros1(m, "nav_msgs/msg/Odometry"))
        if broken is not None:
            writer.write(co, 5 * s, broken)
    return path


def _read_all(path: Path, fast: bool, on_nonfinite: str = "drop"):
    import semslam.mission.bag_reader as bag_reader

    saved = bag_reader.ROS1_FAST
    bag_reader.ROS1_FAST = saved if fast else {}
    bound = {"imu": {"topic": "/imu", "kind": "ahrs"}, "odom": {"topic": "/odom", "kind": "ground_truth"}}
    try:
        m = read_mission(path, ReaderConfig(sensors=bound, on_nonfinite=on_nonfinite))
        exact = lambda v: (v.dtype.str, v.shape, v.tobytes()) if isinstance(v, np.ndarray) else repr(v)  # noqa: E731
        return [(type(x), [(k, exact(v)) for k, v in vars(x).items()]) for x in m], dict(m.dropped_fields)
    except MissionError as exc:
        return str(exc)
    finally:
        bag_reader.ROS1_FAST = saved


def test_ros1_fast_path_gives_the_general_paths_measurements_and_errors(tmp_path):
    """ROS 1 Odometry and Imu are parsed from their bytes (semslam.mission.conversions.ROS1_FAST):
    the same measurements, drops and errors as through rosbags' message objects."""
    path = _ros1_odometry_imu_bag(tmp_path / "ok.bag")
    from semslam.mission.bag_reader import _fast_paths, open_bag

    with open_bag(path) as reader:
        assert set(_fast_paths(reader, reader.connections, 1)) == {"/imu", "/odom"}
    fast, general = _read_all(path, True), _read_all(path, False)
    assert fast == general
    assert len(fast[0]) == 4 and fast[1] == {
        "imu": {"orientation_covariance": 1, "orientation": 1},
        "odom": {"position": 1},
    }
    assert "field position is not finite" in _read_all(path, True, "error") == _read_all(path, False, "error")

    raw = _first_raw(path, "/odom")  # broken variants: truncated, too long, cut in the header, a frame id
    bad_utf8 = raw.replace(b"base", b"ba\xffe")
    # that is not UTF-8, a frame id longer than the message
    for i, broken in enumerate(
        [raw[:-8], raw + b"\0" * 8, raw[:14], bad_utf8, raw[:12] + b"\xff\xff\xff\x7f" + raw[16:]]
    ):
        p = _ros1_odometry_imu_bag(tmp_path / f"bad{i}.bag", broken)
        err = _read_all(p, True)
        assert (
            isinstance(err, str)
            and "topic /odom: message at t=5.000000 s cannot be decoded as nav_msgs/Odometry" in err
        )
        assert err == _read_all(p, False)


def _first_raw(path: Path, topic: str) -> bytes:
    from rosbags.rosbag1 import Reader

    with Reader(path) as r:
        return next(raw for c, _, raw in r.messages() if c.topic == topic)
