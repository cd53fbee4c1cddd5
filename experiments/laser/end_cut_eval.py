"""Where the pipe stage stops a pipe short of its end, against the simulator's truth (issue 21, cause B of
the twins: a pipe detected in part, its rest read as a fitting).

    python experiments/laser/end_cut_eval.py collect --cache DIR --seeds 10,12,19 [--every 3] --out F.pkl
    python experiments/laser/end_cut_eval.py report F.pkl

``collect`` segments every ``--every``-th scan of DIR/tank-seed<N>.bag (read only; "up" from the true
pose) with this checkout's front-end and keeps, for every refined cylinder the pipe stage cut into
runs, the inputs of ``split_at_fittings``, the inliers' points and normals, and the true pose.

``report`` replays ``split_at_fittings`` and looks at every *terminal* stretch it takes off a
cylinder's inliers (flagged bins beyond its last kept run, at either extreme): classified by the truth
as at a fitting (a true object within 0.15 m of the stretch's middle) or at a free end (no true object
within 0.25 m, the stretch within 0.15 m of a true pipe's end that no fitting meets), with what flagged
it (bump by bin median, by the smoothed mean only, crowd of foreign points) and how far it stands out.
"""

from __future__ import annotations

import argparse
import pickle
from collections import Counter
from pathlib import Path

import numpy as np
from inline_eval import _config


def collect(args) -> None:
    from frontends.laser import pipes as P
    from frontends.laser.frontend import segment_scan
    from semslam.mission.bag import read_mission
    from semslam.mission.measurements import GroundTruthPose, PointCloud

    cfg = _config(args.set)
    state: dict = {}
    calls: list = []
    orig_cut, orig_split = P._cut_into_segments, P.split_at_fittings

    def cut_hook(points, normals, sq, cb, ab, rb, idx, pcfg, foreign=None, seabed=None, rays=None):
        state["cyl"] = dict(cb=np.array(cb), ab=np.array(ab), rb=float(rb), pts=points[idx], nrm=normals[idx])
        # every structure point near the cylinder (not only the free ones): along the axis, off its surface
        ta = (points - cb) @ ab
        ra = np.sqrt(np.maximum(sq - 2.0 * points @ cb + cb @ cb - ta * ta, 0.0)) - rb
        ti = ta[idx]
        near = (ra < 0.08) & (ta > ti.min() - 0.3) & (ta < ti.max() + 0.3)
        if foreign is not None:
            near &= foreign
        state["cyl"].update(near_t=ta[near], near_res=ra[near])
        try:
            return orig_cut(points, normals, sq, cb, ab, rb, idx, pcfg, foreign, seabed, rays)
        finally:
            state.pop("cyl", None)

    def split_hook(t, residual, t_foreign, pcfg, t_around=None, open_beyond=None):
        if "cyl" in state:
            c = dict(state["cyl"], stamp=state["stamp"], t=np.array(t), residual=np.array(residual), cfg=pcfg)
            c["t_foreign"] = np.array(t_foreign)
            c["t_around"] = None if t_around is None else np.array(t_around)
            calls.append(c)
        return orig_split(t, residual, t_foreign, pcfg, t_around, open_beyond)

    P._cut_into_segments, P.split_at_fittings = cut_hook, split_hook
    out = {}
    try:
        for seed in [int(s) for s in args.seeds.split(",")]:
            mission = read_mission(args.cache / f"tank-seed{seed}.bag")
            gt = mission.metadata.ground_truth
            sensor = next(s for s in mission.metadata.sensors.values() if s.kind == "laser")
            poses = {m.stamp: m for m in mission.of_type(GroundTruthPose)}
            stamps = np.array(sorted(poses))
            calls.clear()
            scans = {}
            for c in list(mission.of_type(PointCloud))[args.every // 2 :: args.every]:
                T = poses[int(stamps[np.argmin(np.abs(stamps - c.stamp))])].matrix() @ sensor.T_BS
                state["stamp"] = c.stamp
                segment_scan(c.points, cfg, up=T[:3, :3].T @ np.array([0.0, 0.0, -1.0]))
                scans[c.stamp] = T
            objs = np.array([o.position for o in gt.objects])
            pipes = [(np.array(p.p), np.array(p.q)) for p in gt.pipes]
            fitted = [[bool(np.min(np.linalg.norm(objs - e, axis=1)) < 0.25) for e in pq] for pq in pipes]
            cls = [o.cls for o in gt.objects]
            out[seed] = dict(calls=list(calls), scans=scans, objs=objs, pipes=pipes, fitted=fitted, cls=cls)
            print(f"seed {seed}: {len(scans)} scans, {len(calls)} cylinders cut", flush=True)
    finally:
        P._cut_into_segments, P.split_at_fittings = orig_cut, orig_split
    Path(args.out).write_bytes(pickle.dumps(out))


def terminal_stretches(call: dict, cfg) -> list[dict]:
    """The stretches ``split_at_fittings`` takes off the extremes of a cylinder's inliers: for each side
    with dropped inliers beyond the outermost kept run, those inliers (indices) and the run (indices)."""
    from frontends.laser.pipes import split_at_fittings

    t = call["t"]
    runs = [r for r in split_at_fittings(t, call["residual"], call["t_foreign"], cfg, call["t_around"]) if len(r)]
    if not runs:
        return []
    spans = sorted(runs, key=lambda r: t[r].min())
    out = []
    for side, run in ((-1, spans[0]), (1, spans[-1])):
        edge = t[run].min() if side < 0 else t[run].max()
        beyond = np.flatnonzero(t < edge) if side < 0 else np.flatnonzero(t > edge)
        if len(beyond) >= 3:
            out.append(dict(side=side, stretch=beyond, run=run, edge=float(edge)))
    return out


def features(call: dict, cfg, s: dict) -> dict:
    """How a terminal stretch stands out: against the refined cylinder's profile (bins flagged by median,
    by smoothing, by crowd), and pooled over the stretch, against the level of the run's last 0.15 m."""
    from frontends.laser.pipes import bump_profile

    t, res = call["t"], call["residual"]
    prof = bump_profile(t, res, cfg)
    b = prof.bin
    sb = np.unique(b[s["stretch"]])
    h = prof.height(cfg)
    by_median = bool(((prof.median[sb] - prof.level[sb] > h) & (prof.count[sb] >= 3)).any())
    by_smooth = bool(((prof.smooth[sb] - prof.level[sb] > h) & (prof.count[sb] >= 2)).any())
    run = s["run"]
    near_end = run[np.abs(t[run] - s["edge"]) <= 0.15]
    level = float(np.median(res[near_end]))
    off = float(np.median(res[s["stretch"]])) - level
    n = len(s["stretch"])
    z = off / (1.2533 * prof.sigma / np.sqrt(n)) if np.isfinite(prof.sigma) and prof.sigma > 0 else np.nan
    length = float(np.ptp(t[s["stretch"]]))
    # against the run's own cylinder (refitted to the run alone, as the segment is)
    from frontends.laser.pipes import fit_cylinder

    pts, nrm = call["pts"], call["nrm"]
    c, a, r = fit_cylinder(pts[run], nrm[run], call["ab"], cfg)
    v = pts - c
    ta = v @ a
    ra = np.sqrt(np.maximum((v * v).sum(1) - ta * ta, 0)) - r
    lev2 = float(np.median(ra[near_end]))
    off2 = float(np.median(ra[s["stretch"]])) - lev2
    sig2 = 1.4826 * float(np.median(np.abs(ra[run] - np.median(ra[run]))))
    z2 = off2 / (1.2533 * sig2 / np.sqrt(n)) if sig2 > 0 else np.nan
    return dict(
        n=n,
        length=length,
        off=off,
        z=z,
        sigma=prof.sigma,
        by_median=by_median,
        by_smooth=by_smooth,
        run_len=float(np.ptp(t[run])),
        run_n=len(run),
        off2=off2,
        z2=z2,
        **around(call, s),
    )


def around(call: dict, s: dict) -> dict:
    """Structure points (any, but the ground) near a terminal stretch: beyond its outer end (from 1.5 to
    12 cm on, within 8 cm of the cylinder's surface, off it by more than 1.5 cm or on it), and within its
    span off the surface by more than 1.5 cm."""
    t = call["t"]
    side = s["side"]
    outer = t[s["stretch"]].max() if side > 0 else t[s["stretch"]].min()
    d = side * (call["near_t"] - outer)
    res = call["near_res"]
    span = side * (call["near_t"] - s["edge"])
    return dict(
        beyond_off=int(((d > 0.015) & (d < 0.12) & (res > 0.015)).sum()),
        beyond_on=int(((d > 0.015) & (d < 0.12) & (np.abs(res) <= 0.015)).sum()),
        span_off=int(((span > 0) & (d <= 0.015) & (res > 0.015)).sum()),
    )


def classify(call: dict, T: np.ndarray, s: dict, truth: dict) -> tuple[str, float]:
    """'fitting' / 'free end' / 'other', and how far the run's end stops before that true end (m)."""
    mid_t = float(np.median(call["t"][s["stretch"]]))
    x = T[:3, :3] @ (call["cb"] + mid_t * call["ab"]) + T[:3, 3]
    d_obj = float(np.min(np.linalg.norm(truth["objs"] - x, axis=1)))
    if d_obj <= 0.15:
        return "fitting " + truth["cls"][int(np.argmin(np.linalg.norm(truth["objs"] - x, axis=1)))], np.nan
    if d_obj <= 0.25:
        return "other", np.nan
    edge = T[:3, :3] @ (call["cb"] + s["edge"] * call["ab"]) + T[:3, 3]
    for (p, q), fit in zip(truth["pipes"], truth["fitted"]):
        u = (q - p) / np.linalg.norm(q - p)
        for end, f, sign in ((p, fit[0], -1), (q, fit[1], 1)):
            v = x - end
            if not f and np.linalg.norm(v - (v @ u) * u) < 0.04 and abs(v @ u) < 0.15:
                return "free end", float(sign * (end - edge) @ u)
    return "other", np.nan


def report(args) -> None:
    data = pickle.loads(Path(args.file).read_bytes())
    rows = []
    for seed, d in data.items():
        for call in d["calls"]:
            for s in terminal_stretches(call, call["cfg"]):
                if (
                    len(s["run"]) < call["cfg"].min_points
                    or np.ptp(call["t"][s["run"]]) < call["cfg"].min_detect_length
                ):
                    continue  # no segment ends there
                kind, short = classify(call, d["scans"][call["stamp"]], s, d)
                rows.append(dict(seed=seed, kind=kind, short=short, **features(call, call["cfg"], s)))
    for seed in sorted({r["seed"] for r in rows}):
        mine = [r for r in rows if r["seed"] == seed]
        print(f"seed {seed}: terminal stretches {dict(Counter(r['kind'] for r in mine))}")
    for kind in ("fitting", "free end", "other"):
        mine = [r for r in rows if r["kind"] == kind]
        if not mine:
            continue
        print(
            f"{kind} ({len(mine)}): flagged by median {sum(r['by_median'] for r in mine)}, smooth only "
            f"{sum(r['by_smooth'] and not r['by_median'] for r in mine)}, neither (crowd) "
            f"{sum(not r['by_smooth'] and not r['by_median'] for r in mine)}"
        )
        for key in ("n", "length", "off", "z", "off2", "z2", "short", "run_len", "beyond_off", "beyond_on", "span_off"):
            v = np.array([r[key] for r in mine], float)
            v = v[np.isfinite(v)]
            if len(v):
                print(f"  {key}: p5/25/50/75/95 " + " ".join(f"{x:.4g}" for x in np.percentile(v, [5, 25, 50, 75, 95])))
    if args.dump:
        Path(args.dump).write_bytes(pickle.dumps(rows))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="step", required=True)
    c = sub.add_parser("collect")
    c.add_argument("--cache", type=Path, required=True)
    c.add_argument("--seeds", required=True)
    c.add_argument("--every", type=int, default=3)
    c.add_argument("--set", action="append", default=[])
    c.add_argument("--out", required=True)
    r = sub.add_parser("report")
    r.add_argument("file")
    r.add_argument("--dump")
    args = ap.parse_args(argv)
    (collect if args.step == "collect" else report)(args)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
