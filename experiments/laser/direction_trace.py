"""Where the yaw error of the laser's pipe line observations on the pipeline scenario comes from
(issue 22: the mapped pipeline drifts across when the observations' directions are a few tenths of a
degree off; ``pipeline_replay.py --true-directions`` removes that drift).

    python experiments/laser/direction_trace.py --seed 6 [--pipes 1,3] [--every 2] [--set section.key=value]

Simulates pipeline ``--seed``, segments every ``--every``-th cloud that shows >= 0.2 m of one of
``--pipes`` (true pipe ids; default every pipe) with this checkout's front-end ("up" from the true
pose) and, for each reported segment on such a pipe, compares with the true axis the yaw (about
down, deg, signed) and the pitch (deg) of: the reported axis; the principal direction of the
segment's inliers that lie on the true pipe's surface (within 1 cm), i.e. the same fit without the
points of other things; and the axis fitted to those inliers by least squares on their distance to
a cylinder (geometric fit, radius free). It prints per pipe the medians and the share of inliers off
the true surface, and the medians over all.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))


def geometric_axis(P: np.ndarray, a0: np.ndarray, c0: np.ndarray, r0: float, rounds: int = 10):
    """Axis direction of the cylinder fitted to ``P`` by Gauss-Newton on the points' distances to
    its surface (parameters: the axis point's two offsets across it, two tilts, the radius)."""
    from frontends.laser.pipes import _across

    a, c, r = a0 / np.linalg.norm(a0), c0.astype(float), float(r0)
    for _ in range(rounds):
        E = _across(a)
        d = P - c
        t = d @ a
        x = d - np.outer(t, a)
        dist = np.maximum(np.linalg.norm(x, axis=1), 1e-9)
        n = x / dist[:, None]  # unit radial directions
        res = dist - r
        # d res / d(centre offset e_k) = -n·e_k; d res / d(tilt e_k) = -t (n·e_k); d res / dr = -1
        J = np.column_stack([-(n @ E), -(t[:, None] * (n @ E)), -np.ones(len(P))])
        step, *_ = np.linalg.lstsq(J, -res, rcond=None)
        c = c + E @ step[:2]
        a = a + E @ step[2:4]
        a /= np.linalg.norm(a)
        r += step[4]
        if np.abs(step).max() < 1e-7:
            break
    return a


def pipe_views(mission, every: int, wanted: set[int] | None):
    """Every ``every``-th scan of a pipeline mission with ≥ 0.2 m of a wanted pipe in view: (scan,
    {visible pipe ids}, R and t of the laser in {W} at the nearest true pose)."""
    from semslam.mission.measurements import GroundTruthPose, PointCloud

    meta = mission.metadata
    T_BS = next(s for s in meta.sensors.values() if s.kind == "laser").T_BS
    poses = {m.stamp: m.matrix() for m in mission.of_type(GroundTruthPose)}
    stamps = np.array(sorted(poses))
    visible = {s["stamp"]: {int(k): v for k, v in s["pipe_visible_m"].items()} for s in meta.extras["scans"]}
    k = 0
    for m in mission.of_type(PointCloud):
        vis = {g for g, v in visible.get(m.stamp, {}).items() if v >= 0.2 and (wanted is None or g in wanted)}
        if not vis:
            continue
        k += 1
        if k % every:
            continue
        T = poses[int(stamps[np.argmin(np.abs(stamps - m.stamp))])] @ T_BS
        yield m, vis, T[:3, :3], T[:3, 3]


def angles(a: np.ndarray, g: np.ndarray) -> tuple[float, float]:
    """(yaw, pitch) of ``a`` from ``g`` (world, NED; deg): the turn about down, the tilt out of level."""
    a = a * np.sign(a @ g)
    yaw = np.degrees(np.arctan2(a[1], a[0]) - np.arctan2(g[1], g[0]))
    yaw = (yaw + 180.0) % 360.0 - 180.0
    pitch = np.degrees(np.arcsin(np.clip(a[2], -1, 1)) - np.arcsin(np.clip(g[2], -1, 1)))
    return float(yaw), float(pitch)


def main(argv=None) -> int:
    from frontends.laser.config import LaserConfig
    from frontends.laser.evaluation import matching_pipe
    from frontends.laser.frontend import segment_scan
    from semslam.sim.pipeline_config import PipelineSimConfig
    from semslam.sim.pipeline_mission import simulate_pipeline

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=6)
    ap.add_argument("--pipes", default=None)
    ap.add_argument("--every", type=int, default=2)
    ap.add_argument("--set", action="append", default=[], help="section.key=value (front-end configuration)")
    args = ap.parse_args(argv)
    data: dict = {}
    for item in args.set:
        key, value = item.split("=", 1)
        section, name = key.split(".")
        data.setdefault(section, {})[name] = float(value)
    cfg = LaserConfig.model_validate(data)
    mission = simulate_pipeline(PipelineSimConfig(seed=args.seed))
    meta = mission.metadata
    gt = meta.ground_truth
    wanted = None if args.pipes is None else {int(x) for x in args.pipes.split(",")}
    rows: dict[int, list] = {}
    for m, vis, R, t in pipe_views(mission, args.every, wanted):
        seg = segment_scan(m.points, cfg, up=R.T @ np.array([0.0, 0.0, -1.0]), rgb=m.rgb)
        S = seg.structure_points
        for pipe in seg.pipes:
            if not pipe.reported(cfg.pipes):
                continue
            P = np.stack([pipe.p, pipe.q]) @ R.T + t
            g = matching_pipe(P[0], P[1], gt.pipes)
            if g is None or g.id not in vis:
                continue
            gp, gq = np.asarray(g.p, float), np.asarray(g.q, float)
            ga = (gq - gp) / np.linalg.norm(gq - gp)
            X = S[pipe.inliers] @ R.T + t  # inliers in the world
            rel = X - gp
            radial = np.linalg.norm(rel - np.outer(rel @ ga, ga), axis=1)
            on = np.abs(radial - g.radius) < 0.01
            a_rep = R @ pipe.axis
            row = {"rep": angles(a_rep, ga), "off": 1.0 - on.mean(), "n": len(X)}
            if on.sum() >= 20:
                Y = X[on]
                _, vecs = np.linalg.eigh(np.cov((Y - Y.mean(0)).T))
                row["pca_on"] = angles(vecs[:, 2], ga)
                c0 = (pipe.p + pipe.q) / 2 @ R.T + t
                row["geo_on"] = angles(geometric_axis(Y, a_rep, c0, pipe.radius), ga)
                row["geo_all"] = angles(geometric_axis(X, a_rep, c0, pipe.radius), ga)
            rows.setdefault(g.id, []).append(row)

    def med(rs, key, i):
        v = [r[key][i] for r in rs if key in r]
        return round(float(np.median(v)), 3) if v else None

    everything = [r for rs in rows.values() for r in rs]
    for gid, rs in [*sorted(rows.items()), ("all", everything)]:
        print(
            f"pipe {gid}: segments {len(rs)}, inliers off the true surface {np.median([r['off'] for r in rs]):.3f}, "
            f"reported |yaw| median {np.median([abs(r['rep'][0]) for r in rs]):.3f} | "
            + " | ".join(
                f"{key} yaw {med(rs, key, 0)} pitch {med(rs, key, 1)}" for key in ("rep", "pca_on", "geo_on", "geo_all")
            ),
            flush=True,
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
