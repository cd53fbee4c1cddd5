"""Per-scan object detections of the laser front-end on recorded tank bags, against ground truth:
true (a true object within ``--gate``) and false object segments per connectivity configuration,
and the true objects detected, with this checkout's front-end and, with ``--ab``, also with the
in-line gap test off (the behaviour before it: every gap between two collinear pipe ends with enough
points is an object). Reported pipe segments are counted too: true when both ends lie within 5 cm of
one true pipe's axis, with the sum of their axes' angles from that pipe's (millidegrees);
``--no-axis-refit`` fits the segments' axes as before issue 22's geometric refit (the principal
direction of the inliers). ``--set section.key=value`` (repeatable) changes the front-end's configuration.

    python experiments/laser/inline_eval.py --cache DIR --seeds 3,9,10 [--every 10] [--ab] [--no-axis-refit] [--set K=V]

DIR/tank-seed<N>.bag: a bag of ``replay_study.py record`` (or ``semslam study``), read only.
"""

from __future__ import annotations

import argparse
from collections import Counter
from pathlib import Path

import numpy as np
from tank_truth import segment_distance


def _config(overrides: list[str]):
    from frontends.laser.config import LaserConfig
    from semslam.sim import TankSimConfig

    data: dict = {"pipes": {"radius_prior": TankSimConfig().structure.pipe_radius_m}}
    for item in overrides:
        key, value = item.split("=", 1)
        section, name = key.split(".")
        data.setdefault(section, {})[name] = float(value)
    return LaserConfig.model_validate(data)


def _count(mission, every: int, gate: float, overrides: list[str] = ()) -> Counter:
    from frontends.laser.frontend import segment_scan
    from semslam.mission.measurements import GroundTruthPose, PointCloud

    gt = mission.metadata.ground_truth
    sensor = next(s for s in mission.metadata.sensors.values() if s.kind == "laser")
    objs = np.array([o.position for o in gt.objects])
    poses = {m.stamp: m for m in mission.of_type(GroundTruthPose)}
    stamps = np.array(sorted(poses))
    true_pipes = [(np.array(p.p), np.array(p.q)) for p in gt.pipes]
    cfg = _config(list(overrides))
    n = Counter()
    for c in list(mission.of_type(PointCloud))[every // 2 :: every]:
        T = poses[int(stamps[np.argmin(np.abs(stamps - c.stamp))])].matrix() @ sensor.T_BS
        seg = segment_scan(c.points, cfg, up=T[:3, :3].T @ np.array([0.0, 0.0, -1.0]))
        n["scans"] += 1
        found = set()
        for ob in seg.objects:
            d = np.linalg.norm(objs - (T[:3, :3] @ ob.position + T[:3, 3]), axis=1)
            ok = bool(d.min() <= gate)
            n[f"{'true' if ok else 'false'} config {ob.configuration}"] += 1
            n["true" if ok else "false"] += 1
            if ok:
                found.add(int(d.argmin()))
        n["objects detected (per scan, summed)"] += len(found)
        for p in seg.pipes:
            if not p.reported(seg.pipe_config):
                continue
            ends = [T[:3, :3] @ e + T[:3, 3] for e in (p.p, p.q)]
            dist = [max(segment_distance(e, a, b) for e in ends) for a, b in true_pipes]
            ok = min(dist) <= 0.05
            n["pipes true" if ok else "pipes false"] += 1
            if ok:  # the axis' angle from its true pipe's, in millidegrees (a Counter holds the sum)
                a, b = true_pipes[int(np.argmin(dist))]
                u = (ends[1] - ends[0]) / np.linalg.norm(ends[1] - ends[0])
                cos = abs(u @ (b - a)) / np.linalg.norm(b - a)
                n["pipes true: angle sum (mdeg)"] += int(round(1000 * np.degrees(np.arccos(min(1.0, cos)))))
    return n


def main(argv=None) -> int:
    from frontends.laser import objects
    from semslam.mission.bag import read_mission

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cache", type=Path, required=True)
    ap.add_argument("--seeds", type=str, required=True)
    ap.add_argument("--every", type=int, default=10)
    ap.add_argument("--gate", type=float, default=0.15)
    ap.add_argument("--ab", action="store_true")
    ap.add_argument(
        "--no-axis-refit",
        action="store_true",
        help="segments' axes as before the geometric refit (principal direction)",
    )
    ap.add_argument("--set", action="append", default=[], help="section.key=value of the front-end's configuration")
    args = ap.parse_args(argv)
    test = objects.gap_is_pipe
    if args.no_axis_refit:
        from frontends.laser import pipes

        pipes.refine_cylinder = lambda pts, c, a, r, cfg: (c, a, r)
    for seed in [int(s) for s in args.seeds.split(",")]:
        mission = read_mission(args.cache / f"tank-seed{seed}.bag")
        for label, fn in ([("without gap test", lambda *a: False)] if args.ab else []) + [("this checkout", test)]:
            objects.gap_is_pipe = fn
            n = _count(mission, args.every, args.gate, args.set)
            print(f"seed {seed} {label}: " + ", ".join(f"{k} {v}" for k, v in sorted(n.items())), flush=True)
        objects.gap_is_pipe = test
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
