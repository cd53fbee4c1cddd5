"""Front-ends that never read the estimate run in a process of their own (semslam.frontend_process):
the estimators must see exactly what they would see with the front-end inline, and an error in
the process must surface as itself, not hang the run."""

import time
from typing import ClassVar

import numpy as np
import pytest

from semslam.config import SemslamConfig
from semslam.ekf import EkfEstimator
from semslam.mission.measurements import Attitude, Depth, Measurement, PointCloud
from semslam.observations import PointObservation
from semslam.pipeline import run_pipeline
from semslam.registry import Frontend, create_frontends
from tests.support.synthetic_mission import SyntheticConfig, simulate


def _run(mission, frontend_process: bool):
    fes = create_frontends(
        ["oracle"], mission.metadata, {"oracle": {"seed": 3, "false_positive_rate": 0.1, "miss_rate": 0.1}}
    )
    return run_pipeline(
        mission, [EkfEstimator(mission.metadata, SemslamConfig())], fes, frontend_process=frontend_process
    )


def test_the_oracle_in_its_own_process_gives_the_same_stream_and_estimate():
    mission = simulate(SyntheticConfig(duration_s=40.0, seed=2))
    inline, apart = _run(mission, False), _run(mission, True)
    assert "wall" in apart.timing_s and "wall" not in inline.timing_s
    assert apart.timing_s["frontend:oracle"] > 0
    assert len(inline.observations) == len(apart.observations) > 20
    for a, b in zip(inline.observations, apart.observations):
        assert (a.frontend, a.stamp, type(a.observation)) == (b.frontend, b.stamp, type(b.observation))
        assert a.observation.truth_id == b.observation.truth_id
    ta, tb = inline.results["ekf"].trajectory, apart.results["ekf"].trajectory
    np.testing.assert_array_equal(ta.stamps, tb.stamps)
    np.testing.assert_allclose(ta.positions, tb.positions, atol=1e-12)


class FailingFrontend(Frontend):
    """Fails on its third scan, in the front-end process."""

    name: ClassVar[str] = "failing"
    consumes: ClassVar[tuple] = (PointCloud,)
    uses_view: ClassVar[bool] = False

    def __init__(self):
        self.n = 0

    def process(self, measurement, view):
        self.n += 1
        if self.n == 3:
            raise ValueError(f"scan {measurement.stamp} is broken")
        return []


def test_an_error_in_the_front_end_process_is_raised_as_itself():
    mission = simulate(SyntheticConfig(duration_s=20.0, seed=1))
    with pytest.raises(ValueError, match="is broken"):
        run_pipeline(mission, [EkfEstimator(mission.metadata, SemslamConfig())], [FailingFrontend()])


class DyingFrontend(FailingFrontend):
    """Kills its process on the third measurement, without a word (as a crash in C code would).
    It consumes every measurement, so that more than a pipe's worth is queued for it."""

    name: ClassVar[str] = "dying"
    consumes: ClassVar[tuple] = (Measurement,)

    def process(self, measurement, view):
        import os

        self.n += 1
        if self.n == 3:
            os._exit(3)
        return []


def test_a_dead_front_end_process_is_an_error_and_the_run_exits():
    """The pipeline raises, naming the process and its exit code, and nothing waits on measurements
    queued for it (the parent once hung at exit on the queue's feeder thread): a child interpreter
    that runs this test's body after the death must exit promptly."""
    import subprocess
    import sys

    code = (
        "import sys; sys.path.insert(0, {!r})\n"
        "from test_frontend_process import *\n"
        "if __name__ == '__main__':\n"
        "    mission = simulate(SyntheticConfig(duration_s=40.0, seed=1))\n"
        "    try:\n"
        "        run_pipeline(mission, [EkfEstimator(mission.metadata, SemslamConfig())], [DyingFrontend()])\n"
        "    except RuntimeError as exc:\n"
        "        print('raised:', exc)\n"
    ).format(str(__import__("pathlib").Path(__file__).parent))
    # The hang this guards against is forever; the bound only has to survive a loaded machine (the
    # suite runs two test processes on two cores).
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert "raised: the front-end process (dying) died (exit code 3" in out.stdout


class ScanWithAttitude(Frontend):
    """Reports, per scan, the stamp of the latest AHRS reading it kept: a replica that missed one
    would tell. Scans are independent given that (``parallel_consumes``), as the laser's are."""

    name: ClassVar[str] = "scan_att"
    consumes: ClassVar[tuple] = (PointCloud, Attitude)
    parallel_consumes: ClassVar[tuple] = (PointCloud,)
    uses_view: ClassVar[bool] = False

    def __init__(self):
        self.latest = 0

    def process(self, measurement, view):
        import os

        if isinstance(measurement, Attitude):
            self.latest = measurement.stamp
            return []
        return [PointObservation(measurement.stamp, "laser", position=np.array([self.latest * 1e-9, os.getpid(), 1.0]))]

    def finish(self, view=None):
        from semslam.registry import FrontendSummary

        return FrontendSummary(section="scan_att", metrics={"latest": self.latest})


def test_replicas_share_the_scans_and_give_the_inline_stream():
    """With two workers, scans alternate between them while both see every AHRS reading: the
    observations are those of the front-end inline, in the same order, and come from both processes."""
    mission = simulate(SyntheticConfig(duration_s=40.0, seed=1))

    def run(**kw):
        return run_pipeline(
            mission,
            [EkfEstimator(mission.metadata, SemslamConfig())],
            [ScanWithAttitude()],
            keep_observations=True,
            **kw,
        )

    inline, apart = run(frontend_process=False), run(frontend_workers=2)
    a = [(r.stamp, r.observation.position[0]) for r in inline.observations]
    b = [(r.stamp, r.observation.position[0]) for r in apart.observations]
    assert len(a) > 10 and a == b
    assert len({r.observation.position[1] for r in apart.observations}) == 2  # both workers took scans
    assert apart.frontend_summaries["scan_att"].metrics == inline.frontend_summaries["scan_att"].metrics


class ObservesOnAttitude(ScanWithAttitude):
    """Breaks the contract: observes on a type it does not take in parallel."""

    name: ClassVar[str] = "bad_att"

    def process(self, measurement, view):
        if isinstance(measurement, Attitude):
            return [PointObservation(measurement.stamp, "laser", position=np.zeros(3))]
        return []


def test_a_replicated_front_end_observing_on_a_state_type_is_an_error():
    """No worker answers for a replicated front-end's non-parallel types, so an observation there
    would be lost: it is an error naming the front-end and the type."""
    mission = simulate(SyntheticConfig(duration_s=20.0, seed=1))
    with pytest.raises(RuntimeError, match="'bad_att' observed on a Attitude"):
        run_pipeline(
            mission, [EkfEstimator(mission.metadata, SemslamConfig())], [ObservesOnAttitude()], frontend_workers=2
        )


class EnvFrontend(Frontend):
    """Answers each depth reading with the value of SEMSLAM_TEST_ENV in its process."""

    name: ClassVar[str] = "env"
    consumes: ClassVar[tuple] = (Depth,)
    uses_view: ClassVar[bool] = False

    def process(self, measurement, view):
        import os

        return [os.environ.get("SEMSLAM_TEST_ENV")]


def test_a_worker_sees_the_callers_environment_of_its_start(monkeypatch):
    """Workers fork from a server started once per process: each must still see the environment as
    it is when the worker is made (a front-end reads e.g. its cache folder from it), not the server's."""
    from semslam.frontend_process import FrontendProcess

    seen = []
    for value in ("first", "second"):
        monkeypatch.setenv("SEMSLAM_TEST_ENV", value)
        proc = FrontendProcess([EnvFrontend()])
        try:
            assert proc.submit(Depth(stamp=1, sensor="depth", depth=1.0))
            seen.append(proc.result()["env"][0])
        finally:
            proc.close()
    assert seen == [["first"], ["second"]]


class Deaf:
    """An estimator that only listens: the routing tests look at the observation stream."""

    name = "deaf"

    def process_measurement(self, m):
        pass

    def process_observations(self, stamp, obs):
        pass

    def view(self):
        return None

    def finish(self):
        from semslam.estimation import EstimatorResult, Trajectory

        return EstimatorResult(self.name, Trajectory(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 4))))


class CountingScans(ScanWithAttitude):
    """Replicated over the scans (as the laser): each observation says which AHRS reading it had,
    which process drew it and how many scans that process's replica has processed so far."""

    name: ClassVar[str] = "counting"

    def __init__(self):
        super().__init__()
        self.scans = 0

    def process(self, measurement, view):
        import os

        if isinstance(measurement, Attitude):
            self.latest = measurement.stamp
            return []
        self.scans += 1
        return [PointObservation(measurement.stamp, "laser", position=np.array([self.latest, os.getpid(), self.scans]))]


class SequentialScans(Frontend):
    """Sequential, on the same scans (as the laser odometry): each observation carries the latest
    depth stamp it kept, its process and how many scans it has seen, all of which depend on its
    seeing every scan and every depth reading in order, in one process."""

    name: ClassVar[str] = "sequential"
    consumes: ClassVar[tuple] = (PointCloud, Depth)
    uses_view: ClassVar[bool] = False

    def __init__(self):
        self.depth, self.scans = 0, 0

    def process(self, measurement, view):
        import os

        if isinstance(measurement, Depth):
            self.depth = measurement.stamp
            return []
        self.scans += 1
        return [PointObservation(measurement.stamp, "laser", position=np.array([self.depth, os.getpid(), self.scans]))]

    def finish(self, view=None):
        from semslam.registry import FrontendSummary

        return FrontendSummary(section="sequential", metrics={"scans": self.scans, "depth": self.depth})


def test_a_replicated_and_a_sequential_front_end_on_the_same_scans(sample_mission):
    """The replicas share the scans (each scan processed once, not once per worker), the sequential
    front-end lives in one worker and sees every scan and depth reading there, and the stream is
    the one of both front-ends inline: same observations, same order."""
    mission = sample_mission(seconds=12.0)
    n_scans = sum(isinstance(m, PointCloud) for m in mission)

    def run(**kw):
        return run_pipeline(mission, [Deaf()], [CountingScans(), SequentialScans()], **kw)

    inline, apart = run(frontend_process=False), run(frontend_workers=2)

    def stream(result):  # what does not depend on where it ran: front-end, stamp, state it kept
        return [(r.frontend, r.stamp, r.observation.position[0]) for r in result.observations]

    assert stream(apart) == stream(inline)
    assert [r.frontend for r in apart.observations[:2]] == ["counting", "sequential"]  # the front-ends' order
    assert len(apart.observations) == 2 * n_scans == 48

    counting = [r.observation.position for r in apart.observations if r.frontend == "counting"]
    by_process: dict[float, list[float]] = {}
    for _, pid, count in counting:
        by_process.setdefault(pid, []).append(count)
    for counts in by_process.values():  # each worker processed only its own scans
        assert counts == list(range(1, len(counts) + 1))
    assert sum(len(c) for c in by_process.values()) == n_scans

    sequential = [r.observation.position for r in apart.observations if r.frontend == "sequential"]
    assert len({pid for _, pid, _ in sequential}) == 1
    assert [count for _, _, count in sequential] == list(range(1, n_scans + 1))
    assert apart.frontend_summaries["sequential"].metrics == inline.frontend_summaries["sequential"].metrics
    assert apart.timing_s["frontend:sequential"] > 0 and apart.timing_s["frontend:counting"] > 0


class BusyCountingScans(CountingScans):
    name: ClassVar[str] = "counting"

    def process(self, measurement, view):
        if isinstance(measurement, PointCloud):
            time.sleep(0.02)
        return super().process(measurement, view)


class BusySequentialScans(SequentialScans):
    def process(self, measurement, view):
        if isinstance(measurement, PointCloud):
            time.sleep(0.02)
        return super().process(measurement, view)


def test_the_replicated_scans_go_to_the_worker_the_sequential_front_end_leaves_idle(sample_mission):
    """A sequential front-end (the odometry) busy on every scan, a replicated one (the laser) as
    busy: taking turns gave the sequential one's worker half the replicated scans as well (twice the
    other's work); now it gets few of them, and the stream is the same."""
    mission = sample_mission(seconds=12.0)
    fes = [BusyCountingScans(), BusySequentialScans()]
    apart = run_pipeline(mission, [Deaf()], fes, frontend_workers=2)
    home = {r.observation.position[1] for r in apart.observations if r.frontend == "sequential"}
    counting = [r.observation.position[1] for r in apart.observations if r.frontend == "counting"]
    assert len(home) == 1 and len(counting) == sum(isinstance(m, PointCloud) for m in mission) == 24
    at_home = sum(pid in home for pid in counting)
    assert at_home <= 0.25 * len(counting), at_home
    inline = run_pipeline(mission, [Deaf()], [BusyCountingScans(), BusySequentialScans()], frontend_process=False)
    assert [(r.frontend, r.stamp) for r in apart.observations] == [(r.frontend, r.stamp) for r in inline.observations]


class SlowScans(Frontend):
    """Takes 0.2 s a scan and notes each one it finished in a file."""

    name: ClassVar[str] = "slow"
    consumes: ClassVar[tuple] = (PointCloud,)
    uses_view: ClassVar[bool] = False

    def __init__(self, log):
        self.log = str(log)

    def process(self, measurement, view):
        import time

        time.sleep(0.2)
        with open(self.log, "a") as f:
            f.write(f"{measurement.stamp}\n")
        return []


class FailsAtSecondScan(Deaf):
    name = "fails"

    def __init__(self):
        self.scans = 0

    def process_measurement(self, m):
        self.scans += isinstance(m, PointCloud)
        if self.scans == 2:
            raise RuntimeError("estimator failed")


def test_an_error_in_the_driver_kills_the_workers_instead_of_letting_them_finish_the_queue(sample_mission, tmp_path):
    """All 24 scans are queued for the worker at once (the driver reads ahead); when the estimator
    fails at the second, the worker is killed: it does not work through the rest, and nothing is left."""
    import multiprocessing as mp
    import time

    mission = sample_mission(seconds=12.0)
    log = tmp_path / "scans.txt"
    with pytest.raises(RuntimeError, match="estimator failed"):
        run_pipeline(mission, [FailsAtSecondScan()], [SlowScans(log)])
    assert mp.active_children() == []
    done = log.read_text().split()
    time.sleep(0.5)
    assert log.read_text().split() == done  # nobody is still working
    assert len(done) <= 6 < sum(isinstance(m, PointCloud) for m in mission)
