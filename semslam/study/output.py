"""``DIR/study.json``: the study's stable interface (its keys are listed in DESIGN.md).

Missions are listed in the study's order (seeds, or bags as given), whatever order they finished
in, so that the same study gives the same file on any cluster.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

from semslam.study.plan import MissionTask
from semslam.study.stats import study_statistics
from semslam.study.store import write_atomic

SCHEMA = 1
WORST = 5  # missions the report lists as the worst (largest graph ATE)


def mission_entry(task: MissionTask, result: dict | None, previous_failure: dict | None) -> dict:
    """One mission of ``study.json``'s ``missions`` list."""
    src = task.source
    source = {"bag": src["path"]} if src["kind"] == "bag" else {"scenario": src["scenario"], "seed": src["seed"]}
    entry = {"mission": task.mission, "source": source, "status": "not_run", "path": None, "report": None}
    entry |= {"wall_s": None, "compute_s": None, "reused": False, "error": None, "summary": None, "reproduce": None}
    if result is None:
        if previous_failure:
            entry["error"] = f"not run this time; last run: {previous_failure['status']}: {previous_failure['error']}"
        return entry
    entry["status"], entry["wall_s"] = result["status"], result.get("wall_s")
    if result["status"] == "ok":
        rec = result["record"]
        entry |= {
            "path": task.mission,
            "report": f"{task.mission}/{rec['report']}",
            "compute_s": rec.get("compute_s"),
            "reused": bool(result.get("reused")),
            "summary": rec["summary"],
            "reproduce": rec.get("reproduce"),
        }
    else:
        entry["error"] = result["failure"]["error"]
    return entry


def worst_missions(missions: Sequence[dict], n: int = WORST) -> list[dict]:
    """The ``n`` finished missions with the largest ATE of the graph (else of the first estimator
    that has one), largest first."""
    scored = []
    for m in missions:
        ests = (m["summary"] or {}).get("estimators", {})
        name = "graph" if (ests.get("graph") or {}).get("ate_rmse_m") is not None else None
        name = name or next((e for e, row in ests.items() if row.get("ate_rmse_m") is not None), None)
        if name is not None:
            scored.append((ests[name]["ate_rmse_m"], name, m))
    scored.sort(key=lambda s: -s[0])
    return [{"mission": m["mission"], "estimator": e, "ate_rmse_m": v, "report": m["report"]} for v, e, m in scored[:n]]


def build_study(
    tasks: Sequence[MissionTask],
    results: dict[str, dict],
    previous_failures: dict[str, dict],
    study: dict,
) -> dict:
    """The content of ``study.json``; ``study`` describes how the study was run."""
    missions = [mission_entry(t, results.get(t.mission), previous_failures.get(t.mission)) for t in tasks]
    stats = study_statistics([m["summary"] for m in missions])
    counts = {k: sum(m["status"] == k for m in missions) for k in ("ok", "failed", "timeout", "not_run")}
    failures = [
        {
            "mission": m["mission"],
            "status": m["status"],
            "error": m["error"],
            "log": results[m["mission"]]["failure"].get("log"),
        }
        for m in missions
        if m["status"] in ("failed", "timeout")
    ]
    return {
        "schema": SCHEMA,
        "study": study,
        "counts": {"planned": len(missions), **counts},
        "missions": missions,
        **stats,
        "worst": worst_missions(missions),
        "failures": failures,
    }


def write_json(path: Path, data: dict) -> None:
    write_atomic(path, json.dumps(data, indent=1))
