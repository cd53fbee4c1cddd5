"""Map and consistency quality that cannot hide behind a median (issue 21): per landmark class the
duplicates, misses and false landmarks with the errors of those matched; NEES with its χ² band; ATE
after a position+yaw alignment (the gauge a vehicle with depth and roll/pitch but a drifting heading
leaves unobservable). Plain dicts with the keys of ``metrics.json``; None where there is no truth.

Definitions (per class: object, pipe, structure):
- matched: one-to-one assignment to truth within the gate (``match``: metrics.py's ``match_landmarks``,
  passed in so that this module does not import its caller);
- ``<kind>_duplicates``: estimates within the gate of a truth whose nearest truth another estimate has;
- ``<kind>_false``: estimates with no truth within the gate;
- ``<kind>_missed``: truths the sensors saw (``seen_*``; all of them when the mission does not say)
  that no estimate was matched to; ``<kind>_seen``: how many they saw;
- ``objects_once``: every seen object mapped, none twice, none false;
- ``map_aligned``: the same counts and the per-class median errors after moving the map by the
  trajectory's position+yaw alignment: a map right in itself but turned with the vehicle's heading
  (the gauge) is told from one with twins and misses.

NEES: the per-pose NEES of the 3-D position is χ²(3) for a consistent estimator, whatever the
correlation between poses. The mission's mean NEES is tested against the 95 % band of one χ²(3) value
(``nees_band95`` = [0.216, 9.35]): the band of a time average over K independent poses, χ²(3K)/K, is
far narrower, but a drifting estimate's errors are correlated over the whole mission (on a simulated
random walk, Sokal's autocorrelation-time estimate of K put a consistent filter outside that band in
45 % of runs), so K = 1 is the honest choice. The share of poses inside the band (0.95 if consistent)
says more: ``nees_share_in_pose_band``, ``nees_share_above_pose_band`` (overconfidence).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from scipy.stats import chi2

from semslam.estimation import EstimatorResult, LandmarkEstimate, Trajectory
from semslam.mission.ground_truth import GroundTruthMap

#: (landmarks, truth, gate_m) → (matches with .kind, .truth_id, .error_m; {"duplicates", "spurious"})
Matcher = Callable[[list, GroundTruthMap, float], tuple[list, dict]]

KINDS = ("object", "pipe", "structure")
#: what ``map_aligned`` repeats after moving the map by the trajectory's position+yaw alignment
ALIGNED_KEYS = ("object_duplicates", "object_missed", "object_false", "pipe_duplicates", "pipe_missed", "pipe_false")
ALIGNED_KEYS += ("object_median_error_m", "pipe_median_error_m", "objects_once")
NEES_DOF = 3
CONFIDENCE = 0.95


# ------------------------------------------------------------------ landmarks
def landmark_quality(
    landmarks: list[LandmarkEstimate], truth: GroundTruthMap, match: Matcher, gate_m: float = 0.5
) -> dict:
    """Per class: ``<kind>_mapped``, ``_seen``, ``_matched``, ``_duplicates``, ``_missed``, ``_false``,
    ``_median_error_m``, ``_p90_error_m``; and ``objects_once``."""
    out: dict = {}
    truths = {"object": truth.objects, "pipe": truth.pipes, "structure": truth.structures}
    seen_ids = {"object": truth.seen_objects, "pipe": truth.seen_pipes, "structure": truth.seen_structures}
    for kind in KINDS:
        mine = [lm for lm in landmarks if lm.kind == kind]
        seen = {g.id for g in truths[kind]} if seen_ids[kind] is None else set(seen_ids[kind])
        matches, counts = match(mine, truth, gate_m) if mine else ([], {"duplicates": 0, "spurious": 0})
        errors = np.array([m.error_m for m in matches], float)
        out[f"{kind}_mapped"] = len(mine)
        out[f"{kind}_seen"] = len(seen)
        out[f"{kind}_matched"] = len(matches)
        out[f"{kind}_duplicates"] = counts["duplicates"]
        out[f"{kind}_false"] = counts["spurious"]
        out[f"{kind}_missed"] = len(seen - {m.truth_id for m in matches})
        out[f"{kind}_median_error_m"] = float(np.median(errors)) if errors.size else None
        out[f"{kind}_p90_error_m"] = float(np.percentile(errors, 90)) if errors.size else None
    out["objects_once"] = out["object_duplicates"] == 0 and out["object_missed"] == 0 and out["object_false"] == 0
    return out


# ------------------------------------------------------------------ trajectory
def _associate(estimate: Trajectory, truth: Trajectory, max_dt_s: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
    """(estimate rows, truth rows) of the poses whose stamps are within ``max_dt_s`` of a true one."""
    idx = np.clip(np.searchsorted(truth.stamps, estimate.stamps), 1, len(truth.stamps) - 1)
    left_closer = (estimate.stamps - truth.stamps[idx - 1]) < (truth.stamps[idx] - estimate.stamps)
    idx = np.where(left_closer, idx - 1, idx)
    ok = np.abs(truth.stamps[idx] - estimate.stamps) <= max_dt_s * 1e9
    return np.flatnonzero(ok), idx[ok]


def position_yaw_transform(est: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """The rotation about the vertical and translation (4×4) that bring ``est`` (N×3) closest to
    ``ref`` in the least-squares sense (4-DoF Umeyama without scale)."""
    me, mr = est.mean(axis=0), ref.mean(axis=0)
    e, r = est - me, ref - mr
    yaw = np.arctan2(np.sum(e[:, 0] * r[:, 1] - e[:, 1] * r[:, 0]), np.sum(e[:, 0] * r[:, 0] + e[:, 1] * r[:, 1]))
    c, s = np.cos(yaw), np.sin(yaw)
    T = np.eye(4)
    T[:3, :3] = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
    T[:3, 3] = mr - T[:3, :3] @ me
    return T


def align_position_yaw(est: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """``est`` (N×3) moved by :func:`position_yaw_transform` onto ``ref``."""
    T = position_yaw_transform(est, ref)
    return est @ T[:3, :3].T + T[:3, 3]


def ate_position_yaw(estimate: Trajectory, truth: Trajectory) -> tuple[float, np.ndarray] | None:
    """ATE RMSE (m) after the position+yaw alignment, and that alignment (4×4); None without three
    associated poses."""
    if len(estimate) == 0 or len(truth) < 2:
        return None
    rows, truth_rows = _associate(estimate, truth)
    if rows.size < 3:
        return None
    T = position_yaw_transform(estimate.positions[rows], truth.positions[truth_rows])
    aligned = estimate.positions[rows] @ T[:3, :3].T + T[:3, 3]
    return float(np.sqrt(np.mean(np.sum((aligned - truth.positions[truth_rows]) ** 2, axis=1)))), T


def moved(landmarks: list[LandmarkEstimate], T: np.ndarray) -> list[LandmarkEstimate]:
    """The landmarks moved by T (4×4; positions, pipe ends and structure poses), the points of all
    of them at once (dead reckoning's map places thousands)."""
    fields = ("position", "p", "q")
    at = [(k, f) for k, lm in enumerate(landmarks) for f in fields if getattr(lm, f) is not None]
    pts = np.array([getattr(landmarks[k], f) for k, f in at], float).reshape(-1, 3) @ T[:3, :3].T + T[:3, 3]
    new: list[dict] = [dict.fromkeys(fields) for _ in landmarks]
    for (k, f), x in zip(at, pts):
        new[k][f] = x
    out = []
    for lm, changed in zip(landmarks, new):  # dataclasses.replace's copies, without its __init__ per landmark
        m = object.__new__(type(lm))
        m.__dict__.update(lm.__dict__, **changed, pose=None if lm.pose is None else T @ lm.pose)
        out.append(m)
    return out


# ------------------------------------------------------------------ consistency
def nees_band(dof: int = NEES_DOF, confidence: float = CONFIDENCE) -> tuple[float, float]:
    """The two-sided ``confidence`` interval of one χ²(dof) value."""
    lo, hi = chi2.ppf([(1 - confidence) / 2, (1 + confidence) / 2], dof)
    return float(lo), float(hi)


def position_nees_series(estimate: Trajectory, truth: Trajectory) -> np.ndarray | None:
    """The per-pose NEES of the 3-D position (poses with a finite covariance and a true pose)."""
    if estimate.position_cov is None or len(truth) < 2 or len(estimate) == 0:
        return None
    rows, truth_rows = _associate(estimate, truth)
    P = estimate.position_cov[rows]
    ok = np.isfinite(P).all(axis=(1, 2))
    if not ok.any():
        return None
    e = estimate.positions[rows[ok]] - truth.positions[truth_rows[ok]]
    try:
        return np.einsum("ni,ni->n", e, np.linalg.solve(P[ok], e[..., None])[..., 0])
    except np.linalg.LinAlgError:
        return None


def nees_consistency(estimate: Trajectory, truth: Trajectory) -> dict:
    """``nees_band95`` (of one pose's NEES), ``nees_in_band`` (the mission's mean NEES inside it),
    ``nees_share_in_pose_band`` (poses inside it: 0.95 if consistent) and ``nees_share_above_pose_band``
    (0.025 if consistent; more: overconfident)."""
    lo, hi = nees_band()
    out = {"nees_band95": [lo, hi], "nees_in_band": None, "nees_share_in_pose_band": None}
    out["nees_share_above_pose_band"] = None
    nees = position_nees_series(estimate, truth)
    if nees is None or nees.size == 0:
        return out
    out.update(
        nees_in_band=bool(lo <= float(np.mean(nees)) <= hi),
        nees_share_in_pose_band=float(np.mean((nees >= lo) & (nees <= hi))),
        nees_share_above_pose_band=float(np.mean(nees > hi)),
    )
    return out


def map_quality(
    result: EstimatorResult, truth_trajectory: Trajectory | None, truth_map: GroundTruthMap | None, match: Matcher
) -> dict:
    """The issue-21 keys of an estimator's block of metrics.json (see the module)."""
    out: dict = {"ate_rmse_pos_yaw_m": None}
    aligned = None
    if truth_trajectory is not None:
        aligned = ate_position_yaw(result.trajectory, truth_trajectory)
        out["ate_rmse_pos_yaw_m"] = None if aligned is None else aligned[0]
        out.update(nees_consistency(result.trajectory, truth_trajectory))
    if truth_map is not None:
        out.update(landmark_quality(result.landmarks, truth_map, match))
        if aligned is not None:  # the map's own errors, without the gauge (yaw and shift) of the trajectory
            q = landmark_quality(moved(result.landmarks, aligned[1]), truth_map, match)
            out["map_aligned"] = {k: q[k] for k in ALIGNED_KEYS}
    return out
