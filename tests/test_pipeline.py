"""The driver feeds identical, time-ordered streams to every estimator; outputs follow DESIGN.md."""

import json

import numpy as np
import pytest

from semslam.config import SemslamConfig
from semslam.estimation import EstimatorResult, LandmarkEstimate, Trajectory
from semslam.eval.outputs import build_metrics, write_outputs
from semslam.mission import (
    Depth,
    GroundTruthMap,
    GroundTruthPose,
    GtObject,
    Mission,
    MissionMetadata,
    PointCloud,
)
from semslam.observations import PointObservation
from semslam.pipeline import run_pipeline

REQUIRED_ESTIMATOR_KEYS = {
    "ate_rmse_m",
    "ate_max_m",
    "rpe_rmse_m",
    "landmark_median_error_m",
    "n_objects",
    "n_pipes",
    "n_structures",
    "runtime_s",
    "update_ms_median",
    "update_ms_p95",
    "nees_mean",
}


class Recorder:
    """A fake estimator: records what it is fed; its trajectory is the truth shifted by ``offset``."""

    def __init__(self, name, offset=0.0):
        self.name, self.offset, self.stream, self.truth = name, offset, [], []

    def process_measurement(self, m):
        self.stream.append(("m", m.stamp, type(m).__name__))
        if isinstance(m, GroundTruthPose):
            self.truth.append(m)

    def process_observations(self, stamp, obs):
        self.stream.append(("o", stamp, tuple(o.position.tolist() for o in obs)))

    def view(self):
        return self

    def pose_at(self, stamp):
        return None

    def landmarks(self):
        return []

    def finish(self):
        stamps = np.array([p.stamp for p in self.truth])
        pos = np.array([p.position for p in self.truth]) + [self.offset, 0, 0]
        traj = Trajectory(
            stamps,
            pos,
            np.array([p.orientation for p in self.truth]),
            position_cov=np.tile(np.eye(3) * self.offset**2, (len(stamps), 1, 1)),
        )
        lm = LandmarkEstimate(
            id=0,
            kind="object",
            position=np.array([1.0 + self.offset, 2.0, 3.0]),
            class_posterior={"Elbow": 0.8, "R-Tee": 0.2},
        )
        # "a" smooths: its online estimate (a further 0.05 m off) differs from the final one; "b" filters.
        online = Trajectory(stamps, pos + [0.05, 0, 0], traj.orientations) if self.name == "a" else traj
        return EstimatorResult(
            self.name, traj, [lm], online_trajectory=online, update_times_s=np.array([0.001, 0.002, 0.003])
        )


class CountingFrontend:
    name = "counting"
    consumes = (PointCloud,)

    def __init__(self):
        self.views = []

    def process(self, m, view):
        self.views.append(view)
        return [PointObservation(m.stamp, m.sensor, position=m.points.mean(axis=0))]


def _mission():
    ms = []
    for k in range(50):
        t = k * 100_000_000
        ms.append(GroundTruthPose(t, "gt", position=[0.1 * k, 0, 2], orientation=[0, 0, 0, 1]))
        ms.append(Depth(t + 1, "depth", depth=2.0, variance=0.01))
        if k % 10 == 0:
            ms.append(PointCloud(t + 2, "laser", points=np.full((4, 3), k, np.float32)))
    gt = GroundTruthMap(classes=("Elbow", "R-Tee"), objects=(GtObject(7, "Elbow", (1.0, 2.0, 3.0)),))
    return Mission.from_measurements(MissionMetadata(ground_truth=gt), ms[::-1])  # out of order on purpose


def test_every_estimator_sees_the_identical_time_ordered_stream():
    a, b = Recorder("a", 0.1), Recorder("b", 0.2)
    fe = CountingFrontend()
    res = run_pipeline(_mission(), [a, b], [fe], view_estimator="b")
    assert a.stream == b.stream
    stamps = [s[1] for s in a.stream]
    assert stamps == sorted(stamps)
    assert sum(1 for s in a.stream if s[0] == "o") == 5
    assert all(v is b for v in fe.views)  # front-ends see the chosen estimator's view
    assert res.n_measurements == 105 and len(res.observations) == 5
    assert res.duration_s == pytest.approx(4.9, abs=1e-6)


def test_metrics_and_outputs(tmp_path):
    res = run_pipeline(_mission(), [Recorder("a", 0.1), Recorder("b", 0.2)], [CountingFrontend()])
    metrics = build_metrics(res, _mission().metadata)
    assert set(metrics["estimators"]) == {"a", "a_online", "b"}
    for name in ("a", "b"):
        e = metrics["estimators"][name]
        assert REQUIRED_ESTIMATOR_KEYS <= set(e)
    assert metrics["estimators"]["a"]["ate_rmse_m"] == pytest.approx(0.1, abs=1e-9)
    assert metrics["estimators"]["a_online"]["ate_rmse_m"] == pytest.approx(0.15, abs=1e-9)
    assert metrics["estimators"]["a"]["ate_rmse_se3_m"] is None  # a straight line fixes no alignment
    assert metrics["estimators"]["b"]["ate_max_m"] == pytest.approx(0.2, abs=1e-9)
    assert metrics["estimators"]["b"]["landmark_median_error_m"] == pytest.approx(0.2, abs=1e-9)
    assert metrics["estimators"]["a"]["nees_mean"] == pytest.approx(1.0)  # error 1σ along one axis
    assert metrics["estimators"]["a"]["update_ms_median"] == pytest.approx(2.0)
    assert metrics["mission"]["gt_objects"] == 1 and metrics["mission"]["gt_pipes"] == 0

    out = write_outputs(tmp_path / "run", SemslamConfig(), res, metrics)
    names = {p.name for p in out.iterdir()}
    assert {
        "config.yaml",
        "metrics.json",
        "trajectory_a.tum",
        "trajectory_a_online.tum",
        "map_a.json",
        "map_a.ply",
        "trajectory_b.tum",
    } <= names
    tum = np.loadtxt(out / "trajectory_a.tum")
    assert tum.shape == (50, 8) and tum[3, 1] == pytest.approx(0.4)
    m = json.loads((out / "map_b.json").read_text())
    assert m["objects"][0]["class"] == "Elbow"
    assert json.loads((out / "metrics.json").read_text())["estimators"]["a"]["ate_rmse_m"] == pytest.approx(0.1)
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # staging folder cleaned up


def test_report_embeds_every_figure_it_lists(tmp_path):
    from semslam.eval.report import write_report

    mission = _mission()
    res = run_pipeline(mission, [Recorder("dr", 0.3), Recorder("graph", 0.05)], [CountingFrontend()])
    metrics = build_metrics(res, mission.metadata)
    page = write_report(tmp_path, res, mission.metadata, metrics).read_text()
    figs = sorted(p.name for p in (tmp_path / "figures").iterdir())
    assert {"trajectories.png", "maps.png", "position_error.png", "update_cost.png"} <= set(figs)
    assert page.count("data:image/png;base64,") == len(figs)
    md = (tmp_path / "report.md").read_text()
    assert all(f"figures/{f}" in md for f in figs)
    assert "0.300" in md and "0.050" in md  # the ATE of each estimator is in the table


class FinishingFrontend(CountingFrontend):
    """A front-end with a last word: a sonar-like metrics block and a figure file."""

    name = "finishing"

    def finish(self, view):
        from semslam.registry import FrontendSummary

        def figure(path):
            import matplotlib.pyplot as plt

            fig, ax = plt.subplots()
            ax.plot([0, 1], [0, 1])
            path.parent.mkdir(parents=True, exist_ok=True)
            fig.savefig(path)
            plt.close(fig)

        pose = np.eye(4)
        pose[:3, 3] = (1.0, 2.0, 3.0)
        return FrontendSummary(
            section="sonar",
            metrics={
                "structures": [{"model": "manifold", "pose": pose.tolist(), "median_error_m": 0.02, "symmetry": 2}],
                "runtime_s": 1.5,
                "world_model_bytes": 1000,
                "raw_cloud_bytes": 200_000,
            },
            files={"figures/sonar_elevation.png": figure},
        )


def test_frontend_summary_reaches_metrics_outputs_and_report(tmp_path):
    from semslam.eval.report import write_report
    from semslam.mission import GtStructure

    mission = _mission()
    mission.metadata.ground_truth = GroundTruthMap(
        structures=(
            GtStructure(3, "manifold", (1.0, 2.5, 3.0), (0, 0, np.sin(np.pi / 2 + 0.01), np.cos(np.pi / 2 + 0.01))),
        ),
    )
    res = run_pipeline(mission, [Recorder("dr", 0.3), Recorder("graph", 0.05)], [FinishingFrontend()])
    metrics = build_metrics(res, mission.metadata)
    (row,) = metrics["sonar"]["structures"]
    assert row["found"] and row["truth_id"] == 3 and row["position_error_m"] == pytest.approx(0.5)
    # the true yaw is 180° + 1.15°; the model is 2-fold symmetric, so the error is 1.15°
    assert row["yaw_error_deg"] == pytest.approx(np.degrees(0.02), abs=1e-6)
    out = write_outputs(tmp_path / "run", SemslamConfig(), res, metrics)
    assert (out / "figures" / "sonar_elevation.png").is_file()
    write_report(out, res, mission.metadata, metrics)
    md = (out / "report.md").read_text()
    assert "figures/sonar_elevation.png" in md and "Sonar structures" in md and "Run time" in md


def test_semantic_map_lists_every_link_once():
    """map_*.json's connectivity: object ↔ pipe and pipe ↔ structure links, each once."""
    from semslam.estimation import EstimatorResult, LandmarkEstimate, Trajectory
    from semslam.eval.outputs import map_to_dict

    lms = [
        LandmarkEstimate(1, "object", position=np.zeros(3), connected=(2,)),
        LandmarkEstimate(2, "pipe", p=np.zeros(3), q=np.ones(3), connected=(1, 3)),
        LandmarkEstimate(3, "structure", pose=np.eye(4), connected=(2,)),
    ]
    none = Trajectory(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 4)))
    m = map_to_dict(EstimatorResult("graph", none, lms))
    assert m["connectivity"] == [[1, 2], [2, 3]]
    assert m["structures"][0]["connected"] == [2] and m["objects"][0]["connected_pipes"] == [2]


class Watcher:
    """A pipeline observer that notes each step and what the estimators had taken by then."""

    def __init__(self, estimator):
        self.estimator, self.steps = estimator, []

    def step(self, stamp, measurement, observations, views):
        taken = len(self.estimator.stream)  # measurements and observation batches processed so far
        self.steps.append((stamp, measurement, [(fe, len(obs)) for fe, obs in observations], taken, dict(views)))


def test_observers_see_every_step_after_the_estimators_took_it():
    from semslam.pipeline import observed_by

    a, b = Recorder("a", 0.1), Recorder("b", 0.2)
    w, ambient = Watcher(a), Watcher(a)
    with observed_by(ambient):
        res = run_pipeline(_mission(), [a, b], [FinishingFrontend()], observers=[w])
    assert w.steps == ambient.steps  # observed_by reaches a run that passes no observers itself
    measured = [s for s in w.steps if s[1] is not None]
    assert [s[0] for s in measured] == sorted(m.stamp for m in _mission())  # every measurement, in order
    assert all(s[0] == s[1].stamp for s in measured)
    # each step comes after every estimator took the measurement and the observations drawn from it
    assert all(a.stream[s[3] - 1][1] == s[0] for s in measured)
    scans = [s for s in measured if isinstance(s[1], PointCloud)]
    assert len(scans) == 5 and all(s[2] == [("finishing", 1)] for s in scans)
    assert all(s[2] == [] for s in measured if not isinstance(s[1], PointCloud))
    assert set(measured[0][4]) == {"a", "b"} and measured[0][4]["b"] is b
    assert len(w.steps) == res.n_measurements  # a summary without observations adds no step
    # outside the block, nothing is watched
    run_pipeline(_mission(), [Recorder("a")], [CountingFrontend()])
    assert len(ambient.steps) == res.n_measurements


def test_the_frontends_last_word_is_a_step_without_measurement():
    from semslam.registry import FrontendSummary

    class LastWord(CountingFrontend):
        name = "last"

        def finish(self, view):
            return FrontendSummary(observations=[PointObservation(0, "laser", position=np.ones(3))] * 2)

    a = Recorder("a")
    w = Watcher(a)
    run_pipeline(_mission(), [a], [LastWord()], observers=[w])
    stamp, measurement, observations, taken, _ = w.steps[-1]
    assert measurement is None and observations == [("last", 2)]
    assert stamp == w.steps[-2][0] and taken == len(a.stream)  # at the last stamp, after the estimators


def test_a_watched_run_gives_the_same_result():
    plain = run_pipeline(_mission(), [Recorder("a", 0.1)], [CountingFrontend()])
    watched_est = Recorder("a", 0.1)
    watched = run_pipeline(_mission(), [watched_est], [CountingFrontend()], observers=[Watcher(watched_est)])
    assert np.array_equal(plain.results["a"].trajectory.positions, watched.results["a"].trajectory.positions)
    assert [(r.frontend, r.stamp) for r in plain.observations] == [(r.frontend, r.stamp) for r in watched.observations]


class SecondFrontend(CountingFrontend):
    name = "second"

    def process(self, m, view):
        return [PointObservation(m.stamp, m.sensor, position=m.points.mean(axis=0) + 1.0)]


def test_one_measurements_observations_of_every_frontend_reach_an_estimator_in_one_call():
    """A graph makes one update per call: one call per front-end made its result depend on how many
    front-ends answered a scan, even when the second one's observations carried no information."""
    a = Recorder("a")
    res = run_pipeline(_mission(), [a], [CountingFrontend(), SecondFrontend()], frontend_process=False)
    calls = [s for s in a.stream if s[0] == "o"]
    assert len(calls) == 5  # one a scan, not one a scan and front-end
    assert all(len(positions) == 2 for _, _, positions in calls)  # the first front-end's, then the second's
    assert all(p2[0] == p1[0] + 1.0 for _, _, (p1, p2) in calls)
    assert [r.frontend for r in res.observations] == ["counting", "second"] * 5  # kept per front-end


def test_a_run_freezes_the_heap_it_starts_with_and_unfreezes_it_after():
    import gc

    class Watching(Recorder):  # the collector's state as each measurement reaches the estimator
        def process_measurement(self, m):
            super().process_measurement(m)
            self.seen = gc.get_threshold(), gc.get_freeze_count()

    before = gc.get_threshold()
    a = Watching("a")
    run_pipeline(_mission(), [a], [CountingFrontend()])
    threshold, frozen = a.seen
    assert threshold == before  # when the generations are collected is not changed
    assert frozen > 0  # what existed before the run is out of its collections
    assert gc.get_freeze_count() == 0

    class Failing(Recorder):
        def process_observations(self, stamp, obs):
            raise RuntimeError("boom")

    with pytest.raises(RuntimeError, match="boom"):
        run_pipeline(_mission(), [Failing("a")], [CountingFrontend()])
    assert gc.get_freeze_count() == 0  # unfrozen after an error too


def test_the_outermost_frozen_block_decides():
    import gc

    from semslam.collector import heap_frozen

    with heap_frozen():
        with heap_frozen():
            assert gc.get_freeze_count() > 0
        assert gc.get_freeze_count() > 0  # the inner block's end leaves the outer one frozen
    assert gc.get_freeze_count() == 0
