"""Benchmark: wall time of simulating the default tank mission (target ≤ 60 s, median of runs).

    python experiments/bench_simulate.py [--runs 3] [--seed 0] [--preview out.png]

Prints per-run times, the median, and what was simulated (counts, points per scan, DVL dropouts).
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections import Counter

import numpy as np

from semslam.mission import PointCloud
from semslam.sim.config import TankSimConfig
from semslam.sim.simulate import simulate_tank


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--preview", default=None, help="also render the preview PNG of the last run")
    args = ap.parse_args()
    times = []
    mission = None
    for i in range(args.runs):
        mission = None  # free the previous run's ~300 MB of points first
        t0 = time.perf_counter()
        mission = simulate_tank(TankSimConfig(seed=args.seed))
        times.append(time.perf_counter() - t0)
        print(f"run {i + 1}: {times[-1]:.1f} s", flush=True)
    print(f"median {statistics.median(times):.1f} s over {args.runs} runs (min {min(times):.1f}, max {max(times):.1f})")
    counts = Counter(type(m).__name__ for m in mission)
    pts = np.array([len(m.points) for m in mission.of_type(PointCloud)])
    gt = mission.metadata.ground_truth
    ex = mission.metadata.extras
    print("measurements:", dict(counts))
    print(
        f"points per scan: median {np.median(pts):.0f}, min {pts.min()}, max {pts.max()}, total {pts.sum() / 1e6:.1f} M"
    )
    print(f"objects {len(gt.objects)} (seen {len(gt.seen_objects)}), pipes {len(gt.pipes)} (seen {len(gt.seen_pipes)})")
    print(
        f"DVL invalid: {100 * ex['dvl_dropouts']['invalid_fraction']:.1f} % in {len(ex['dvl_dropouts']['intervals_s'])} bursts"
    )
    if args.preview:
        from semslam.sim.preview import render_preview

        render_preview(mission, args.preview)
        print("preview:", args.preview)


if __name__ == "__main__":
    main()
