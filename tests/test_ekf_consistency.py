"""The navigation filter is consistent: average NEES of the 9-state vehicle estimate within the 95 %
χ² bounds over Monte Carlo runs of a simulated navigation-only mission (with a DVL dropout).
A larger study is ``experiments/ekf_nees_study.py``."""

import numpy as np
import pytest
from scipy.stats import chi2

from semslam.config import SemslamConfig
from semslam.ekf import DeadReckoning, EkfEstimator
from semslam.ekf import geometry as geo
from semslam.mission.measurements import Attitude, Depth, DvlVelocity, GroundTruthPose, PointCloud
from tests.support.ekf_mission import seen_from_truth, simulate_circling
from tests.support.replay import Scanner, probe

ACCEL, RATE = 0.01, 0.002
N_RUNS = 6


def nees_run(seed: int, duration_s: float = 50.0, sample_every_s: float = 1.0, bias_walk: float = 0.0):
    """NEES of the vehicle state (9 dof; 10 with the AHRS heading bias of a mission that has one) of one
    run sampled every ``sample_every_s``, and the position σ over time."""
    sim = simulate_circling(
        seed=seed,
        duration_s=duration_s,
        accel_sigma=ACCEL,
        rate_sigma=RATE,
        dropouts=((20.0, 12.0),),
        with_features=False,
        velocity_tau_s=None,
        track_gain=0.0,
        heading_bias_walk=bias_walk,
    )
    cfg = SemslamConfig(
        motion={"accel_sigma_m_s2": ACCEL, "angular_rate_sigma_rad_s": RATE},
        sensors={"heading_bias_rate_sigma_rad_per_s": 0.0},  # the simulated bias is a random walk, no drift rate
    )
    est = EkfEstimator(sim.metadata, cfg)
    nv = 10 if bias_walk > 0 else 9
    assert est.nav.nv == nv
    ts = sim.truth_stamps
    period = int(sample_every_s * 1e9)
    nees, sd, times = [], [], []

    def look(m):  # after the filter took the AHRS reading
        if m.stamp % period or m.stamp == 0:
            return
        i = np.searchsorted(ts, m.stamp)
        truth = sim.truth_states[i] if nv == 9 else np.r_[sim.truth_states[i], sim.extras["heading_bias"][i]]
        e = est.nav.state.x[:nv] - truth
        e[3:6] = geo.wrap(e[3:6])
        P = est.nav.state.P[:nv, :nv]
        nees.append(e @ np.linalg.solve(P, e))
        sd.append(np.sqrt(np.trace(P[:2, :2])))
        times.append(m.stamp * 1e-9)

    sim.run([est], [probe((Attitude,), look)], observations=False)
    return np.array(times), np.array(nees), np.array(sd)


@pytest.mark.parametrize("bias_walk", [0.0, 0.003])
def test_navigation_filter_is_consistent(bias_walk):
    """Also with an AHRS heading bias (a random walk; the filter's 10th state, unobservable here)."""
    dim = 10 if bias_walk > 0 else 9
    runs = [nees_run(seed, bias_walk=bias_walk) for seed in range(N_RUNS)]
    times = runs[0][0]
    anees = np.mean([r[1] for r in runs], axis=0)  # average over runs at each time
    lo, hi = chi2.ppf([0.025, 0.975], dim * N_RUNS) / N_RUNS
    inside = np.mean((anees > lo) & (anees < hi))
    assert inside >= 0.85, f"ANEES inside [{lo:.2f}, {hi:.2f}] only {inside:.0%} of the time: {anees.round(1)}"
    # over the whole mission the mean NEES is close to the dimension
    assert dim * 0.75 < anees.mean() < dim * 1.25
    # the DVL dropout (20–32 s) makes the horizontal uncertainty grow, and it stops growing after it
    sd = runs[0][2]
    before, after_drop, end = sd[times == 19][0], sd[times == 32][0], sd[-1]
    assert after_drop > 2 * before
    assert end < 1.3 * after_drop


def test_dead_reckoning_is_the_same_filter_without_features():
    sim = simulate_circling(seed=3, duration_s=20.0, with_features=True, accel_sigma=ACCEL, rate_sigma=RATE)
    cfg = SemslamConfig(motion={"accel_sigma_m_s2": ACCEL, "angular_rate_sigma_rad_s": RATE})
    r_dr = sim.run([DeadReckoning(sim.metadata, cfg), EkfEstimator(sim.metadata, cfg)])["dr"]
    r_nav = sim.run([EkfEstimator(sim.metadata, cfg)], observations=False)["ekf"]
    np.testing.assert_allclose(r_dr.trajectory.positions, r_nav.trajectory.positions)
    np.testing.assert_allclose(r_dr.trajectory.position_cov, r_nav.trajectory.position_cov)
    # DR's map is every observation placed with the DR pose
    n_obs = sum(len(v) for v in sim.observations.values())
    assert len(r_dr.landmarks) == n_obs


def _pipes_only_run(mode: str, seed: int = 1, sigma: float = 0.002):
    """A slow circle near the world origin's vertical, seeing mm-precise vertical pipes close to it (small
    ρ, as in the tank); returns (horizontal σ when the first pipe entered the map, the smallest after)."""

    sim = simulate_circling(seed=seed, duration_s=60.0, dropouts=(), with_features=False, radius_m=1.0, speed_m_s=0.1)
    rng = np.random.default_rng(seed + 100)
    pipes = [
        (np.array([x, y, 3.5]), np.array([x, y, 4.5]))
        for x, y in ((0.3, 0.2), (-0.25, 0.4), (0.2, -0.3), (-0.3, -0.2), (0.6, 0.9))
    ]
    pipes.append((np.array([-1.0, -0.5, 4.5]), np.array([1.0, -0.2, 4.5])))
    est = EkfEstimator(sim.metadata, SemslamConfig(ekf={"line_jacobians": mode}))
    first, sig = [], []

    def scan(m):  # every 2 s, every pipe seen from the true pose
        if m.stamp % 2_000_000_000 or m.stamp == 0:
            return []
        return seen_from_truth(sim, m.stamp, pipes, [], rng, sigma)

    def look(m):  # after the scan's update
        if m.stamp % 2_000_000_000 == 0 and m.stamp and len(est.map):
            s = np.sqrt(np.trace(est.nav.state.Pvv[:2, :2]))
            first.append(first[0] if first else s)
            sig.append(s)

    sim.run([est], [Scanner((Attitude,), scan), probe((Attitude,), look)], observations=False)
    assert len(est.map) == len(pipes)
    return first[0], min(sig)


def test_pipes_give_no_absolute_position_information():
    """Pipes are relative measurements: a common translation of vehicle and map stays unobservable, so
    the horizontal position σ cannot fall below its value when the map was started. Line parameters
    with the moment about the world origin change under a translation by an amount that depends on
    the estimate, strongly for lines near the origin's vertical (these pipes): with the Jacobians at
    the current estimate the σ collapsed below 0.7 of its start. With each pipe's moment about its own
    anchor, square to where it was first seen (semslam.ekf.geometry.line_anchor), it holds with either
    Jacobians."""
    for mode in ("current", "first_estimate"):
        first, smallest = _pipes_only_run(mode)
        assert smallest > 0.99 * first, mode


def _turned_line(m, d, anchor, a):
    """Parameters (moment about ``anchor``) of the line (m, d) turned by ``a`` about the world's vertical."""
    Rz = geo.rot(0.0, 0.0, a)
    return geo.line_params(Rz @ m - np.cross(anchor, Rz @ d), Rz @ d)


def _yaw_null_space(est, nv):
    """The rotation of vehicle and map about the world's vertical (the bias taking the opposite turn), in
    first estimates: vehicle at the propagated position, each feature at its first estimate."""
    from semslam.ekf.geometry import anchored_plucker

    ez = np.array([0.0, 0.0, 1.0])
    N_x = np.zeros(nv)
    N_x[:3] = np.cross(ez, est.nav.p_fe)
    N_x[5] = 1.0
    N_x[9] = -1.0
    N_l = {}
    for f in est.map.features:
        if f.kind == "object":
            N_l[f.id] = np.cross(ez, f.l_first)
        else:  # the line rotated by δ about the vertical through the origin (its anchor stays), numerically
            m, d = anchored_plucker(f.l_first, f.anchor)
            h = 1e-6
            lp, lm = (_turned_line(m, d, f.anchor, a) for a in (h, -h))
            N_l[f.id] = np.r_[geo.wrap(lp[:3] - lm[:3]), lp[3] - lm[3]] / (2 * h)
    return N_x, N_l


@pytest.mark.parametrize("mode", ["first_estimate", "current"])
def test_heading_first_estimates_keep_the_rotation_about_the_vertical_unobservable(mode):
    """With the AHRS heading bias modelled, only the map observes the heading; a common rotation of
    vehicle and map about the vertical (the bias turning back) changes no measurement. The filter's
    linearisation must not observe it: the prediction Jacobians carry the null space of one step to the
    next (F N_k = N_k+1) and every landmark Jacobian annihilates it (H N = 0), in first estimates — with
    heading_jacobians = first_estimate exactly, with the textbook Jacobians not."""
    from semslam.ekf.features import ScanPairs
    from semslam.mapping.builder import Scan

    sim = simulate_circling(seed=4, duration_s=40.0, accel_sigma=ACCEL, rate_sigma=RATE, heading_bias_walk=0.003)
    cfg = SemslamConfig(
        motion={"accel_sigma_m_s2": ACCEL, "angular_rate_sigma_rad_s": RATE},
        ekf={"heading_jacobians": mode},
        sensors={"heading_bias_rate_sigma_rad_per_s": 0.0},  # a random-walk bias: the 10-state filter
    )
    est = EkfEstimator(sim.metadata, cfg)
    steps, worst_H, kinds, n_pairs = [], 0.0, set(), 0
    state = est.nav

    def look(m):  # after the filter took m, before the scan's observations
        nonlocal worst_H, n_pairs
        if state.state is not None and not steps:
            predict = state.state.predict_vehicle

            def spy(xv, F, Q, _predict=predict):
                steps.append((xv[:3].copy(), F.copy()))  # the propagated position, the step's Jacobian
                _predict(xv, F, Q)

            state.state.predict_vehicle = spy
            steps.append((state.p_fe.copy(), None))
        obs = sim.observations.get(m.stamp) if isinstance(m, PointCloud) else None
        if obs and len(est.map):  # the scan's landmark Jacobians against the null space in first estimates
            est.map.begin()
            pairs = ScanPairs(est.map, est.map.prepared(obs), 0.999, Scan(est.book, est.assoc, *[np.zeros((0, 3))] * 2))
            N_x, N_l = _yaw_null_space(est, 10)
            for k, j in enumerate(pairs.feat):
                f = est.map.features[j]
                worst_H = max(worst_H, np.abs(pairs.H_x[k] @ N_x[:9] + pairs.H_l[k] @ N_l[f.id]).max())
                kinds.add(f.kind)
                n_pairs += 1

    sim.run([est], before=[probe((Attitude, Depth, DvlVelocity, GroundTruthPose, PointCloud), look)])
    # propagation: F N(p_k) = N(p_k+1), N at the positions the Jacobians are taken at
    ez = np.array([0.0, 0.0, 1.0])
    worst_F = 0.0
    for (p0, _), (p1, F) in zip(steps[:-1], steps[1:]):
        N0, N1 = np.zeros(10), np.zeros(10)
        N0[:3], N1[:3] = np.cross(ez, p0), np.cross(ez, p1)
        N0[5] = N1[5] = 1.0
        N0[9] = N1[9] = -1.0
        worst_F = max(worst_F, np.abs(F @ N0 - N1).max())
    assert n_pairs > 20 and kinds == {"object", "pipe"}
    if mode == "first_estimate":
        assert worst_F < 1e-12 and worst_H < 1e-5, (worst_F, worst_H)
    else:  # each step starts from the updated position, each Jacobian at the updated estimates
        assert worst_F > 1e-3 and worst_H > 1e-3, (worst_F, worst_H)
