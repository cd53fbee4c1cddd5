"""Benchmark of a whole mission with the odometry front-end (issue 23: ≥ 10× real time): runs the
``semslam`` command as a user does (``run`` or ``compare``, ``--frontends laser,odometry`` by
default) on the default tank mission, several times, and reports per run the wall time, the
real-time factor and the CPU time (user + system) of the main process and of its workers (the
front-end processes). The machine may be shared: the CPU times say what the run itself cost.

The workers' CPU time is read from the process tree every ``--poll`` seconds (the last reading of each
process before it exits; a worker loses at most one poll: the workers are children of
multiprocessing's fork server, so the main process's ``wait4`` does not count them). Two bounds for
a quiet machine follow from the CPU times: all of it spread over every core
(``x_real_time_all_cores``), and the busiest process alone (``x_real_time_busiest``: the pipeline
waits for each front-end's results in order, so it cannot run faster than its busiest worker).

    python experiments/odometry_bench.py [--runs 3] [--command run] [--frontends laser,odometry] [BAG]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import psutil


def _cpu(p: psutil.Process) -> float | None:
    try:
        t = p.cpu_times()
        return t.user + t.system
    except psutil.Error:
        return None


def one_run(argv: list[str], poll_s: float) -> dict:
    t0 = time.perf_counter()
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    main = psutil.Process(proc.pid)
    workers: dict[int, float] = {}
    main_cpu = 0.0
    while True:
        pid, status, _ = os.wait4(proc.pid, os.WNOHANG)
        if pid:
            break
        main_cpu = _cpu(main) or main_cpu
        try:
            children = main.children(recursive=True)
        except psutil.Error:
            children = []
        for c in children:
            cpu = _cpu(c)
            if cpu is not None:
                workers[c.pid] = cpu
        time.sleep(poll_s)
    wall = time.perf_counter() - t0
    proc.returncode = os.waitstatus_to_exitcode(status)
    if proc.returncode:
        sys.exit(f"{' '.join(argv)} failed ({proc.returncode}): {proc.stderr.read().decode()[-2000:]}")
    return {
        "wall_s": wall,
        "cpu_main_s": main_cpu,
        "cpu_workers_s": sum(workers.values()),
        "cpu_total_s": main_cpu + sum(workers.values()),
        "cpu_busiest_s": max([main_cpu, *workers.values()]),
        "cpu_per_process_s": sorted([round(v, 1) for v in workers.values()], reverse=True),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("bag", nargs="?", help="default: the demo's cached default tank mission")
    ap.add_argument("--command", default="run", choices=("run", "compare"))
    ap.add_argument("--frontends", default="laser,odometry")
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--poll", type=float, default=0.2)
    args = ap.parse_args()
    if args.bag is None:
        from semslam.demo import demo_mission

        args.bag = str(demo_mission())
    semslam = shutil.which("semslam", path=str(Path(sys.executable).parent)) or "semslam"
    rows = []
    for i in range(args.runs):
        out = Path(tempfile.mkdtemp(prefix="odometry_bench_")) / "out"
        argv = [semslam, args.command, args.bag, "--frontends", args.frontends, "--out", str(out)]
        load = os.getloadavg()[0]
        row = one_run(argv, args.poll)
        metrics = json.loads((out / "metrics.json").read_text())
        row["mission_s"] = metrics["mission"]["duration_s"]
        row["x_real_time"] = row["mission_s"] / row["wall_s"]
        row["x_real_time_all_cores"] = row["mission_s"] / (row["cpu_total_s"] / (os.cpu_count() or 1))
        row["x_real_time_busiest"] = row["mission_s"] / row["cpu_busiest_s"]
        row["load_before"] = load
        odometry = metrics.get("odometry") or (metrics.get("frontends") or {}).get("odometry")
        if odometry:
            row["odometry"] = odometry
        # each front-end's seconds as the pipeline saw them (wall time in its worker: grows with the load)
        row["frontend_wall_s"] = {
            k.removeprefix("frontend:"): round(v, 1)
            for k, v in metrics.get("timing_s", {}).items()
            if k.startswith("frontend:")
        }
        rows.append(row)
        shutil.rmtree(out.parent, ignore_errors=True)
        print(f"run {i + 1}: " + json.dumps(row), flush=True)
    for key in ("wall_s", "x_real_time", "cpu_main_s", "cpu_workers_s", "cpu_total_s"):
        print(f"median {key}: {statistics.median(r[key] for r in rows):.2f}")


if __name__ == "__main__":
    main()
