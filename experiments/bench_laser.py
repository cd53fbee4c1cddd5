"""Benchmark of the laser front-end: median time per ~100k-point scan, per stage.

Scans are those of the simulated tank mission (``--source tank``, every ``--every``-th, the known
pipe radius as prior) or ray-cast views of the synthetic mock-up (``--source synthetic``), each
processed ``--repeat`` times; reports the median wall time and the median CPU time of the process (on a
machine shared with other jobs the wall time includes waiting for a core; CPU time does not, but
counts both cores when a library runs two threads). Target (issue 6): ≤ 0.2 s per 100k-point scan.
With ``--process``, also ``LaserFrontend.process`` (the geometry and the recognition of every object
of the scan, what a mission pays per scan; issue 9 aims at ≤ 0.12 s).

    python experiments/bench_laser.py [--source tank] [--scans 8] [--repeat 3] [--process] [--config '{...}']
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


def _bench_process(scans, overrides: dict, repeat: int) -> dict:
    """Median wall and CPU time of ``LaserFrontend.process`` per scan, and of its recognition."""
    from frontends.laser import LaserFrontend
    from semslam.mission.measurements import PointCloud

    fe = LaserFrontend(None, overrides)
    clouds = [PointCloud(stamp=k, sensor="laser", points=p) for k, p in enumerate(scans)]
    fe.process(clouds[0])  # warm-up: builds (or loads) the recogniser's view database
    wall, cpu, n_objects = [], [], []
    for pc in clouds:
        for _ in range(repeat):
            c0, w0 = time.process_time(), time.perf_counter()
            obs = fe.process(pc)
            wall.append(time.perf_counter() - w0)
            cpu.append(time.process_time() - c0)
        n_objects.append(sum(1 for o in obs if getattr(o, "class_likelihood", None) is not None))
    return {
        "wall_median_s": round(float(np.median(wall)), 4),
        "cpu_median_s": round(float(np.median(cpu)), 4),
        "recognised_objects_per_scan": float(np.median(n_objects)),
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scans", type=int, default=8)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--rays", type=int, default=100_000)
    ap.add_argument("--config", type=str, default="{}")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--source", choices=("tank", "synthetic"), default="tank")
    ap.add_argument("--every", type=int, default=25, help="tank: every n-th scan")
    ap.add_argument("--process", action="store_true", help="also time LaserFrontend.process (with recognition)")
    args = ap.parse_args(argv)
    overrides = json.loads(args.config)
    scans = []
    if args.source == "tank":
        from semslam.mission.measurements import PointCloud
        from semslam.sim import TankSimConfig, simulate_tank

        sim = TankSimConfig(seed=args.seed)
        overrides.setdefault("pipes", {}).setdefault("radius_prior", sim.structure.pipe_radius_m)
        clouds = list(simulate_tank(sim).of_type(PointCloud))
        scans = [c.points for c in clouds[args.every // 2 :: args.every]][: args.scans]
    else:
        rng = np.random.default_rng(args.seed)
        for i in range(args.scans):
            T = viewpoint(rng.uniform(0, 360), rng.uniform(-0.3, 0.3, 2), rng.uniform(-10, 10), rng.uniform(-0.5, 0.3))
            scans.append(raycast(default_scene(), n_rays=args.rays, T_scene=T, seed=i).points)
    cfg = LaserConfig.model_validate(overrides)
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
    if args.process:
        out_process = _bench_process(scans, overrides, args.repeat)
    load = os.getloadavg()[0]
    out = {
        "source": args.source,
        "points_per_scan": int(np.median([len(p) for p in scans])),
        "voxels_per_scan": int(np.median(voxels)),
        "voxel_size": cfg.preprocess.voxel_size,
        "runs": len(wall),
        "wall_median_s": round(float(np.median(wall)), 4),
        "cpu_median_s": round(float(np.median(cpu)), 4),
        "stage_median_s": {k: round(float(np.median(v)), 4) for k, v in stages.items()},  # wall; cpu_*: CPU
        "load_average_1min": round(load, 2),
        "cores": os.cpu_count(),
    }
    if args.process:
        out["process"] = out_process
    print(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
