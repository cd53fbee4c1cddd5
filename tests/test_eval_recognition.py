"""Recognition tables of a run: observations labelled by the ground truth, fused by landmark id."""

import numpy as np
import pytest

from semslam.estimation import EstimatorResult, Trajectory
from semslam.eval import recognition
from semslam.eval.recognition import recognition_block
from semslam.mapping.book import view_key
from semslam.mission import GroundTruthMap, GtObject, MissionMetadata, SensorInfo
from semslam.observations import Connectivity, PointObservation
from semslam.results import LabelledViews, PipelineResult

CLASSES = ("A", "B")


def _setup():
    T_BS = np.eye(4)
    T_BS[:3, 3] = (0.5, 0, 0)
    meta = MissionMetadata(
        sensors={"laser": SensorInfo("laser", "laser", T_BS=T_BS)},
        ground_truth=GroundTruthMap(
            classes=CLASSES, objects=(GtObject(1, "A", (3.5, 0, 0)), GtObject(2, "B", (0.5, 2, 0)))
        ),
    )
    stamps = np.arange(0, 10) * 1_000_000_000
    truth = Trajectory(
        stamps,
        np.column_stack([np.arange(10) * 0.0 + 1.0, np.zeros(10), np.zeros(10)]),
        np.tile([0, 0, 0, 1.0], (10, 1)),
    )
    lik_A, lik_B = {"A": 0.7, "B": 0.3}, {"A": 0.3, "B": 0.7}
    obs = [
        # body at (1,0,0), sensor 0.5 m ahead: object A at (3.5,0,0) is 2 m ahead of the sensor
        PointObservation(stamps[1], "laser", position=[2.0, 0, 0], class_likelihood=lik_A),
        PointObservation(
            stamps[2], "laser", position=[2.01, 0, 0], class_likelihood={"A": 0.4, "B": 0.6}
        ),  # wrong alone
        PointObservation(
            stamps[3], "laser", position=[1.99, 0, 0], class_likelihood=lik_A, connectivity=Connectivity(1, 1)
        ),
        PointObservation(stamps[4], "laser", position=[-1.0, 2, 0], class_likelihood=lik_B),  # object B
        PointObservation(stamps[5], "laser", position=[0.0, -3, 0], class_likelihood=lik_A),  # no object there
    ]
    key = [view_key(o.stamp, o.sensor, o.position) for o in obs]
    history = {"landmark_of_observation": {key[0]: 7, key[1]: 7, key[2]: 7, key[3]: 8}}
    res = EstimatorResult("graph", truth, history=history)
    views = LabelledViews()
    for o in obs:
        views.append(int(o.stamp), o)
    pipe = PipelineResult({"graph": res}, truth, labelled=views)
    return pipe, meta


def test_stages_from_labelled_observations():
    pipe, meta = _setup()
    rec = recognition_block(pipe, meta, syn={"accuracy": 0.9})
    assert rec["SYN"] == {"accuracy": 0.9}
    # the observation far from every true object is not scored
    assert rec["DESC"]["n"] == 4
    # DESC: the second view of A looks like B on its own; fused with the first (same landmark) it is A
    assert rec["DESC"]["accuracy"] == pytest.approx(3 / 4)
    assert rec["BAYS"]["accuracy"] == pytest.approx(1.0)  # 0.7·0.4 for A beats 0.3·0.6 for B
    assert rec["DESC"]["confusion"][0] == [2, 1]


def test_no_ground_truth_no_tables():
    pipe, meta = _setup()
    meta.ground_truth = None
    assert recognition_block(pipe, meta) == {}


def test_labelled_views_give_back_what_the_tables_read():
    """The packed views give back each observation's stamps, sensor, position, likelihoods (their
    order too) and pipe configuration, whatever class set each observation names."""
    obs = [
        PointObservation(5, "laser", position=[0.1, -2.5, 3e-9], class_likelihood={"B": 0.25, "A": 0.75}),
        PointObservation(6, "sonar", position=[1, 2, 3], class_likelihood={"A": 0.5, "C": 0.1, "B": 0.4}),
        PointObservation(
            7, "laser", position=[4, 5, 6], class_likelihood={"B": 0.9, "A": 0.1}, connectivity=Connectivity(3, 4)
        ),
    ]
    views = LabelledViews()
    for i, o in enumerate(obs):
        views.append(100 + i, o)
    got = list(views)
    assert len(views) == len(got) == 3
    for i, (o, v) in enumerate(zip(obs, got)):
        assert (v.stamp, v.view_stamp, v.sensor) == (100 + i, o.stamp, o.sensor)
        assert np.array_equal(v.position, o.position)
        assert list(v.class_likelihood.items()) == list(o.class_likelihood.items())
        assert view_key(v.view_stamp, v.sensor, v.position) == view_key(o.stamp, o.sensor, o.position)
    assert [v.configuration for v in got] == [None, None, 4]


def test_the_tables_of_a_long_survey_never_hold_every_view_at_once(monkeypatch):
    """A 2-hour survey has ~72,000 labelled views: the tables read them a chunk at a time and keep a
    few numbers of each (its true and recognised classes), not every view's Python objects (~2 kB a
    view: its likelihood dict, position array and record), which made the run's memory peak."""
    import tracemalloc

    pipe, meta = _setup()
    recognition_block(pipe, meta)  # what it imports (scipy's rotations) is not what is measured
    monkeypatch.setattr(recognition, "RECORD_CHUNK", 256)  # views placed at once: a constant, kept small here
    n = 5_000
    views, landmark_of = LabelledViews(), pipe.results["graph"].history["landmark_of_observation"]
    for k in range(n):  # object A, 2 m ahead of the sensor, seen from the pose at 1 s, all in landmark 7
        z = PointObservation(1_000_000_000 + k, "laser", position=[2.0, 0, 0], class_likelihood={"A": 0.7, "B": 0.3})
        views.append(1_000_000_000, z)
        landmark_of[view_key(z.stamp, z.sensor, z.position)] = 7
    pipe.labelled = views
    tracemalloc.start()
    try:
        rec = recognition_block(pipe, meta)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert rec["DESC"]["n"] == n and rec["SEM"]["accuracy"] == 1.0
    assert peak < 400 * n, f"{peak / n:.0f} bytes a view at the peak"
