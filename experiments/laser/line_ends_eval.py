"""How far the laser front-end's pipe line observations reach past their true pipes' ends (issue 21:
pipe landmark error on some tank worlds is mostly the mapped extent overshooting the true pipe).

    python experiments/laser/line_ends_eval.py --bag B.bag [--every 3] [--set K=V]

Segments every ``--every``-th scan of B.bag ("up" and placement from the true pose) with this
checkout's front-end. Each reported pipe segment is matched to the true pipe of least cost as
``semslam.eval.metrics`` matches mapped pipes (mean distance of its ends to the axis plus how far they
reach past the pipe's extent); per end it records how far along that axis it lies beyond the true
pipe's end (0 when inside), and whether that true end meets a fitting or is free. Prints the share
of ends beyond 3 / 5 / 10 cm and the largest, split by fitted and free true ends.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from inline_eval import _config


def main(argv=None) -> int:
    from frontends.laser.frontend import segment_scan
    from semslam.mission.bag import read_mission
    from semslam.mission.measurements import GroundTruthPose, PointCloud

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bag", type=Path, required=True)
    ap.add_argument("--every", type=int, default=3)
    ap.add_argument("--set", action="append", default=[], help="section.key=value of the front-end's configuration")
    args = ap.parse_args(argv)
    mission = read_mission(args.bag)
    gt = mission.metadata.ground_truth
    P = np.array([p.p for p in gt.pipes])
    Q = np.array([p.q for p in gt.pipes])
    L = np.linalg.norm(Q - P, axis=1)
    D = (Q - P) / L[:, None]
    fitted = np.array(
        [
            [
                any(p.id in o.pipes and np.linalg.norm(np.array(o.position) - e) < 0.25 for o in gt.objects)
                for e in (a, b)
            ]
            for p, a, b in zip(gt.pipes, P, Q)
        ]
    )
    sensor = next(s for s in mission.metadata.sensors.values() if s.kind == "laser")
    poses = {m.stamp: m for m in mission.of_type(GroundTruthPose)}
    stamps = np.array(sorted(poses))
    cfg = _config(args.set)
    rows = []  # (beyond m, true end fitted?, off-axis m)
    for c in list(mission.of_type(PointCloud))[args.every // 2 :: args.every]:
        T = poses[int(stamps[np.argmin(np.abs(stamps - c.stamp))])].matrix() @ sensor.T_BS
        seg = segment_scan(c.points, cfg, up=T[:3, :3].T @ np.array([0.0, 0.0, -1.0]))
        for pipe in seg.pipes:
            if not pipe.reported(seg.pipe_config):
                continue
            ends = np.array([T[:3, :3] @ e + T[:3, 3] for e in (pipe.p, pipe.q)])
            v = ends[None] - P[:, None]
            t = np.einsum("gkc,gc->gk", v, D)
            off = np.linalg.norm(v - t[..., None] * D[:, None], axis=-1)
            beyond = np.maximum(0.0, np.maximum(-t, t - L[:, None]))
            g = int((off.mean(axis=1) + beyond.max(axis=1)).argmin())  # as the metrics match pipes
            if off[g].mean() > 0.05:
                continue  # no true pipe under it (a false segment)
            for k in range(2):
                before, after = -t[g, k], t[g, k] - L[g]
                side = 0 if before > after else 1
                rows.append((max(before, after, 0.0), bool(fitted[g, side]), float(off[g, k])))
    r = np.array(rows)
    print(f"{args.bag.name}: {len(r)} segment ends on true pipes")
    for label, sel in (("at fitted true ends", r[:, 1] == 1), ("at free true ends", r[:, 1] == 0)):
        b = r[sel, 0]
        if len(b):
            print(
                f"  {label}: {len(b)}, beyond 3 / 5 / 10 cm: "
                + " / ".join(f"{np.mean(b > x):.3f}" for x in (0.03, 0.05, 0.10))
                + f", p99 {np.percentile(b, 99) * 100:.1f} cm, max {b.max() * 100:.1f} cm"
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
