"""The EKF's odometry pseudo-measurement is gated by its NIS, so that it, like the graph's robust
factor, refuses a registration that converged wrong where the filter knows its velocity."""

import numpy as np
import pytest

import tests.test_backend_odometry as relative
from semslam.config import SemslamConfig
from semslam.ekf.estimator import EkfEstimator
from semslam.pipeline import run_pipeline
from tests.support.synthetic_mission import SyntheticConfig, simulate

# the 14th registration (of 2 s each, at ~28 s): 8 s into a 40 s DVL dropout, where the registrations before
# it keep the filter's velocity to centimetres per second
WRONG = 14


@pytest.fixture(scope="module")
def mission():
    return simulate(
        SyntheticConfig(duration_s=100.0, n_objects=0, n_pipes=0, n_structures=0, dropouts=((20.0, 40.0),), seed=5)
    )


def _run(mission, gate: float | None, wrong: int):
    cfg = SemslamConfig.model_validate({"ekf": {"odometry_gate_probability": gate}})
    fe = relative.OneWrongRegistration(wrong, lag_s=2.0)
    result = run_pipeline(mission, [EkfEstimator(mission.metadata, cfg)], [fe]).results["ekf"]
    return result.trajectory, result.diagnostics, fe


def _pull(a, b) -> float:
    assert np.array_equal(a.stamps, b.stamps)
    return float(np.max(np.linalg.norm(a.positions - b.positions, axis=1)))


def test_nis_gate_rejects_a_wrong_registration_where_the_filter_is_confident(mission):
    clean, clean_notes, fe = _run(mission, 0.99, wrong=-1)
    wrong, notes, fe_wrong = _run(mission, 0.99, wrong=WRONG)
    ungated_clean, _, _ = _run(mission, None, wrong=-1)
    ungated, ungated_notes, _ = _run(mission, None, wrong=WRONG)
    n = len(fe.froms)
    assert n > 40 and 20e9 < fe_wrong.froms[WRONG - 1] < 60e9  # the wrong one is inside the dropout
    # true registrations pass the gate (at most the 1 % a χ²₃ gate drops by chance, and one more)
    rejected_clean = [d for d in clean_notes if d.startswith("odometry:")]
    assert not rejected_clean or int(rejected_clean[0].split()[1]) <= 0.01 * n + 1
    # the 1 m registration (σ 1 cm over 2 s: 0.5 m/s off the filter's velocity) is rejected ...
    counted = [d for d in notes if d.startswith("odometry:")]
    assert counted and int(counted[0].split()[1]) == 1 + (int(rejected_clean[0].split()[1]) if rejected_clean else 0)
    assert _pull(wrong, clean) < 0.02  # ... and the track moves by what one true registration fewer makes (7 mm)
    # without the gate the same registration drags the filter's track by a metre through the dropout
    assert not any(d.startswith("odometry:") for d in ungated_notes)
    assert _pull(ungated, ungated_clean) > 0.5
