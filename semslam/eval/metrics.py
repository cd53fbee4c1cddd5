"""Metrics of an estimator's result against ground truth: trajectory errors (evo's, computed at once),
landmark errors, consistency (NEES) and timing. Library functions that return plain dicts with
the keys of ``metrics.json`` (DESIGN.md); a key without ground truth is None, never invented."""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.spatial.transform import Rotation

from semslam.estimation import EstimatorResult, LandmarkEstimate, Trajectory
from semslam.eval.map_quality import map_quality
from semslam.eval.structures import pose_at, structure_counts, structure_rows
from semslam.mission.ground_truth import GroundTruthMap

ALIGNMENTS = ("none", "se3", "origin")


def matching_time_indices(stamps_1: np.ndarray, stamps_2: np.ndarray, max_diff: float) -> tuple[list, list]:
    """evo's ``sync.matching_time_indices`` (the nearest of ``stamps_2`` to each of ``stamps_1``
    within ``max_diff``, its tie rules included) at once instead of stamp by stamp; evo's own when
    ``stamps_2`` is not sorted."""
    from evo.core import sync

    s1, s2 = np.asarray(stamps_1, float), np.asarray(stamps_2, float)
    if len(s2) == 0 or np.any(np.diff(s2) < 0):
        return sync.matching_time_indices(s1, s2, max_diff)
    i2 = np.minimum(np.searchsorted(s2, s1, side="right"), len(s2) - 1)
    diff_ub = s2[i2] - s1
    diff_lb = np.where(i2 > 0, s1 - s2[np.maximum(i2 - 1, 0)], np.inf)
    upper = (diff_ub <= max_diff) & (diff_ub < diff_lb)
    lower = ~upper & (diff_lb <= max_diff) & (diff_lb <= diff_ub)
    inside = (s1 >= s2[0] - max_diff) & (s1 <= s2[-1] + max_diff) & (upper | lower)
    ids_1 = np.flatnonzero(inside)
    return ids_1.tolist(), np.where(upper, i2, i2 - 1)[ids_1].tolist()


class GeometryException(ValueError):
    """The positions cannot fix an SE(3) alignment (all on one line or one point): evo's condition."""


def _associated(estimate: Trajectory, truth: Trajectory, max_dt_s: float) -> tuple[list, list] | None:
    """(truth rows, estimate rows) of the associated poses, as evo's ``sync.associate_trajectories``
    pairs them (nearest stamp within ``max_dt_s``, from the trajectory with fewer poses); None when
    nothing associates."""
    est_longer = len(estimate) > len(truth)
    short, long_ = (truth, estimate) if est_longer else (estimate, truth)
    ids_short, ids_long = matching_time_indices(short.stamps * 1e-9, long_.stamps * 1e-9, max_dt_s)
    if not ids_short:
        return None
    return (ids_short, ids_long) if est_longer else (ids_long, ids_short)


def umeyama(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation r and translation t (no scale) with y ≈ r x + t for points x, y (N×3): evo's
    ``geometry.umeyama_alignment``, its covariance summed at once instead of point by point;
    :class:`GeometryException` where evo raises its own."""
    mean_x, mean_y = x.mean(axis=0), y.mean(axis=0)
    cov_xy = (y - mean_y).T @ (x - mean_x) / len(x)
    u, d, v = np.linalg.svd(cov_xy)
    if np.count_nonzero(d > np.finfo(d.dtype).eps) < 2:
        raise GeometryException("degenerate covariance rank: no SE(3) alignment")
    s = np.eye(3)
    if np.linalg.det(u) * np.linalg.det(v) < 0.0:
        s[2, 2] = -1
    r = u @ s @ v
    return r, mean_y - r @ mean_x


def path_pairs(positions: np.ndarray, delta: float) -> list[tuple[int, int]]:
    """evo's consecutive pairs of poses ``delta`` metres of path apart (``filters.filter_pairs_by_path``:
    the path summed from each pair's first pose until it reaches ``delta``), each end found by a search
    on the cumulative path and confirmed by evo's sum from the pair's first pose, instead of pose by pose."""
    steps = np.linalg.norm(np.diff(positions, axis=0), axis=1)
    cum = np.concatenate([[0.0], np.cumsum(steps)])  # cum[k]: the path from pose 0 to pose k
    ids, i = [0], 0
    while i < len(steps):
        guess = int(np.searchsorted(cum, cum[i] + delta, side="left"))  # the end, up to rounding
        run = np.cumsum(steps[i : guess + 4])  # evo's sum from pose i, in its order
        hit = np.flatnonzero(run >= delta)
        if not len(hit) and guess + 4 < len(steps):  # a rounding short of delta, then a standstill
            hit = np.flatnonzero(np.cumsum(steps[i:]) >= delta)
        if not len(hit):
            break
        i += 1 + int(hit[0])
        ids.append(i)
    return list(zip(ids, ids[1:]))


@dataclass
class TrajectoryErrors:
    ate_rmse_m: float
    ate_max_m: float
    ate_median_m: float
    rpe_rmse_m: float | None
    errors_m: np.ndarray  # per associated pose
    stamps: np.ndarray  # ns, of the associated poses


def trajectory_errors(
    estimate: Trajectory,
    truth: Trajectory,
    alignment: str = "none",
    rpe_delta_m: float = 1.0,
    max_dt_s: float = 0.05,
    rpe: bool = True,
) -> TrajectoryErrors | None:
    """APE (translation) and RPE (translation per ``rpe_delta_m`` travelled, consecutive pairs
    from the estimate; ``rpe`` False: not computed, None) as evo computes them (its
    ``metrics.APE``/``RPE`` with ``PoseRelation.translation_part``), on all poses at once: evo
    builds, aligns and compares pose matrices one by one (most of the metrics' time).

    ``alignment``: "none" (the world frame is observable: depth and AHRS fix it — the default),
    "se3" (Umeyama) or "origin" (first poses aligned). None when no pose could be associated.
    """
    if alignment not in ALIGNMENTS:
        raise ValueError(f"alignment must be one of {ALIGNMENTS}")
    if len(estimate) == 0 or len(truth) == 0:
        return None
    rows = _associated(estimate, truth, max_dt_s)
    if rows is None:
        return None
    ref_p, est_p = truth.positions[rows[0]], estimate.positions[rows[1]]
    ref_R = Rotation.from_quat(truth.orientations[rows[0]]).as_matrix()
    est_R = Rotation.from_quat(estimate.orientations[rows[1]]).as_matrix()
    if alignment == "se3":
        r, t = umeyama(est_p, ref_p)
    elif alignment == "origin":  # T_ref0 · T_est0⁻¹
        r = ref_R[0] @ est_R[0].T
        t = ref_p[0] - r @ est_p[0]
    if alignment != "none":
        est_p, est_R = est_p @ r.T + t, r @ est_R
    errors = np.linalg.norm(est_p - ref_p, axis=1)
    rpe_rmse = None
    pairs = np.array(path_pairs(est_p, rpe_delta_m), int).reshape(-1, 2) if rpe else np.zeros((0, 2), int)
    if len(pairs):  # |t(Q_rel⁻¹ P_rel)| = |t(P_rel) − t(Q_rel)|, t(A_rel) = R_Aiᵀ (a_j − a_i)
        i, j = pairs[:, 0], pairs[:, 1]
        t_est = np.einsum("nki,nk->ni", est_R[i], est_p[j] - est_p[i])
        t_ref = np.einsum("nki,nk->ni", ref_R[i], ref_p[j] - ref_p[i])
        rpe_rmse = float(np.sqrt(np.mean(np.sum((t_est - t_ref) ** 2, axis=1))))
    return TrajectoryErrors(
        ate_rmse_m=float(np.sqrt(np.mean(errors**2))),
        ate_max_m=float(errors.max()),
        ate_median_m=float(np.median(errors)),
        rpe_rmse_m=rpe_rmse,
        errors_m=errors,
        stamps=np.round(np.asarray(truth.stamps, np.int64)[rows[0]] * 1e-9 * 1e9).astype(np.int64),
    )


def position_nees(estimate: Trajectory, truth: Trajectory, max_dt_s: float = 0.05) -> float | None:
    """Mean over poses of eᵀ P⁻¹ e for the 3-D position error (expected value 3 if consistent)."""
    if estimate.position_cov is None or len(truth) == 0 or len(estimate) == 0:
        return None
    idx = np.searchsorted(truth.stamps, estimate.stamps)
    idx = np.clip(idx, 1, len(truth.stamps) - 1)
    left_closer = (estimate.stamps - truth.stamps[idx - 1]) < (truth.stamps[idx] - estimate.stamps)
    idx = np.where(left_closer, idx - 1, idx)
    ok = np.abs(truth.stamps[idx] - estimate.stamps) <= max_dt_s * 1e9
    ok &= np.isfinite(estimate.position_cov).all(axis=(1, 2))  # poses without a covariance are skipped
    if not ok.any():
        return None
    e = estimate.positions[ok] - truth.positions[idx[ok]]
    P = estimate.position_cov[ok]
    try:
        nees = np.einsum("ni,ni->n", e, np.linalg.solve(P, e[..., None])[..., 0])
    except np.linalg.LinAlgError:
        return None
    return float(np.mean(nees))


def _pipe_costs(ends: np.ndarray, p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """(E, G) cost of estimated segments ``ends`` (E, 2, 3) against true pipes from ``p`` to ``q``
    (G, 3): the mean distance of the two ends to the true axis, plus how far (m) their projections
    fall outside the true segment (a segment beyond the true pipe's extent is not that pipe)."""
    L = np.linalg.norm(q - p, axis=1)  # (G,)
    d = (q - p) / L[:, None]
    v = ends[:, None, :, :] - p[None, :, None, :]  # (E, G, 2, 3)
    t = np.einsum("egkc,gc->egk", v, d)
    off_axis = np.linalg.norm(v - t[..., None] * d[None, :, None, :], axis=-1).mean(axis=-1)
    beyond = np.maximum(0.0, np.maximum(-t, t - L[None, :, None])).max(axis=-1)
    return off_axis + beyond


@dataclass
class LandmarkMatch:
    kind: str
    estimate_id: int
    truth_id: int
    error_m: float


def match_landmarks(
    landmarks: list[LandmarkEstimate], truth: GroundTruthMap, gate_m: float = 0.5
) -> tuple[list[LandmarkMatch], dict]:
    """One-to-one assignment (Hungarian) of mapped landmarks to ground truth within ``gate_m``.

    Object error: distance between positions. Pipe error: mean distance of the estimated endpoints
    to the true pipe axis (endpoints are only as long as what was seen). Structure error: distance
    between origins. Returns the matches and counts of duplicates (estimates beyond the first whose
    nearest truth within the gate is the same) and spurious estimates (no truth within the gate).
    """
    matches: list[LandmarkMatch] = []
    counts = {"duplicates": 0, "spurious": 0}
    for kind, gts in (("object", truth.objects), ("pipe", truth.pipes), ("structure", truth.structures)):
        ests = [lm for lm in landmarks if lm.kind == kind]
        if not ests:
            continue
        if not gts:
            counts["spurious"] += len(ests)
            continue
        if kind == "pipe":
            ends = np.array([[lm.p, lm.q] for lm in ests], float)
            C = _pipe_costs(ends, np.array([g.p for g in gts], float), np.array([g.q for g in gts], float))
        else:
            at = np.array([lm.position if kind == "object" else np.asarray(lm.pose)[:3, 3] for lm in ests], float)
            C = np.linalg.norm(at[:, None, :] - np.array([g.position for g in gts], float)[None], axis=2)
        big = 1e6
        rows, cols = linear_sum_assignment(np.where(np.isfinite(C) & (C <= gate_m), C, big))
        matched_rows = set()
        for a, b in zip(rows, cols):
            if C[a, b] <= gate_m:
                matches.append(LandmarkMatch(kind, ests[a].id, gts[b].id, float(C[a, b])))
                matched_rows.add(a)
        # duplicates by nearest truth, not by what the assignment left over: a second estimate of one
        # pipe is otherwise assigned to an unseen neighbour within the gate and hidden
        nearest = np.argmin(C, axis=1)
        within = np.min(C, axis=1) <= gate_m
        counts["spurious"] += int(np.sum(~within))
        counts["duplicates"] += int(within.sum() - len(np.unique(nearest[within])))
    return matches, counts


MAX_DIAGNOSTICS = 50  # in metrics.json; the count says how many there were

# What the estimators' diagnostics say when an update, a slide or the batch failed and was recovered
# from (semslam.backend.session/window/result): the estimate may be off from there on.
_FAILURE = re.compile(r"\bfailed\b|re-anchoring")


def recovered_failures(diagnostics: list[str]) -> list[str]:
    """The diagnostics that report a failure the estimator recovered from."""
    return [d for d in diagnostics if _FAILURE.search(d)]


def estimator_metrics(
    result: EstimatorResult,
    truth_trajectory: Trajectory | None,
    truth_map: GroundTruthMap | None,
    runtime_s: float | None,
    alignment: str = "none",
) -> dict:
    """The per-estimator block of metrics.json."""
    out: dict = {
        "ate_rmse_m": None,
        "ate_max_m": None,
        "rpe_rmse_m": None,
        # after an SE(3) (Umeyama) alignment: without the error of the global frame, which a
        # heading-biased AHRS leaves unobservable (the map's yaw about the start)
        "ate_rmse_se3_m": None,
        "landmark_median_error_m": None,
        "n_objects": sum(lm.kind == "object" for lm in result.landmarks),
        "n_pipes": sum(lm.kind == "pipe" for lm in result.landmarks),
        "n_structures": sum(lm.kind == "structure" for lm in result.landmarks),
        "runtime_s": runtime_s,
        "update_ms_median": None,
        "update_ms_p95": None,
        "nees_mean": None,
        # objects the map building left out at the end as false views (semslam.mapping.visibility)
        "objects_left_out": result.history.get("objects_left_out"),
        # what the estimator recovered from or left out, as it said it (at most MAX_DIAGNOSTICS)
        "diagnostics_count": len(result.diagnostics),
        "recovered_failures": len(recovered_failures(result.diagnostics)),
        "diagnostics": list(result.diagnostics[:MAX_DIAGNOSTICS]),
    }
    if len(result.update_times_s):
        out["update_ms_median"] = float(np.median(result.update_times_s) * 1e3)
        out["update_ms_p95"] = float(np.percentile(result.update_times_s, 95) * 1e3)
    if truth_trajectory is not None:
        errs = trajectory_errors(result.trajectory, truth_trajectory, alignment=alignment)
        if errs is not None:
            out.update(ate_rmse_m=errs.ate_rmse_m, ate_max_m=errs.ate_max_m, rpe_rmse_m=errs.rpe_rmse_m)
            out["ate_rmse_se3_m"] = _aligned_ate(result.trajectory, truth_trajectory)
        out["nees_mean"] = position_nees(result.trajectory, truth_trajectory)
    if truth_map is not None and result.landmarks:
        matches, counts = match_landmarks(result.landmarks, truth_map)
        if matches:
            out["landmark_median_error_m"] = float(np.median([m.error_m for m in matches]))
        for kind in ("object", "pipe", "structure"):
            errs_k = [m.error_m for m in matches if m.kind == kind]
            out[f"{kind}_median_error_m"] = float(np.median(errs_k)) if errs_k else None
        out.update({f"landmark_{k}": v for k, v in counts.items()})
    # per class duplicates/misses/false, the NEES band, position+yaw ATE (semslam.eval.map_quality)
    out.update(map_quality(result, truth_trajectory, truth_map, match_landmarks))
    return out


def _aligned_ate(estimate: Trajectory, truth: Trajectory) -> float | None:
    """ATE RMSE after SE(3) alignment; None when the trajectory cannot fix one (a straight line)."""
    try:
        errs = trajectory_errors(estimate, truth, alignment="se3", rpe=False)
    except GeometryException:
        return None
    return errs.ate_rmse_m if errs is not None else None


def sonar_metrics(frontend: dict, truth: GroundTruthMap | None, truth_trajectory: Trajectory | None = None) -> dict:
    """The ``sonar`` block of metrics.json from a sonar front-end's summary and the ground truth.
    With the truth's trajectory, a structure is judged relative to the estimated trajectory where
    it was seen (:func:`semslam.eval.structures.structure_rows`), so that a navigation error there
    is not counted as the registration's; without it, against the truth in the world frame.

    ``frontend["structures"]`` lists what the front-end registered: ``model``, ``pose`` (T_W,model
    4×4 as it placed it), ``median_error_m`` (median point-to-model distance after registration)
    and ``symmetry`` (rotational order about the vertical: yaw errors are taken modulo 2π/order).
    With ground truth, every true structure the sensor saw gets an entry (``found`` only when a
    registration of its model lies at the right place: :mod:`semslam.eval.structures`), with its
    position and yaw errors; registrations at no right place follow with ``truth_id`` None (false
    structures, ``wrong_place`` when on a true structure of their model but wrongly), and the counts.
    """
    found = [dict(s) for s in frontend.get("structures", [])]
    out = {k: v for k, v in frontend.items() if k != "structures"}
    for k in ("runtime_s", "world_model_bytes", "raw_cloud_bytes"):
        out.setdefault(k, None)
    if truth is None or not truth.structures:
        out["structures"] = [
            {
                "model": s["model"],
                "found": True,
                "median_error_m": s.get("median_error_m"),
                "yaw_error_deg": None,
                "position_error_m": None,
                "truth_id": None,
            }
            for s in found
        ]
        return out
    along = pose_at(truth_trajectory) if truth_trajectory is not None and len(truth_trajectory.stamps) > 1 else None
    out["structures"] = structure_rows(found, truth, along)
    out.update(structure_counts(out["structures"]))
    return out
