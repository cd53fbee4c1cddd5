"""Downward multibeam sonar: one instantaneous swath of beams across track per stamp.

Beam i points along (0, sin a_i, cos a_i) in the sonar frame {S} (z looks down at a = 0, positive
angles to starboard y), the angles evenly spaced over ``swath_deg``. Each beam is one ray on its
axis: the beam widths (1° along track, the across-track footprint) are not modelled, so a return
is the range to the first surface on the axis, plus white Gaussian noise ``range_sigma_m``.
Returns outside [min_range, max_range] are dropped (a swath keeps only the beams with a return,
as :class:`~semslam.mission.measurements.SonarSwath` does). Intensity is a Lambertian echo,
reflectivity of the surface hit × |cos incidence|, without noise.

Angles lie on a float32 grid and ranges / intensities are float32 values, so that a swath written
as ``sensor_msgs/LaserScan`` reads back identically. All swaths are ray-cast in blocks of rays
(no Python loop per beam); the noise is drawn for every beam of every swath, hit or not.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from semslam.mission.measurements import SonarSwath
from semslam.sim.field_config import SonarConfig
from semslam.sim.raycast import NO_HIT, LabelledScene
from semslam.sim.trajectory import MotionModel

BLOCK_SWATHS = 512  # swaths ray-cast together: ~260k rays, a few MB of rays and hits


def beam_angles(cfg: SonarConfig) -> np.ndarray:
    """The beam angles (rad): an evenly spaced grid whose first angle and increment are float32."""
    half = np.float32(np.deg2rad(cfg.swath_deg) / 2)
    inc = np.float32(2 * float(half) / (cfg.n_beams - 1))
    return -float(half) + np.arange(cfg.n_beams) * float(inc)


def beam_dirs(cfg: SonarConfig) -> np.ndarray:
    """Unit beam directions in {S} (B×3)."""
    a = beam_angles(cfg)
    return np.stack([np.zeros_like(a), np.sin(a), np.cos(a)], 1)


@dataclass
class SonarResult:
    measurements: list[SonarSwath]
    seen: dict[int, set[int]] = field(default_factory=dict)  # kind → ids hit by at least one kept return
    n_points: int = 0


def simulate_sonar(
    cfg: SonarConfig,
    traj: MotionModel,
    scene: LabelledScene,
    stamps: np.ndarray,
    t: np.ndarray,
    rng: np.random.Generator,
    reflectivity: dict[int, float],
    sensor: str = "sonar",
    progress: bool = False,
) -> SonarResult:
    """One swath per stamp, from the true pose at that instant. ``reflectivity`` maps the scene's
    geometry kinds to the echo strength of their surface (0..1)."""
    T_BS = cfg.mount.matrix()
    R_BS, t_BS = T_BS[:3, :3], T_BS[:3, 3]
    angles = beam_angles(cfg)
    d_S = beam_dirs(cfg)
    nb = len(angles)
    refl = np.zeros(max(reflectivity, default=0) + 2, np.float32)  # index -1 (no hit) → 0
    for kind, r in reflectivity.items():
        refl[kind] = r
    seen: dict[int, set[int]] = {k: set() for k in reflectivity}
    out: list[SonarSwath] = []
    n_points = 0
    blocks = range(0, len(t), BLOCK_SWATHS)
    if progress:
        from tqdm import tqdm

        blocks = tqdm(blocks, desc="sonar swaths", unit="block")
    for b0 in blocks:
        tb = t[b0 : b0 + BLOCK_SWATHS]
        T_WB = traj.poses(tb)
        R_WS = T_WB[:, :3, :3] @ R_BS
        origins = T_WB[:, :3, :3] @ t_BS + T_WB[:, :3, 3]
        d_W = np.einsum("nij,bj->nbi", R_WS, d_S)
        dist, kind, ident, normal = scene.cast_with_normals(np.repeat(origins, nb, axis=0), d_W.reshape(-1, 3))
        noise = rng.normal(0.0, cfg.range_sigma_m, size=dist.shape)
        r = (dist + noise).astype(np.float32)
        keep = np.isfinite(dist) & (r >= cfg.min_range_m) & (r <= cfg.max_range_m)
        cos_inc = np.abs(np.einsum("ni,ni->n", normal, d_W.reshape(-1, 3)))
        intensity = (refl[kind] * cos_inc).astype(np.float32)
        for k in seen:
            seen[k].update(np.unique(ident[keep & (kind == k)]).tolist())
        n_points += int(keep.sum())
        r, keep, intensity = r.reshape(-1, nb), keep.reshape(-1, nb), intensity.reshape(-1, nb)
        for i in range(len(tb)):
            m = keep[i]
            out.append(
                SonarSwath(
                    stamp=int(stamps[b0 + i]),
                    sensor=sensor,
                    angles=angles[m],
                    ranges=r[i, m],
                    intensities=intensity[i, m],
                )
            )
    seen = {k: {i for i in v if i != NO_HIT} for k, v in seen.items()}
    return SonarResult(out, seen, n_points)
