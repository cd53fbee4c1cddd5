"""Benchmark of the laser front-end: median time per ~100k-point scan, per stage.

Scans are ray-cast views of the synthetic mock-up (``frontends.laser.synthetic``), each processed
``--repeat`` times; reports the median wall time and the median CPU time of the process (on a
machine shared with other jobs the wall time includes waiting for a core; CPU time does not, but
counts both cores when a library runs two threads). Target (issue 6): ≤ 0.2 s per 100k-point scan.

    python experiments/bench_laser.py [--scans 5] [--repeat 5] [--config '{"preprocess": {"voxel_size": 0.02}}']
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from frontends.laser import LaserConfig, segment_scan  # noqa: E402
from frontends.laser.synthetic import default_scene, raycast, viewpoint  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scans", type=int, default=5)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--rays", type=int, default=100_000)
    ap.add_argument("--config", type=str, default="{}")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    cfg = LaserConfig.model_validate(json.loads(args.config))
    rng = np.random.default_rng(args.seed)
    scans = []
    for i in range(args.scans):
        T = viewpoint(rng.uniform(0, 360), rng.uniform(-0.3, 0.3, 2), rng.uniform(-10, 10), rng.uniform(-0.5, 0.3))
        scans.append(raycast(default_scene(), n_rays=args.rays, T_scene=T, seed=i).points)
    segment_scan(scans[0], cfg)  # warm-up (imports, open3d initialisation)
    wall, cpu, stages, voxels = [], [], {}, []
    for pts in scans:
        for _ in range(args.repeat):
            c0, w0 = time.process_time(), time.perf_counter()
            seg = segment_scan(pts, cfg)
            wall.append(time.perf_counter() - w0)
            cpu.append(time.process_time() - c0)
            for k, v in seg.timings.items():
                stages.setdefault(k, []).append(v)
        voxels.append(len(seg.pre.points))
    load = os.getloadavg()[0]
    out = {
        "points_per_scan": int(np.median([len(p) for p in scans])),
        "voxels_per_scan": int(np.median(voxels)),
        "voxel_size": cfg.preprocess.voxel_size,
        "runs": len(wall),
        "wall_median_s": round(float(np.median(wall)), 4),
        "cpu_median_s": round(float(np.median(cpu)), 4),
        "stage_wall_median_s": {k: round(float(np.median(v)), 4) for k, v in stages.items()},
        "load_average_1min": round(load, 2),
        "cores": os.cpu_count(),
    }
    print(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
