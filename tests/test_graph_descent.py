"""Views of a tentative landmark are compared with what the pose drifted (north, east, yaw) between them,
not with what it had accumulated since the start (the start at rest's growing uncertainty while the DVL
has no bottom lock: common to every view, it moves the whole map, not one view against another); the
depth, measured absolutely, is each view's own; and a scan's continuations share its pose (stop 37).

Tank world 79 (experiments/estimators/README.md, stop 36): before its first landmark was promoted, the
graph gated its tentative views with the vehicle's absolute pose uncertainty (0.10 m at 4 s, 0.19 m at
16 s under the start at rest), so views of two objects one lattice spacing (0.45 m) apart made one track;
its views, each a factor at its own keyframe, bent the trajectory and the whole map was mapped 0.46 m
north of the truth.
"""

import numpy as np
import pytest

from semslam.backend.graph import GraphEstimator
from semslam.compare import estimators_input
from semslam.config import SemslamConfig
from semslam.mission.measurements import Attitude, Depth, DvlVelocity, GroundTruthPose, PointCloud
from semslam.mission.mission import Mission, MissionMetadata, SensorInfo
from semslam.observations import PointObservation
from semslam.pipeline import run_pipeline
from tests.support.replay import Replay

S = 1_000_000_000
A = np.array([3.0, 0.0, 5.0])  # two objects one lattice spacing apart, seen from the surface
B = A + np.array([0.45, 0.0, 0.0])
# A alone at 6 s, B alone at 8 s (A missed), both from 10 s on
SCANS = {6: [A], 8: [B], **{t: [A, B] for t in range(10, 26, 2)}}


def descent(depth=lambda t: 0.0, depth_variance=1e-4) -> Mission:
    """26 s at rest at the origin (yaw 0, on the surface) with no bottom lock: AHRS, depth (``depth(t)``
    read, t in s), invalid DVL."""
    sensors = {
        n: SensorInfo(n, kind, f"/{n}", "x", np.eye(4))
        for n, kind in (
            ("ahrs", "ahrs"),
            ("depth", "depth"),
            ("dvl", "dvl"),
            ("laser", "laser"),
            ("gt", "ground_truth"),
        )
    }
    q, ms = np.array([0.0, 0.0, 0.0, 1.0]), []
    acov = np.diag(np.radians([0.1, 0.1, 0.3]) ** 2)
    ms += [Attitude(k * S // 20, "ahrs", orientation=q, covariance=acov) for k in range(26 * 20)]
    ms += [Depth(k * S // 8 + 1, "depth", depth=depth(k / 8), variance=depth_variance) for k in range(26 * 8)]
    nan = np.full(3, np.nan)
    ms += [DvlVelocity(k * S // 5 + 2, "dvl", velocity=nan, covariance=np.eye(3), valid=False) for k in range(26 * 5)]
    ms += [GroundTruthPose(k * S // 10 + 3, "gt", position=np.zeros(3), orientation=q) for k in range(26 * 10)]
    ms += [PointCloud(t * S + 4, "laser") for t in range(2, 26, 2)]
    return Mission.from_measurements(MissionMetadata(name="descent", sensors=sensors), ms)


def mapped(mission: Mission, scans: dict, sigma: dict | None = None):
    """The graph on ``mission`` with the objects of ``scans`` (s → positions) seen exactly where they
    are, with a declared σ of 5 mm (or ``sigma[t]``): its objects sorted along north, and its trajectory."""
    config = SemslamConfig()  # the start at rest on (σ 0.1 m/s): the pose's σ grows to ~0.15 m by 24 s
    est = GraphEstimator(mission.metadata, config)
    seen = {
        t * S + 4: [
            PointObservation(t * S + 4, "laser", position=p, covariance=np.eye(3) * (sigma or {}).get(t, 0.005) ** 2)
            for p in ps
        ]
        for t, ps in scans.items()
    }
    result = run_pipeline(estimators_input(mission, config), [est], [Replay(seen)], keep_observations=False)
    graph = result.results["graph"]
    objects = sorted((lm.position for lm in graph.landmarks if lm.kind == "object"), key=lambda p: p[0])
    return objects, graph.trajectory


def test_two_objects_a_lattice_spacing_apart_seen_in_turn_during_the_descent_stay_two_landmarks():
    objects, trajectory = mapped(descent(), SCANS)
    assert len(objects) == 2
    np.testing.assert_allclose(objects, [A, B], atol=0.03)
    # the vehicle held where it was: no view of B bent its pose onto A
    assert np.abs(trajectory.positions[:, :2]).max() < 0.03


def test_the_depth_sensors_noise_between_two_views_does_not_give_the_object_to_its_neighbour():
    """Tank world 10 (stop 37): the pressure sensor's noise (σ 2 cm a reading) moved the vehicle's depth
    estimate 3.5 cm between an object's first view and the scan that saw it with its neighbour 0.42 m
    away. Depth is measured absolutely: that error is each pose's own, not shared with the track's
    first view, so the object's view stays its track's and the neighbour's starts another."""
    b = A + np.array([0.42, 0.0, -0.035])  # 3.5 cm higher: its view lands at the depth of A's first
    scans = {4: [A], **{t: [A, b] for t in range(10, 26, 2)}}
    # the vehicle stays on the surface; from 9 s the depth sensor reads 3.5 cm deeper
    objects, trajectory = mapped(descent(lambda t: 0.035 * (t > 9), depth_variance=0.02**2), scans)
    assert len(objects) == 2
    np.testing.assert_allclose(np.array(objects)[:, :2], [A[:2], b[:2]], atol=0.03)  # their depths: the sensor's
    assert np.abs(trajectory.positions[:, :2]).max() < 0.03


def test_a_view_does_not_join_a_neighbours_track_while_the_scans_other_view_stays_on_its_own():
    """Tank world 79 (stop 37): objects P and Q seen at 2 s, then, 12 s later without bottom lock, Q and
    R, R a lattice spacing (0.45 m) north of P, P out of view. Alone, R's view passes P's track (the pose
    drifted up to 0.17 m meanwhile); with Q's view on its own track in the same scan, it would need
    the scan's pose to have both stayed and moved 0.45 m: the two continuations are jointly
    incompatible and R's view starts its own track."""
    q, r = A + np.array([0.0, 0.6, 0.0]), A + np.array([0.45, 0.0, 0.0])
    scans = {2: [A, q], **{t: [q, r] for t in range(14, 26, 2)}}
    objects, trajectory = mapped(descent(), scans)
    assert len(objects) == 2  # P, seen once, stays tentative
    np.testing.assert_allclose(sorted(objects, key=lambda p: p[1]), [r, q], atol=0.03)
    assert np.abs(trajectory.positions[:, :2]).max() < 0.03


def wrong_first_view(depth):
    scans = {2: [A + np.array([0.16, 0.0, 0.0])], **{t: [A] for t in range(6, 26, 2)}}
    return mapped(descent(depth=depth), scans, sigma={2: 0.02})


@pytest.mark.xfail(strict=True, reason="issue 21, tank world 78: open (experiments/estimators/README.md, stop 38)")
def test_a_wrong_first_view_of_an_object_does_not_move_the_map():
    """Tank world 78 (stop 38): the laser front-end put the first scan's view of a valve 16 cm north of
    it (declared σ 2 cm). Without bottom lock the drift over the next 4 s lets it into the valve's
    track; promoted, its factor at the first keyframe, held only by the start prior (σ 0.1 m), pulls
    the whole solution north (here the object is mapped 15 cm north of where every later view puts
    it). No graph-side rule tells it from the drift yet: this test fails until one does. Here the
    vehicle dives from the start (0.1 m/s), so the start at rest's zero readings have their loose σ
    (0.1 m/s) throughout (the depth never says it waits): the drift of stop 38."""
    objects, trajectory = wrong_first_view(lambda t: 0.1 * t)
    assert len(objects) == 1
    np.testing.assert_allclose(objects[0], A, atol=0.03)
    assert np.abs(trajectory.positions[:, :2]).max() < 0.03


def test_a_wrong_first_view_while_the_vehicle_waits_does_not_move_the_map():
    """The same views with the vehicle waiting at its depth (stop 41): the start at rest's zero readings
    have the waiting σ (0.01 m/s), the pose hardly drifts, and the wrong view stays out of the valve's
    track (here, as in stop 38's account of world 78, the first view comes at 2 s, before the dive; world
    78's 10 cm offset went with this change, not traced further)."""
    objects, trajectory = wrong_first_view(lambda t: 0.0)
    assert len(objects) == 1
    np.testing.assert_allclose(objects[0], A, atol=0.03)
    assert np.abs(trajectory.positions[:, :2]).max() < 0.03


def test_a_row_seen_again_after_the_drift_is_not_shifted_onto_its_neighbours_tracks():
    """Tank world 79 (stop 38): objects A and B seen at 2 s, then from 16 s on, without bottom lock, B and
    C, C a lattice spacing (0.45 m) beyond B. After 14 s of drift the row shifted by one spacing (B's
    view on A's track, C's on B's: d² 7.1 each, off by the same 0.45 m, which the scan's common drift
    explains, so the joint test passes) costs 14.2 against the right assignment's 16.3 (B's view on B's
    track, C's starting one). Committed to the cheaper, the mixed tracks promote and tie the first
    keyframe to a site one spacing away: main maps A and B instead of B and C and moves the vehicle
    0.45 m. With odds of 3:1 either way, which track is which object is in doubt: the two old tracks
    are forgotten and the views start tracks of their own."""
    c = B + np.array([0.45, 0.0, 0.0])
    scans = {2: [A, B], **{t: [B, c] for t in range(16, 26, 2)}}
    objects, trajectory = mapped(descent(), scans)
    assert len(objects) == 2  # A, seen once, is not mapped
    np.testing.assert_allclose(objects, [B, c], atol=0.03)
    assert np.abs(trajectory.positions[:, :2]).max() < 0.03
