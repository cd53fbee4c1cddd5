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
