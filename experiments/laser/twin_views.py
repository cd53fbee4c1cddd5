"""False object observations of recorded laser runs (``replay_study.py record``), placed in the world
with the true poses and classified by how the front-end made them.

    python experiments/laser/twin_views.py --cache DIR --seeds 3,4 [--gate 0.15] [--rerun]

For each seed: DIR/tank-seed<N>.bag (ground truth, true poses) and DIR/tank-seed<N>.obs.pkl (the
recorded observations). An object observation is false when no true object lies within ``--gate``
of it; per seed it prints true / false counts by connectivity configuration (1 lone end, 2 in line,
3-4 junction) and, for the false ones, how far they lie from the nearest true pipe axis. With
``--rerun``, the scans of false in-line observations are segmented again by this checkout's front-end
(objects only counted, against the same truth), to see whether the false ones are gone.
"""

from __future__ import annotations

import argparse
import pickle
from collections import Counter
from pathlib import Path

import numpy as np
from tank_truth import segment_distance


def main(argv=None) -> int:
    from semslam.mission.bag import read_mission
    from semslam.mission.measurements import GroundTruthPose, PointCloud

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cache", type=Path, required=True)
    ap.add_argument("--seeds", type=str, required=True)
    ap.add_argument("--gate", type=float, default=0.15)
    ap.add_argument("--rerun", action="store_true")
    ap.add_argument("--max-rerun", type=int, default=20)
    args = ap.parse_args(argv)
    for seed in [int(s) for s in args.seeds.split(",")]:
        bag = args.cache / f"tank-seed{seed}.bag"
        payload = pickle.loads((args.cache / f"tank-seed{seed}.obs.pkl").read_bytes())
        mission = read_mission(bag)
        gt = mission.metadata.ground_truth
        sensor = next(s for s in mission.metadata.sensors.values() if s.kind == "laser")
        objs = np.array([o.position for o in gt.objects])
        pipes = [(np.array(p.p), np.array(p.q)) for p in gt.pipes]
        poses = {m.stamp: m for m in mission.of_type(GroundTruthPose)}
        stamps = np.array(sorted(poses))

        def T_WS(stamp, poses=poses, stamps=stamps, T_BS=sensor.T_BS):
            return poses[int(stamps[np.argmin(np.abs(stamps - stamp))])].matrix() @ T_BS

        counts: Counter = Counter()
        false_inline: list[int] = []
        for stamp, obs in sorted(payload["observations"]["laser"].items()):
            T = T_WS(stamp)
            for o in obs:
                if type(o).__name__ != "PointObservation":
                    continue
                x = T[:3, :3] @ o.position + T[:3, 3]
                d_obj = float(np.min(np.linalg.norm(objs - x, axis=1)))
                conf = o.connectivity.configuration if o.connectivity else 0
                ok = d_obj <= args.gate
                counts[(conf, ok)] += 1
                if not ok:
                    d_pipe = min(segment_distance(x, p, q) for p, q in pipes)
                    counts[(conf, "on pipe" if d_pipe < 0.05 else "off pipe")] += 1
                    if conf == 2:
                        false_inline.append(stamp)
        print(
            f"seed {seed}: "
            + ", ".join(
                f"config {c} {'true' if k is True else 'false' if k is False else k}: {n}"
                for (c, k), n in sorted(counts.items(), key=str)
            )
        )
        if args.rerun and false_inline:
            from frontends.laser.config import LaserConfig
            from frontends.laser.frontend import segment_scan
            from semslam.sim import TankSimConfig

            cfg = LaserConfig.model_validate({"pipes": {"radius_prior": TankSimConfig().structure.pipe_radius_m}})
            want = set(sorted(set(false_inline))[: args.max_rerun])
            again: Counter = Counter()
            for c in mission.of_type(PointCloud):
                if c.stamp not in want:
                    continue
                T = T_WS(c.stamp)
                seg = segment_scan(c.points, cfg, up=T[:3, :3].T @ np.array([0.0, 0.0, -1.0]))
                for ob in seg.objects:
                    x = T[:3, :3] @ ob.position + T[:3, 3]
                    ok = float(np.min(np.linalg.norm(objs - x, axis=1))) <= args.gate
                    again[(ob.configuration, ok)] += 1
            print(f"  rerun of {len(want)} scans with false in-line views: {dict(again)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
