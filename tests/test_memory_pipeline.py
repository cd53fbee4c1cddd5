"""Memory of a long run (issue 26): once the graph's window has filled, what the pipeline and the
estimator keep alive stays the same however long the mission goes on. Counted as live objects (the
observations and ground-truth poses fed), not as bytes."""

import dataclasses
import gc

import pytest

from semslam.config import SemslamConfig
from semslam.estimators import create_estimator
from semslam.mapping.book import labelled
from semslam.mission.measurements import GroundTruthPose
from semslam.mission.mission import Mission
from semslam.observations import Observation
from semslam.pipeline import run_pipeline
from semslam.registry import create_frontends
from tests.support.synthetic_mission import SyntheticConfig, simulate

WINDOW_S = 30.0  # slides from 45 s on


class LiveObjects:
    """A pipeline observer: every ``every_s`` of mission, the observations fed so far and the
    observation and ground-truth objects alive."""

    def __init__(self, every_s: float):
        self.every_ns = int(every_s * 1e9)
        self.fed = self.truth_fed = 0
        self.rows: list[dict] = []
        self._next = None

    def step(self, stamp, measurement, observations, views):
        self.fed += sum(len(obs) for _, obs in observations)
        self.truth_fed += isinstance(measurement, GroundTruthPose)
        self._next = stamp if self._next is None else self._next
        if stamp >= self._next:
            self._next += self.every_ns
            live = gc.get_objects()
            self.rows.append(
                {
                    "stamp": stamp,
                    "fed": self.fed,
                    "truth_fed": self.truth_fed,
                    "observations": sum(isinstance(o, Observation) for o in live),
                    "labelled": sum(isinstance(o, Observation) and labelled(o) for o in live),
                    "truth": sum(isinstance(o, GroundTruthPose) for o in live),
                }
            )


@pytest.fixture(scope="module")
def mission():
    """A synthetic mission whose ground-truth poses are made as they are read, as a bag's are (the
    synthetic one holds every measurement in a list)."""
    listed = simulate(SyntheticConfig(duration_s=150.0, seed=5))
    return Mission(
        listed.metadata,
        lambda: (dataclasses.replace(m) if isinstance(m, GroundTruthPose) else m for m in listed),
    )


_RUNS: dict = {}  # (mission, keep_observations) -> one run's outcome: the tests read the same runs


def _run(mission, keep_observations):
    key = (id(mission), keep_observations)
    if key not in _RUNS:
        _RUNS[key] = _run_once(mission, keep_observations)
    return _RUNS[key]


def _run_once(mission, keep_observations):
    cfg = SemslamConfig(graph={"window_s": WINDOW_S}, association={"track_timeout_s": 10.0})
    est = create_estimator("graph", mission.metadata, cfg)
    fes = create_frontends(["oracle"], mission.metadata, {"oracle": {"seed": 1}})
    live = LiveObjects(every_s=10.0)
    result = run_pipeline(
        mission, [est], fes, keep_observations=keep_observations, frontend_process=False, observers=[live]
    )
    filled = next(r for r in live.rows if (r["stamp"] - live.rows[0]["stamp"]) * 1e-9 >= 2 * WINDOW_S)
    return result, filled, live.rows[-1]


def test_after_the_window_filled_no_observation_or_truth_pose_is_kept_per_second(mission):
    result, filled, end = _run(mission, keep_observations=False)
    fed = end["fed"] - filled["fed"]
    assert fed > 200 and end["truth_fed"] - filled["truth_fed"] > 1000  # the mission went on
    # what is alive is the window's (factors, tentative tracks), not the mission's: before, the map's
    # book kept every view and the pipeline every ground-truth pose
    assert end["observations"] - filled["observations"] < 0.15 * fed, (filled, end)
    assert end["truth"] - filled["truth"] < 10, (filled, end)
    # what the results need is there all the same: the truth at its full rate, every view counted
    assert len(result.truth) == end["truth_fed"]
    views = sum(lm.n_observations for lm in result.results["graph"].landmarks)
    assert views > 0.5 * end["fed"]


def test_labelled_records_keep_the_recognition_observations_alone(mission):
    result, filled, end = _run(mission, keep_observations="labelled")
    assert result.observations and all(labelled(r.observation) for r in result.observations)
    # the records are all that grows: the other observations are not kept
    others = [r["observations"] - r["labelled"] for r in (filled, end)]
    assert others[1] - others[0] < 0.15 * (end["fed"] - filled["fed"]), (filled, end)
    # each record's landmark, by identity, as the recognition tables look it up
    landmark_of = result.results["graph"].history["landmark_of_observation"]
    found = [landmark_of.get(id(r.observation)) for r in result.observations]
    assert sum(f is not None for f in found) > 0.5 * len(found)


def test_the_recognition_tables_are_the_same_from_the_labelled_records_alone(mission):
    """`semslam run` keeps only the labelled records: its recognition tables must not change."""
    from semslam.eval.recognition import recognition_block

    every, _, _ = _run(mission, keep_observations=True)
    labelled_only, _, _ = _run(mission, keep_observations="labelled")
    assert len(labelled_only.observations) < len(every.observations)
    table = recognition_block(every, mission.metadata)
    assert table and table.get("SEM"), table  # there is something to compare
    assert recognition_block(labelled_only, mission.metadata) == table
