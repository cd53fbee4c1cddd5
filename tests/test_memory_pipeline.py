"""Memory of a long run (issue 26): once the graph's window has filled, what the pipeline and the
estimator keep alive stays the same however long the mission goes on. Counted as live objects (the
observations and ground-truth poses fed), not as bytes."""

import dataclasses
import gc

import pytest

from semslam.config import SemslamConfig
from semslam.estimators import create_estimator
from semslam.eval.recognition import labelled_object_records, recognition_block
from semslam.mapping.book import labelled, view_key
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
        self.fed = self.labelled_fed = self.truth_fed = 0
        self.rows: list[dict] = []
        self._next = None

    def step(self, stamp, measurement, observations, views):
        self.fed += sum(len(obs) for _, obs in observations)
        self.labelled_fed += sum(labelled(z) for _, obs in observations for z in obs)
        self.truth_fed += isinstance(measurement, GroundTruthPose)
        self._next = stamp if self._next is None else self._next
        if stamp >= self._next:
            self._next += self.every_ns
            live = gc.get_objects()
            self.rows.append(
                {
                    "stamp": stamp,
                    "fed": self.fed,
                    "labelled_fed": self.labelled_fed,
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
    # `semslam run`'s records (the labelled views' numbers: no observation), the run the next tests read
    result, filled, end = _run(mission, keep_observations="labelled")
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


def test_labelled_records_keep_numbers_not_observations(mission):
    """`semslam run`'s records: what the recognition tables read of each labelled view, as numbers;
    no observation, labelled or not, stays alive for them."""
    result, filled, end = _run(mission, keep_observations="labelled")
    assert not result.observations and len(result.labelled) >= end["labelled_fed"] > 100  # end: the last sample
    labelled_fed = end["labelled_fed"] - filled["labelled_fed"]
    assert labelled_fed > 100  # the mission went on with labelled views
    # before, the records kept every labelled observation (1.25 kB each) to find its landmark by id()
    assert end["labelled"] - filled["labelled"] < 0.15 * labelled_fed, (filled, end)
    others = [r["observations"] - r["labelled"] for r in (filled, end)]
    assert others[1] - others[0] < 0.15 * (end["fed"] - filled["fed"]), (filled, end)
    # each view's key names it alone, and most views ended in a landmark
    keys = [view_key(v.view_stamp, v.sensor, v.position) for v in result.labelled]
    assert len(set(keys)) == len(keys)
    assert set(result.results["graph"].history["landmark_of_observation"]) <= set(keys)
    records = labelled_object_records(result, mission.metadata)
    assert sum(r.landmark_id is not None for r in records) > 0.5 * len(records)


def test_a_views_key_names_the_landmark_that_holds_that_view(mission):
    """Recognition finds each view's landmark by value (view_key): it is a landmark holding that view."""
    every, _, _ = _run(mission, keep_observations=True)
    history = every.results["graph"].history
    held = {lid: set(views) for lid, views in history["landmark_observations"].items()}
    named = 0
    for r in every.observations:
        z = r.observation
        if not labelled(z):
            continue
        lid = history["landmark_of_observation"].get(view_key(z.stamp, z.sensor, z.position))
        if lid is not None:
            assert (r.stamp, z.truth_id) in held[lid]
            named += 1
    assert named > 100


def test_the_recognition_tables_are_the_same_from_the_labelled_records_alone(mission):
    """`semslam run` keeps only the labelled views' numbers: its recognition tables must not change."""

    every, _, _ = _run(mission, keep_observations=True)
    labelled_only, _, _ = _run(mission, keep_observations="labelled")
    assert len(labelled_only.observations) < len(every.observations)
    table = recognition_block(every, mission.metadata)
    assert table and table.get("SEM"), table  # there is something to compare
    assert recognition_block(labelled_only, mission.metadata) == table
