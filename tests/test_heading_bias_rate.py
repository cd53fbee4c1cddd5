"""The AHRS heading bias's drift rate (factors.heading_bias): a bias that drifts as a ramp, observed
early in a mission, is carried on by the learned rate where nothing observes it — in the graph's
factor chain and in the EKF's prediction alike — while the random walk alone freezes it."""

import gtsam
import numpy as np
import pytest

from factors.heading_bias import RATE_UNIT_S, heading_bias_drift_covariance
from factors.navigation import heading_bias_drift_factor, heading_bias_walk_factor
from semslam.backend.window import B, D, FrozenValues
from semslam.config import SemslamConfig
from semslam.ekf import models as mdl
from semslam.ekf.filter import EkfState
from tests.test_factors_jacobians import check_factor_jacobians

# A mission of T s whose bias ramps to DRIFT (as the simulator's does), declared as a drift over T.
T, DRIFT, DT = 600.0, 0.03, 5.0
SEEN_UNTIL, SIGMA_SEEN = 200.0, 0.002  # the bias observed (a map's sightings) until then
WALK = DRIFT / np.sqrt(T)
RATE_SIGMA = DRIFT / T
RATE_WALK = RATE_SIGMA / np.sqrt(T)


class _Meta:
    extras = {"noise": {"ahrs": {"heading_bias_drift_rad": DRIFT, "heading_bias_drift_over_s": T}}}


def test_rate_keys_come_from_the_declared_drift():
    s = SemslamConfig().sensors
    assert s.heading_bias_rate_sigma(_Meta) == pytest.approx(RATE_SIGMA)
    assert s.heading_bias_rate_walk(_Meta) == pytest.approx(RATE_WALK)
    assert SemslamConfig(sensors={"heading_bias_rate_sigma_rad_per_s": 0.0}).sensors.heading_bias_rate_sigma(_Meta) == 0
    no_bias = SemslamConfig(sensors={"heading_bias_walk_rad_per_sqrt_s": 0.0}).sensors
    assert no_bias.heading_bias_rate_sigma(_Meta) == 0  # no rate without a bias state


def test_drift_covariance_is_the_integrated_random_walk():
    """Monte Carlo of b, r driven by white noises of the declared intensities, over one step."""
    rng = np.random.default_rng(0)
    dt, n, sub = 7.0, 20000, 70
    h = dt / sub
    b = np.zeros(n)
    r = np.zeros(n)
    for _ in range(sub):
        b += r * h + rng.normal(scale=WALK * np.sqrt(h), size=n)
        r += rng.normal(scale=1e-3 * np.sqrt(h), size=n)  # a rate walk large enough to see
    C = np.cov(np.stack([b, r * RATE_UNIT_S]))
    expected = heading_bias_drift_covariance(dt, WALK, 1e-3)
    assert np.allclose(C, expected, rtol=0.06, atol=1e-12), (C, expected)


def test_drift_factor_jacobians():
    f = heading_bias_drift_factor(B(0), D(0), B(1), D(1), 3.0, WALK, RATE_WALK)
    v = gtsam.Values()
    for key, x in ((B(0), 0.01), (D(0), -0.004), (B(1), 0.02), (D(1), 0.003)):
        v.insert(key, np.array([x]))
    check_factor_jacobians(f, v)
    e = f.unwhitenedError(v)
    assert np.allclose(e, [0.02 - 0.01 - 3.0 / RATE_UNIT_S * -0.004, 0.003 + 0.004])


def _graph_bias(with_rate: bool) -> tuple[np.ndarray, np.ndarray]:
    """Smoothed bias of a keyframe chain every DT s, the bias seen (σ SIGMA_SEEN) until SEEN_UNTIL."""
    ts = np.arange(0.0, T + DT / 2, DT)
    g, v = gtsam.NonlinearFactorGraph(), gtsam.Values()
    g.add(gtsam.PriorFactorVector(B(0), np.zeros(1), gtsam.noiseModel.Isotropic.Sigma(1, 1e-4)))
    if with_rate:
        g.add(gtsam.PriorFactorVector(D(0), np.zeros(1), gtsam.noiseModel.Isotropic.Sigma(1, RATE_SIGMA * RATE_UNIT_S)))
    rng = np.random.default_rng(1)
    for k, t in enumerate(ts):
        v.insert(B(k), np.zeros(1))
        if with_rate:
            v.insert(D(k), np.zeros(1))
        if k:
            g.add(
                heading_bias_drift_factor(B(k - 1), D(k - 1), B(k), D(k), DT, WALK, RATE_WALK)
                if with_rate
                else heading_bias_walk_factor(B(k - 1), B(k), DT, WALK)
            )
        if 0 < t <= SEEN_UNTIL and k % 4 == 0:
            z = DRIFT * t / T + rng.normal(scale=SIGMA_SEEN)
            g.add(gtsam.PriorFactorVector(B(k), np.array([z]), gtsam.noiseModel.Isotropic.Sigma(1, SIGMA_SEEN)))
    out = gtsam.LevenbergMarquardtOptimizer(g, v).optimize()
    return ts, np.array([out.atVector(B(k))[0] for k in range(len(ts))])


def test_graph_carries_a_learned_drift_on():
    ts, b_rate = _graph_bias(True)
    _, b_walk = _graph_bias(False)
    truth = DRIFT * ts / T
    late = ts > SEEN_UNTIL + 50
    err_rate = np.sqrt(np.mean((b_rate - truth)[late] ** 2))
    err_walk = np.sqrt(np.mean((b_walk - truth)[late] ** 2))
    assert np.ptp(b_walk[late]) < 1e-6  # the walk alone: frozen after the last sighting
    # the declared walk keeps most of the rate's uncertainty (the rate is learnt in part): ~0.7
    assert err_rate < 0.75 * err_walk, (err_rate, err_walk)
    i = np.searchsorted(ts, SEEN_UNTIL)
    assert b_rate[-1] - b_rate[i] > 0.004  # carried on (the ramp adds 0.02 from there)


def test_ekf_prediction_carries_a_learned_drift_on():
    """The filter's 11-state prediction: the same chain as the graph's factors, filtered."""

    def run(with_rate):
        nv = mdl.NX + 1 + with_rate
        P0 = np.eye(nv) * 1e-4
        P0[mdl.BIAS, mdl.BIAS] = 1e-8
        if with_rate:
            P0[mdl.BIAS + 1, mdl.BIAS + 1] = (RATE_SIGMA * RATE_UNIT_S) ** 2
        st = EkfState(np.zeros(nv), P0)
        rng = np.random.default_rng(1)
        H = np.zeros((1, nv))
        H[0, mdl.BIAS] = 1.0
        out = []
        for k, t in enumerate(np.arange(DT, T + DT / 2, DT)):
            rate_walk = RATE_WALK if with_rate else None
            xv, F, Q = mdl.predict_biased(st.xv.copy(), np.zeros(3), DT, 0.01, 0.001, WALK, rate_walk)
            st.predict_vehicle(xv, F, Q)
            if t <= SEEN_UNTIL and (k + 1) % 4 == 0:
                z = DRIFT * t / T + rng.normal(scale=SIGMA_SEEN)
                st.update_vehicle(np.array([z - st.xv[mdl.BIAS]]), H, np.array([[SIGMA_SEEN**2]]), nis=False)
            out.append((t, st.xv[mdl.BIAS]))
        return np.array(out)

    with_rate, walk = run(True), run(False)
    truth = DRIFT * with_rate[:, 0] / T
    late = with_rate[:, 0] > SEEN_UNTIL + 50
    err_rate = np.sqrt(np.mean((with_rate[:, 1] - truth)[late] ** 2))
    err_walk = np.sqrt(np.mean((walk[:, 1] - truth)[late] ** 2))
    assert err_rate < 0.75 * err_walk, (err_rate, err_walk)


def test_frozen_values_keep_the_rate():
    fz = FrozenValues()
    v = gtsam.Values()
    v.insert(B(3), np.array([0.011]))
    v.insert(D(3), np.array([-0.002]))
    fz.insert_or_assign(v, [B(3), D(3)])
    back = gtsam.Values()
    fz.insert_into(back)
    assert back.atVector(B(3))[0] == 0.011 and back.atVector(D(3))[0] == -0.002
