"""Sensor models of the simulated vehicle: DVL, AHRS, pressure (depth), GPS, laser scanner, ground truth.

Each model samples the true trajectory at its own stamps (integer ns), expresses the quantity in its
sensor frame {S} through the extrinsic T_BS, and adds the declared noise: the covariances written in
the messages are exactly the noise that was added. Every model draws its noise from its own random
stream and draws it for every sample (valid or not), so that changing one setting (e.g. the dropout
rate) does not reshuffle the noise of the others.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from semslam.mission.measurements import Attitude, Depth, DvlVelocity, GpsFix, GroundTruthPose, PointCloud
from semslam.sim.config import AhrsConfig, DepthConfig, DvlConfig, LaserConfig
from semslam.sim.field_config import GpsConfig
from semslam.sim.raycast import NO_HIT, LabelledScene
from semslam.sim.tank import OBJECT, PIPE, WALL, TankScene
from semslam.sim.trajectory import MotionModel, Trajectory


def sample_times(
    start_ns: int, rate_hz: float, duration_s: float, first: int = 0, offset_s: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """Stamps (int64 ns) at ``rate_hz``, the first ``offset_s`` after ``start_ns`` (sample index
    ``first`` on), up to the end of the mission; and the same instants in float seconds since the start."""
    period = int(round(1e9 / rate_hz))
    off = int(round(offset_s * 1e9))
    n_last = int(np.floor((duration_s * 1e9 - off) / period + 1e-9))
    k = np.arange(first, n_last + 1, dtype=np.int64)
    ns = off + k * period
    return start_ns + ns, ns * 1e-9


def _skew_cross(w: np.ndarray, r: np.ndarray) -> np.ndarray:
    return np.cross(w, r[None, :])


# ----------------------------------------------------------------------------------------------
# DVL


@dataclass
class DvlResult:
    measurements: list[DvlVelocity]
    valid: np.ndarray  # per sample
    beam_valid: np.ndarray  # per sample × beam
    intervals: list[tuple[float, float, str]] = field(default_factory=list)  # (start_s, end_s, cause)

    @property
    def invalid_fraction(self) -> float:
        return float(1.0 - self.valid.mean()) if len(self.valid) else 0.0


def dvl_beam_dirs(cfg: DvlConfig) -> np.ndarray:
    """Unit beam directions in {S} (B×3): tilted ``beam_angle_deg`` from +z (down) at the azimuths."""
    b = np.deg2rad(cfg.beam_angle_deg)
    a = np.deg2rad(np.asarray(cfg.beam_azimuths_deg))
    return np.stack([np.sin(b) * np.cos(a), np.sin(b) * np.sin(a), np.full_like(a, np.cos(b))], 1)


def _merge(intervals):
    out = []
    for s, e, c in sorted(intervals):
        if out and s <= out[-1][1]:
            ps, pe, pc = out[-1]
            out[-1] = (ps, max(pe, e), pc if c == pc else f"{pc}+{c}")
        else:
            out.append((s, e, c))
    return out


def random_bursts(rate: float, burst_s: tuple[float, float], duration_s: float, rng: np.random.Generator):
    """Random dropout bursts, non-overlapping, of lengths uniform in ``burst_s`` and totalling
    ``rate`` × ``duration_s`` (the last one shortened to fit; a remainder below ``burst_s[0]``
    lengthens the shortest burst), placed uniformly at random: (start_s, end_s) pairs in time order."""
    total = rate * duration_s
    lengths: list[float] = []
    while total - sum(lengths) >= burst_s[0]:
        lengths.append(min(float(rng.uniform(*burst_s)), total - sum(lengths)))
    if not lengths:
        return []
    rest = total - sum(lengths)  # < burst_s[0]: lengthen the shortest burst by it if it stays ≤ burst_s[1]
    i = int(np.argmin(lengths))
    if lengths[i] + rest <= burst_s[1]:
        lengths[i] += rest
    free = duration_s - sum(lengths)
    # n+1 gaps: a uniformly random split of the free time (sorted uniform cut points)
    cuts = np.sort(rng.uniform(0.0, free, size=len(lengths)))
    gaps = np.diff(np.concatenate([[0.0], cuts]))
    out, t = [], 0.0
    for g, d in zip(gaps, lengths):
        t += float(g)
        out.append((t, t + d))
        t += d
    return out


def simulate_dvl(
    cfg: DvlConfig,
    traj: MotionModel,
    scene: LabelledScene,
    stamps: np.ndarray,
    t: np.ndarray,
    rng_noise: np.random.Generator,
    rng_dropout: np.random.Generator,
    sensor: str = "dvl",
    *,
    lost_kinds: tuple[int, ...] | None = None,
    lost_cause: str = "walls",
) -> DvlResult:
    """Velocity of the DVL head over ground in {S}: v_S = R_BSᵀ (R_WBᵀ v_W + ω_B × t_BS) + noise.

    Each beam is ray-cast into the scene; a beam is lost when it hits a surface of ``lost_kinds``
    (default, the tank: its sloped walls if ``cfg.wall_beams_lost``) or has no return within
    [min_range, max_range]. With fewer than ``min_valid_beams`` the bottom lock is lost (an
    interval labelled ``lost_cause``); re-acquiring it takes ``relock_s`` and a loss lasts at least
    ``burst_s[0]``. Random bursts (``random_dropout_rate`` of the time) are placed ≥ 1 s clear of
    those. Invalid readings carry NaN velocity and ``valid=False``.
    """
    T_BS = cfg.mount.matrix()
    R_BS, t_BS = T_BS[:3, :3], T_BS[:3, 3]
    p, v_W = traj.position_velocity(t)
    R_WB = traj.rotation(t).as_matrix()
    w_B = traj.angular_rate(t)
    v_B = np.einsum("nji,nj->ni", R_WB, v_W) + _skew_cross(w_B, t_BS)
    v_S = v_B @ R_BS  # R_BSᵀ v for each row

    beams_S = dvl_beam_dirs(cfg)
    R_WS = R_WB @ R_BS
    origins = p + R_WB @ t_BS
    dirs = np.einsum("nij,bj->nbi", R_WS, beams_S)
    nb = len(beams_S)
    rng_t, kind, _ = scene.cast(np.repeat(origins, nb, axis=0), dirs.reshape(-1, 3))
    rng_t, kind = rng_t.reshape(-1, nb), kind.reshape(-1, nb)
    if lost_kinds is None:
        lost_kinds = (WALL,) if cfg.wall_beams_lost else ()
    beam_ok = (kind != NO_HIT) & ~np.isin(kind, lost_kinds) & (rng_t >= cfg.min_range_m) & (rng_t <= cfg.max_range_m)
    lost = beam_ok.sum(1) < cfg.min_valid_beams

    duration = float(t[-1]) if len(t) else 0.0
    dt = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
    intervals = []
    idx = np.flatnonzero(lost)
    if len(idx):
        splits = np.flatnonzero(np.diff(idx) > 1) + 1
        for run in np.split(idx, splits):
            s = float(t[run[0]])
            e = float(t[run[-1]]) + dt + cfg.relock_s
            e = max(e, s + cfg.burst_s[0])
            intervals.append((s, min(e, duration + dt), lost_cause))
    # random bursts keep ≥ 1 s clear of the wall dropouts so that bursts stay within burst_s (redraw
    # the placement until they do; after 200 tries, accept merged bursts)
    for _ in range(200):
        rnd = random_bursts(cfg.random_dropout_rate, cfg.burst_s, duration, rng_dropout)
        if all(s >= we + 1.0 or e <= ws - 1.0 for s, e in rnd for ws, we, _ in intervals):
            break
    if cfg.outage_s is not None:  # after the bursts' draw: the same seed gives the same bursts with or without it
        start, length = cfg.outage_s
        intervals.append((start, min(start + length, duration + dt), "outage"))
    intervals = _merge(intervals + [(s, e, "random") for s, e in rnd])
    valid = np.ones(len(t), bool)
    for s, e, _ in intervals:
        valid[(t >= s - 1e-9) & (t < e - 1e-9)] = False

    noise = rng_noise.normal(0.0, cfg.sigma_m_s, size=(len(t), 3))
    meas_v = np.where(valid[:, None], v_S + noise, np.nan)
    cos_b = np.cos(np.deg2rad(cfg.beam_angle_deg))
    alt = np.where(beam_ok, rng_t * cos_b, np.nan)
    cov = np.eye(3) * cfg.sigma_m_s**2
    out = []
    for i in range(len(t)):
        a = float(np.nanmean(alt[i])) if valid[i] and beam_ok[i].any() else None
        out.append(
            DvlVelocity(
                stamp=int(stamps[i]),
                sensor=sensor,
                velocity=meas_v[i],
                covariance=cov,
                valid=bool(valid[i]),
                beam_valid=tuple(bool(b) for b in (beam_ok[i] & valid[i])),
                altitude=a,
            )
        )
    return DvlResult(out, valid, beam_ok, intervals)


# ----------------------------------------------------------------------------------------------
# AHRS and depth


def heading_bias(cfg: AhrsConfig, t: np.ndarray, duration_s: float, rng: np.random.Generator) -> np.ndarray:
    """Heading bias (rad) drifting linearly from 0 to ±``heading_bias_drift_deg`` over the mission."""
    sign = 1.0 if rng.uniform() < 0.5 else -1.0
    return sign * np.deg2rad(cfg.heading_bias_drift_deg) * np.asarray(t) / max(duration_s, 1e-9)


def simulate_ahrs(
    cfg: AhrsConfig,
    traj: MotionModel,
    stamps: np.ndarray,
    t: np.ndarray,
    rng: np.random.Generator,
    bias: np.ndarray,
    gyro_bias: np.ndarray,
    sensor: str = "ahrs",
) -> list[Attitude]:
    """R_WS with roll/pitch/yaw noise (σ in the covariance) and the heading bias added to the yaw;
    angular rate ω_S = R_BSᵀ ω_B + ``gyro_bias`` (sensor axes, constant) + noise."""
    T_BS = cfg.mount.matrix()
    R_BS = T_BS[:3, :3]
    R_WS = traj.rotation(t) * Rotation.from_matrix(R_BS)
    ypr = R_WS.as_euler("ZYX")
    s_rp, s_h = np.deg2rad(cfg.roll_pitch_sigma_deg), np.deg2rad(cfg.heading_sigma_deg)
    n = rng.normal(size=(len(t), 3)) * np.array([s_h, s_rp, s_rp])
    ypr = ypr + n
    ypr[:, 0] += bias
    q = Rotation.from_euler("ZYX", ypr).as_quat()
    w_S = traj.angular_rate(t) @ R_BS + gyro_bias + rng.normal(0.0, cfg.angular_rate_sigma_rad_s, size=(len(t), 3))
    cov = np.diag([s_rp**2, s_rp**2, s_h**2])
    return [
        Attitude(stamp=int(stamps[i]), sensor=sensor, orientation=q[i], covariance=cov, angular_rate=w_S[i])
        for i in range(len(t))
    ]


def mounted_point(traj: MotionModel, t: np.ndarray, t_BS: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The body origin p_WB and the point at lever arm t_BS, p_WB + R_WB t_BS, in {W} (N×3 each)."""
    p, _ = traj.position_velocity(t)
    return p, p + traj.rotation(t).as_matrix() @ t_BS


def simulate_depth(
    cfg: DepthConfig,
    traj: MotionModel,
    stamps: np.ndarray,
    t: np.ndarray,
    rng: np.random.Generator,
    sensor: str = "depth",
) -> list[Depth]:
    """Depth of the pressure sensor (z of p_WB + R_WB t_BS) plus white noise."""
    _, at = mounted_point(traj, t, cfg.mount.matrix()[:3, 3])
    z = at[:, 2] + rng.normal(0.0, cfg.sigma_m, size=len(t))
    var = cfg.sigma_m**2
    return [Depth(stamp=int(stamps[i]), sensor=sensor, depth=float(z[i]), variance=var) for i in range(len(t))]


def simulate_gps(
    cfg: GpsConfig,
    traj: MotionModel,
    stamps: np.ndarray,
    t: np.ndarray,
    rng: np.random.Generator,
    sensor: str = "gps",
) -> list[GpsFix]:
    """Fixes of the antenna (p_WB + R_WB t_BA) plus white noise (σ horizontal, vertical), kept only
    at the samples where the body origin is shallower than ``surface_depth_m``."""
    p, antenna = mounted_point(traj, t, cfg.mount.matrix()[:3, 3])
    sig = np.array([cfg.horizontal_sigma_m, cfg.horizontal_sigma_m, cfg.vertical_sigma_m])
    noisy = antenna + rng.normal(size=(len(t), 3)) * sig
    cov = np.diag(sig**2)
    up = np.flatnonzero(p[:, 2] <= cfg.surface_depth_m)
    return [GpsFix(stamp=int(stamps[i]), sensor=sensor, position=noisy[i], covariance=cov) for i in up]


def ground_truth_poses(traj: MotionModel, stamps: np.ndarray, t: np.ndarray, sensor: str = "ground_truth"):
    p, _ = traj.position_velocity(t)
    q = traj.rotation(t).as_quat()
    return [
        GroundTruthPose(stamp=int(stamps[i]), sensor=sensor, position=p[i], orientation=q[i]) for i in range(len(t))
    ]


# ----------------------------------------------------------------------------------------------
# laser


def laser_ray_dirs(cfg: LaserConfig) -> np.ndarray:
    """Unit ray directions in {S} (x right, y down, z along the view axis), row-major (along, across)."""
    fh, fv = np.deg2rad(cfg.fov_deg)
    nh, nv = cfg.resolution
    az = np.linspace(-fh / 2, fh / 2, nh)
    el = np.linspace(-fv / 2, fv / 2, nv)
    A, E = np.meshgrid(az, el)
    return np.stack([np.sin(A) * np.cos(E), np.sin(E), np.cos(A) * np.cos(E)], -1).reshape(-1, 3)


@dataclass
class LaserResult:
    measurements: list[PointCloud]
    seen_objects: set[int]
    seen_pipes: set[int]


def simulate_laser(
    cfg: LaserConfig,
    traj: Trajectory,
    scene: TankScene,
    stamps: np.ndarray,
    t: np.ndarray,
    rng: np.random.Generator,
    sensor: str = "laser",
    progress: bool = False,
) -> LaserResult:
    """One instantaneous ray-cast grid per stamp; ranges get white noise along the ray; returns
    outside [min_range, max_range] (or none: rays leaving through the surface) are dropped.
    Points are float32 in {S}."""
    T_BS = cfg.mount.matrix()
    R_BS, t_BS = T_BS[:3, :3], T_BS[:3, 3]
    d_S = laser_ray_dirs(cfg).astype(np.float32)
    T_WB = traj.poses(t)
    seen_o: set[int] = set()
    seen_p: set[int] = set()
    out = []
    it = range(len(t))
    if progress:
        from tqdm import tqdm

        it = tqdm(it, desc="laser scans", unit="scan")
    for i in it:
        R_WS = (T_WB[i, :3, :3] @ R_BS).astype(np.float32)
        o = T_WB[i, :3, :3] @ t_BS + T_WB[i, :3, 3]
        # d_S @ R_WSᵀ written out: a BLAS matmul with a 3-wide inner dimension is slow on busy machines
        d_W = d_S[:, :1] * R_WS[:, 0] + d_S[:, 1:2] * R_WS[:, 1] + d_S[:, 2:3] * R_WS[:, 2]
        dist, kind, ident = scene.cast(o, d_W)
        r = dist + rng.normal(0.0, cfg.range_sigma_m, size=len(d_S)).astype(np.float32)
        keep = np.isfinite(dist) & (r >= cfg.min_range_m) & (r <= cfg.max_range_m)
        seen_o.update(np.unique(ident[keep & (kind == OBJECT)]).tolist())
        seen_p.update(np.unique(ident[keep & (kind == PIPE)]).tolist())
        pts = (d_S * r[:, None])[keep]
        out.append(PointCloud(stamp=int(stamps[i]), sensor=sensor, points=pts))
    return LaserResult(out, seen_o, seen_p)
