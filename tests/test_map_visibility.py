"""Was a mapped object seen when it was in view (semslam.mapping.visibility, both estimators' rule):
a false object from a burst of front-end views is left out of the final map once the scans that see
the pipe beside it show it is not there; a real object seen scan after scan stays."""

import numpy as np

from semslam.config import AssociationConfig
from semslam.mapping.visibility import InView

PIPE = np.array([[[0.0, 0.0, 3.0], [0.5, 0.0, 3.0]]])  # a pipe seen in every scan
REAL, FALSE = np.array([0.6, 0.0, 3.0]), np.array([0.55, 0.05, 3.0])  # a valve at its end; a burst's "object"
FAR = np.array([[[3.0, 0.0, 3.0], [3.5, 0.0, 3.0]]])


def test_an_object_not_seen_while_its_place_is_in_view_is_unconfirmed():
    a = AssociationConfig()
    log = InView(a.object_view_reach_m)
    log.start(1, seen=3, in_view=3)  # the real valve, promoted at its third view in three scans
    log.start(2, seen=3, in_view=3)  # the burst: three views in three scans, then never again
    ids, at = [1, 2], np.array([REAL, FALSE])
    for _ in range(40):
        log.scan(ids, at, np.zeros((0, 3)), PIPE, seen={1})
    assert log.unconfirmed(a.object_confirm_ratio, a.object_confirm_scans) == {2}
    assert (log.seen[1], log.in_view[1], log.seen[2], log.in_view[2]) == (43, 43, 3, 43)
    # too few scans to judge: kept
    early = InView(a.object_view_reach_m)
    early.start(2, seen=3, in_view=3)
    for _ in range(a.object_confirm_scans - 4):
        early.scan([2], np.array([FALSE]), np.zeros((0, 3)), PIPE, seen=set())
    assert early.unconfirmed(a.object_confirm_ratio, a.object_confirm_scans) == set()
    # scans that saw only something far away do not count; 0 turns the rule off
    away = InView(a.object_view_reach_m)
    away.start(2, seen=3, in_view=3)
    for _ in range(40):
        away.scan([2], np.array([FALSE]), np.zeros((0, 3)), FAR, seen=set())
    assert away.in_view[2] == 3 and away.unconfirmed(a.object_confirm_ratio, 1) == set()
    assert log.unconfirmed(0.0, a.object_confirm_scans) == set()


def test_merged_objects_add_their_views():
    log = InView(0.3)
    log.start(1, seen=30, in_view=40)
    log.start(2, seen=10, in_view=40)
    log.merge(1, 2)
    assert (log.seen, log.in_view) == ({1: 40}, {1: 40})


def test_metrics_say_how_many_objects_were_left_out():
    from semslam.estimation import EstimatorResult, Trajectory
    from semslam.eval.metrics import estimator_metrics

    empty = Trajectory(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 4)))
    told = EstimatorResult("graph", empty, history={"objects_left_out": 2})
    assert estimator_metrics(told, None, None, None)["objects_left_out"] == 2
    # an estimator without map building (dead reckoning) says nothing: null, not 0
    assert estimator_metrics(EstimatorResult("dr", empty), None, None, None)["objects_left_out"] is None


def test_a_valve_outside_a_narrow_view_is_not_in_view_while_the_pipe_beside_it_is():
    """A narrow camera (±10° × ±7.5°, {S} z forward) passes along a pipe; the valve at the pipe's end
    is inside its frame in 6 scans (seen in 4: partly buried) and just outside it, the pipe seen up to
    0.1-0.25 m short of it, in 20 more. Only the scans with the valve's place in the view count."""
    from semslam.mapping.visibility import SensorView

    a = AssociationConfig()
    view = SensorView()
    edge = np.array([[np.tan(np.radians(10)), np.tan(np.radians(7.5)), 1.0]])
    view.add(np.vstack([edge * 1.2, edge * [-1.4, -1.4, 1.4], [[0.0, 0.0, -1.0]]]))  # behind: ignored
    assert np.allclose(view.tan, [np.tan(np.radians(10)), np.tan(np.radians(7.5))]) and view.far == 1.4
    at_1m = np.tan(np.radians(7.5))  # the frame's half height at 1 m
    valve_S = np.array([[0.0, at_1m - 0.02, 1.0], [0.0, at_1m + 0.04, 1.0], [0.0, at_1m + 0.15, 1.0]])
    assert view.contains(valve_S, 0.05).tolist() == [True, True, False]  # inside, within the margin, out
    assert view.contains(np.array([[0.0, 0.0, 1.43], [0.0, 0.0, 1.5]]), 0.05).tolist() == [True, False]  # range

    valve = np.array([[0.6, 0.0, 3.0]])
    log, before = InView(a.object_view_reach_m), InView(a.object_view_reach_m)
    for lg in (log, before):
        lg.start(1, seen=3, in_view=4)
    for k in range(26):
        in_frame = k < 6
        seen = {1} if k < 4 else set()
        log.scan([1], valve, np.zeros((0, 3)), PIPE, seen, lambda places, f=in_frame: np.full(len(places), f))
        before.scan([1], valve, np.zeros((0, 3)), PIPE, seen)  # main's rule: the pipe within reach counts
    assert (log.seen[1], log.in_view[1]) == (7, 10) and log.unconfirmed(a.object_confirm_ratio, 1) == set()
    assert before.in_view[1] == 30 and before.unconfirmed(a.object_confirm_ratio, 1) == {1}
    # a seen object counts in view whatever the view says (a view is proof of sight)
    log.scan([1], valve, np.zeros((0, 3)), np.zeros((0, 2, 3)), {1}, lambda places: np.zeros(len(places), bool))
    assert (log.seen[1], log.in_view[1]) == (8, 11)
