"""What a study keeps of one mission's metrics.json: the numbers its statistics are made of."""

from __future__ import annotations

#: per-estimator keys of metrics.json the study keeps (absent ones are None)
ESTIMATOR_KEYS = (
    "ate_rmse_m",
    "ate_rmse_se3_m",
    "rpe_rmse_m",
    "landmark_median_error_m",
    "object_median_error_m",
    "pipe_median_error_m",
    "landmark_duplicates",
    "landmark_spurious",
    "nees_mean",
    # issue 21: what a median hides (semslam.eval.map_quality)
    "ate_rmse_pos_yaw_m",
    "nees_in_band",
    "nees_share_in_pose_band",
    "objects_once",
    "object_seen",
    "object_duplicates",
    "object_missed",
    "object_false",
    "object_p90_error_m",
    "pipe_seen",
    "pipe_duplicates",
    "pipe_missed",
    "pipe_false",
    "pipe_p90_error_m",
    "structure_missed",
    "structure_false",
    "n_objects",
    "n_pipes",
    "n_structures",
    "runtime_s",
    "recovered_failures",
    # with --hold-out-gps: the error at the fixes held out (the reference of a real recording)
    "gps_error_rmse_m",
    "gps_error_last_m",
)


def _ratio(n, truth):
    return None if n is None or not truth else n / truth


def mission_summary(metrics: dict) -> dict:
    """The per-mission summary of ``study.json`` from a mission's ``metrics.json``: mission size,
    per estimator its :data:`ESTIMATOR_KEYS` plus ``objects_mapped_ratio`` / ``pipes_mapped_ratio``
    (landmarks mapped over the true ones), ``pipes_seen_mapped_ratio`` (seen pipes matched by an
    estimate over those seen) and ``pipe_duplicate_ratio`` (duplicate pipes over those seen), recognition F1 per stage, sonar structures found."""
    mission = metrics.get("mission") or {}
    out = {
        "duration_s": mission.get("duration_s"),
        "gt_objects": mission.get("gt_objects"),
        "gt_pipes": mission.get("gt_pipes"),
        "gt_structures": mission.get("gt_structures"),
        "reference": metrics.get("reference"),
        "estimators": {},
        "recognition_f1": {
            stage: (block or {}).get("f1") for stage, block in (metrics.get("recognition") or {}).items()
        },
        "structures_found": None,
    }
    for name, e in (metrics.get("estimators") or {}).items():
        row = {k: e.get(k) for k in ESTIMATOR_KEYS}
        row["objects_mapped_ratio"] = _ratio(e.get("n_objects"), mission.get("gt_objects"))
        row["pipes_mapped_ratio"] = _ratio(e.get("n_pipes"), mission.get("gt_pipes"))
        seen, missed = e.get("pipe_seen"), e.get("pipe_missed")
        row["pipes_seen_mapped_ratio"] = None if missed is None else _ratio(seen - missed, seen)
        row["pipe_duplicate_ratio"] = _ratio(e.get("pipe_duplicates"), seen)
        out["estimators"][name] = row
    sonar = metrics.get("sonar")
    if sonar and sonar.get("structures") is not None:
        out["structures_found"] = sum(bool(s.get("found")) for s in sonar["structures"])
    return out
