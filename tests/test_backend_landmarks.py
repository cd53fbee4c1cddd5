"""Landmark bookkeeping: collinear pipe-segment merge (0.175 rad / 0.3 m) and class posteriors."""

import numpy as np
import pytest

from semslam.mapping.book import LandmarkBook
from semslam.mapping.pipes import collinear, merge_collinear
from semslam.observations import LineObservation


def seg(p, q, tid=None, sensor="laser"):
    return LineObservation(
        0, sensor, p=np.array(p, float), q=np.array(q, float), covariance=np.eye(6) * 1e-4, truth_id=tid
    )


def test_collinear_thresholds():
    a = ([0, 0, 0], [1, 0, 0])
    assert collinear(*map(np.array, a), np.array([1.2, 0, 0]), np.array([2.0, 0, 0]), 0.175, 0.3)  # gap 0.2
    assert not collinear(*map(np.array, a), np.array([1.4, 0, 0]), np.array([2.0, 0, 0]), 0.175, 0.3)  # gap 0.4
    assert not collinear(*map(np.array, a), np.array([0.5, 0.35, 0]), np.array([2.0, 0.35, 0]), 0.175, 0.3)  # offset
    tilt = 0.2  # > 0.175 rad
    assert not collinear(
        *map(np.array, a), np.array([0.5, 0, 0]), np.array([0.5 + np.cos(tilt), np.sin(tilt), 0]), 0.175, 0.3
    )
    # Order of the endpoints does not matter.
    assert collinear(np.array([1.0, 0, 0]), np.zeros(3), np.array([2.0, 0, 0]), np.array([1.1, 0, 0]), 0.175, 0.3)


def test_merge_collinear_spans_all_members():
    out = merge_collinear(
        [seg([0, 0, 0], [1, 0, 0], 1), seg([1.1, 0.01, 0], [2.5, 0.0, 0], 1), seg([0, 2, 0], [1, 2, 0], 2)], 0.175, 0.3
    )
    assert len(out) == 2
    merged = max(out, key=lambda o: np.linalg.norm(o.q - o.p))
    assert sorted([merged.p[0], merged.q[0]]) == pytest.approx([0.0, 2.5])
    assert merged.truth_id == 1
    # Chains merge transitively (union-find), other sensors are never merged.
    out = merge_collinear(
        [seg([0, 0, 0], [1, 0, 0]), seg([1.2, 0, 0], [2, 0, 0]), seg([2.2, 0, 0], [3, 0, 0])], 0.175, 0.3
    )
    assert len(out) == 1
    assert (
        len(merge_collinear([seg([0, 0, 0], [1, 0, 0]), seg([1.1, 0, 0], [2, 0, 0], sensor="other")], 0.175, 0.3)) == 2
    )


def _posterior(likelihoods):
    """A landmark's class posterior in the shared book, from views with these likelihood vectors."""
    from semslam.observations import PointObservation

    book = LandmarkBook()
    for k, lk in enumerate(likelihoods):
        book.observe(1, k, PointObservation(k, "laser", class_likelihood=lk))
    return book.class_posterior(1)


def test_class_posterior_is_normalised_product():
    lk = [{"a": 0.8, "b": 0.1, "c": 0.1}, {"a": 0.1, "b": 0.8, "c": 0.1}, {"a": 0.8, "b": 0.1, "c": 0.1}]
    post = _posterior(lk)
    expected = np.array([0.8 * 0.1 * 0.8, 0.1 * 0.8 * 0.1, 0.1 * 0.1 * 0.1])
    np.testing.assert_allclose([post["a"], post["b"], post["c"]], expected / expected.sum())
    assert _posterior([]) is None
    # Many confident views do not underflow.
    post = _posterior([{"a": 1e-200, "b": 1.0}] * 50 + [{"a": 1.0, "b": 1e-300}])
    assert np.isfinite(list(post.values())).all() and np.isclose(sum(post.values()), 1.0)


def test_landmark_report_keys_truth_ids_by_kind():
    """Object 3 and pipe 3 are different things: one landmark each is no duplicate; two object
    landmarks of object 3 are."""
    import numpy as np

    from semslam.estimation import EstimatorResult, LandmarkEstimate, Trajectory
    from semslam.mission.ground_truth import GroundTruthMap, GtObject, GtPipe
    from tests.support.synthetic_mission import landmark_report

    gt = GroundTruthMap(
        objects=(GtObject(3, "Elbow", (0.0, 0.0, 1.0)),), pipes=(GtPipe(3, (1.0, 0, 1), (2.0, 0, 1), 0.03),)
    )
    obj = LandmarkEstimate(0, "object", position=np.array([0.0, 0.0, 1.0]))
    pipe = LandmarkEstimate(1, "pipe", p=np.array([1.0, 0, 1]), q=np.array([2.0, 0, 1]))
    hist = {"landmark_observations": {0: [(0, 3)], 1: [(0, 3)]}}
    none = Trajectory(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 4)))
    res = EstimatorResult("graph", none, [obj, pipe], history=hist)
    assert landmark_report(res, gt).duplicated == []
    twin = LandmarkEstimate(2, "object", position=np.array([0.01, 0.0, 1.0]))
    hist["landmark_observations"][2] = [(1, 3)]
    res = EstimatorResult("graph", res.trajectory, [obj, pipe, twin], history=hist)
    assert landmark_report(res, gt).duplicated == [("object", 3)]


class _SensorAt:
    """The one thing merging a batch's segments asks of an estimator: where the sensor is."""

    def __init__(self, T_WS):
        self.T_WS = T_WS

    def sensor_pose(self, sensor):
        return self.T_WS


def test_a_mapped_in_line_object_keeps_two_collinear_pipe_views_apart():
    """Two collinear segments 0.2 m apart (closer than the paper's 0.3 m merge distance) merge into
    one pipe view, unless an object lies between them: one seen in the same scan or, when the
    scan missed it, one already mapped (or tracked) there."""
    from semslam.config import AssociationConfig
    from semslam.mapping.builder import MapBuilder
    from semslam.observations import LineObservation, PointObservation

    T_WS = np.eye(4)
    T_WS[:3, :3] = [[np.cos(0.3), -np.sin(0.3), 0], [np.sin(0.3), np.cos(0.3), 0], [0, 0, 1]]
    T_WS[:3, 3] = [1.0, 2.0, 3.0]
    builder = MapBuilder(_SensorAt(T_WS), AssociationConfig(), LandmarkBook(), [])
    a = LineObservation(0, "laser", p=[-0.6, 0.0, 2.0], q=[-0.1, 0.0, 2.0], covariance=np.eye(6) * 1e-4)
    b = LineObservation(0, "laser", p=[0.1, 0.0, 2.0], q=[0.6, 0.0, 2.0], covariance=np.eye(6) * 1e-4)
    none = np.zeros((0, 3))
    assert len(builder.merge_lines([a, b], none)) == 1
    valve_S = np.array([0.0, 0.02, 2.0])
    seen = PointObservation(0, "laser", position=valve_S, covariance=np.eye(3) * 1e-4)
    assert len([z for z in builder.merge_lines([a, b, seen], none) if isinstance(z, LineObservation)]) == 2
    valve_W = T_WS[:3, :3] @ valve_S + T_WS[:3, 3]
    assert len(builder.merge_lines([a, b], valve_W[None])) == 2
    assert len(builder.merge_lines([a, b], valve_W[None] + 0.5)) == 1  # mapped elsewhere


def test_the_builders_sight_test_places_the_mapped_and_tentative_objects_in_the_batchs_sensor_view():
    """``MapBuilder._in_sight``: the sensor's view grown by the batch's observations, then a function of
    places in {W} (the mapped objects for the confirmation, the tentative ones for the promotion)."""
    from semslam.config import AssociationConfig
    from semslam.mapping.builder import MapBuilder

    T_WS = np.eye(4)
    T_WS[:3, :3] = [[np.cos(0.3), -np.sin(0.3), 0], [np.sin(0.3), np.cos(0.3), 0], [0, 0, 1]]
    T_WS[:3, 3] = [1.0, 2.0, 3.0]
    builder = MapBuilder(_SensorAt(T_WS), AssociationConfig(), LandmarkBook(), [])
    tx, ty = np.tan(np.radians(10)), np.tan(np.radians(7.5))
    pipe = LineObservation(0, "laser", p=[-tx * 1.2, -ty * 1.2, 1.2], q=[tx * 1.2, ty * 1.2, 1.2])
    sight = builder._in_sight([pipe])
    in_S = np.array([[0.0, 0.0, 1.0], [0.0, ty + 0.04, 1.0], [0.0, ty + 0.2, 1.0], [0.0, 0.0, 1.4]])
    in_W = in_S @ T_WS[:3, :3].T + T_WS[:3, 3]
    assert sight(in_W).tolist() == [True, True, False, False]
    assert sight(np.zeros((0, 3))).shape == (0,)
    off = MapBuilder(_SensorAt(T_WS), AssociationConfig(object_view_margin_m=None), LandmarkBook(), [])
    assert off._in_sight([pipe]) is None
