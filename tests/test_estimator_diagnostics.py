"""An estimator's recovered failures are not silent: counted and listed in metrics.json, and said
as a warning (on stderr and in metrics.json's input warnings) with the mission time of the first."""

import numpy as np

from semslam.compare import input_after_the_pass
from semslam.estimation import EstimatorResult, Trajectory
from semslam.eval.metrics import MAX_DIAGNOSTICS, estimator_metrics
from semslam.results import PipelineResult
from tests.support.synthetic_mission import SyntheticConfig, simulate

T0 = 1_700_000_000_000_000_000


def result(diagnostics: list[str]) -> EstimatorResult:
    stamps = T0 + np.arange(5, dtype=np.int64) * 1_000_000_000
    traj = Trajectory(stamps, np.zeros((5, 3)), np.tile([0.0, 0.0, 0.0, 1.0], (5, 1)))
    return EstimatorResult("graph", traj, diagnostics=diagnostics)


FAILED = [
    f"{T0 + 2_500_000_000}: iSAM2 update failed (Indeterminate linear system x12); dropped the factors of landmarks []",
    "rebuild needed a weak re-anchoring prior on x12 (Indeterminate linear system x12)",
]


def test_recovered_failures_are_counted_and_listed_in_metrics():
    routine = [f"{T0}: 3 observations before the first keyframe, ignored"] * (MAX_DIAGNOSTICS + 5)
    m = estimator_metrics(result([*routine, *FAILED]), None, None, None)
    assert m["diagnostics_count"] == MAX_DIAGNOSTICS + 7
    assert m["recovered_failures"] == 2
    assert len(m["diagnostics"]) == MAX_DIAGNOSTICS
    clean = estimator_metrics(result(routine[:1]), None, None, None)
    assert clean["recovered_failures"] == 0 and clean["diagnostics_count"] == 1


def test_a_recovered_failure_is_a_warning_with_its_mission_time():
    mission = simulate(SyntheticConfig(duration_s=5.0, n_objects=0, n_pipes=0, n_structures=0, seed=1))
    for _ in mission:  # the complete pass the function expects
        pass
    pipeline = PipelineResult(results={"graph": result(FAILED), "ekf": result([])}, truth=None)
    pipeline.results["ekf"].name = "ekf"
    block, said = input_after_the_pass(mission, pipeline)
    assert len(said) == 1 and said == block["warnings"]
    assert said[0].startswith("graph: recovered from 2 solver failure(s), the first at 2.5 s: iSAM2 update failed")
