"""Benchmark: wall time of simulating the default sonar field mission (target ≤ 60 s with the bag).

    python experiments/bench_simulate_field.py [--runs 3] [--seed 0] [--bag out.bag] [--preview out.png]

Prints per-run times and their median, what was simulated (counts, swaths, points, raw cloud bytes
as float32 x, y, z), the time and size of the bag (written once, to a temporary directory unless
``--bag``), the structure meshes' bytes against the raw cloud, and the dead-reckoning drift
between neighbouring survey lines.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from collections import Counter
from pathlib import Path

from semslam.mission.bag import write_mission
from semslam.models.structures import STRUCTURES, structure_library
from semslam.sim.field_config import FieldSimConfig
from semslam.sim.field_mission import simulate_field


def _size(path: Path) -> int:
    return path.stat().st_size if path.is_file() else sum(p.stat().st_size for p in path.rglob("*") if p.is_file())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--bag", default=None, help="write the bag here (default: a temporary .bag, removed)")
    ap.add_argument("--preview", default=None, help="also render the preview PNG of the last run")
    args = ap.parse_args()
    times = []
    mission = None
    for i in range(args.runs):
        mission = None  # free the previous run first
        t0 = time.perf_counter()
        mission = simulate_field(FieldSimConfig(seed=args.seed))
        times.append(time.perf_counter() - t0)
        print(f"run {i + 1}: {times[-1]:.1f} s", flush=True)
    print(
        f"simulation: median {statistics.median(times):.1f} s over {args.runs} runs "
        f"(min {min(times):.1f}, max {max(times):.1f})"
    )

    ex = mission.metadata.extras
    gt = mission.metadata.ground_truth
    print("measurements:", dict(Counter(type(m).__name__ for m in mission)))
    print(
        f"mission: {ex['trajectory']['duration_s']:.0f} s ({ex['trajectory']['duration_s'] / 60:.1f} min), "
        f"{len(ex['trajectory']['lines'])} lines {ex['trajectory']['line_spacing_m']} m apart"
    )
    sonar = ex["sonar"]
    n_beams = ex["noise"]["sonar"]["n_beams"]
    print(
        f"sonar: {sonar['swaths']} swaths × {n_beams} beams, {sonar['points'] / 1e6:.2f} M points, "
        f"raw cloud {sonar['raw_cloud_bytes'] / 1e6:.1f} MB (float32 x, y, z)"
    )
    lib = structure_library()
    mesh_bytes = sum(12 * (len(lib[n].vertices) + len(lib[n].triangles)) for n in STRUCTURES)
    print(
        f"structure meshes: {mesh_bytes / 1e3:.0f} kB = {100 * mesh_bytes / sonar['raw_cloud_bytes']:.2f} % "
        f"of the raw cloud ({', '.join(f'{n} {len(lib[n].triangles)} triangles' for n in STRUCTURES)})"
    )
    print(
        f"structures seen {gt.seen_structures} of {len(gt.structures)}, pipelines seen {gt.seen_pipes} of {len(gt.pipes)}"
    )
    print(
        f"DVL invalid: {100 * ex['dvl_dropouts']['invalid_fraction']:.1f} % in {len(ex['dvl_dropouts']['intervals_s'])} bursts"
    )
    d = ex["navigation_drift"]
    print(
        f"dead reckoning: between-line drift median {100 * d['between_lines_median_m']:.1f} cm, "
        f"p95 {100 * d['between_lines_p95_m']:.1f} cm, max {100 * d['between_lines_max_m']:.1f} cm "
        f"(per pair: {', '.join(f'{100 * x:.0f}' for x in d['between_lines_max_per_pair_m'])} cm); "
        f"final error {d['final_m']:.2f} m"
    )

    with tempfile.TemporaryDirectory() as tmp:
        bag = Path(args.bag) if args.bag else Path(tmp) / "field.bag"
        t0 = time.perf_counter()
        write_mission(mission, bag, overwrite=True)
        dt = time.perf_counter() - t0
        print(
            f"bag: written in {dt:.1f} s, {_size(bag) / 1e6:.1f} MB ({bag if args.bag else 'temporary'}); "
            f"simulation + bag {statistics.median(times) + dt:.1f} s"
        )
    if args.preview:
        from semslam.sim.field_preview import render_field_preview

        render_field_preview(mission, args.preview)
        print("preview:", args.preview)


if __name__ == "__main__":
    main()
