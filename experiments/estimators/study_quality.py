"""Issue 21's acceptance over a study: how often every landmark is mapped once, graph against EKF.

    python experiments/estimators/study_quality.py STUDY_DIR [STUDY_DIR ...]

Reads only ``study.json`` (its per-mission summaries, a stable interface) and prints, over the
missions that finished, each criterion with its value and whether it holds:

- objects mapped exactly once (no duplicate, no miss) in ≥ 95 % of missions, per estimator;
- pipes: ≥ 95 % of the pipes the front-end saw mapped, ≤ 2 % duplicates (pooled over missions);
- no false structure; every structure found in ≥ 90 % of fields (sonar studies);
- graph/EKF unaligned ATE: median paired ratio ≤ 0.5, its 95 % CI below 0.6, graph worse in ≤ 5 %;
  SE(3)-aligned median ratio ≤ 0.5;
- landmark median error ≤ 2 cm for objects and pipes (graph; median over missions), graph ≤ EKF on
  it in ≥ 90 % of missions;
- mean position NEES inside the 95 % χ² band in ≥ 90 % of missions, graph and EKF.

Several folders are pooled (e.g. a tank study and a field study).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def _rows(dirs: list[Path]) -> list[dict]:
    rows = []
    for d in dirs:
        study = json.loads((d / "study.json").read_text())
        rows += [m["summary"] for m in study["missions"] if m["status"] == "ok" and m["summary"]]
    return rows


def _col(rows: list[dict], est: str, key: str) -> np.ndarray:
    vals = [((r["estimators"].get(est) or {}).get(key)) for r in rows]
    return np.array([np.nan if v is None else float(v) for v in vals])


def _share(x: np.ndarray) -> float:
    x = x[np.isfinite(x)]
    return float(np.mean(x)) if x.size else float("nan")


def criteria(rows: list[dict]) -> list[tuple[str, float, bool]]:
    """(criterion, value, holds) over the finished missions' summaries."""
    from semslam.study.stats import paired_ratio

    out = []
    for est in ("graph", "ekf"):
        once = _share(_col(rows, est, "objects_once"))
        out.append((f"{est}: missions with every object once (≥ 0.95)", once, once >= 0.95))
        seen, missed, dup = (np.nansum(_col(rows, est, k)) for k in ("pipe_seen", "pipe_missed", "pipe_duplicates"))
        if seen:
            out.append((f"{est}: seen pipes mapped, pooled (≥ 0.95)", 1 - missed / seen, 1 - missed / seen >= 0.95))
            out.append((f"{est}: pipe duplicates / seen, pooled (≤ 0.02)", dup / seen, dup / seen <= 0.02))
        fields = [r for r in rows if r.get("gt_structures")]
        if fields:
            false = np.nansum(_col(fields, est, "structure_false"))
            found = _share(_col(fields, est, "structure_missed") == 0)
            out.append((f"{est}: false structures (0)", false, false == 0))
            out.append((f"{est}: fields with every structure found (≥ 0.9)", found, found >= 0.9))
    for key, label in (("ate_rmse_m", "unaligned"), ("ate_rmse_se3_m", "SE(3)-aligned")):
        r = paired_ratio(list(_col(rows, "graph", key)), list(_col(rows, "ekf", key)))
        if not r["n"]:
            continue
        out.append((f"graph/ekf ATE {label}: median ratio (≤ 0.5)", r["median"], r["median"] <= 0.5))
        if key == "ate_rmse_m":
            hi = r["median_ci95"][1] if r["median_ci95"] else float("nan")
            out.append(("graph/ekf ATE unaligned: upper 95 % CI of the median (< 0.6)", hi, hi < 0.6))
            ratios = np.array([v for v in r["values"] if v is not None])
            worse = float(np.mean(ratios > 1))  # counted, not 1 - share below 1 (rounding, ties)
            out.append(("graph/ekf ATE unaligned: share of missions graph worse (≤ 0.05)", worse, worse <= 0.05))
    for key in ("object_median_error_m", "pipe_median_error_m"):
        g, e = _col(rows, "graph", key), _col(rows, "ekf", key)
        med = float(np.nanmedian(g)) if np.isfinite(g).any() else float("nan")
        out.append((f"graph {key}: median over missions (≤ 0.02 m)", med, med <= 0.02))
        both = np.isfinite(g) & np.isfinite(e)
        share = float(np.mean(g[both] <= e[both])) if both.any() else float("nan")
        out.append((f"graph ≤ ekf on {key}: share of missions (≥ 0.9)", share, share >= 0.9))
    for est in ("graph", "ekf"):
        inband = _share(_col(rows, est, "nees_in_band"))
        out.append((f"{est}: missions with mean NEES in the 95 % band (≥ 0.9)", inband, inband >= 0.9))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("studies", nargs="+", type=Path)
    args = ap.parse_args()
    rows = _rows(args.studies)
    print(f"{len(rows)} finished missions in {', '.join(str(d) for d in args.studies)}")
    for name, value, holds in criteria(rows):
        print(f"{'holds' if holds else 'FAILS':5}  {value:8.3f}  {name}")


if __name__ == "__main__":
    main()
