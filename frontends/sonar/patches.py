"""Patches: consecutive swaths over a metre or so of track, stored rigidly in the body frame of their
middle swath (the anchor), so that the current estimate of the anchor's pose re-places them.

Inside a patch the swaths are placed relative to the anchor with the estimate's relative motion
when the patch closes (a second of DVL/AHRS: millimetres); the patch then moves as one rigid piece
whenever the estimate of its anchor changes (swath registration and structure landmarks correct it).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation


def yaw_of(T: np.ndarray) -> float:
    return float(np.arctan2(T[1, 0], T[0, 0]))


def inv(T: np.ndarray) -> np.ndarray:
    out = np.eye(4)
    R = T[:3, :3]
    out[:3, :3] = R.T
    out[:3, 3] = -R.T @ T[:3, 3]
    return out


def transform(T: np.ndarray, pts: np.ndarray) -> np.ndarray:
    return np.asarray(pts, float) @ T[:3, :3].T + T[:3, 3]


@dataclass
class Patch:
    """``points``: N×3 float32 in the anchor body frame; ``swath`` (N,) index of each point's swath in
    ``stamps``; ``T_nav``: T_W,anchor as navigated when the patch closed (before its own
    registration); ``heading_change``: |yaw change| over the patch (rad); ``track_m``: track length."""

    id: int
    stamps: np.ndarray
    anchor_stamp: int
    points: np.ndarray
    swath: np.ndarray
    T_nav: np.ndarray
    heading_change: float
    track_m: float
    # bounding box (north, east) as placed when closed: a cheap pre-filter for overlaps (drift is cm)
    lo: np.ndarray = field(default_factory=lambda: np.zeros(2))
    hi: np.ndarray = field(default_factory=lambda: np.zeros(2))
    top: np.ndarray | None = None  # one point per map cell (the upper surface), anchor frame, for recognition

    def world(self, T_WA: np.ndarray) -> np.ndarray:
        """Points in {W} with the anchor placed at ``T_WA``."""
        return transform(T_WA, self.points)

    @property
    def t(self) -> float:
        return self.anchor_stamp * 1e-9


def overlap_area(a_lo, a_hi, b_lo, b_hi) -> float:
    d = np.minimum(a_hi, b_hi) - np.maximum(a_lo, b_lo)
    return float(np.prod(np.maximum(d, 0.0)))


def interpolate_pose(T0: np.ndarray, T1: np.ndarray, s: float) -> np.ndarray:
    from scipy.spatial.transform import Slerp

    r = Slerp([0.0, 1.0], Rotation.from_matrix(np.stack([T0[:3, :3], T1[:3, :3]])))([s]).as_matrix()[0]
    T = np.eye(4)
    T[:3, :3] = r
    T[:3, 3] = (1 - s) * T0[:3, 3] + s * T1[:3, 3]
    return T


def top_points(points: np.ndarray, cell: float, q: float = 0.1) -> np.ndarray:
    """One point per (x, y) cell of ``cell`` (anchor frame, z down): the cell centre at the ``q``
    quantile of its depths (the upper surface)."""
    from frontends.sonar.grid import cell_medians

    if len(points) == 0:
        return np.zeros((0, 3), np.float32)
    ij = np.floor(points[:, :2] / cell).astype(np.int64)
    ij -= ij.min(0)
    w = int(ij[:, 1].max()) + 1
    keys = ij[:, 0] * w + ij[:, 1]
    uniq, z, _ = cell_medians(keys, points[:, 2].astype(float), q)
    i0 = np.floor(points[:, :2].min(0) / cell)
    x = (uniq // w + i0[0] + 0.5) * cell
    y = (uniq % w + i0[1] + 0.5) * cell
    return np.column_stack([x, y, z]).astype(np.float32)


def make_patch(
    pid: int, stamps: np.ndarray, clouds: list[np.ndarray], poses: list, mounts: list[np.ndarray], map_cell_m: float
) -> Patch | None:
    """The patch ``pid`` of consecutive swaths: ``clouds`` in their sensor frames, ``poses`` T_WB at
    ``stamps`` (None where the estimate has none: that swath is left out), ``mounts`` T_BS. Anchored
    on the middle placed swath; None with fewer than two placed swaths."""
    keep = [k for k, T in enumerate(poses) if T is not None]
    if len(keep) < 2:
        return None
    a = keep[len(keep) // 2]
    T_WA = poses[a]
    A_inv = inv(T_WA)
    pts, idx, yaws, pos = [], [], [], []
    for k in keep:
        pts.append(transform(A_inv @ poses[k] @ mounts[k], clouds[k]).astype(np.float32))
        idx.append(np.full(len(clouds[k]), k, np.int32))
        yaws.append(yaw_of(poses[k]))
        pos.append(poses[k][:3, 3])
    P = np.concatenate(pts) if pts else np.zeros((0, 3), np.float32)
    yaws = np.unwrap(np.array(yaws))
    track = float(np.linalg.norm(np.diff(np.array(pos), axis=0), axis=1).sum())
    patch = Patch(
        pid, stamps, int(stamps[a]), P, np.concatenate(idx), T_WA.copy(), float(yaws.max() - yaws.min()), track
    )
    if len(P):
        W = transform(T_WA, P)
        patch.lo, patch.hi = W[:, :2].min(0), W[:, :2].max(0)
        patch.top = top_points(P, map_cell_m)
    return patch
