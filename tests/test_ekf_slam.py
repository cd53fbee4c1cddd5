"""EKF-SLAM on a simulated mission with observations: dead reckoning drifts, the EKF bounds the error
(ATE RMSE ≤ 0.5 × DR's), maps each seen pipe and object once, and returns the outputs of the contract."""

import numpy as np
import pytest

from semslam.config import SemslamConfig
from semslam.ekf import DeadReckoning, EkfEstimator
from semslam.estimation import Estimator
from tests.support.ekf_mission import simulate_circling

ACCEL, RATE = 0.03, 0.002


def _ate(result, sim) -> float:
    tr = result.trajectory
    ts = sim.truth_stamps
    idx = np.clip(np.searchsorted(ts, tr.stamps), 0, len(ts) - 1)
    ok = ts[idx] == tr.stamps
    err = tr.positions[ok] - sim.truth_states[idx[ok], :3]
    return float(np.sqrt((err**2).sum(axis=1).mean()))


@pytest.fixture(scope="module")
def runs():
    sim = simulate_circling(
        seed=1, duration_s=150.0, accel_sigma=ACCEL, rate_sigma=RATE, dropouts=((30.0, 20.0), (90.0, 20.0))
    )
    cfg = SemslamConfig(motion={"accel_sigma_m_s2": ACCEL, "angular_rate_sigma_rad_s": RATE})
    return sim, sim.run([DeadReckoning(sim.metadata, cfg), EkfEstimator(sim.metadata, cfg)])


def test_estimators_follow_the_protocol():
    sim = simulate_circling(seed=0, duration_s=2.0, with_features=False)
    for cls in (EkfEstimator, DeadReckoning):
        assert isinstance(cls(sim.metadata, SemslamConfig()), Estimator)


def test_dr_drifts_and_ekf_bounds_the_error(runs):
    sim, res = runs
    ate_dr, ate_ekf = _ate(res["dr"], sim), _ate(res["ekf"], sim)
    assert ate_dr > 0.3, ate_dr  # dead reckoning drifts through the DVL dropouts
    assert ate_ekf <= 0.5 * ate_dr, (ate_ekf, ate_dr)
    assert ate_ekf < 0.1


def test_ekf_maps_each_seen_feature_once(runs):
    sim, res = runs
    gt = sim.metadata.ground_truth
    lms = res["ekf"].landmarks
    objects = [lm for lm in lms if lm.kind == "object"]
    pipes = [lm for lm in lms if lm.kind == "pipe"]
    assert len(objects) == len(gt.seen_objects)
    assert len(pipes) == len(gt.seen_pipes)
    # each mapped object lies on a distinct true object, each pipe on a distinct true pipe axis
    truth_obj = np.array([gt.objects[i].position for i in gt.seen_objects])
    nearest = [int(np.argmin(np.linalg.norm(truth_obj - o.position, axis=1))) for o in objects]
    assert len(set(nearest)) == len(objects)
    assert all(np.linalg.norm(truth_obj[k] - o.position) < 0.1 for k, o in zip(nearest, objects))
    for lm in pipes:
        dists = []
        for i in gt.seen_pipes:
            a, b = np.array(gt.pipes[i].p), np.array(gt.pipes[i].q)
            d = (b - a) / np.linalg.norm(b - a)
            off = lambda x: np.linalg.norm((x - a) - ((x - a) @ d) * d)  # noqa: B023
            dists.append(max(off(lm.p), off(lm.q)))
        assert min(dists) < 0.1
        assert np.linalg.norm(lm.q - lm.p) > 1.0  # the saved extent grew with the views
    assert all(lm.covariance.shape == (4, 4) for lm in pipes)
    assert all(lm.class_posterior and max(lm.class_posterior, key=lm.class_posterior.get) != "other" for lm in objects)


def test_outputs_and_histories(runs):
    sim, res = runs
    for _name, r in res.items():
        tr = r.trajectory
        assert len(tr) > 1000 and np.all(np.diff(tr.stamps) > 0)
        assert tr.position_cov.shape == (len(tr), 3, 3) and tr.velocity_cov.shape == (len(tr), 3, 3)
        np.testing.assert_allclose(np.linalg.norm(tr.orientations, axis=1), 1.0)
        assert len(r.update_times_s) == len(r.update_n_landmarks) == len(sim.observations)
        stamps, cov = r.history["vehicle_cov"]
        assert cov.shape == (len(stamps), 9, 9)
        assert set(r.history["landmark_volume"]) == {lm.id for lm in r.landmarks}
        assert len({lm.id for lm in r.landmarks}) == len(r.landmarks)
    # uncertainty volumes of the EKF's features decrease as they are re-observed (Figs. 11–12)
    for _lid, (stamps, vol) in res["ekf"].history["landmark_volume"].items():
        assert len(stamps) == len(vol)
        if len(vol) > 5:
            assert vol[-1] < vol[0]
    # the EKF's position uncertainty stays bounded; dead reckoning's grows
    sd = lambda r: np.sqrt(np.trace(r.trajectory.position_cov[-1]))
    assert sd(res["ekf"]) < 0.5 * sd(res["dr"])


def test_heading_bias_is_estimated_from_the_map_and_grows_in_dead_reckoning():
    """An AHRS heading bias declared by the mission (the shared sensor model) is a 10th vehicle state of
    both filters. Dead reckoning cannot observe it: its σ grows with the walk and so does the heading's,
    consistently. The map makes it observable: EKF-SLAM tracks it (within 3σ, with a smaller σ). A
    configured walk of 0 is the paper's 9-state filter."""
    walk, T = 0.004, 150.0
    sim = simulate_circling(
        seed=2, duration_s=T, accel_sigma=ACCEL, rate_sigma=RATE, dropouts=((30.0, 20.0),), heading_bias_walk=walk
    )
    cfg = SemslamConfig(
        motion={"accel_sigma_m_s2": ACCEL, "angular_rate_sigma_rad_s": RATE},
        sensors={"heading_bias_rate_sigma_rad_per_s": 0.0},  # the simulated bias is a random walk, no drift rate
    )
    assert cfg.sensors.heading_bias_walk(sim.metadata) == pytest.approx(walk)
    ests = [DeadReckoning(sim.metadata, cfg), EkfEstimator(sim.metadata, cfg)]
    plain = EkfEstimator(sim.metadata, SemslamConfig(sensors={"heading_bias_walk_rad_per_sqrt_s": 0.0}))
    assert [e.nav.nv for e in ests] == [10, 10] and plain.nav.nv == 9
    res = sim.run(ests)
    truth = sim.extras["heading_bias"]
    for name, r in res.items():
        stamps, b, sb = r.history["heading_bias"]
        assert len(stamps) == len(r.trajectory) and r.history["vehicle_cov"][1].shape[1:] == (10, 10)
        k = np.searchsorted(sim.truth_stamps, stamps[-1])
        assert abs(b[-1] - truth[k]) < 3 * sb[-1], (name, b[-1], truth[k], sb[-1])
    _, _, sb_dr = res["dr"].history["heading_bias"]
    _, _, sb_ekf = res["ekf"].history["heading_bias"]
    s0 = cfg.sensors.heading_bias_sigma0(sim.metadata)
    quarters = sb_dr[np.linspace(len(sb_dr) // 10, len(sb_dr) - 1, 5).astype(int)]
    assert np.all(np.diff(quarters) > 0)  # grows (an AHRS update takes a little off: ψ + b vs the gyro)
    # at most the walk's growth (less: with a gyro this good, ψ + b from the AHRS tells a little of b)
    assert 1.3 * s0 < sb_dr[-1] <= 1.001 * np.hypot(s0, walk * np.sqrt(T))
    assert sb_ekf[-1] < 0.8 * sb_dr[-1]
    # dead reckoning's heading σ grows with the bias's (the AHRS pins ψ + b only)
    _, P_dr = res["dr"].history["vehicle_cov"]
    assert np.sqrt(P_dr[-1, 5, 5]) > 0.9 * sb_dr[-1] > np.sqrt(P_dr[1, 5, 5])
