"""A small synthetic mission generator for testing and benchmarking the graph back-end (test scaffolding).

Not the tank simulator (``semslam.sim``): a smooth analytic trajectory (a circle, or a lawnmower
for long missions) over a flat seabed with objects and pipes, and the navigation sensors the
back-end needs (DVL with lever arm and dropouts, AHRS, depth), ground-truth poses, and laser scan
stamps (empty clouds: the oracle front-end only needs to know when the laser scans).
Frames and units are those of DESIGN.md ({W} NED, {B} x fwd / y right / z down, SI, ns stamps).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from semslam.mission.ground_truth import GroundTruthMap, GtObject, GtPipe, GtStructure
from semslam.mission.measurements import Attitude, Depth, DvlVelocity, GroundTruthPose, PointCloud
from semslam.mission.mission import Mission, MissionMetadata, SensorInfo

CLASSES = ("valve", "elbow", "tee", "flange", "reducer", "cap")


@dataclass
class SyntheticConfig:
    duration_s: float = 240.0
    path: str = "circle"  # "circle" or "lawnmower"
    radius_m: float = 4.0  # circle radius
    speed_m_s: float = 0.25
    lane_length_m: float = 40.0  # lawnmower
    lane_spacing_m: float = 4.0
    n_lanes: int = 8
    vehicle_depth_m: float = 2.0
    seabed_depth_m: float = 5.0
    n_objects: int = 20
    n_pipes: int = 12
    n_structures: int = 1
    min_separation_m: float = 1.0
    dvl_rate_hz: float = 5.0
    ahrs_rate_hz: float = 20.0
    depth_rate_hz: float = 8.0
    laser_rate_hz: float = 0.5
    gt_rate_hz: float = 20.0
    dvl_sigma_m_s: float = 0.01
    dvl_bias_m_s: tuple[float, float, float] = (0.003, -0.002, 0.0)  # slow error that makes DR drift
    ahrs_sigma_rp_rad: float = 0.003
    ahrs_sigma_yaw_rad: float = 0.01
    ahrs_yaw_bias_rad: float = 0.01
    depth_sigma_m: float = 0.01
    dropouts: tuple[tuple[float, float], ...] = ()  # (start_s, duration_s) of DVL dropouts
    seed: int = 0
    extras: dict = field(default_factory=dict)


def _rot(rpy) -> np.ndarray:
    return Rotation.from_euler("xyz", rpy).as_matrix()


def _T(R, t) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T


EXTRINSICS = {
    "dvl": _T(_rot([0.0, 0.0, np.pi / 4]), [0.4, 0.05, 0.25]),
    "ahrs": _T(_rot([0.0, 0.0, 0.02]), [0.0, 0.0, 0.0]),
    "depth": _T(np.eye(3), [-0.5, 0.0, -0.1]),
    "laser": _T(_rot([0.0, 0.0, np.pi / 2]), [0.6, 0.0, 0.3]),  # looks down (+z) like the body
    "gt": np.eye(4),
}
KINDS = {"dvl": "dvl", "ahrs": "ahrs", "depth": "depth", "laser": "laser", "gt": "ground_truth"}


class _Trajectory:
    """Body pose and rates as smooth functions of time."""

    def __init__(self, cfg: SyntheticConfig):
        self.cfg = cfg
        if cfg.path == "lawnmower":
            self._build_lawnmower()

    def _build_lawnmower(self):
        c = self.cfg
        pts = []
        for k in range(c.n_lanes):
            x0, x1 = (0.0, c.lane_length_m) if k % 2 == 0 else (c.lane_length_m, 0.0)
            y = k * c.lane_spacing_m
            pts += [(x0, y), (x1, y)]
        pts = np.array(pts)
        # Densify with rounded corners: a closed loop of the lanes, smoothed by a periodic spline.
        from scipy.interpolate import CubicSpline

        loop = np.vstack(
            [
                pts,
                [pts[-1][0], pts[-1][1] + c.lane_spacing_m],
                [pts[0][0] - c.lane_spacing_m, pts[-1][1]],
                [pts[0][0] - c.lane_spacing_m, -c.lane_spacing_m],
                [pts[0][0], -c.lane_spacing_m * 0.5],
                pts[:1],
            ]
        )
        seg = np.linalg.norm(np.diff(loop, axis=0), axis=1)
        s = np.concatenate([[0], np.cumsum(seg)])
        fine = np.linspace(0, s[-1], 20 * len(loop))
        lin = np.column_stack([np.interp(fine, s, loop[:, 0]), np.interp(fine, s, loop[:, 1])])
        # Smooth corners with a moving average (periodic).
        k = 15
        ker = np.ones(k) / k
        ext = np.vstack([lin[-k:], lin, lin[:k]])
        sm = np.column_stack([np.convolve(ext[:, i], ker, "same") for i in range(2)])[k:-k]
        sm = np.vstack([sm, sm[:1]])
        arc = np.concatenate([[0], np.cumsum(np.linalg.norm(np.diff(sm, axis=0), axis=1))])
        self._spline = CubicSpline(arc, sm, bc_type="periodic")
        self._loop_len = arc[-1]

    def xy(self, t):
        c = self.cfg
        if c.path == "circle":
            w = c.speed_m_s / c.radius_m
            # A slow radial sway so that the motion is not a pure constant turn.
            r = c.radius_m + 0.3 * np.sin(0.05 * t)
            return np.stack([r * np.cos(w * t), r * np.sin(w * t)], axis=-1)
        return self._spline((c.speed_m_s * t) % self._loop_len)

    def pose(self, t: np.ndarray):
        """Positions (N,3), rotations (N,3,3), world velocities (N,3), body angular rates (N,3)."""
        c = self.cfg
        t = np.asarray(t, float)
        h = 1e-3
        xy = self.xy(t)
        dxy = (self.xy(t + h) - self.xy(t - h)) / (2 * h)
        z = c.vehicle_depth_m + 0.2 * np.sin(0.03 * t)
        dz = 0.2 * 0.03 * np.cos(0.03 * t)
        pos = np.column_stack([xy, z])
        vel = np.column_stack([dxy, dz])
        R = self.rot(t)
        Rp, Rm = self.rot(t + h), self.rot(t - h)
        # ω_B from R(t+h) ≈ R(t−h) Exp(2h ω_B)
        omega = Rotation.from_matrix(np.einsum("nji,njk->nik", Rm, Rp)).as_rotvec() / (2 * h)
        return pos, R, vel, omega

    def rot(self, t):
        h = 1e-3
        dxy = (self.xy(t + h) - self.xy(t - h)) / (2 * h)
        yaw = np.arctan2(dxy[:, 1], dxy[:, 0]) + 0.05 * np.sin(0.1 * t)  # a little crab
        roll = 0.03 * np.sin(0.21 * t)
        pitch = 0.02 * np.sin(0.17 * t + 1.0)
        return Rotation.from_euler("ZYX", np.column_stack([yaw, pitch, roll])).as_matrix()


def _place_landmarks(cfg: SyntheticConfig, traj: _Trajectory, rng) -> GroundTruthMap:
    """Objects and pipes on the seabed along the path (within 2.5 m of it), kept apart."""
    tt = np.linspace(0, cfg.duration_s, 2000)
    path = traj.xy(tt)
    sep = cfg.min_separation_m
    grid: dict[tuple[int, int], list[np.ndarray]] = {}  # cell → sample points, for O(1) separation checks

    def cells(pts):
        return {(int(np.floor(x / sep)), int(np.floor(y / sep))) for x, y in pts[:, :2]}

    def free(pts):
        near = [
            p
            for cx, cy in cells(pts)
            for dx in (-1, 0, 1)
            for dy in (-1, 0, 1)
            for p in grid.get((cx + dx, cy + dy), ())
        ]
        if not near:
            return True
        d = np.linalg.norm(pts[:, None, :2] - np.array(near)[None, :, :2], axis=2)
        return d.min() >= sep

    def place(pts):
        for p in pts:
            grid.setdefault((int(np.floor(p[0] / sep)), int(np.floor(p[1] / sep))), []).append(p)

    def near_path():
        base = path[rng.integers(len(path))]
        ang = rng.uniform(0, 2 * np.pi)
        return base + rng.uniform(0, 2.0) * np.array([np.cos(ang), np.sin(ang)])

    objects, pipes, structures = [], [], []
    for _ in range(50 * (cfg.n_pipes + 1)):
        if len(pipes) >= cfg.n_pipes:
            break
        a = near_path()
        ang = rng.uniform(0, np.pi)
        L = rng.uniform(1.0, 2.5)
        b = a + L * np.array([np.cos(ang), np.sin(ang)])
        zz = cfg.seabed_depth_m - 0.1
        samples = np.column_stack([np.linspace(a[0], b[0], 12), np.linspace(a[1], b[1], 12), np.full(12, zz)])
        if free(samples):
            place(samples)
            pipes.append(GtPipe(len(pipes), (a[0], a[1], zz), (b[0], b[1], zz), 0.05))
    for _ in range(50 * (cfg.n_objects + 1)):
        if len(objects) >= cfg.n_objects:
            break
        a = near_path()
        p = np.array([a[0], a[1], cfg.seabed_depth_m - 0.15])
        if free(p[None]):
            place(p[None])
            objects.append(GtObject(100 + len(objects), CLASSES[len(objects) % len(CLASSES)], tuple(p)))
    for k in range(cfg.n_structures):
        a = near_path()
        structures.append(
            GtStructure(1000 + k, "manifold", (a[0], a[1], cfg.seabed_depth_m - 0.5), (0, 0, np.sin(0.3), np.cos(0.3)))
        )
    return GroundTruthMap(classes=CLASSES, objects=tuple(objects), pipes=tuple(pipes), structures=tuple(structures))


def simulate(cfg: SyntheticConfig | None = None) -> Mission:
    """A synthetic mission following ``cfg`` (see :class:`SyntheticConfig`)."""
    cfg = cfg or SyntheticConfig()
    rng = np.random.default_rng(cfg.seed)
    traj = _Trajectory(cfg)
    gt_map = _place_landmarks(cfg, traj, rng)
    sensors = {n: SensorInfo(n, KINDS[n], topic=f"/{n}", T_BS=T) for n, T in EXTRINSICS.items()}
    meas = []

    def stamps(rate):
        return np.arange(0.0, cfg.duration_s + 1e-9, 1.0 / rate)

    def ns(t):
        return int(round(t * 1e9))

    # Ground truth.
    t = stamps(cfg.gt_rate_hz)
    pos, R, _, _ = traj.pose(t)
    q = Rotation.from_matrix(R).as_quat()
    meas += [GroundTruthPose(ns(ti), "gt", position=p, orientation=qi) for ti, p, qi in zip(t, pos, q)]
    # DVL: v_S = R_SB (v_B + ω × t_BS), with white noise, a small bias and dropouts.
    t = stamps(cfg.dvl_rate_hz)
    _, R, vel, om = traj.pose(t)
    T_BS = EXTRINSICS["dvl"]
    v_B = np.einsum("nji,nj->ni", R, vel)
    v_S = (v_B + np.cross(om, T_BS[:3, 3])) @ T_BS[:3, :3]
    v_S += rng.normal(size=v_S.shape) * cfg.dvl_sigma_m_s + np.asarray(cfg.dvl_bias_m_s)
    cov = np.eye(3) * cfg.dvl_sigma_m_s**2
    for ti, v in zip(t, v_S):
        valid = not any(s <= ti < s + d for s, d in cfg.dropouts)
        meas.append(
            DvlVelocity(ns(ti), "dvl", velocity=v if valid else np.full(3, np.nan), covariance=cov, valid=valid)
        )
    # AHRS: R_WS = R_WB R_BS with roll/pitch/yaw noise and a constant heading bias.
    t = stamps(cfg.ahrs_rate_hz)
    _, R, _, om = traj.pose(t)
    R_BS = EXTRINSICS["ahrs"][:3, :3]
    ypr = Rotation.from_matrix(R @ R_BS).as_euler("ZYX")
    ypr[:, 0] += rng.normal(size=len(t)) * cfg.ahrs_sigma_yaw_rad + cfg.ahrs_yaw_bias_rad
    ypr[:, 1:] += rng.normal(size=(len(t), 2)) * cfg.ahrs_sigma_rp_rad
    qs = Rotation.from_euler("ZYX", ypr).as_quat()
    acov = np.diag([cfg.ahrs_sigma_rp_rad**2, cfg.ahrs_sigma_rp_rad**2, cfg.ahrs_sigma_yaw_rad**2])
    rates = om @ R_BS  # ω_S = R_SB ω_B
    meas += [
        Attitude(ns(ti), "ahrs", orientation=qi, covariance=acov, angular_rate=w) for ti, qi, w in zip(t, qs, rates)
    ]
    # Depth of the pressure sensor.
    t = stamps(cfg.depth_rate_hz)
    pos, R, _, _ = traj.pose(t)
    d = pos[:, 2] + R[:, 2, :] @ EXTRINSICS["depth"][:3, 3] + rng.normal(size=len(t)) * cfg.depth_sigma_m
    meas += [Depth(ns(ti), "depth", depth=float(di), variance=cfg.depth_sigma_m**2) for ti, di in zip(t, d)]
    # Laser scan stamps.
    meas += [PointCloud(ns(ti), "laser") for ti in stamps(cfg.laser_rate_hz)[1:]]
    md = MissionMetadata(name=f"synthetic-{cfg.path}", sensors=sensors, ground_truth=gt_map, extras=dict(cfg.extras))
    return Mission.from_measurements(md, meas)


# ----------------------------------------------------------------------------------------------
# Reference dead reckoning and error helpers (for tests and benchmarks)


def dead_reckoning(mission: Mission) -> tuple[np.ndarray, np.ndarray]:
    """DVL + AHRS + depth dead reckoning from the first true pose: (stamps ns, positions (N,3)).

    Horizontal position integrates R_WB v_B (lever-arm corrected) at the DVL rate, holding the last
    velocity over dropouts (what a plain dead reckoner does); depth comes from the pressure sensor.
    """
    md = mission.metadata
    T_dvl = next(s.T_BS for s in md.sensors.values() if s.kind == "dvl")
    R_ahrs = next(s.T_BS for s in md.sensors.values() if s.kind == "ahrs")[:3, :3]
    t_depth = next(s.T_BS for s in md.sensors.values() if s.kind == "depth")[:3, 3]
    pos = None
    R = np.eye(3)
    omega = np.zeros(3)
    v_B = np.zeros(3)
    last_t = None
    out_t, out_p = [], []
    for m in mission:
        if isinstance(m, GroundTruthPose) and pos is None:
            pos = np.array(m.position, float)
            last_t = m.stamp
        if pos is None:
            continue
        if isinstance(m, Attitude):
            R = Rotation.from_quat(m.orientation).as_matrix() @ R_ahrs.T
            if m.angular_rate is not None:
                omega = R_ahrs @ m.angular_rate
        elif isinstance(m, DvlVelocity):
            dt = (m.stamp - last_t) * 1e-9
            pos = pos + R @ v_B * dt
            last_t = m.stamp
            if m.valid:
                v_B = T_dvl[:3, :3] @ m.velocity - np.cross(omega, T_dvl[:3, 3])
            out_t.append(m.stamp)
            out_p.append(pos.copy())
        elif isinstance(m, Depth):
            pos[2] = m.depth - R[2] @ t_depth
    return np.array(out_t, np.int64), np.array(out_p)


def ground_truth_positions(mission: Mission) -> tuple[np.ndarray, np.ndarray]:
    gts = list(mission.of_type(GroundTruthPose))
    return np.array([g.stamp for g in gts], np.int64), np.array([g.position for g in gts])


def position_errors(stamps: np.ndarray, positions: np.ndarray, gt_stamps: np.ndarray, gt_pos: np.ndarray) -> np.ndarray:
    """Euclidean position errors (no alignment) against ground truth interpolated at ``stamps``."""
    ref = np.column_stack([np.interp(stamps, gt_stamps, gt_pos[:, i]) for i in range(3)])
    return np.linalg.norm(positions - ref, axis=1)


@dataclass
class LandmarkReport:
    """Mapped landmarks against ground truth, through the ``truth_id`` of their observations
    (evaluation only: the estimator never reads it)."""

    errors_m: (
        dict  # landmark id → error (object/structure: position; pipe: mean distance of the GT axis ends to the line)
    )
    truth_of: dict  # landmark id → majority truth id (None: a false positive)
    duplicated: list  # (kind, truth id) mapped by more than one landmark
    wrongly_merged: list  # landmark ids whose observations come from more than one truth id (or mix in false positives)
    missed: list  # truth ids observed at least min_obs times but not mapped

    @property
    def median_error_m(self) -> float:
        return float(np.median(list(self.errors_m.values()))) if self.errors_m else float("nan")


def landmark_report(result, gt: GroundTruthMap) -> LandmarkReport:
    from collections import Counter

    hist = result.history.get("landmark_observations", {})
    objects = {o.id: o for o in gt.objects}
    pipes = {p.id: p for p in gt.pipes}
    structures = {s.id: s for s in gt.structures}
    errors, truth_of, merged = {}, {}, []
    for lm in result.landmarks:
        ids = [tid for _, tid in hist.get(lm.id, [])]
        counts = Counter(ids)
        tid = counts.most_common(1)[0][0] if counts else None
        truth_of[lm.id] = tid
        if len(counts) > 1:
            merged.append(lm.id)
        if tid is None:
            continue
        if lm.kind == "object" and tid in objects:
            errors[lm.id] = float(np.linalg.norm(lm.position - np.asarray(objects[tid].position)))
        elif lm.kind == "pipe" and tid in pipes:
            d = (lm.q - lm.p) / np.linalg.norm(lm.q - lm.p)
            ends = np.array([pipes[tid].p, pipes[tid].q]) - lm.p
            errors[lm.id] = float(np.mean(np.linalg.norm(ends - np.outer(ends @ d, d), axis=1)))
        elif lm.kind == "structure" and tid in structures:
            errors[lm.id] = float(np.linalg.norm(lm.pose[:3, 3] - np.asarray(structures[tid].position)))
    # Truth ids are unique per kind only (the tank's object 14 and pipe 14 are different things).
    kind_of = {lm.id: lm.kind for lm in result.landmarks}
    c = Counter((kind_of[i], t) for i, t in truth_of.items() if t is not None)
    return LandmarkReport(errors, truth_of, sorted(t for t, n in c.items() if n > 1), merged, [])


def run_graph(mission, config=None, frontends=(), batch: bool | None = None):
    """The graph back-end alone over ``mission`` with ``frontends`` (which see its view), through the
    one driver; its result."""
    from semslam.backend.graph import GraphEstimator
    from semslam.pipeline import run_pipeline

    est = GraphEstimator(mission.metadata, config, batch=batch)
    return run_pipeline(mission, [est], frontends, keep_observations=False).results[est.name]
