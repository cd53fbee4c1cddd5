"""A stereo camera's point clouds: organised (one point per left-camera pixel, NaN where stereo
fails), with RGB, and the errors of real stereo under water.

Geometry: a pinhole grid of rays from the left camera ({S}: x right, y down, z along the optical
axis), cast into the scene; the right camera sits ``baseline_m`` along +x. Depth z (along the
optical axis) comes from the disparity δ = f·b/z (f the focal length in pixels, b the baseline), so
a disparity error σ_δ gives σ_z = z²·σ_δ/(f·b): the noise grows with the square of the range. Part
of the disparity noise is spatially correlated (matching windows), the rest white. A point keeps
its pixel's ray: it moves along the ray with its depth.

Where stereo fails the point is NaN (the cloud stays organised): pixels the right camera cannot see
(occlusion, found by casting from the right camera to the surface point), low-texture patches
(smooth random blobs covering ``hole_share`` of the image), and dropouts that grow with range
(turbidity). Edge artefacts: next to a depth jump, pixels on the far side take depths between the
far surface and the near one (foreground fattening and mixed pixels of window matching).
Outliers: a share of pixels with a wrong depth (mismatches) and a few returns from marine snow
between 0.3 and 1 m. Colours: the surface albedo lit by lamps at the camera (Lambert, inverse-square
falloff), attenuated over the path there and back and veiled by the water colour (backscatter),
with sensor noise.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.ndimage import gaussian_filter, minimum_filter

from semslam.mission.measurements import PointCloud
from semslam.sim.pipeline_config import StereoConfig
from semslam.sim.pipeline_scene import OBJECT, PIPE, ROCK, PipelineScene
from semslam.sim.trajectory import MotionModel

_COVER_BIN_M = 0.02  # a pipe's visible length is counted in bins of this length along its axis ...
_COVER_POINTS = 3  # ... holding at least this many of its valid points


def focal_px(cfg: StereoConfig) -> float:
    """Focal length in pixels of the left camera."""
    return (cfg.resolution[0] / 2) / np.tan(np.radians(cfg.fov_deg[0]) / 2)


def depth_sigma(cfg: StereoConfig, z) -> np.ndarray:
    """σ (m) of a depth z (m) from the disparity noise: z²·σ_δ/(f·b)."""
    return np.asarray(z, float) ** 2 * cfg.disparity_sigma_px / (focal_px(cfg) * cfg.baseline_m)


def pixel_rays(cfg: StereoConfig) -> np.ndarray:
    """Unit rays of the left camera's pixels in {S} (H·W × 3, row-major: v down the image, u across)."""
    w, h = cfg.resolution
    f = focal_px(cfg)
    fy = (h / 2) / np.tan(np.radians(cfg.fov_deg[1]) / 2)
    u = (np.arange(w) + 0.5 - w / 2) / f
    v = (np.arange(h) + 0.5 - h / 2) / fy
    U, V = np.meshgrid(u, v)
    d = np.stack([U, V, np.ones_like(U)], -1).reshape(-1, 3)
    return d / np.linalg.norm(d, axis=1)[:, None]


@dataclass
class ScanTruth:
    """What one cloud saw: per pipe id its visible length (m, bins of 2 cm along the axis with at
    least 3 valid points) and the span of those bins (m along the axis from the pipe's p), per
    fitting id its valid points, and the valid points on rocks."""

    stamp: int
    pipes: dict[int, tuple[float, float, float]] = field(default_factory=dict)
    objects: dict[int, int] = field(default_factory=dict)
    rock_points: int = 0

    def to_dict(self) -> dict:
        return {
            "stamp": self.stamp,
            "pipe_visible_m": {str(k): round(v[0], 3) for k, v in self.pipes.items()},
            "pipe_seen_span_m": {str(k): [round(v[1], 3), round(v[2], 3)] for k, v in self.pipes.items()},
            "object_points": {str(k): v for k, v in self.objects.items()},
            "rock_points": self.rock_points,
        }


@dataclass
class StereoResult:
    measurements: list[PointCloud]
    seen_objects: set[int]
    seen_pipes: set[int]
    scans: list[ScanTruth]


def _smooth_noise(rng: np.random.Generator, shape, sigma_px: float) -> np.ndarray:
    """Gaussian noise smoothed over ``sigma_px`` pixels, rescaled to unit variance."""
    n = gaussian_filter(rng.normal(size=shape), sigma_px, mode="reflect")
    return n / max(float(n.std()), 1e-12)


def _colours(cfg: StereoConfig, albedo, normals_W, dirs_W, dist, rng) -> np.ndarray:
    """RGB (N×3 uint8) seen by the camera: lamp-lit albedo, attenuated and veiled with range."""
    lambert = np.clip(-np.einsum("ij,ij->i", normals_W, dirs_W), 0.0, 1.0)
    r = np.where(np.isfinite(dist), dist, 10.0)
    light = (0.15 + 0.85 * lambert) * np.minimum(1.0, (1.2 / np.maximum(r, 0.3)) ** 2)
    att = np.exp(-cfg.turbidity_per_m * 2 * r)[:, None]
    water = np.asarray(cfg.water_rgb, float) / 255.0
    veil = 1.0 - np.exp(-cfg.turbidity_per_m * r)[:, None]
    rgb = 255.0 * (albedo * light[:, None] * att * 1.3 + water * veil) + rng.normal(0.0, cfg.rgb_noise, albedo.shape)
    return np.clip(np.round(rgb), 0, 255).astype(np.uint8)


def _edge_artefacts(cfg: StereoConfig, z: np.ndarray, rng) -> np.ndarray:
    """Depth image with the far side of depth jumps pulled towards the near side (H×W, NaN kept)."""
    if cfg.edge_px <= 0:
        return z
    filled = np.where(np.isfinite(z), z, np.inf)
    near = minimum_filter(filled, size=2 * cfg.edge_px + 1, mode="nearest")
    far_side = np.isfinite(z) & np.isfinite(near) & (z > near * (1.0 + cfg.edge_jump))
    mix = rng.uniform(size=z.shape) ** 2  # mostly near the foreground (fattening), some in between
    return np.where(far_side, near + mix * (z - near), z)


def _visible_lengths(scene: PipelineScene, P_W: np.ndarray, ident: np.ndarray) -> dict[int, tuple[float, float, float]]:
    """Per pipe hit: its visible length (bins of 2 cm along its axis with ≥ 3 points) and the span
    (m along its axis from its p) from the first to the last such bin."""
    out = {}
    for pid in np.unique(ident):
        pp = scene.layout.pipes[int(pid)]
        t = (P_W[ident == pid] - pp.p) @ pp.axis
        t0 = t.min()
        counts = np.bincount(np.floor((t - t0) / _COVER_BIN_M).astype(np.int64))
        full = np.flatnonzero(counts >= _COVER_POINTS)
        span = (t0 + full[0] * _COVER_BIN_M, t0 + (full[-1] + 1) * _COVER_BIN_M) if len(full) else (t0, t0)
        out[int(pid)] = (float(len(full) * _COVER_BIN_M), float(span[0]), float(span[1]))
    return out


def simulate_stereo(
    cfg: StereoConfig,
    traj: MotionModel,
    scene: PipelineScene,
    stamps: np.ndarray,
    t: np.ndarray,
    rng: np.random.Generator,
    sensor: str = "stereo",
    progress: bool = False,
) -> StereoResult:
    """One organised cloud (float32, {S}, NaN where stereo fails, with RGB) per stamp."""
    T_BS = cfg.mount.matrix()
    w, h = cfg.resolution
    d_S = pixel_rays(cfg)
    fb = focal_px(cfg) * cfg.baseline_m
    T_WB = traj.poses(t)
    seen_o: set[int] = set()
    seen_p: set[int] = set()
    out, truths = [], []
    it = range(len(t))
    if progress:
        from tqdm import tqdm

        it = tqdm(it, desc="stereo clouds", unit="cloud")
    for i in it:
        T_WS = T_WB[i] @ T_BS
        R_WS, o = T_WS[:3, :3], T_WS[:3, 3]
        d_W = d_S @ R_WS.T
        dist, kind, ident, normals = scene.cast_with_normals(o, d_W)
        dist = dist.astype(float)
        z = dist * d_S[:, 2]
        P_W = o + d_W * np.where(np.isfinite(dist), dist, 0.0)[:, None]
        ok = np.isfinite(dist) & (dist >= cfg.min_range_m) & (dist <= cfg.max_range_m)
        # the right camera must see the point too
        o_R = o + R_WS[:, 0] * cfg.baseline_m
        to_p = P_W - o_R
        reach = np.linalg.norm(to_p, axis=1)
        d_R = to_p / np.maximum(reach, 1e-9)[:, None]
        dist_R, _, _ = scene.cast(o_R, d_R)
        ok &= dist_R >= reach - 0.005
        ok &= rng.uniform(size=len(z)) >= 1.0 - np.exp(-((dist / cfg.dropout_range_m) ** 4))
        if cfg.hole_share > 0:
            blobs = _smooth_noise(rng, (h, w), cfg.hole_size_px).ravel()
            ok &= blobs < np.quantile(blobs, 1.0 - cfg.hole_share)
        # depth from a noisy disparity; then edge artefacts, mismatches and marine snow
        c = cfg.correlated_share
        noise = np.sqrt(1 - c) * rng.normal(size=(h, w)) + np.sqrt(c) * _smooth_noise(rng, (h, w), cfg.correlation_px)
        disparity = fb / np.where(ok, z, 1.0)
        zn = fb / np.maximum(disparity + cfg.disparity_sigma_px * noise.ravel(), 1e-6)
        zn = _edge_artefacts(cfg, np.where(ok, zn, np.nan).reshape(h, w), rng).ravel()
        wrong = ok & (rng.uniform(size=len(z)) < cfg.mismatch_share)
        zn[wrong] *= rng.uniform(0.7, 1.3, int(wrong.sum()))
        snow = rng.uniform(size=len(z)) < cfg.snow_share
        zn[snow] = rng.uniform(0.3, 1.0, int(snow.sum())) * d_S[snow, 2]
        valid = np.isfinite(zn)
        pts = np.full((len(z), 3), np.nan, np.float32)
        pts[valid] = (d_S[valid] * (zn[valid] / d_S[valid, 2])[:, None]).astype(np.float32)

        albedo = scene.albedo(kind, ident, P_W)
        albedo[snow] = 0.9
        rgb = _colours(cfg, albedo, normals, d_W, np.where(snow, 0.6, dist), rng)
        out.append(PointCloud(stamp=int(stamps[i]), sensor=sensor, points=pts, rgb=rgb))

        truth_ok = valid & ok & ~snow & ~wrong
        seen_o.update(np.unique(ident[truth_ok & (kind == OBJECT)]).tolist())
        on_pipe = truth_ok & (kind == PIPE)
        seen_p.update(np.unique(ident[on_pipe]).tolist())
        objects = np.bincount(ident[truth_ok & (kind == OBJECT)], minlength=len(scene.layout.fittings))
        truths.append(
            ScanTruth(
                int(stamps[i]),
                _visible_lengths(scene, P_W[on_pipe], ident[on_pipe]),
                {int(k): int(n) for k, n in enumerate(objects) if n},
                int((truth_ok & (kind == ROCK)).sum()),
            )
        )
    return StereoResult(out, seen_o, seen_p, truths)
