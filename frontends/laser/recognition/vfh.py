"""Viewpoint Feature Histogram (VFH), Rusu et al. IROS 2010, as PCL's ``VFHEstimation``.

308 bins = four 45-bin histograms of the pair features between the cloud's centroid (with the
mean normal) and every point (with its normal) — f1 (the angle of the point normal about the
Darboux frame's u axis, in [−π, π]), f2 and f3 (cosines in [−1, 1]) and f4 (the distance to the
centroid) — followed by a 128-bin histogram of the cosine between each normal and the direction
from the centroid to the viewpoint. The first 180 bins (the "shape part") depend only on the
cloud's shape; the last 128 (the "viewpoint part") on where it is seen from.

Follows PCL ``features/impl/vfh.hpp`` and ``pfh_tools.cpp::computePairFeatures`` (read,
re-implemented vectorised). Deviations, each deliberate:

- f2 and f3 are cosines; they are binned over [−1, 1] (``(f + 1) / 2``) as in the VFH paper and
  older PCL releases, where current PCL bins every angular feature over [−π, π] and so crowds f2
  and f3 into the middle third of their histograms.
- The mean normal is normalised to unit length before use (PCL uses the raw mean, which scales f3
  by its length); CVFH normalises it too.
- The distance component is always filled and normalised by the largest point-to-centroid
  distance (PCL's CVFH setting; plain VFH leaves it empty by default), making it scale-free.
- Bins are normalised as PCL's ``normalize_bins``: each angular / distance histogram sums to 100
  over the pairs, the viewpoint histogram to 100 over the points.
- Normals come from :func:`normals_and_curvature` (k nearest neighbours, facing the viewpoint).

Frames: the cloud, its normals and the viewpoint are in the same frame (the sensor frame, with the
viewpoint at its origin, for a segment of a scan).
"""

from __future__ import annotations

import numpy as np

from frontends.laser.recognition.normals import normals_and_curvature

VFH_BINS = 308
SHAPE_BINS = 180  # f1, f2, f3, f4
_NF = 45
_NVP = 128


def pair_features(p1: np.ndarray, n1: np.ndarray, p2: np.ndarray, n2: np.ndarray) -> tuple[np.ndarray, ...]:
    """PCL's ``computePairFeatures`` for one source (``p1``, ``n1``: 3-vectors) against many
    targets (``p2``, ``n2``: N×3). Returns ``(f1, f2, f3, f4, valid)``.

    The Darboux frame is built on whichever end of each pair has the normal more nearly aligned
    with the connecting line (PCL's role swap), so that the features do not depend on pair order.
    """
    dp = p2 - p1
    f4 = np.linalg.norm(dp, axis=1)
    valid = f4 > 0
    f4s = np.where(valid, f4, 1.0)
    a1 = (dp @ n1) / f4s
    a2 = np.einsum("ij,ij->i", n2, dp) / f4s
    swap = np.arccos(np.clip(np.abs(a1), 0, 1)) > np.arccos(np.clip(np.abs(a2), 0, 1))
    u = np.where(swap[:, None], n2, n1[None, :])  # source normal
    t = np.where(swap[:, None], n1[None, :], n2)  # target normal
    d = np.where(swap[:, None], -dp, dp)
    f3 = np.where(swap, -a2, a1)
    v = np.cross(d, u)
    vn = np.linalg.norm(v, axis=1)
    valid &= vn > 0
    v = v / np.where(vn > 0, vn, 1.0)[:, None]
    w = np.cross(u, v)
    f2 = np.einsum("ij,ij->i", v, t)
    f1 = np.arctan2(np.einsum("ij,ij->i", w, t), np.einsum("ij,ij->i", u, t))
    return f1, f2, f3, f4, valid


def _bin(x: np.ndarray, lo: float, hi: float, n: int) -> np.ndarray:
    return np.clip(np.floor(n * (x - lo) / (hi - lo)).astype(np.int64), 0, n - 1)


def vfh_from_normals(
    cloud: np.ndarray,
    normals: np.ndarray,
    viewpoint: np.ndarray | tuple[float, float, float] = (0.0, 0.0, 0.0),
    *,
    centroid: np.ndarray | None = None,
    mean_normal: np.ndarray | None = None,
) -> np.ndarray:
    """VFH of an N×3 cloud with unit normals (N×3), seen from ``viewpoint``.

    ``centroid`` and ``mean_normal`` default to the cloud's; CVFH passes a smooth region's.
    """
    pts = np.asarray(cloud, dtype=np.float64)
    nrm = np.asarray(normals, dtype=np.float64)
    c = pts.mean(axis=0) if centroid is None else np.asarray(centroid, dtype=np.float64)
    nc = nrm.mean(axis=0) if mean_normal is None else np.asarray(mean_normal, dtype=np.float64)
    nc_norm = np.linalg.norm(nc)
    if nc_norm == 0:
        raise ValueError("VFH: the normals cancel out (no mean normal)")
    nc = nc / nc_norm

    f1, f2, f3, f4, valid = pair_features(c, nc, pts, nrm)
    dmax = np.linalg.norm(pts - c, axis=1).max()
    incr = 100.0 / max(len(pts) - 1, 1)
    hist = np.zeros(VFH_BINS)
    idx = np.concatenate(
        [
            _bin(f1[valid], -np.pi, np.pi, _NF),
            _NF + _bin(f2[valid], -1.0, 1.0, _NF),
            2 * _NF + _bin(f3[valid], -1.0, 1.0, _NF),
            3 * _NF + _bin(f4[valid] / dmax if dmax > 0 else f4[valid], 0.0, 1.0, _NF),
        ]
    )
    hist[:SHAPE_BINS] = np.bincount(idx, minlength=SHAPE_BINS) * incr

    view_dir = np.asarray(viewpoint, dtype=np.float64) - c
    view_dir /= np.linalg.norm(view_dir)
    alpha = (nrm @ view_dir + 1.0) * 0.5
    hist[SHAPE_BINS:] = np.bincount(_bin(alpha, 0.0, 1.0, _NVP), minlength=_NVP) * (100.0 / len(pts))
    return hist


def vfh(
    cloud: np.ndarray,
    viewpoint: np.ndarray | tuple[float, float, float] = (0.0, 0.0, 0.0),
    *,
    k: int = 20,
) -> np.ndarray:
    """VFH (308 bins) of an N×3 cloud seen from ``viewpoint`` (same frame); normals from the ``k``
    nearest neighbours."""
    normals, _ = normals_and_curvature(cloud, viewpoint, k=k)
    return vfh_from_normals(cloud, normals, viewpoint)
