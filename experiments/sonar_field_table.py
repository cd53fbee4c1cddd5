"""The structures of a sonar-field study (`semslam study --scenario field --keep-bags`), judged again
against the truth *relative to the estimated trajectory* (semslam.eval.structures), as a table.

The study's metrics.json judge a structure in the final map against the truth (absolute: the
navigation error where it was seen is part of it). Each registration there keeps its ``pose`` and
its ``support`` (the patches it was registered on, with their anchors' poses as the final estimate
placed them); with the true trajectory from the mission's kept bag, this script reads each
registration from the estimated trajectory where it was seen and judges it within the relative
tolerance, and reports both. Per seed: found / wrong place / missed / false (relative; absolute in
brackets), graph and dead-reckoning ATE, per structure position and yaw error (absolute and
relative), pipes mapped by the graph (of those seen) and by the front-end's final map.

    python experiments/sonar_field_table.py STUDY_DIR [--out STUDY_DIR/structures.md]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from semslam.eval.structures import pose_at, registrations_of, structure_counts, structure_rows
from semslam.mission.bag_reader import read_mission
from semslam.mission.measurements import GroundTruthPose
from semslam.results import PoseLog


def truth_of(bag: Path):
    """(ground-truth map, true trajectory) of a kept mission bag."""
    mission = read_mission(bag)
    gt_sensors = [n for n, s in mission.metadata.sensors.items() if s.kind == "ground_truth"]
    log = PoseLog()
    for m in mission.only(gt_sensors) if gt_sensors else mission:
        if isinstance(m, GroundTruthPose):
            log.append(m.stamp, m.position, m.orientation)
    return mission.metadata.ground_truth, log.trajectory()


def judge_mission(mission_dir: Path) -> dict:
    """The mission's structures judged relative (with its bag) and absolute, and its numbers."""
    metrics = json.loads((mission_dir / "metrics.json").read_text())
    sonar = metrics.get("sonar") or {}
    registered = registrations_of(sonar.get("structures") or [])
    bag = mission_dir / "mission.bag"
    truth_map, truth_traj = truth_of(bag)
    relative = structure_rows(registered, truth_map, pose_at(truth_traj))
    absolute = structure_rows(registered, truth_map)
    est = metrics.get("estimators") or {}
    graph, dr = est.get("graph") or {}, est.get("dr") or {}
    return {
        "mission": mission_dir.name,
        "relative": relative,
        "relative_counts": structure_counts(relative),
        "absolute_counts": structure_counts(absolute),
        "unconfirmed": [
            {k: s.get(k) for k in ("model", "fitness", "median_error_m")}
            for s in sonar.get("unconfirmed_structures", [])
        ],
        "ate_graph_m": graph.get("ate_rmse_m"),
        "ate_dr_m": dr.get("ate_rmse_m"),
        "graph_structures": graph.get("n_structures"),
        "pipes_seen": graph.get("pipe_seen"),
        "pipes_missed_graph": graph.get("pipe_missed"),
        "pipes_graph": graph.get("n_pipes"),
        "pipes_frontend": len(sonar.get("pipes") or []),
    }


def _f(x, fmt="{:.2f}"):
    return "–" if x is None else fmt.format(x)


def describe(row: dict) -> str:
    """Per structure: model (status): absolute position m / yaw °, relative position m / yaw °."""
    out = []
    for s in row["relative"]:
        status = (
            ""
            if s["found"]
            else " MISS"
            if s["truth_id"] is not None
            else " WRONG"
            if s.get("wrong_place")
            else " FALSE"
        )
        errs = ""
        if s.get("position_error_m") is not None:
            errs = (
                f" {_f(s['position_error_m'])}m/{_f(s['yaw_error_deg'], '{:.1f}')}°"
                f" (rel {_f(s['relative_position_error_m'])}m/{_f(s['relative_yaw_error_deg'], '{:.1f}')}°)"
            )
        out.append(f"{s['model']}{status}{errs}")
    return ", ".join(out)


def table(rows: list[dict]) -> str:
    lines = [
        "| mission | found | wrong place | missed | false | graph ATE | dr ATE | pipes graph (seen) / front-end "
        "| structures: model abs. position / yaw (relative) |",
        "|---|---:|---:|---:|---:|---:|---:|---|---|",
    ]
    for r in rows:
        c, a = r["relative_counts"], r["absolute_counts"]
        wrong = c["structures_wrong_place"]
        pipes_graph = (
            "–"
            if r["pipes_seen"] is None
            else f"{r['pipes_seen'] - (r['pipes_missed_graph'] or 0)} ({r['pipes_seen']})"
        )
        lines.append(
            f"| {r['mission']} | {c['structures_found']}/{c['structures_seen']} [{a['structures_found']}] "
            f"| {wrong} [{a['structures_wrong_place']}] | {c['structures_missed']} [{a['structures_missed']}] "
            f"| {c['structures_false'] - wrong} [{a['structures_false'] - a['structures_wrong_place']}] "
            f"| {_f(r['ate_graph_m'])} | {_f(r['ate_dr_m'])} | {pipes_graph} / {r['pipes_frontend']} | {describe(r)} |"
        )
    return "\n".join(lines)


def overall(rows: list[dict]) -> dict:
    """The issue's acceptance over the fields: no false structure; each true structure (by model)
    found in ≥ 90 % of the fields where it was seen."""
    by_model: dict[str, list[bool]] = {}
    for r in rows:
        for s in r["relative"]:
            if s["truth_id"] is not None:
                by_model.setdefault(s["model"], []).append(bool(s["found"]))
    found = [s for r in rows for s in r["relative"] if s["found"]]
    return {
        "missions": len(rows),
        "false_structures_relative": sum(r["relative_counts"]["structures_false"] for r in rows),
        "false_structures_absolute": sum(r["absolute_counts"]["structures_false"] for r in rows),
        "found_share_by_model": {m: float(np.mean(v)) for m, v in by_model.items()},
        "relative_position_error_m_max": max((s["relative_position_error_m"] for s in found), default=None),
        "relative_yaw_error_deg_max": max((s["relative_yaw_error_deg"] for s in found), default=None),
        "position_error_m_max": max((s["position_error_m"] for s in found), default=None),
    }


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("study", type=Path)
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args(argv)
    dirs = sorted(p for p in args.study.iterdir() if (p / "metrics.json").is_file() and (p / "mission.bag").exists())
    rows = [judge_mission(d) for d in dirs]
    md = table(rows) + "\n\n" + json.dumps(overall(rows), indent=1) + "\n"
    out = args.out or args.study / "structures.md"
    out.write_text(md)
    (out.with_suffix(".json")).write_text(json.dumps(rows, indent=1, default=float))
    print(md)


if __name__ == "__main__":
    main()
