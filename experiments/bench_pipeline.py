"""Benchmark of the whole default mission (issue 9: ≥ 10× real time): reading, the laser front-end
and all three estimators, as `semslam compare` runs them, without the report.

Runs alternate between the front-end worker counts given (``--workers 1,2``: the laser in one
process, or its scans shared by two replicas), so that a change of the machine's load falls on all
of them; reports, per worker count, the median wall time, the real-time factor and the median of
each stage (CPU-side sums: with the front-ends apart, the stages overlap and their sum exceeds the
wall time). The estimates are checked identical across runs (ATE of each estimator).

    python experiments/bench_pipeline.py [--runs 3] [--workers 1,2] [--json experiments/out/bench_pipeline.json]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from semslam.compare import DEFAULT_ESTIMATORS
from semslam.demo import demo_config, demo_mission
from semslam.estimators import create_estimator
from semslam.eval.outputs import build_metrics
from semslam.mission.bag import read_mission
from semslam.pipeline import run_pipeline
from semslam.registry import create_frontends


def one_run(mission, cfg, workers: int) -> dict:
    fes = create_frontends(["laser"], mission.metadata, cfg.frontends)
    ests = [create_estimator(n, mission.metadata, cfg) for n in DEFAULT_ESTIMATORS]
    t0 = time.perf_counter()
    res = run_pipeline(mission, ests, fes, view_estimator="graph", frontend_workers=workers)
    wall = time.perf_counter() - t0
    metrics = build_metrics(res, mission.metadata)
    return {
        "workers": workers,
        "wall_s": wall,
        "real_time_factor": res.duration_s / wall,
        "stages_s": {k: v for k, v in res.timing_s.items() if k != "wall"},
        "ate_m": {n: metrics["estimators"][n]["ate_rmse_m"] for n in DEFAULT_ESTIMATORS},
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--workers", default="1,2", help="front-end worker counts to compare, comma-separated")
    ap.add_argument("--json", default="experiments/out/bench_pipeline.json")
    args = ap.parse_args()
    cfg = demo_config()
    mission = read_mission(demo_mission(), cfg.reader)
    counts = [int(w) for w in args.workers.split(",")]
    runs = []
    for i in range(args.runs):
        for w in counts:
            r = one_run(mission, cfg, w)
            runs.append(r)
            print(
                f"run {i} workers {w}: wall {r['wall_s']:.1f} s ({r['real_time_factor']:.1f}× real time); ATE "
                + ", ".join(f"{n} {a:.4f}" for n, a in r["ate_m"].items()),
                flush=True,
            )
    ates = {json.dumps(r["ate_m"], sort_keys=True) for r in runs}
    summary = {}
    for w in counts:
        rs = [r for r in runs if r["workers"] == w]
        stages = sorted({k for r in rs for k in r["stages_s"]})
        summary[w] = {
            "wall_s_median": float(np.median([r["wall_s"] for r in rs])),
            "real_time_factor_median": float(np.median([r["real_time_factor"] for r in rs])),
            "stages_s_median": {k: float(np.median([r["stages_s"].get(k, 0.0) for r in rs])) for k in stages},
        }
        s = summary[w]
        print(
            f"workers {w}: median wall {s['wall_s_median']:.1f} s = {s['real_time_factor_median']:.1f}× real time; "
            "stages " + ", ".join(f"{k} {v:.1f}" for k, v in s["stages_s_median"].items())
        )
    print("estimates identical across runs:", len(ates) == 1)
    Path(args.json).parent.mkdir(parents=True, exist_ok=True)
    Path(args.json).write_text(json.dumps({"runs": runs, "summary": summary, "identical": len(ates) == 1}, indent=1))


if __name__ == "__main__":
    main()
