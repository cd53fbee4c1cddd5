"""Benchmark of the whole `semslam compare` of the default mission (issue 27: ≥ 30× real time on 2 cores,
the pipeline alone ≥ 50×): reading, the laser front-end and all three estimators, the metrics, the
output files and the report, each timed as a stage.

Each run does what ``semslam compare MISSION --out DIR`` does after its imports: read the mission, run
the pipeline (``run_comparison``), build metrics.json, write the results and the report (and with
``--record`` the replay, as the demo does: its recorder's per-step cost is timed apart). Runs
alternate between the front-end worker counts given (``--workers 1,2``), so that a change of the
machine's load falls on all of them; per worker count it reports the median of the whole compare's
wall time and real-time factor, of the pipeline's, and of each stage (wall, and the main process's CPU:
the machine's load, given per run, inflates the wall times). The pipeline's own stages
("read", "frontend:<name>", "estimator:<name>") are CPU-side sums: with the front-ends apart they
overlap, and their sum exceeds the pipeline's wall time. The estimates are checked identical across
runs (ATE of each estimator).

    python experiments/bench_pipeline.py [--runs 3] [--workers 2] [--record] [--json experiments/out/bench_pipeline.json]
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from semslam.compare import DEFAULT_ESTIMATORS, run_comparison
from semslam.demo import demo_config, demo_mission
from semslam.eval.outputs import staged_output, write_results
from semslam.eval.report import write_report
from semslam.mission.bag import read_mission
from semslam.pipeline import observed_by


class TimedObserver:
    """Passes every step on to ``inner`` (the replay recorder) and adds up the time it takes."""

    def __init__(self, inner):
        self.inner = inner
        self.seconds = 0.0

    def step(self, *args) -> None:
        t0 = time.perf_counter()
        self.inner.step(*args)
        self.seconds += time.perf_counter() - t0


class Stages:
    """Wall and CPU seconds (this process's: the front-end workers' CPU is not in it) of each stage."""

    def __init__(self):
        self.wall: dict[str, float] = {}
        self.cpu: dict[str, float] = {}

    @contextmanager
    def time(self, name: str):
        t0, c0 = time.perf_counter(), time.process_time()
        yield
        self.wall[name] = time.perf_counter() - t0
        self.cpu[name] = time.process_time() - c0


def one_run(bag: Path, cfg, workers: int, record: bool) -> dict:
    from semslam.eval.replay import LAYOUT_FILE, LAYOUT_PATH, REPLAY_FILE, make_recorder

    st = Stages()
    load_before = os.getloadavg()[0]
    t_start = time.perf_counter()
    with st.time("open mission"):
        mission = read_mission(bag, cfg.reader)
    recorder = TimedObserver(make_recorder(True, mission.metadata, None)) if record else None
    with st.time("pipeline + metrics"), observed_by(*([recorder] if recorder else [])):
        result, metrics = run_comparison(mission, cfg, frontend_workers=workers)
    # run_comparison's metrics, timed again on their own (the same call: build_metrics)
    from semslam.eval.outputs import build_metrics

    with st.time("metrics"):
        build_metrics(result, mission.metadata)
    for d in (st.wall, st.cpu):
        d["pipeline"] = d.pop("pipeline + metrics") - d["metrics"]
    if recorder is not None:
        st.wall["replay recorder (in the pipeline)"] = recorder.seconds
    with tempfile.TemporaryDirectory(prefix="bench_pipeline_") as tmp:
        with staged_output(Path(tmp) / "out") as stage:
            with st.time("outputs"):
                write_results(stage, cfg, result, metrics)
            if recorder is not None:
                import shutil

                with st.time("replay write"):
                    recorder.inner.write(stage / REPLAY_FILE, result)
                    shutil.copyfile(LAYOUT_PATH, stage / LAYOUT_FILE)
            with st.time("report"):
                write_report(stage, result, mission.metadata, metrics, replay=recorder is not None)
    # the whole compare: the metrics counted once (run_comparison built them; the second call only timed them)
    wall = time.perf_counter() - t_start - st.wall["metrics"]
    stages = dict(st.wall)
    for k, v in result.timing_s.items():
        if k != "wall":
            stages[f"pipeline {k}"] = v
    return {
        "workers": workers,
        "wall_s": wall,
        "real_time_factor": result.duration_s / wall,
        "pipeline_wall_s": st.wall["pipeline"],
        "pipeline_real_time_factor": result.duration_s / st.wall["pipeline"],
        "stages_s": stages,
        "stages_cpu_s": st.cpu,
        "load_average": [load_before, os.getloadavg()[0]],  # 1-minute, at the start and the end of the run
        "ate_m": {n: metrics["estimators"][n]["ate_rmse_m"] for n in DEFAULT_ESTIMATORS},
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--workers", default="2", help="front-end worker counts to compare, comma-separated")
    ap.add_argument("--record", action="store_true", help="record the replay too, as the demo does")
    ap.add_argument("--json", default="experiments/out/bench_pipeline.json")
    args = ap.parse_args()
    cfg = demo_config()
    bag = demo_mission()
    read_mission(bag, cfg.reader)  # a first read warms the file cache for every run alike
    counts = [int(w) for w in args.workers.split(",")]
    runs = []
    for i in range(args.runs):
        for w in counts:
            r = one_run(bag, cfg, w, args.record)
            runs.append(r)
            print(
                f"run {i} workers {w}: compare {r['wall_s']:.1f} s ({r['real_time_factor']:.1f}× real time), "
                f"pipeline {r['pipeline_wall_s']:.1f} s ({r['pipeline_real_time_factor']:.1f}×); ATE "
                + ", ".join(f"{n} {a:.4f}" for n, a in r["ate_m"].items()),
                flush=True,
            )
    ates = {json.dumps(r["ate_m"], sort_keys=True) for r in runs}
    summary = {}
    for w in counts:
        rs = [r for r in runs if r["workers"] == w]
        stages = list(dict.fromkeys(k for r in rs for k in r["stages_s"]))

        def med(key, rs=rs):
            return float(np.median([r[key] for r in rs]))

        summary[w] = {
            "wall_s_median": med("wall_s"),
            "real_time_factor_median": med("real_time_factor"),
            "pipeline_wall_s_median": med("pipeline_wall_s"),
            "pipeline_real_time_factor_median": med("pipeline_real_time_factor"),
            "stages_s_median": {k: float(np.median([r["stages_s"].get(k, 0.0) for r in rs])) for k in stages},
            "stages_cpu_s_median": {
                k: float(np.median([r["stages_cpu_s"][k] for r in rs])) for k in rs[0]["stages_cpu_s"]
            },
            "load_average": [r["load_average"] for r in rs],
        }
        s = summary[w]
        print(
            f"workers {w}, median of {len(rs)}: compare {s['wall_s_median']:.1f} s = "
            f"{s['real_time_factor_median']:.1f}× real time; pipeline {s['pipeline_wall_s_median']:.1f} s = "
            f"{s['pipeline_real_time_factor_median']:.1f}×"
        )
        cpu = s["stages_cpu_s_median"]
        print(f"  {'stage':40s} {'wall':>9s} {'CPU (main)':>11s}")
        for k, v in s["stages_s_median"].items():
            print(f"  {k:40s} {v:7.2f} s" + (f" {cpu[k]:9.2f} s" if k in cpu else ""))
        print("  load average (1 min) at the start and end of each run:", s["load_average"])
    print("estimates identical across runs:", len(ates) == 1)
    Path(args.json).parent.mkdir(parents=True, exist_ok=True)
    Path(args.json).write_text(json.dumps({"runs": runs, "summary": summary, "identical": len(ates) == 1}, indent=1))


if __name__ == "__main__":
    main()
