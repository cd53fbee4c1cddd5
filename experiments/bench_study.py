"""Benchmark: `semslam study` on a LocalCluster against the same missions run one after the other.

    python experiments/bench_study.py [--seeds 0-19] [--workers N] [--sim-config F] [--out DIR]

Serial: for each seed, ``semslam simulate tank --seed N`` then ``semslam compare`` (two commands,
as a user would run them; timed together). Study: ``semslam study --scenario tank --seeds ...`` on
a LocalCluster (the study's default: one worker per two cores), which simulates and compares the same missions
(the same numbers: tests/test_study.py). Printed and written to ``DIR/bench_study.json``:

- wall times, serial and study, and the speed-up (serial / study; at best about the worker count);
- the study's overhead per mission, in worker-seconds: (workers × study wall − serial total) / missions,
  i.e. what the study costs beyond the missions' own work (cluster start, tasks, the child process
  per mission, idle workers at the end);
- from ``study.json``: per mission, the task's wall time against the child's compute time (the
  difference: starting the process and importing semslam).

Default: 20 default-length tank missions (``--vary all``). ``--sim-config`` (e.g. short missions)
and ``--seeds`` make a small version.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

from semslam.study.plan import parse_seeds

SEMSLAM = [sys.executable, "-m", "semslam.cli"]


def run(cmd: list[str]) -> float:
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="0-19")
    ap.add_argument("--workers", type=int, help="LocalCluster workers (default: the study's)")
    ap.add_argument("--sim-config", help="YAML over the simulator's defaults (e.g. short missions)")
    ap.add_argument("--frontends", help="front-ends for both runs (default: by sensor kind)")
    ap.add_argument("--out", type=Path, default=Path("experiments/out/bench_study"))
    args = ap.parse_args()
    seeds = parse_seeds(args.seeds)
    shutil.rmtree(args.out, ignore_errors=True)
    serial_dir, study_dir = args.out / "serial", args.out / "study"
    serial_dir.mkdir(parents=True)
    sim = ["--sim-config", args.sim_config] if args.sim_config else []
    fe = ["--frontends", args.frontends] if args.frontends else []

    serial = {}
    for seed in seeds:
        bag = serial_dir / f"tank-seed{seed}.bag"
        t = run([*SEMSLAM, "simulate", "tank", "--seed", str(seed), *sim, "--out", str(bag)])
        t += run([*SEMSLAM, "compare", str(bag), *fe, "--out", str(serial_dir / f"tank-seed{seed}")])
        for f in serial_dir.glob(bag.name + "*"):
            shutil.rmtree(f) if f.is_dir() else f.unlink()
        serial[seed] = t
        print(f"serial seed {seed}: {t:.1f} s", flush=True)
    serial_total = sum(serial.values())

    workers = ["--workers", str(args.workers)] if args.workers else []
    cmd = [*SEMSLAM, "study", "--scenario", "tank", "--seeds", args.seeds, *workers, *sim, *fe]
    study_wall = run([*cmd, "--out", str(study_dir)])
    study = json.loads((study_dir / "study.json").read_text())
    n_workers = study["study"]["workers"]
    missions = [m for m in study["missions"] if m["status"] == "ok"]
    task_overhead = [m["wall_s"] - m["compute_s"] for m in missions]
    out = {
        "missions": len(seeds),
        "workers": n_workers,
        "cores": os.cpu_count(),
        "sim_config": args.sim_config,
        "serial_s": serial,
        "serial_total_s": serial_total,
        "study_wall_s": study_wall,
        "speedup": serial_total / study_wall,
        "overhead_worker_s_per_mission": (n_workers * study_wall - serial_total) / len(seeds),
        "task_overhead_s_median": statistics.median(task_overhead) if task_overhead else None,
        "study_ok": len(missions),
    }
    (args.out / "bench_study.json").write_text(json.dumps(out, indent=1))
    print(
        f"{len(seeds)} missions: serial {serial_total:.0f} s, study {study_wall:.0f} s on {n_workers} workers "
        f"({os.cpu_count()} cores): speed-up {out['speedup']:.2f}; overhead "
        f"{out['overhead_worker_s_per_mission']:.1f} worker-s per mission (task: process start and imports, median "
        f"{out['task_overhead_s_median']:.1f} s); {len(missions)}/{len(seeds)} missions finished"
    )


if __name__ == "__main__":
    main()
