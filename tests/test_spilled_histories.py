"""What the estimators append for hours and read only at the end, on disk as it comes (issue 26):
each landmark's views (:class:`semslam.mapping.book.LandmarkBook`) and the covariances of what left
the smoothing window (:class:`semslam.backend.window.LeftCovariances`). Read back, they are what a
plain list per landmark and a plain dict would have held."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import semslam.estimation as estimation
from frontends.oracle import OracleFrontend
from semslam.backend.graph import GraphEstimator
from semslam.backend.keyframes import OnlinePoses
from semslam.backend.result import online_trajectory
from semslam.backend.window import LeftCovariances
from semslam.config import SemslamConfig
from semslam.estimation import SpillError, SpillLog, spilling_into
from semslam.mapping.book import LandmarkBook, view_key
from semslam.observations import LineObservation, PointObservation
from semslam.pipeline import run_pipeline
from tests.support.synthetic_mission import SyntheticConfig, simulate


@pytest.fixture
def small_chunks(monkeypatch):
    monkeypatch.setattr(estimation, "SPILL_CHUNK_ROWS", 5)  # every log spills after 5 rows


def _point(stamp: int, rng, labelled: bool, truth: int | None, sensor: str) -> PointObservation:
    return PointObservation(
        stamp=stamp,
        sensor=sensor,
        position=rng.normal(size=3),
        covariance=np.eye(3),
        class_likelihood={"valve": 0.7, "flange": 0.3} if labelled else None,
        truth_id=truth,
    )


def test_views_come_back_by_landmark_through_merges_and_forgets(small_chunks):
    """Views of tentative tracks merged into landmarks (before and after more views), a duplicate
    merged, a track forgotten: each landmark's views in the order a list extended on each merge
    would hold them, and each labelled view's landmark by its key."""
    rng = np.random.default_rng(7)
    book = LandmarkBook()
    expected: dict = {}  # key -> [(stamp, truth, view key or None)], the plain model
    stamp = 0

    def see(key, labelled=True, truth=3, sensor="laser"):
        nonlocal stamp
        stamp += 1_000_000
        z = _point(stamp - 17, rng, labelled, truth, sensor)
        book.observe(key, stamp, z)
        expected.setdefault(key, []).append(
            (stamp, truth, view_key(z.stamp, z.sensor, z.position) if labelled else None)
        )

    def merge(keep, drop):
        book.merge(keep, drop)
        expected.setdefault(keep, []).extend(expected.pop(drop, []))

    for _ in range(4):
        see(1)
        see("track-a", labelled=False, truth=None)
        see("track-b", sensor="sonar")
    merge(1, "track-a")
    see(1, truth=None)
    see(2, sensor="sonar")
    merge(2, "track-b")
    see(2, labelled=False)
    see("track-c")
    book.forget("track-c")
    expected.pop("track-c")
    merge(1, 2)  # a duplicate
    for _ in range(3):
        see(1)
        see(4, truth=9)
    line = LineObservation(stamp=stamp, sensor="laser", p=np.zeros(3), q=np.ones(3), truth_id=5)
    book.observe(5, stamp, line)
    expected[5] = [(stamp, 5, None)]

    history = book.history([1, 4, 5, 6])
    assert history["landmark_observations"] == {
        1: [(s, t) for s, t, _ in expected[1]],
        4: [(s, t) for s, t, _ in expected[4]],
        5: [(stamp, 5)],
        6: [],
    }
    labelled = {k: lid for lid in (1, 4) for _, _, k in expected[lid] if k is not None}
    assert history["landmark_of_observation"] == labelled
    assert list(history["landmark_of_observation"]) == list(labelled)  # in the order seen
    assert [book.n_views(k) for k in (1, 2, 4, 5, "track-c")] == [len(expected[1]), 0, 3, 1, 0]


def test_left_covariances_are_a_dict_updated_as_they_left():
    rng = np.random.default_rng(1)
    left, plain = LeftCovariances(), {}
    X, L = gtsam.symbol_shorthand.X, gtsam.symbol_shorthand.L
    for slide in range(40):  # 40 slides, over the log's 256 rows in memory
        part = {X(10 * slide): rng.normal(size=(6, 6)), L(slide % 7): rng.normal(size=(3, 3))}
        part[gtsam.symbol_shorthand.P(slide % 3)] = np.asfortranarray(rng.normal(size=(4, 4)))
        left.update(part)
        plain.update(part)
        if slide % 9 == 0:  # read while the window slides on
            assert len(left) == len(plain)
    assert list(left) == list(plain)  # the keys, in the order first given
    for k, c in left.items():
        assert c.shape == plain[k].shape and np.array_equal(c, plain[k])  # bit for bit, the last given
        assert c.flags.f_contiguous  # as GTSAM gives them
    assert X(0) in left and X(1) not in left and len(left) == 40 + 7 + 3


def test_logs_spill_into_the_directory_of_the_enclosing_block(tmp_path, small_chunks):
    """A log given no directory opens its file where the run said, when it opens it; a missing
    directory (as a disk gone) is one line naming it."""
    gone = tmp_path / "gone"
    log = SpillLog("<i8")
    with spilling_into(gone), spilling_into(None):  # None: the enclosing block's
        with pytest.raises(SpillError, match=f"^{gone}: the run's spill file: No such file or directory$"):
            for i in range(5):
                log.append(i)
    elsewhere = SpillLog("<i8")
    with spilling_into(tmp_path):
        for i in range(12):
            elsewhere.append(i)
    assert np.array_equal(elsewhere.array(), np.arange(12))


def _run_small_graph(duration_s: float = 40.0):

    mission = simulate(SyntheticConfig(duration_s=duration_s, n_pipes=0, n_structures=0, seed=3))
    est = GraphEstimator(mission.metadata, SemslamConfig())
    fe = OracleFrontend(mission.metadata, {"seed": 1})
    return est, run_pipeline(mission, [est], [fe], keep_observations=False).results[est.name]


def test_online_poses_come_back_as_the_list_of_poses_held(small_chunks):
    """Each keyframe's online pose (the newest renewed after its landmarks) is on disk past a chunk and
    comes back as the trajectory a list of (stamp, Pose3, covariance) gave."""

    rng = np.random.default_rng(4)
    log, held = OnlinePoses(), []
    for k in range(13):
        for renewed in range(int(rng.integers(1, 3))):  # appended, then renewed once or not at all
            pose = gtsam.Pose3(gtsam.Rot3.Expmap(rng.normal(size=3)), rng.normal(size=3))
            cov = rng.normal(size=(3, 3))
            if renewed:
                log.renew(pose, cov)
                held[-1] = (held[-1][0], pose, cov)
            else:
                log.append(1000 + k, pose, cov)
                held.append((1000 + k, pose, cov))
    assert len(log) == 13 and log._rows._spilled == 10  # two chunks on disk, the newest not yet in the log
    traj = online_trajectory(log.array())
    assert np.array_equal(traj.stamps, [s for s, _, _ in held])
    assert np.array_equal(traj.positions, [p.translation() for _, p, _ in held])
    assert np.array_equal(
        traj.orientations, [Rotation.from_matrix(p.rotation().matrix()).as_quat() for _, p, _ in held]
    )
    assert np.array_equal(traj.position_cov, [c for _, _, c in held])


def test_graph_keeps_a_chunk_of_its_timings_and_online_poses(small_chunks):
    """What the graph appends an update or a keyframe (its timings, each keyframe's online pose) is on
    disk past a chunk during the mission, and the result has every one of them."""
    est, result = _run_small_graph()
    n_updates, n_keyframes = len(result.update_times_s), len(result.online_trajectory)
    assert n_updates > 20 and n_keyframes > 20
    assert est.updates._buffered < 5 and est.updates._spilled == n_updates - est.updates._buffered
    assert est.keyframes.online._rows._buffered < 5 and len(est.keyframes.online) == n_keyframes
    kinds = result.history["update_kinds"]
    assert len(kinds) == len(result.update_n_landmarks) == len(result.history["update_cpu_s"]) == n_updates
    assert set(kinds) <= {"gps", "keyframe", "observations"} and "observations" in kinds
    assert result.update_n_landmarks.dtype == int and result.update_n_landmarks[-1] == len(est.map)
    assert np.array_equal(result.online_trajectory.stamps, est.keyframes.stamps)
