"""Scoring a segmented scan against ground truth (tests and ``experiments/laser_eval.py``).

Ground truth for one scan, in the sensor frame {S}: what every raw point hit (``kind``: plane,
pipe, object or other; ``index``: which pipe / object), the pipe axes and the object positions
with their connectivity configuration. The figures are those of the acceptance of issue 6.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from frontends.laser.frontend import ScanSegmentation

PLANE, PIPE, OBJECT, OTHER = 0, 2, 3, -1


@dataclass
class ScanTruth:
    """``kind`` (N,) per raw point: PLANE, PIPE, OBJECT or OTHER; ``index`` (N,) pipe / object index
    (−1 otherwise); ``pipes`` list of (p, q, radius); ``objects`` list of (position, configuration);
    ``object_visible_configuration`` the configuration counting only the pipes seen (or None)."""

    kind: np.ndarray
    index: np.ndarray
    pipes: list[tuple[np.ndarray, np.ndarray, float]]
    objects: list[tuple[np.ndarray, int | None]]
    object_visible_configuration: list[int | None] | None = None
    object_classes: list[str] | None = None  # class name per object, when known


@dataclass
class ScanScore:
    structure_kept: float  # fraction of pipe + object points kept by plane removal
    plane_removed: float  # fraction of floor + wall points removed
    n_visible_pipes: int  # ≥ min_visible of their length seen
    n_recalled_pipes: int
    n_visible_long_pipes: int  # ... and seen over at least min_pipe_length (what the detector may report)
    n_recalled_long_pipes: int
    n_detections: int  # reported (≥ min_pipe_length)
    n_true_detections: int
    n_structure_points: int = 0
    n_structure_kept: int = 0
    n_plane_points: int = 0
    n_plane_removed: int = 0
    endpoint_errors: list[float] = field(default_factory=list)  # m, against the visible extent
    axis_errors_deg: list[float] = field(default_factory=list)
    # Normalised errors with the reported covariances (consistency: their mean should be the dof).
    endpoint_perp_nees: list[float] = field(default_factory=list)  # 2 dof: offset from the true axis
    endpoint_along_nees: list[float] = field(default_factory=list)  # 1 dof: against the visible extent
    n_visible_objects: int = 0
    n_single_segment: int = 0  # visible objects with exactly one segment
    object_errors: list[float] = field(default_factory=list)  # m, of the single segments
    object_nees: list[float] = field(default_factory=list)  # 3 dof, of the single segments
    n_config_correct: int = 0  # of the single segments, configuration = truth
    n_config_visible_correct: int = 0  # ... = configuration of the pipes seen
    n_config_visible_known: int = 0  # single segments whose seen-pipes configuration is known
    n_object_segments: int = 0
    n_spurious_objects: int = 0  # segments near no visible object
    # What repeats across views and so becomes a false landmark in the back-end:
    n_spurious_at_free_end: int = 0  # spurious segments at a pipe end that enters no object
    # segments per true object (each segment to its nearest object within split_gate), for the
    # visible objects with at least one: class → [objects with one segment, objects with more]
    segments_by_class: dict = field(default_factory=dict)
    bridged_by_class: dict = field(
        default_factory=dict
    )  # class → reported pipe segments running through it (> 0.1 m each side)
    # signed error of single segments towards the sensor (m), by configuration found (1-4)
    toward_sensor_by_config: dict = field(default_factory=dict)
    # fraction of an object's own hits in its single segment, by class
    coverage_by_class: dict = field(default_factory=dict)
    configuration_pairs: dict = field(default_factory=dict)  # "found-true" → single segments


def _unit(v):
    return v / np.linalg.norm(v)


def _perpendicular_basis(a: np.ndarray) -> np.ndarray:
    """3×2 orthonormal basis of the plane orthogonal to the unit vector ``a``."""
    e1 = _unit(np.cross(a, [1.0, 0, 0]) if abs(a[0]) < 0.9 else np.cross(a, [0, 1.0, 0]))
    return np.column_stack([e1, np.cross(a, e1)])


def pipe_visibility(points: np.ndarray, truth: ScanTruth, k: int, bin_size: float = 0.02):
    """Fraction of pipe k's length hit by the scan, and the visible extent [t0, t1] along p→q."""
    p, q, _ = truth.pipes[k]
    a = _unit(q - p)
    length = float(np.linalg.norm(q - p))
    hits = points[(truth.kind == PIPE) & (truth.index == k)]
    if len(hits) == 0:
        return 0.0, None
    t = np.clip((hits - p) @ a, 0.0, length)
    n_bins = max(int(np.ceil(length / bin_size)), 1)
    covered = np.unique(np.minimum((t / bin_size).astype(int), n_bins - 1))
    return len(covered) / n_bins, (float(t.min()), float(t.max()))


def score_scan(
    points: np.ndarray,
    seg: ScanSegmentation,
    truth: ScanTruth,
    min_visible: float = 0.5,
    match_angle_deg: float = 10.0,
    match_distance: float = 0.1,
    object_gate: float = 0.15,
    min_object_hits: int = 30,
    min_pipe_length: float = 0.30,
) -> ScanScore:
    points = np.asarray(points, dtype=np.float64)
    v = seg.pre.raw_to_voxel
    kept = np.zeros(len(points), bool)
    kept[v >= 0] = seg.planes.structure[v[v >= 0]]
    struct = (truth.kind == PIPE) | (truth.kind == OBJECT)
    plane = truth.kind == PLANE
    structure_kept = float(kept[struct].mean()) if struct.any() else float("nan")
    plane_removed = float(1.0 - kept[plane].mean()) if plane.any() else float("nan")

    # Pipes: a detection is true when near-parallel to a truth pipe, on its axis and overlapping it.
    vis = [pipe_visibility(points, truth, k) for k in range(len(truth.pipes))]
    dets = [det for det in seg.pipes if not det.objects_only]  # runs that only serve the objects are no detection
    match = np.full(len(dets), -1)
    for d, det in enumerate(dets):
        best = np.inf
        for k, (p, q, _) in enumerate(truth.pipes):
            a = _unit(q - p)
            if abs(a @ det.axis) < np.cos(np.radians(match_angle_deg)):
                continue
            mid = 0.5 * (det.p + det.q)
            lateral = np.linalg.norm((mid - p) - ((mid - p) @ a) * a)
            t = sorted([(det.p - p) @ a, (det.q - p) @ a])
            overlap = min(t[1], np.linalg.norm(q - p)) - max(t[0], 0.0)
            if lateral <= match_distance and overlap > 0 and lateral < best:
                best, match[d] = lateral, k
    # Detections at least min_pipe_length long are the reported ones (precision, recall of long
    # pipes); shorter ones only count in the recall of all pipes.
    reported = np.array([det.length >= min_pipe_length for det in dets], bool)
    visible = [k for k, (f, _) in enumerate(vis) if f >= min_visible]
    # "long": seen over at least min_pipe_length (a pipe seen over less cannot give a reported segment)
    long = [k for k in visible if vis[k][1][1] - vis[k][1][0] >= min_pipe_length]
    found = set(match[match >= 0].tolist())
    found_reported = set(match[(match >= 0) & reported].tolist())
    score = ScanScore(
        structure_kept,
        plane_removed,
        len(visible),
        len(found & set(visible)),
        len(long),
        len(found_reported & set(long)),
        int(reported.sum()),
        int(((match >= 0) & reported).sum()),
    )
    score.n_structure_points = int(struct.sum())
    score.n_structure_kept = int(kept[struct].sum())
    score.n_plane_points = int(plane.sum())
    score.n_plane_removed = int(plane.sum() - kept[plane].sum())
    for d, k in enumerate(match):
        if k < 0 or vis[k][1] is None:
            continue
        p, q, _ = truth.pipes[k]
        a = _unit(q - p)
        det = dets[d]
        score.axis_errors_deg.append(float(np.degrees(np.arccos(min(abs(a @ det.axis), 1.0)))))
        t0, t1 = vis[k][1]
        forward = (det.q - det.p) @ a > 0
        ends = (det.p, det.q) if forward else (det.q, det.p)
        covs = (det.covariance[:3, :3], det.covariance[3:, 3:])
        covs = covs if forward else covs[::-1]
        B = _perpendicular_basis(a)
        for e, t, C in zip(ends, (t0, t1), covs):
            err = e - (p + t * a)
            score.endpoint_errors.append(float(np.linalg.norm(err)))
            perp = B.T @ err  # the offset from the true axis (the along-axis part is the extent's)
            score.endpoint_perp_nees.append(float(perp @ np.linalg.solve(B.T @ C @ B, perp)))
            score.endpoint_along_nees.append(float((err @ a) ** 2 / max(a @ C @ a, 1e-300)))

    # Objects: visible = hit by enough rays; exactly one segment within the gate.
    seg_pos = np.array([o.position for o in seg.objects]).reshape(-1, 3)
    score.n_object_segments = len(seg_pos)
    near_any = np.zeros(len(seg_pos), bool)
    for j, (pos, config) in enumerate(truth.objects):
        hits = int(((truth.kind == OBJECT) & (truth.index == j)).sum())
        d = np.linalg.norm(seg_pos - pos, axis=1) if len(seg_pos) else np.zeros(0)
        near = d <= object_gate
        near_any |= near
        if hits < min_object_hits:
            continue
        score.n_visible_objects += 1
        if near.sum() == 1:
            score.n_single_segment += 1
            o = seg.objects[int(np.flatnonzero(near)[0])]
            score.object_errors.append(float(d[near][0]))
            err = o.position - pos
            score.object_nees.append(float(err @ np.linalg.solve(o.covariance, err)))
            score.n_config_correct += int(o.configuration == config)
            key = f"{o.configuration}-{config}"
            score.configuration_pairs[key] = score.configuration_pairs.get(key, 0) + 1
            if truth.object_visible_configuration is not None:
                score.n_config_visible_known += 1
                score.n_config_visible_correct += int(o.configuration == truth.object_visible_configuration[j])
    score.n_spurious_objects = int((~near_any).sum())
    _score_map_errors(points, seg, truth, score, seg_pos, near_any, min_object_hits, min_pipe_length)
    return score


def _score_map_errors(
    points,
    seg,
    truth,
    score,
    seg_pos,
    near_any,
    min_object_hits,
    min_pipe_length,
    split_gate=0.25,
    free_end_gate=0.2,
    bridge_margin=0.10,
    bridge_lateral=0.04,
):
    """The errors that repeat across consecutive views (so the back-end maps them): spurious
    segments at free pipe ends, objects segmented more than once, pipe segments running through an
    object, a position bias towards the sensor, and how much of each object its segment holds."""
    obj_pos = np.array([pos for pos, _ in truth.objects]).reshape(-1, 3)
    classes = truth.object_classes or ["object"] * len(obj_pos)
    # pipe ends that enter no object: lone ends where nothing is to be found
    ends = np.array([e for p, q, _ in truth.pipes for e in (p, q)]).reshape(-1, 3)
    if len(ends) and len(obj_pos):
        free = ends[np.linalg.norm(ends[:, None] - obj_pos[None], axis=2).min(axis=1) > free_end_gate]
    else:
        free = ends
    for j in np.flatnonzero(~near_any):
        if len(free) and np.linalg.norm(free - seg_pos[j], axis=1).min() <= free_end_gate:
            score.n_spurious_at_free_end += 1
    hits = np.bincount(truth.index[truth.kind == OBJECT], minlength=len(obj_pos)) if len(obj_pos) else np.zeros(0, int)
    if len(seg_pos) and len(obj_pos):
        d = np.linalg.norm(seg_pos[:, None] - obj_pos[None], axis=2)
        nearest = d.argmin(axis=1)
        owned = np.bincount(nearest[d.min(axis=1) <= split_gate], minlength=len(obj_pos))
    else:
        owned = np.zeros(len(obj_pos), int)
    for j in range(len(obj_pos)):
        if hits[j] >= min_object_hits and owned[j] >= 1:
            c = score.segments_by_class.setdefault(classes[j], [0, 0])
            c[0 if owned[j] == 1 else 1] += 1
    # reported pipe segments through an object (on their axis, more than bridge_margin inside both
    # ends: the back-end keeps collinear segments apart when an object lies between them, reaching
    # at most 0.1 m into either)
    for det in (d for d in seg.pipes if not d.objects_only):
        if det.length < min_pipe_length or not len(obj_pos):
            continue
        v = obj_pos - det.p
        t = v @ det.axis
        lateral = np.linalg.norm(v - t[:, None] * det.axis, axis=1)
        for j in np.flatnonzero((lateral <= bridge_lateral) & (t > bridge_margin) & (t < det.length - bridge_margin)):
            score.bridged_by_class[classes[j]] = score.bridged_by_class.get(classes[j], 0) + 1
    # bias towards the sensor and coverage, for the objects with a single segment
    raw_obj = truth.kind == OBJECT
    for j, (pos, _) in enumerate(truth.objects):
        if hits[j] < min_object_hits or not len(seg_pos):
            continue
        dj = np.linalg.norm(seg_pos - pos, axis=1)
        near = np.flatnonzero(dj <= 0.15)
        if len(near) != 1:
            continue
        o = seg.objects[near[0]]
        u = -pos / max(np.linalg.norm(pos), 1e-12)
        score.toward_sensor_by_config.setdefault(int(o.configuration), []).append(float((o.position - pos) @ u))
        if hasattr(seg, "raw_indices"):
            raw = seg.raw_indices(o.indices)
            mine = raw_obj[raw] & (truth.index[raw] == j)
            score.coverage_by_class.setdefault(classes[j], []).append(float(mine.sum() / max(hits[j], 1)))


def summarize(scores: list[ScanScore]) -> dict:
    """Overall figures of a list of scan scores (the acceptance of issue 6)."""

    def ratio(a, b):
        return float(a / b) if b else None

    def med(x):
        return float(np.median(x)) if len(x) else None

    def mean(lists):  # mean over the concatenated per-scan lists (dof for a consistent covariance)
        x = [e for lst in lists for e in lst]
        return float(np.mean(x)) if x else None

    structure = [s.structure_kept for s in scores if np.isfinite(s.structure_kept)]
    plane = [s.plane_removed for s in scores if np.isfinite(s.plane_removed)]
    ep = [e for s in scores for e in s.endpoint_errors]
    ax = [e for s in scores for e in s.axis_errors_deg]
    oe = [e for s in scores for e in s.object_errors]
    vis_obj = sum(s.n_visible_objects for s in scores)
    single = sum(s.n_single_segment for s in scores)
    return {
        "scans": len(scores),
        "structure_kept_overall": ratio(
            sum(s.n_structure_kept for s in scores), sum(s.n_structure_points for s in scores)
        ),
        "plane_removed_overall": ratio(sum(s.n_plane_removed for s in scores), sum(s.n_plane_points for s in scores)),
        "structure_kept_mean": float(np.mean(structure)) if structure else None,
        "structure_kept_min": float(np.min(structure)) if structure else None,
        "plane_removed_mean": float(np.mean(plane)) if plane else None,
        "plane_removed_min": float(np.min(plane)) if plane else None,
        "pipe_recall": ratio(sum(s.n_recalled_pipes for s in scores), sum(s.n_visible_pipes for s in scores)),
        "pipe_recall_long": ratio(
            sum(s.n_recalled_long_pipes for s in scores), sum(s.n_visible_long_pipes for s in scores)
        ),
        "pipe_precision": ratio(sum(s.n_true_detections for s in scores), sum(s.n_detections for s in scores)),
        "endpoint_error_median_m": med(ep),
        "endpoint_error_p90_m": float(np.percentile(ep, 90)) if ep else None,
        "axis_error_median_deg": med(ax),
        "axis_error_p90_deg": float(np.percentile(ax, 90)) if ax else None,
        "endpoint_perp_nees_mean": mean(s.endpoint_perp_nees for s in scores),
        "endpoint_perp_nees_median": med([e for s in scores for e in s.endpoint_perp_nees]),
        "endpoint_along_nees_mean": mean(s.endpoint_along_nees for s in scores),
        "objects_single_segment": ratio(single, vis_obj),
        "object_error_median_m": med(oe),
        "object_within_5cm": ratio(sum(e <= 0.05 for e in oe), len(oe)),
        "object_nees_mean": mean(s.object_nees for s in scores),
        "object_nees_median": med([e for s in scores for e in s.object_nees]),
        "configuration_correct": ratio(sum(s.n_config_correct for s in scores), single),
        # the same over all visible objects (an object without exactly one segment counts as wrong):
        # the stricter reading of "configuration correct for >= 90 % of them"
        "configuration_correct_of_visible": ratio(sum(s.n_config_correct for s in scores), vis_obj),
        "configuration_visible_correct": ratio(
            sum(s.n_config_visible_correct for s in scores), sum(s.n_config_visible_known for s in scores)
        ),
        "spurious_objects": sum(s.n_spurious_objects for s in scores),
        "spurious_objects_per_scan": ratio(sum(s.n_spurious_objects for s in scores), len(scores)),
        "scans_with_spurious": sum(s.n_spurious_objects > 0 for s in scores),
        "spurious_at_free_end": sum(s.n_spurious_at_free_end for s in scores),
        "objects_split_by_class": _merge_counts(s.segments_by_class for s in scores),
        "scans_with_split": sum(any(c[1] for c in s.segments_by_class.values()) for s in scores),
        "bridged_by_class": _merge_counts(s.bridged_by_class for s in scores),
        "scans_with_bridged": sum(bool(s.bridged_by_class) for s in scores),
        "configuration_pairs": _merge_counts(s.configuration_pairs for s in scores),
        "toward_sensor_by_config": _stats_by_key(s.toward_sensor_by_config for s in scores),
        "coverage_by_class": _stats_by_key(s.coverage_by_class for s in scores),
        "visible_objects": vis_obj,
        "visible_pipes": sum(s.n_visible_pipes for s in scores),
        "visible_long_pipes": sum(s.n_visible_long_pipes for s in scores),
    }


def _merge_counts(dicts) -> dict:
    """Sum of count dictionaries (values int or [one segment, more] lists)."""
    out: dict = {}
    for d in dicts:
        for k, v in d.items():
            if isinstance(v, list):
                acc = out.setdefault(k, [0] * len(v))
                out[k] = [a + b for a, b in zip(acc, v)]
            else:
                out[k] = out.get(k, 0) + v
    return dict(sorted(out.items(), key=lambda kv: str(kv[0])))


def _stats_by_key(dicts) -> dict:
    """Mean, median and count of the values gathered under each key."""
    acc: dict = {}
    for d in dicts:
        for k, v in d.items():
            acc.setdefault(k, []).extend(v)
    return {
        str(k): {"mean": round(float(np.mean(v)), 4), "median": round(float(np.median(v)), 4), "n": len(v)}
        for k, v in sorted(acc.items(), key=lambda kv: str(kv[0]))
    }


# ----------------------------------------------------------------------------------------------
# pipe observations of a whole mission against its ground-truth pipes (world frame)


def matching_pipe(p: np.ndarray, q: np.ndarray, truth_pipes, angle_deg: float = 10.0, distance: float = 0.05):
    """The true pipe (of ``truth_pipes``: objects with ``p``, ``q``, in {W}) a segment p-q ({W})
    lies on: axes within ``angle_deg``, both endpoints within ``distance`` of its axis and the segment
    overlapping its extent (±10 cm); the nearest such, or None."""
    a = _unit(q - p)
    best, best_d = None, np.inf
    for g in truth_pipes:
        gp, gq = np.asarray(g.p, float), np.asarray(g.q, float)
        length = float(np.linalg.norm(gq - gp))
        ga = (gq - gp) / length
        if abs(a @ ga) < np.cos(np.radians(angle_deg)):
            continue
        v = np.stack([p, q]) - gp
        t = v @ ga
        d = float(np.linalg.norm(v - np.outer(t, ga), axis=1).max())
        if d <= distance and t.max() > -0.1 and t.min() < length + 0.1 and d < best_d:
            best, best_d = g, d
    return best


def score_pipe_observations(views, truth_pipes, min_visible: float = 0.2) -> dict:
    """Scores of a mission's pipe observations against its true pipes.

    ``views``: per scan (``T_WS`` 4×4, the line observations ({S}) of that scan, ``visible``: true
    pipe id → length seen in the scan, m). A scan with a pipe seen over ``min_visible`` or more
    counts as detected when some observation lies on such a pipe (:func:`matching_pipe`); an
    observation on no true pipe is false. Radius errors: of the observations on a true pipe.
    """
    n_visible = n_detected = n_false = n_obs = 0
    radius_errors = []
    for T, lines, visible in views:
        hit = set()
        for o in lines:
            n_obs += 1
            P = np.stack([o.p, o.q]) @ T[:3, :3].T + T[:3, 3]
            g = matching_pipe(P[0], P[1], truth_pipes)
            if g is None:
                n_false += 1
                continue
            hit.add(g.id)
            if o.radius is not None:
                radius_errors.append(abs(o.radius - g.radius))
        wanted = {k for k, v in visible.items() if v >= min_visible}
        if wanted:
            n_visible += 1
            n_detected += bool(wanted & hit)
    n = len(views)
    return {
        "scans": n,
        "observations": n_obs,
        "scans_pipe_visible": n_visible,
        "scans_pipe_detected": n_detected,
        "detection_rate": n_detected / n_visible if n_visible else None,
        "false_per_scan": n_false / n if n else None,
        "false_observations": n_false,
        "radius_error_median_m": float(np.median(radius_errors)) if radius_errors else None,
    }
