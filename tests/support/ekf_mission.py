"""A small synthetic mission for testing the EKF on its own: a vehicle circling over a few pipes and
objects, with DVL (dropouts), AHRS (with body rate) and depth readings, ground-truth poses, and noisy
point/line observations in a down-looking sensor's frame.

The truth follows the filter's own motion model (body velocity = nominal + random walk of density
``accel_sigma``; attitude driven by the true body rate), and the AHRS rate noise is drawn so that its
integral has density ``rate_sigma``, so that a consistent filter must show NEES ≈ its dimension.
With ``heading_bias_walk`` > 0 the AHRS heading carries a bias drawn from the filter's model too
(b₀ ~ N(0, ``heading_bias_sigma0``²), then a random walk of that intensity), declared in the
metadata as the tank simulator declares its drift (``extras["noise"]["ahrs"]``). The gyro's bias is
declared as the simulators declare theirs (σ ``gyro_bias_sigma``, constant): with the default 0 the rates
are unbiased and declared so (no gyro-bias state); > 0 draws one constant bias per axis of the AHRS.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from semslam.ekf import geometry as geo
from semslam.mission.ground_truth import GroundTruthMap, GtObject, GtPipe
from semslam.mission.measurements import Attitude, Depth, DvlVelocity, GroundTruthPose, Measurement, PointCloud
from semslam.mission.mission import Mission, MissionMetadata, SensorInfo
from semslam.observations import LineObservation, Observation, PointObservation


def _T(R: np.ndarray, t) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T


@dataclass
class SyntheticMission:
    metadata: MissionMetadata
    measurements: list[Measurement]
    observations: dict[int, list[Observation]]  # stamp → observations of that scan
    truth_stamps: np.ndarray  # (K,) ns
    truth_states: np.ndarray  # (K, 9) [x y z φ θ ψ u v w] at truth_stamps
    extras: dict = field(default_factory=dict)  # "heading_bias": (K,) the AHRS heading bias at truth_stamps;
    # "gyro_bias_S", "gyro_bias_B": the gyro's constant bias (rad/s) in the AHRS's axes and in {B}

    def stream(self):
        """(measurement, observations or None) in stamp order, as the pipeline would feed them."""
        for m in self.measurements:
            yield m, self.observations.get(m.stamp) if m.sensor == "laser" else None

    def mission(self) -> Mission:
        return Mission.from_measurements(self.metadata, self.measurements)

    def run(self, estimators, frontends=(), observations: bool = True, before=()) -> dict:
        """Every estimator through the one driver, with the scans' observations (``observations``),
        ``frontends`` after them and ``before`` them; their results by name."""
        from semslam.pipeline import run_pipeline
        from tests.support.replay import Replay

        fes = [*before, *([Replay(self.observations)] if observations else []), *frontends]
        return run_pipeline(self.mission(), list(estimators), fes, frontend_process=False).results


def simulate_circling(
    seed: int = 0,
    duration_s: float = 120.0,
    radius_m: float = 3.0,
    speed_m_s: float = 0.3,
    depth_m: float = 2.0,
    accel_sigma: float = 0.01,
    rate_sigma: float = 0.002,
    dvl_sigma: float = 0.01,
    depth_sigma: float = 0.02,
    att_sigma: float = 0.01,
    dropouts: tuple[tuple[float, float], ...] = ((40.0, 15.0),),
    with_features: bool = True,
    point_sigma: float = 0.03,
    line_sigma: float = 0.02,
    sensor_range_m: float = 4.5,
    sensor_half_fov_rad: float = np.deg2rad(50.0),
    scan_period_s: float = 2.0,
    dt_sim: float = 0.01,
    velocity_tau_s: float | None = 30.0,
    track_gain: float = 0.1,
    heading_bias_walk: float = 0.0,
    heading_bias_sigma0: float = 0.0175,
    gyro_bias_sigma: float = 0.0,
) -> SyntheticMission:
    """Circle of ``radius_m`` at ``depth_m`` starting at the origin heading north; AHRS 20 Hz, DVL 5 Hz,
    depth 8 Hz, ground truth 10 Hz, scans every ``scan_period_s``; DVL invalid during ``dropouts``
    ((start_s, length_s), ...). The body velocity deviates from the nominal as a random walk of density
    ``accel_sigma`` pulled back with time constant ``velocity_tau_s`` (None: a pure random walk), plus a
    feedback of gain ``track_gain`` (1/s) towards the nominal circle (0: none, the model exactly). Scene: pipes and objects on a floor 2.5 m below the vehicle."""
    rng = np.random.default_rng(seed)
    R_dvl = geo.rot(0.0, 0.0, np.pi / 4)
    T_dvl = _T(R_dvl, [-0.3, 0.0, 0.25])
    T_ahrs = _T(geo.rot(0.0, 0.0, np.pi / 2), [0.1, 0.0, 0.0])
    T_depth = _T(np.eye(3), [-0.4, 0.0, -0.1])
    T_laser = _T(geo.rot(0.0, 0.0, 0.0), [0.5, 0.0, 0.2])  # z of {S} looks down
    sensors = {
        "dvl": SensorInfo("dvl", "dvl", T_BS=T_dvl),
        "ahrs": SensorInfo("ahrs", "ahrs", T_BS=T_ahrs),
        "depth": SensorInfo("depth", "depth", T_BS=T_depth),
        "laser": SensorInfo("laser", "laser", T_BS=T_laser),
        "gt": SensorInfo("gt", "ground_truth"),
    }

    # ---- truth at dt_sim: body velocity random walk around the nominal, constant yaw rate
    n = int(round(duration_s / dt_sim)) + 1
    t = np.arange(n) * dt_sim
    yaw_rate = speed_m_s / radius_m
    # Euler rates: small roll/pitch oscillations and a constant yaw rate (body rates follow from them)
    eul_rate = np.column_stack([0.01 * np.sin(0.3 * t), 0.01 * np.cos(0.2 * t), np.full(n, yaw_rate)])
    w_true = np.zeros((n, 3))
    dv = rng.normal(scale=accel_sigma * np.sqrt(dt_sim), size=(n, 3))
    tau = np.full(3, np.inf) if velocity_tau_s is None else np.full(3, velocity_tau_s)
    decay = np.exp(-dt_sim / tau)
    # the nominal circle (for the station-keeping feedback that keeps the vehicle over the scene)
    yaw_nom = yaw_rate * t
    p_nom = np.column_stack([radius_m * np.sin(yaw_nom), radius_m * (1 - np.cos(yaw_nom)), np.full(n, depth_m)])
    noise = np.zeros(3)
    v_true = np.zeros((n, 3))
    pos = np.zeros((n, 3))
    eul = np.zeros((n, 3))
    pos[0] = [0.0, 0.0, depth_m]
    for k in range(n):  # Euler integration at 1/dt_sim
        R = geo.rot(*eul[k])
        v_true[k] = [speed_m_s, 0.0, 0.0] + noise + R.T @ (track_gain * (p_nom[k] - pos[k]))
        w_true[k] = geo.euler_rate_to_body(eul[k, 0], eul[k, 1]) @ eul_rate[k]
        if k + 1 < n:
            pos[k + 1] = pos[k] + R @ v_true[k] * dt_sim
            eul[k + 1] = eul[k] + eul_rate[k] * dt_sim
            # Ornstein–Uhlenbeck deviation (a random walk of density accel_sigma over short horizons)
            noise = decay * noise + dv[k]
    eul[:, 0] = geo.wrap(eul[:, 0])
    eul[:, 2] = geo.wrap(eul[:, 2])
    ns = lambda i: int(round(t[i] * 1e9))

    def every(period):
        return np.arange(0, n, int(round(period / dt_sim)))

    meas: list[Measurement] = []
    for i in every(0.1):
        q = Rotation.from_euler("ZYX", eul[i, ::-1]).as_quat()
        meas.append(GroundTruthPose(ns(i), "gt", position=pos[i], orientation=q))
    # AHRS heading bias (its own generator: the other streams stay those of the seed without it)
    bias = np.zeros(n)
    if heading_bias_walk > 0:
        brng = np.random.default_rng([seed, 7])
        steps = brng.normal(scale=heading_bias_walk * np.sqrt(dt_sim), size=n)
        steps[0] = brng.normal(scale=heading_bias_sigma0)
        bias = np.cumsum(steps)
    # the gyro's constant bias in the AHRS's axes (its own generator too)
    gyro_bias = np.random.default_rng([seed, 11]).normal(scale=gyro_bias_sigma, size=3)
    # AHRS: orientation of {S} with Euler noise (and the bias on the heading: Rz(b) R_WS), body rate
    # in {S} with noise of density rate_sigma, plus the gyro's bias
    dt_ahrs = 0.05
    for i in every(dt_ahrs):
        R_WS = geo.rot(*eul[i]) @ T_ahrs[:3, :3]
        e_S = geo.euler(R_WS) + rng.normal(scale=att_sigma, size=3)
        e_S[2] += bias[i]
        rate = T_ahrs[:3, :3].T @ (w_true[i] + rng.normal(scale=rate_sigma / np.sqrt(dt_ahrs), size=3)) + gyro_bias
        q = Rotation.from_euler("ZYX", e_S[::-1]).as_quat()
        meas.append(Attitude(ns(i), "ahrs", orientation=q, covariance=np.eye(3) * att_sigma**2, angular_rate=rate))
    for i in every(0.2):
        valid = not any(s <= t[i] < s + d for s, d in dropouts)
        R_BS, t_BS = T_dvl[:3, :3], T_dvl[:3, 3]
        v = R_BS.T @ (v_true[i] + np.cross(w_true[i], t_BS)) + rng.normal(scale=dvl_sigma, size=3)
        meas.append(
            DvlVelocity(
                ns(i),
                "dvl",
                velocity=v if valid else np.full(3, np.nan),
                covariance=np.eye(3) * dvl_sigma**2,
                valid=valid,
            )
        )
    for i in every(0.125):
        z = pos[i, 2] + (geo.rot(*eul[i]) @ T_depth[:3, 3])[2] + rng.normal(scale=depth_sigma)
        meas.append(Depth(ns(i), "depth", depth=z, variance=depth_sigma**2))

    # ---- scene and observations
    floor = depth_m + 2.5
    c = np.array([0.0, radius_m, 0.0])  # the circle's centre (the vehicle starts north-bound, turning east)
    pipes = [
        GtPipe(0, tuple(c + [-4.0, -2.0, floor]), tuple(c + [4.0, -2.0, floor]), 0.05),
        GtPipe(1, tuple(c + [-2.0, -4.0, floor]), tuple(c + [-2.0, 4.0, floor - 0.3]), 0.05),
        GtPipe(2, tuple(c + [1.0, 3.5, floor - 0.2]), tuple(c + [4.0, 0.5, floor - 0.2]), 0.05),
    ]
    objects = [
        GtObject(0, "valve", tuple(c + [0.0, -2.0, floor])),
        GtObject(1, "elbow", tuple(c + [-2.0, 0.0, floor - 0.15])),
        GtObject(2, "tee", tuple(c + [2.5, 2.0, floor - 0.2])),
        GtObject(3, "valve", tuple(c + [3.5, -3.5, floor])),
        GtObject(4, "flange", tuple(c + [-3.0, 3.0, floor])),
    ]
    obs: dict[int, list[Observation]] = {}
    seen_o, seen_p = set(), set()
    if with_features:
        R_BS, t_BS = T_laser[:3, :3], T_laser[:3, 3]
        for i in every(scan_period_s)[1:]:
            R_WS = geo.rot(*eul[i]) @ R_BS
            t_WS = pos[i] + geo.rot(*eul[i]) @ t_BS
            batch: list[Observation] = []

            def visible(pw):
                ps = (pw - t_WS) @ R_WS  # noqa: B023
                r = np.linalg.norm(ps, axis=-1)
                ang = np.arccos(np.clip(ps[..., 2] / np.maximum(r, 1e-9), -1, 1))
                return (r < sensor_range_m) & (ang < sensor_half_fov_rad), ps

            for o in objects:
                ok, ps = visible(np.array(o.position))
                if ok:
                    seen_o.add(o.id)
                    cov = np.eye(3) * point_sigma**2
                    batch.append(
                        PointObservation(
                            ns(i),
                            "laser",
                            position=ps + rng.normal(scale=point_sigma, size=3),
                            covariance=cov,
                            class_likelihood={o.cls: 0.8, "other": 0.2},
                            truth_id=o.id,
                        )
                    )
            for p in pipes:
                s = np.linspace(0.0, 1.0, 200)
                pts = np.array(p.p) + s[:, None] * (np.array(p.q) - np.array(p.p))
                ok, ps = visible(pts)
                if ok.sum() < 2:
                    continue
                a, b = np.flatnonzero(ok)[[0, -1]]
                if np.linalg.norm(ps[b] - ps[a]) < 0.3:
                    continue
                seen_p.add(p.id)
                e = rng.normal(scale=line_sigma, size=(2, 3))
                batch.append(
                    LineObservation(
                        ns(i),
                        "laser",
                        p=ps[a] + e[0],
                        q=ps[b] + e[1],
                        covariance=np.eye(6) * line_sigma**2,
                        radius=p.radius,
                        truth_id=p.id,
                    )
                )
            if batch:
                obs[ns(i)] = batch
                # the scan itself: a marker measurement at the scan stamp (the pipeline's PointCloud)
                meas.append(PointCloud(ns(i), "laser"))
    meas.sort(key=lambda m: m.stamp)
    gt_map = GroundTruthMap(
        classes=("valve", "elbow", "tee", "flange"),
        objects=tuple(objects),
        pipes=tuple(pipes),
        seen_objects=tuple(sorted(seen_o)),
        seen_pipes=tuple(sorted(seen_p)),
    )
    # the gyro's bias declared as the simulators declare it (0: unbiased rates, no bias state)
    ahrs_noise = {"gyro_bias_sigma_rad_s": gyro_bias_sigma, "gyro_bias_walk_rad_s_per_sqrt_s": 0.0}
    if heading_bias_walk > 0:  # declared as the tank simulator does: a drift over the mission
        ahrs_noise |= {
            "heading_bias_drift_rad": heading_bias_walk * np.sqrt(duration_s),
            "heading_bias_drift_over_s": duration_s,
            "heading_bias_initial_sigma_rad": heading_bias_sigma0,
        }
    extras = {"noise": {"ahrs": ahrs_noise}}
    meta = MissionMetadata("synthetic-circling", sensors, ground_truth=gt_map, extras=extras)
    truth = np.column_stack([pos, eul, v_true])
    idx = every(0.05)
    return SyntheticMission(
        meta,
        meas,
        obs,
        np.array([ns(i) for i in range(n)], np.int64)[idx],
        truth[idx],
        extras={"heading_bias": bias[idx], "gyro_bias_S": gyro_bias, "gyro_bias_B": T_ahrs[:3, :3] @ gyro_bias},
    )


def seen_from_truth(
    sim: SyntheticMission, stamp: int, segments, points, rng, line_sigma: float, point_sigma: float = 0.0
):
    """Pipe segments ((a, b) in {W}) and object points ({W}) as the laser sees them at ``stamp`` from the
    true pose, with white noise of the given σ per coordinate and that σ as their covariance."""
    from semslam.ekf.models import sensor_pose

    T = sim.metadata.sensors["laser"].T_BS
    xt = sim.truth_states[np.searchsorted(sim.truth_stamps, stamp)]
    R, t, _, _ = sensor_pose(xt, T[:3, :3], T[:3, 3])
    obs: list[Observation] = [
        LineObservation(
            stamp,
            "laser",
            p=(a - t) @ R + rng.normal(0, line_sigma, 3),
            q=(b - t) @ R + rng.normal(0, line_sigma, 3),
            covariance=np.eye(6) * line_sigma**2,
        )
        for a, b in segments
    ]
    obs += [
        PointObservation(
            stamp, "laser", position=(c - t) @ R + rng.normal(0, point_sigma, 3), covariance=np.eye(3) * point_sigma**2
        )
        for c in points
    ]
    return obs
