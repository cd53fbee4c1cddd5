"""The navigation filter is consistent: average NEES of the 9-state vehicle estimate within the 95 %
χ² bounds over Monte Carlo runs of a simulated navigation-only mission (with a DVL dropout).
A larger study is ``experiments/ekf_nees_study.py``."""

import numpy as np
from scipy.stats import chi2

from semslam.config import SemslamConfig
from semslam.ekf import DeadReckoning, EkfEstimator
from semslam.ekf import geometry as geo
from semslam.ekf.synthetic import simulate_circling

ACCEL, RATE = 0.01, 0.002
N_RUNS = 6


def nees_run(seed: int, duration_s: float = 50.0, sample_every_s: float = 1.0):
    """NEES (9 dof) of one run sampled every ``sample_every_s``, and the position σ over time."""
    sim = simulate_circling(seed=seed, duration_s=duration_s, accel_sigma=ACCEL, rate_sigma=RATE,
                            dropouts=((20.0, 12.0),), with_features=False, velocity_tau_s=None, track_gain=0.0)
    cfg = SemslamConfig(motion={"accel_sigma_m_s2": ACCEL, "angular_rate_sigma_rad_s": RATE})
    est = EkfEstimator(sim.metadata, cfg)
    ts = sim.truth_stamps
    period = int(sample_every_s * 1e9)
    nees, sd, times = [], [], []
    for m in sim.measurements:
        est.process_measurement(m)
        if m.sensor == "ahrs" and m.stamp % period == 0 and m.stamp > 0:
            i = np.searchsorted(ts, m.stamp)
            e = est.state.x[:9] - sim.truth_states[i]
            e[3:6] = geo.wrap(e[3:6])
            P = est.state.P[:9, :9]
            nees.append(e @ np.linalg.solve(P, e))
            sd.append(np.sqrt(np.trace(P[:2, :2])))
            times.append(m.stamp * 1e-9)
    return np.array(times), np.array(nees), np.array(sd)


def test_navigation_filter_is_consistent():
    runs = [nees_run(seed) for seed in range(N_RUNS)]
    times = runs[0][0]
    anees = np.mean([r[1] for r in runs], axis=0)  # average over runs at each time
    lo, hi = chi2.ppf([0.025, 0.975], 9 * N_RUNS) / N_RUNS
    inside = np.mean((anees > lo) & (anees < hi))
    assert inside >= 0.85, f"ANEES inside [{lo:.2f}, {hi:.2f}] only {inside:.0%} of the time: {anees.round(1)}"
    # over the whole mission the mean NEES is close to the dimension (9)
    assert 9 * 0.75 < anees.mean() < 9 * 1.25
    # the DVL dropout (20–32 s) makes the horizontal uncertainty grow, and it stops growing after it
    sd = runs[0][2]
    before, after_drop, end = sd[times == 19][0], sd[times == 32][0], sd[-1]
    assert after_drop > 2 * before
    assert end < 1.3 * after_drop


def test_dead_reckoning_is_the_same_filter_without_features():
    sim = simulate_circling(seed=3, duration_s=20.0, with_features=True, accel_sigma=ACCEL, rate_sigma=RATE)
    cfg = SemslamConfig(motion={"accel_sigma_m_s2": ACCEL, "angular_rate_sigma_rad_s": RATE})
    dr, ekf = DeadReckoning(sim.metadata, cfg), EkfEstimator(sim.metadata, cfg)
    nav_only = EkfEstimator(sim.metadata, cfg)
    for m, obs in sim.stream():
        for est in (dr, ekf, nav_only):
            est.process_measurement(m)
        if obs:
            dr.process_observations(m.stamp, obs)
            ekf.process_observations(m.stamp, obs)
    r_dr, r_nav = dr.finish(), nav_only.finish()
    np.testing.assert_allclose(r_dr.trajectory.positions, r_nav.trajectory.positions)
    np.testing.assert_allclose(r_dr.trajectory.position_cov, r_nav.trajectory.position_cov)
    # DR's map is every observation placed with the DR pose
    n_obs = sum(len(v) for v in sim.observations.values())
    assert len(r_dr.landmarks) == n_obs


def _pipes_only_run(mode: str, seed: int = 1, sigma: float = 0.002):
    """A slow circle near the world origin's vertical, seeing mm-precise vertical pipes close to it (small
    ρ, as in the tank); returns (horizontal σ when the first pipe entered the map, the smallest after)."""
    from semslam.ekf import models as mdl
    from semslam.observations import LineObservation

    sim = simulate_circling(seed=seed, duration_s=60.0, dropouts=(), with_features=False, radius_m=1.0, speed_m_s=0.1)
    rng = np.random.default_rng(seed + 100)
    T = sim.metadata.sensors["laser"].T_BS
    pipes = [(np.array([x, y, 3.5]), np.array([x, y, 4.5]))
             for x, y in ((0.3, 0.2), (-0.25, 0.4), (0.2, -0.3), (-0.3, -0.2), (0.6, 0.9))]
    pipes.append((np.array([-1.0, -0.5, 4.5]), np.array([1.0, -0.2, 4.5])))
    est = EkfEstimator(sim.metadata, SemslamConfig(ekf={"line_jacobians": mode}))
    first, sig = None, []
    for m in sim.measurements:
        est.process_measurement(m)
        if m.sensor != "ahrs" or m.stamp % 2_000_000_000 or m.stamp == 0:
            continue
        xt = sim.truth_states[np.searchsorted(sim.truth_stamps, m.stamp)]
        R, t, _, _ = mdl.sensor_pose(xt, T[:3, :3], T[:3, 3])
        est.process_observations(m.stamp, [
            LineObservation(m.stamp, "laser", p=(a - t) @ R + rng.normal(0, sigma, 3), q=(b - t) @ R + rng.normal(0, sigma, 3),
                            covariance=np.eye(6) * sigma**2) for a, b in pipes])
        if est._features:
            s = np.sqrt(np.trace(est.state.Pvv[:2, :2]))
            first = first or s
            sig.append(s)
    assert len(est._features) == len(pipes)
    return first, min(sig)


def test_pipes_give_no_absolute_position_information():
    """Pipes are relative measurements: a common translation of vehicle and map stays unobservable, so
    the horizontal position σ cannot fall below its value when the map was started. With the pipe
    Jacobians at the current estimate, the world-origin line parameters (whose change under a
    translation depends on the estimate, strongly for lines near the origin's vertical) make it
    observable and the σ collapses; the first-estimates Jacobians keep it."""
    first, smallest = _pipes_only_run("current")
    assert smallest < 0.7 * first
    first, smallest = _pipes_only_run("first_estimate")
    assert smallest > 0.99 * first
