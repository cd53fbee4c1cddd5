"""Short pipe segments between two fittings on the tank (issue 22, tank world 72's 0.124 m pipe):
per recorded tank mission, every ``--every``-th scan segmented with this checkout's front-end ("up"
from the true pose, the demo's radius prior), and the segments shorter than ``min_partial_length``
whose both ends stop at a fitting's bump (``Pipe.between_fittings``) placed with the true pose
against the true pipes: on a pipe (both ends within 2 cm of its axis and within 3 cm of its extent)
or not (an end 2 cm or more off every pipe's axis: a fitting's middle found as a pipe). Prints, per
seed and per length bin, how many of each; ``--long`` also tallies the segments reported by length.

    python experiments/laser/between_fittings_eval.py --bags DIR --seeds 60,62,72,77 [--every 4]

``DIR`` holds ``tank-seed<N>.bag`` as ``experiments/estimators/replay_study.py record`` writes them.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

BINS = (0.07, 0.09, 0.1008, 0.12, 0.15)  # 0.1008: between_fittings_radii (3.2) × 31.5 mm


def off_truth(P: np.ndarray, Q: np.ndarray, truth) -> tuple[float, float, int]:
    """(largest distance of P, Q from the axis, largest overrun beyond the extent, pipe id) of the true
    pipe that fits the segment P-Q best."""
    best = (np.inf, np.inf, -1)
    for g in truth:
        p, q = np.array(g.p), np.array(g.q)
        L = float(np.linalg.norm(q - p))
        u = (q - p) / L
        lat = over = 0.0
        for X in (P, Q):
            t = float((X - p) @ u)
            lat = max(lat, float(np.linalg.norm(X - p - t * u)))
            over = max(over, -t, t - L)
        if max(lat, over) < max(best[0], best[1]):
            best = (lat, over, g.id)
    return best


def _arguments(argv) -> argparse.Namespace:
    from semslam.study.plan import parse_seeds

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bags", type=Path, required=True)
    ap.add_argument("--seeds", type=parse_seeds, required=True)
    ap.add_argument("--every", type=int, default=4)
    ap.add_argument("--long", action="store_true", help="also tally the segments reported by their length")
    return ap.parse_args(argv)


def main(argv=None) -> int:
    args = _arguments(argv)
    from frontends.laser import LaserConfig, segment_scan
    from semslam.demo import demo_config
    from semslam.mission.bag import read_mission
    from semslam.mission.measurements import GroundTruthPose, PointCloud

    config = demo_config()
    cfg = LaserConfig.model_validate(config.frontends["laser"])
    for seed in args.seeds:
        bag = args.bags / f"tank-seed{seed}.bag"
        if not bag.exists():
            print(f"{bag}: no such bag", file=sys.stderr)
            return 2
        mission = read_mission(bag, config.reader)
        truth = mission.metadata.ground_truth.pipes
        T_BS = mission.metadata.sensors["laser"].T_BS
        poses = {m.stamp: m for m in mission.of_type(GroundTruthPose)}
        stamps = np.array(sorted(poses))
        tally = {}  # (kind, length bin) -> [on a pipe, overrunning it, off every pipe]
        pipes_seen: set[int] = set()
        scans = 0
        for k, scan in enumerate(mission.of_type(PointCloud)):
            if k % args.every:
                continue
            scans += 1
            T_WS = poses[stamps[np.argmin(np.abs(stamps - scan.stamp))]].matrix() @ T_BS
            seg = segment_scan(scan.points, cfg, T_WS[:3, :3].T @ np.array([0.0, 0.0, -1.0]))
            for pipe in seg.pipes:
                if pipe.length >= cfg.pipes.min_partial_length:
                    if not args.long:
                        continue
                    kind, b = "long", "-"
                elif pipe.between_fittings:
                    kind = "between fittings"
                    b = next((f"<{x:.3f}" for x in BINS if pipe.length < x), "-")
                else:
                    continue
                P = T_WS[:3, :3] @ pipe.p + T_WS[:3, 3]
                Q = T_WS[:3, :3] @ pipe.q + T_WS[:3, 3]
                lat, over, pid = off_truth(P, Q, truth)
                row = tally.setdefault((kind, b), [0, 0, 0])
                row[0 if lat < 0.02 and over < 0.03 else 1 if lat < 0.02 else 2] += 1
                if kind != "long" and lat < 0.02 and pipe.reported(seg.pipe_config):
                    pipes_seen.add(pid)
        print(f"seed {seed}: {scans} scans")
        for (kind, b), (on, overrun, off) in sorted(tally.items()):
            print(
                f"  {kind:17s} length {b:7s} on a pipe {on:4d}  overrunning it >= 3 cm {overrun:4d}  off >= 2 cm {off:4d}"
            )
        print(f"  true pipes given a short between-fittings view now reported: {sorted(pipes_seen)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
