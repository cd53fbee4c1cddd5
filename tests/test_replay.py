"""replay.mcap read back with rosbags: every topic, counts that match the run, stamps within the
mission, frames that agree with each other and with the estimates."""

from __future__ import annotations

from collections import defaultdict

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from semslam.config import SemslamConfig
from semslam.estimation import EstimatorResult, LandmarkEstimate, Trajectory
from semslam.eval import ros_messages as rm
from semslam.eval.replay import ReplayConfig, ReplayRecorder
from semslam.mission import GroundTruthPose, Mission, MissionMetadata, PointCloud, SensorInfo
from semslam.models.cad import CLASS_COLORS, CLASSES
from semslam.observations import LineObservation, PointObservation
from semslam.pipeline import run_pipeline

ESTIMATORS = ("dr", "ekf", "graph")


def read_bag(path) -> dict[str, list[tuple[int, object]]]:
    """topic → [(log time, message)] of an MCAP file, decoded with rosbags."""
    from rosbags.rosbag2 import Reader

    out = defaultdict(list)
    with Reader(path) as reader:
        for conn, stamp, raw in reader.messages():
            out[conn.topic].append((stamp, rm.STORE.deserialize_cdr(raw, conn.msgtype)))
    return dict(out)


def ns(msg) -> int:
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


def xyz(v) -> np.ndarray:
    return np.array([v.x, v.y, v.z])


def quat(q) -> np.ndarray:
    return np.array([q.x, q.y, q.z, q.w])


@pytest.fixture(scope="module")
def synthetic_run(tmp_path_factory):
    """dr, ekf and graph with the oracle front-end on a 60 s synthetic mission with ground truth,
    recorded and written as a replay."""
    from semslam.estimators import create_estimator
    from semslam.registry import create_frontends
    from tests.support.synthetic_mission import SyntheticConfig, simulate

    mission = simulate(SyntheticConfig(duration_s=60.0, seed=4))
    cfg = SemslamConfig()
    ests = [create_estimator(n, mission.metadata, cfg) for n in ESTIMATORS]
    fes = create_frontends(["oracle"], mission.metadata, cfg.frontends)
    rec = ReplayRecorder(mission.metadata)
    result = run_pipeline(mission, ests, fes, observers=[rec])
    path = tmp_path_factory.mktemp("replay") / "replay.mcap"
    counts = rec.write(path, result)
    stamps = [m.stamp for m in mission]
    return mission, result, rec, counts, read_bag(path), (min(stamps), max(stamps))


def test_every_topic_is_there_and_counted(synthetic_run):
    mission, result, rec, counts, bag, _ = synthetic_run
    expected = {"/tf_static", "/tf", "/semslam/scan/laser"}
    expected |= {f"/semslam/{e}/{t}" for e in (*ESTIMATORS, "truth") for t in ("pose", "path")}
    expected |= {"/semslam/graph/map", "/semslam/ekf/map", "/semslam/truth/map"}
    assert set(bag) == expected
    assert {t: len(m) for t, m in bag.items()} == counts
    assert len(bag["/semslam/scan/laser"]) == sum(isinstance(m, PointCloud) for m in mission)


def test_stamps_within_the_mission(synthetic_run):
    *_, bag, (first, last) = synthetic_run
    for topic, msgs in bag.items():
        for log_time, msg in msgs:
            assert first <= log_time <= last, topic
            stamped = [msg] if hasattr(msg, "header") else getattr(msg, "transforms", None) or msg.markers
            assert all(ns(m) == log_time for m in stamped), topic


def test_one_pose_per_keyframe_or_update_at_most_the_configured_rate(synthetic_run):
    _, result, rec, _, bag, _ = synthetic_run
    period = 1e9 / rec.config.pose_rate_hz
    for name in ESTIMATORS:
        traj = result.results[name].online_trajectory
        poses = bag[f"/semslam/{name}/pose"]
        stamps = np.array([ns(m) for _, m in poses])
        assert np.all(np.diff(stamps) >= period)
        # every pose is the estimator's at that stamp, with its position covariance
        idx = np.searchsorted(traj.stamps, stamps)
        assert np.array_equal(traj.stamps[idx], stamps)
        for (_, m), i in zip(poses, idx):
            assert np.allclose(xyz(m.pose.pose.position), traj.positions[i])
            assert np.allclose(np.abs(quat(m.pose.pose.orientation)), np.abs(traj.orientations[i]))
            assert np.allclose(m.pose.covariance.reshape(6, 6)[:3, :3], traj.position_cov[i])
            assert m.header.frame_id == "world"
        # and none is left out that came at least a period after the one before
        kept = set(stamps.tolist())
        last = None
        for s in traj.stamps:
            if last is None or s - last >= period:
                assert s in kept
                last = s
    graph = result.results["graph"].online_trajectory
    assert np.min(np.diff(graph.stamps)) >= period  # keyframes are sparser than the rate: one pose each
    assert len(bag["/semslam/graph/pose"]) == len(graph)


def test_transforms_agree_with_poses_and_mounts(synthetic_run):
    mission, result, _, _, bag, _ = synthetic_run
    ((_, static),) = bag["/tf_static"]
    edges = {(t.header.frame_id, t.child_frame_id): t.transform for t in static.transforms}
    R = Rotation.from_quat(quat(edges[("map", "world")].rotation)).as_matrix()
    assert np.allclose(R @ [1, 2, 3], [2, 1, -3])  # NED in ENU: east, north, up
    for sensor in ("dvl", "laser"):
        tf = edges[("graph/base_link", f"graph/{sensor}")]
        T_BS = mission.metadata.sensors[sensor].T_BS
        assert np.allclose(xyz(tf.translation), T_BS[:3, 3])
        assert np.allclose(Rotation.from_quat(quat(tf.rotation)).as_matrix(), T_BS[:3, :3])
    poses = {ns(m): xyz(m.pose.pose.position) for _, m in bag["/semslam/graph/pose"]}
    graph_tf = [t for _, m in bag["/tf"] for t in m.transforms if t.child_frame_id == "graph/base_link"]
    assert len(graph_tf) == len(poses) and all(t.header.frame_id == "world" for t in graph_tf)
    assert all(np.allclose(xyz(t.transform.translation), poses[ns(t)]) for t in graph_tf)


def test_paths_grow_and_end_with_the_final_trajectory(synthetic_run):
    _, result, rec, _, bag, (first, last) = synthetic_run
    paths = bag["/semslam/graph/path"]
    # every period after the start, the last one at the end of the mission
    assert len(paths) == int(np.ceil((last - first) / (rec.config.path_period_s * 1e9)))
    assert ns(paths[0][1]) == first + rec.config.path_period_s * 1e9 and ns(paths[-1][1]) == last
    sizes = [len(m.poses) for _, m in paths]
    assert sizes == sorted(sizes) and sizes[0] > 0
    final = result.results["graph"].trajectory
    _, end = paths[-1]
    at = np.searchsorted(final.stamps, [ns(p) for p in end.poses])
    assert np.allclose([xyz(p.pose.position) for p in end.poses], final.positions[at])


def test_map_markers_stand_where_the_map_has_its_landmarks(synthetic_run):
    mission, result, rec, _, bag, _ = synthetic_run
    final = {lm.id: lm for lm in result.results["graph"].landmarks}
    log_time, last_map = bag["/semslam/graph/map"][-1]
    assert last_map.markers[0].action == rm.Marker.DELETEALL
    spheres = {m.id: m for m in last_map.markers if m.ns == "objects"}
    assert set(spheres) == {i for i, lm in final.items() if lm.kind == "object"}
    for i, m in spheres.items():
        assert m.header.frame_id == "world" and np.allclose(xyz(m.pose.position), final[i].position)
    cylinders = {m.id: m for m in last_map.markers if m.ns == "pipes"}
    for i, m in cylinders.items():
        p, q = final[i].p, final[i].q
        assert np.allclose(xyz(m.pose.position), (p + q) / 2) and np.isclose(m.scale.z, np.linalg.norm(q - p))
        axis = Rotation.from_quat(quat(m.pose.orientation)).apply([0, 0, 1])
        assert np.isclose(abs(axis @ (q - p)) / np.linalg.norm(q - p), 1.0)
    # structures as their CAD mesh (triangles in the model frame) placed at their pose
    structures = {m.id: m for m in last_map.markers if m.ns == "structures"}
    assert structures and set(structures) == {i for i, lm in final.items() if lm.kind == "structure"}
    for i, m in structures.items():
        assert m.type == rm.Marker.TRIANGLE_LIST and len(m.points) % 3 == 0 and len(m.points) > 0
        assert np.allclose(xyz(m.pose.position), final[i].pose[:3, 3])
        R = Rotation.from_quat(quat(m.pose.orientation)).as_matrix()
        assert np.allclose(R, final[i].pose[:3, :3], atol=1e-6)
    # the final map (a smoother's covariances come at the end) has an ellipsoid per object
    assert {m.id for m in last_map.markers if m.ns == "ellipsoids"} >= set(spheres)
    # the truth, once, at its true positions
    ((_, truth),) = bag["/semslam/truth/map"]
    truth_objects = {m.id: xyz(m.pose.position) for m in truth.markers if m.ns == "truth_objects"}
    gt = mission.metadata.ground_truth
    assert truth_objects.keys() == {o.id for o in gt.objects}
    assert all(np.allclose(truth_objects[o.id], o.position) for o in gt.objects)
    # map updates are those the recorder saw change, and the EKF's follow its own estimate
    assert len(bag["/semslam/graph/map"]) == len(rec.map_updates("graph", result.results["graph"].landmarks))
    ekf_final = {lm.id: lm.position for lm in result.results["ekf"].landmarks if lm.kind == "object"}
    _, ekf_last = bag["/semslam/ekf/map"][-1]
    assert all(np.allclose(xyz(m.pose.position), ekf_final[m.id]) for m in ekf_last.markers if m.ns == "objects")


# ------------------------------------------------------------------ a scripted run: exact expectations
T_BS = np.eye(4)
T_BS[:3, :3] = Rotation.from_euler("y", 90, degrees=True).as_matrix()  # laser looking down
T_BS[:3, 3] = (0.5, 0.0, 0.2)


class Scripted:
    """An estimator whose map after the k-th observation batch is ``maps[k]`` and whose trajectory is
    a straight run north at 1 m/s, heading east (yaw 90°)."""

    name = "graph"

    def __init__(self, maps):
        self.maps, self.k, self.stamps = maps, 0, []

    def process_measurement(self, m):
        self.stamps.append(m.stamp)

    def process_observations(self, stamp, obs):
        self.k += 1

    def view(self):
        return self

    def pose_at(self, stamp):
        return None

    def landmarks(self):
        return self.maps[min(self.k, len(self.maps) - 1)]

    def trajectory(self) -> Trajectory:
        s = np.array(sorted(set(self.stamps)), np.int64)
        pos = np.column_stack([s * 1e-9, np.zeros(len(s)), np.full(len(s), 2.0)])
        q = np.tile(Rotation.from_euler("z", 90, degrees=True).as_quat(), (len(s), 1))
        return Trajectory(s, pos, q, position_cov=np.tile(np.eye(3) * 0.01, (len(s), 1, 1)))

    def finish(self):
        return EstimatorResult(self.name, self.trajectory(), self.landmarks())


class Segmenting:
    """A front-end that finds an object in the first 10 points of each scan and a pipe along y = 1."""

    name = "seg"
    consumes = (PointCloud,)

    def process(self, m, view):
        obj = PointObservation(m.stamp, m.sensor, position=m.points[:10].mean(0), cloud=m.points[:10],
                               class_likelihood={"Elbow": 0.8, "R-Tee": 0.2})  # fmt: skip
        pipe = LineObservation(m.stamp, m.sensor, p=[0, 1, 0], q=[3, 1, 0], radius=0.05)
        return [obj, pipe]


def _obj(i, x, cls="Elbow", p=0.9):
    other = "R-Tee" if cls == "Elbow" else "Elbow"
    return LandmarkEstimate(i, "object", position=np.array([x, 0, 3.0]), class_posterior={cls: p, other: 1 - p})


def _scripted_mission(n_scans=8):
    rng = np.random.default_rng(1)
    grid = np.array([(x, y, 0.0) for x in np.arange(0, 3, 0.1) for y in np.arange(-1, 1.5, 0.1)], np.float32)
    ms = []
    for k in range(n_scans):
        t = (k + 1) * 1_000_000_000
        ms.append(GroundTruthPose(t - 1, "gt", position=[k, 0, 2], orientation=[0, 0, 0, 1]))
        far = grid + [5.0, 5.0, 0.0]  # away from the pipe: points the front-end labelled nothing
        ms.append(PointCloud(t, "laser", points=np.vstack([rng.normal(0, 0.01, (10, 3)) + [2, -0.5, 0.5], grid, far])))
    meta = MissionMetadata(
        sensors={"laser": SensorInfo("laser", "laser", T_BS=T_BS), "gt": SensorInfo("gt", "ground_truth")}
    )
    return Mission.from_measurements(meta, ms)


def test_one_marker_update_per_map_change(tmp_path):
    o0 = _obj(0, 1.0)
    pipe = LandmarkEstimate(1, "pipe", p=np.array([0, 1, 3.0]), q=np.array([2, 1, 3.0]))
    maps = [
        [],  # before any observation
        [o0],  # 1: new object -> update
        [o0],  # 2: same
        [_obj(0, 1.001)],  # 3: moved 1 mm (< tolerance 5 mm): no update
        [_obj(0, 1.02)],  # 4: moved 2 cm -> update
        [_obj(0, 1.02), pipe],  # 5: a pipe -> update
        [_obj(0, 1.02, "R-Tee", 0.6), pipe],  # 6: its class changed -> update
        [_obj(0, 1.02, "R-Tee", 0.6), pipe],  # 7: same
    ]

    def updates(period_s):
        cfg = ReplayConfig(map_tolerance_m=0.005, map_period_s=period_s, map_estimators=("graph",))
        rec = ReplayRecorder(_scripted_mission().metadata, cfg)
        result = run_pipeline(_scripted_mission(), [Scripted(maps)], [Segmenting()], observers=[rec])
        rec.write(tmp_path / "r.mcap", result)
        out = read_bag(tmp_path / "r.mcap")["/semslam/graph/map"]
        (tmp_path / "r.mcap").unlink()
        return out

    assert [t // 1_000_000_000 for t, _ in updates(0.0)] == [1, 4, 5, 6]  # scans 1, 4, 5, 6 changed the map
    # read every 2 s (scans 1, 3, 5, 7): changes seen at 1, 5 (moved, a pipe) and 7 (class)
    assert [t // 1_000_000_000 for t, _ in updates(2.0)] == [1, 5, 7]
    updates = updates(0.0)
    _, fourth = updates[-1]
    by_ns = defaultdict(list)
    for m in fourth.markers:
        by_ns[m.ns].append(m)
    assert [m.text for m in by_ns["labels"]] == ["0 R-Tee 0.60"]
    (sphere,) = by_ns["objects"]
    assert np.allclose([sphere.color.r, sphere.color.g, sphere.color.b], CLASS_COLORS["R-Tee"])
    (cyl,) = by_ns["pipes"]
    assert np.isclose(cyl.scale.x, 2 * 0.05)  # the radius the front-end measured


def test_scans_in_the_world_with_the_front_ends_segmentation(tmp_path):
    mission = _scripted_mission(n_scans=3)
    est = Scripted([[]])
    cfg = ReplayConfig(scan_voxel_m=0.0, scan_points=10_000, label_tolerance_m=0.02, map_estimators=())
    rec = ReplayRecorder(mission.metadata, cfg)
    result = run_pipeline(mission, [est], [Segmenting()], observers=[rec])
    rec.write(tmp_path / "r.mcap", result)
    scans = read_bag(tmp_path / "r.mcap")["/semslam/scan/laser"]
    assert len(scans) == 3
    raw = [m for m in mission if isinstance(m, PointCloud)]
    for (_, msg), m in zip(scans, raw):
        pts = rm.cloud_points(msg)
        assert msg.header.frame_id == "world" and ns(msg) == m.stamp and len(pts) == len(m.points)
        # T_WB from the estimator's trajectory at the scan: at x = t (s), z = 2, heading east
        R_WB = Rotation.from_euler("z", 90, degrees=True).as_matrix()
        expected = (m.points @ T_BS[:3, :3].T + T_BS[:3, 3]) @ R_WB.T + [m.stamp * 1e-9, 0, 2]
        assert np.allclose(np.column_stack([pts["x"], pts["y"], pts["z"]]), expected, atol=1e-5)
        seg = pts["segment"]
        assert np.all(seg[:10] == 2) and np.all(pts["class"][:10] == CLASSES.index("Elbow"))
        rgb = pts["rgb"][0]
        assert np.allclose(
            [(rgb >> 16) & 255, (rgb >> 8) & 255, rgb & 255], np.round(np.array(CLASS_COLORS["Elbow"]) * 255)
        )
        on_pipe = np.abs(m.points[10:, 1] - 1) <= 0.05 + 0.02 + 1e-6  # within radius + tolerance of y = 1
        on_pipe &= np.abs(m.points[10:, 2]) <= 0.07
        assert np.array_equal(seg[10:] == 1, on_pipe)
        assert np.all(seg[10:][~on_pipe] == 0)


def test_a_thinned_scan_keeps_what_the_front_end_labelled_first():
    from semslam.eval.scan_segments import SEGMENT_OBJECT, SegmentedScan, keep_at_most

    n = 1000
    segment = np.zeros(n, np.uint8)
    segment[[3, 500, 999]] = SEGMENT_OBJECT
    scan = SegmentedScan(
        0,
        "laser",
        np.arange(3 * n, dtype=np.float32).reshape(n, 3),
        segment,
        segment.copy(),
        np.zeros((n, 3), np.uint8),
    )
    kept = keep_at_most(scan, 50, seed=7)
    assert len(kept.points) == 50 and np.sum(kept.segment == SEGMENT_OBJECT) == 3
    assert np.all(np.diff(kept.points[:, 0]) > 0)  # in scan order
    assert np.array_equal(keep_at_most(scan, 50, seed=7).points, kept.points)  # the same scan, the same points
    assert keep_at_most(scan, 2000, seed=7) is scan
