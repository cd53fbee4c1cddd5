"""Objects at lone pipe ends of recorded tank bags against the simulator's truth (issue 21: twins at lone ends).

    python experiments/laser/lone_end_eval.py --cache DIR --seeds 3,9,10 [--every 3] [--gate 0.15]

Segments every ``--every``-th scan of DIR/tank-seed<N>.bag (read only; "up" from the true pose) with
this checkout's front-end and looks at every lone pipe end whose object cluster has enough own points
(the candidates that reach ``pipe_continues``): its would-be position against the nearest true object
(true within ``--gate``, false beyond 0.25 m), how many of its points stand off the pipe's cylinder,
and its points beyond the end as offsets from the pipe's own radial level. It prints, for the
candidates without a body (fewer than ``min_own_points`` off the cylinder), how many true and false
ones the rule before this change kept (every 2 cm stretch beyond the end within ``tail_tolerance`` of
the level, either side, or it is an object) and how many this checkout's rule keeps (a 4 cm stretch
wider than the pipe by ``tail_tolerance`` and ``tail_sigmas`` × the noise of its median), for several
``tail_sigmas``.
"""

from __future__ import annotations

import argparse
from collections import Counter
from pathlib import Path

import numpy as np


def _old_rule_keeps(t: np.ndarray, offset: np.ndarray, cfg) -> bool:
    """The rule before this change (for comparison): an object unless every 2 cm stretch beyond the end
    (or all of them together when no stretch holds 5 points) lies within tail_tolerance of the level."""
    stretch = ((t - cfg.own_beyond) / 0.02).astype(np.int64)
    counts = np.bincount(stretch)
    full = np.flatnonzero(counts >= 5)
    if not len(full):
        return bool(abs(np.median(offset)) > cfg.tail_tolerance)
    return any(abs(np.median(offset[stretch == b])) > cfg.tail_tolerance for b in full)


def main(argv=None) -> int:
    from frontends.laser import objects as O
    from frontends.laser.config import LaserConfig
    from frontends.laser.frontend import segment_scan
    from semslam.mission.bag import read_mission
    from semslam.mission.measurements import GroundTruthPose, PointCloud
    from semslam.sim import TankSimConfig

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cache", type=Path, required=True)
    ap.add_argument("--seeds", required=True)
    ap.add_argument("--every", type=int, default=3)
    ap.add_argument("--gate", type=float, default=0.15)
    ap.add_argument("--sigmas", default="0,1,2,2.5,3")
    args = ap.parse_args(argv)
    cfg = LaserConfig.model_validate({"pipes": {"radius_prior": TankSimConfig().structure.pipe_radius_m}})
    rows: list[dict] = []
    scan: dict = {}
    rule = O.pipe_continues

    def record(points, end, out, pipe, all_points, ocfg):
        t, rad = O.along_and_off_axis(points, end, out)
        level, sigma = O.surface_level(pipe, all_points)
        lo, hi = np.percentile(t, [2, 98])
        x = scan["T"][:3, :3] @ (end + out * 0.5 * (max(lo, 0.0) + hi)) + scan["T"][:3, 3]
        beyond = t > ocfg.own_beyond
        rows.append(
            dict(
                seed=scan["seed"],
                d=float(np.min(np.linalg.norm(scan["objs"] - x, axis=1))),
                body=int((rad > pipe.radius + ocfg.own_margin).sum()) >= ocfg.min_own_points,
                t=t[beyond],
                offset=rad[beyond] - level,
                sigma=sigma,
            )
        )
        return rule(points, end, out, pipe, all_points, ocfg)

    O.pipe_continues = record
    try:
        for seed in [int(s) for s in args.seeds.split(",")]:
            mission = read_mission(args.cache / f"tank-seed{seed}.bag")
            scan.update(seed=seed, objs=np.array([o.position for o in mission.metadata.ground_truth.objects]))
            sensor = next(s for s in mission.metadata.sensors.values() if s.kind == "laser")
            poses = {m.stamp: m for m in mission.of_type(GroundTruthPose)}
            stamps = np.array(sorted(poses))
            for c in list(mission.of_type(PointCloud))[args.every // 2 :: args.every]:
                scan["T"] = poses[int(stamps[np.argmin(np.abs(stamps - c.stamp))])].matrix() @ sensor.T_BS
                segment_scan(c.points, cfg, up=scan["T"][:3, :3].T @ np.array([0.0, 0.0, -1.0]))
    finally:
        O.pipe_continues = rule
    ocfg = cfg.objects

    def label(r):
        return "true" if r["d"] <= args.gate else "false" if r["d"] > 0.25 else "between"

    for seed in sorted({r["seed"] for r in rows}):
        mine = [r for r in rows if r["seed"] == seed and len(r["t"])]
        old = [r for r in mine if r["body"] or _old_rule_keeps(r["t"], r["offset"], ocfg)]
        n = Counter(label(r) for r in old)
        bodiless = [r for r in old if not r["body"]]
        nb = Counter(label(r) for r in bodiless)
        print(f"seed {seed}: candidates the old rule keeps {dict(n)}, of them without a body {dict(nb)}")
        for k in [float(s) for s in args.sigmas.split(",")]:
            c = ocfg.model_copy(update={"tail_sigmas": k})
            kept = Counter(
                label(r) for r in bodiless if O.wider_stretch(r["t"] - c.own_beyond, r["offset"], r["sigma"], c)
            )
            print(f"  tail_sigmas {k:g}: kept without a body {dict(kept)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
