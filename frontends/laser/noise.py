"""The noise of a scan, measured on the scan itself: σ(range) of the points about their surface.

A laser's range noise is about constant; a stereo camera's depth noise grows with the square of
the range; either may differ from what a configuration says. So every scan measures its own: each
raw point's offset along its coarse voxel's normal from the voxel's centroid (a 3 cm voxel of a
smooth surface is flat at the scale of the noise), on the smooth voxels only (low curvature: not
edges, not pipes), robustly (1.4826 × the median absolute offset) per band of range; the bands' σ
are fitted by σ(r) = σ_ref · (r / r_ref)^k, k in [0, 2] (0: a laser, 2: stereo), r_ref the median
range of those points. The noise is along the ray (range or depth), so the offset along the normal
is divided by the cosine of the incidence, on surfaces facing the sensor within 60° only: σ is the
noise along the ray, which bounds a point's offset along any surface normal.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from frontends.laser.grid import median_of, row_dot
from frontends.laser.preprocess import Preprocessed

_MIN_POINTS = 200  # fewer smooth points than this: no measurement
_BANDS = 4  # range bands (by quantiles of the points' ranges)
_SMOOTH_CURVATURE = 0.03  # voxels below this curvature measure the noise (a rough seabed's are above 0.05)
_MIN_FACING = 0.5  # only surfaces facing the sensor within 60°: the noise is along the ray
_MAX_SAMPLE = 20000  # points used at most (evenly strided): the median needs no more


@dataclass(frozen=True)
class NoiseModel:
    """σ(r) = ``sigma_ref`` · (r / ``range_ref``)^``exponent`` (m), measured on ``n_points`` points."""

    sigma_ref: float
    range_ref: float
    exponent: float
    n_points: int

    def at(self, r) -> np.ndarray | float:
        """σ (m) at range(s) ``r`` (m)."""
        return self.sigma_ref * (np.maximum(np.asarray(r, float), 1e-3) / self.range_ref) ** self.exponent


def measure_noise(raw: np.ndarray, pre: Preprocessed) -> NoiseModel | None:
    """The scan's noise model from the raw points (N×3, {S}) and their coarse voxels; None when too
    few points lie on smooth surfaces to tell."""
    inv = pre.raw_to_voxel
    if len(pre.points) == 0:
        return None
    # a voxel's centroid is pulled towards its own points: their offsets shrink by √(1 − 1/k)
    counts = pre.counts
    smooth = np.append((pre.curvature < _SMOOTH_CURVATURE) & (counts >= 3), False)  # index −1 reads False
    idx = np.flatnonzero(smooth[inv])
    if len(idx) < _MIN_POINTS:
        return None
    if len(idx) > _MAX_SAMPLE:
        idx = idx[:: len(idx) // _MAX_SAMPLE]
    v = inv[idx]
    p = raw.take(idx, axis=0)
    n = pre.normals.take(v, axis=0)
    rng = np.sqrt(row_dot(p, p))
    facing = np.abs(row_dot(p, n)) / np.maximum(rng, 1e-9)  # |cos| of the incidence
    ok = np.flatnonzero(facing >= _MIN_FACING)  # (gathers by index: faster than boolean selections)
    if len(ok) < _MIN_POINTS:
        return None
    p, n, v, rng, facing = p.take(ok, axis=0), n.take(ok, axis=0), v[ok], rng[ok], facing[ok]
    # the offset along the surface normal, brought back to the ray (where the noise is)
    off = np.abs(row_dot(p - pre.points.take(v, axis=0), n)) / facing / np.sqrt(1.0 - 1.0 / counts[v])
    edges = np.quantile(rng, np.linspace(0, 1, _BANDS + 1))
    band = np.clip(np.searchsorted(edges, rng, side="right") - 1, 0, _BANDS - 1)
    r_mid, sig, w = [], [], []
    for b in range(_BANDS):
        sel = np.flatnonzero(band == b)
        if len(sel) < _MIN_POINTS // _BANDS:
            continue
        # (median_of: np.median's values, without its overhead per call)
        r_mid.append(median_of(rng[sel]))
        sig.append(1.4826 * median_of(off[sel]))
        w.append(float(len(sel)))
    if not sig:
        return None
    r_ref = median_of(rng)
    r_mid, sig, w = np.array(r_mid), np.maximum(np.array(sig), 1e-5), np.array(w)
    k = 0.0
    span = np.log(r_mid.max() / r_mid.min()) if len(r_mid) > 1 else 0.0
    if span > 0.15:  # ranges spread enough (±7 %) to tell how the noise grows
        x = np.log(r_mid / r_ref)
        k = float(np.clip(np.polyfit(x, np.log(sig), 1, w=np.sqrt(w))[0], 0.0, 2.0))
    # σ at r_ref: the weighted geometric mean of the bands' σ brought to r_ref by the exponent
    s_ref = float(np.exp(np.average(np.log(sig) - k * np.log(r_mid / r_ref), weights=w)))
    return NoiseModel(s_ref, r_ref, k, len(idx))
