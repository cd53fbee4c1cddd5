"""Where the pipe stage cuts the tank's pipes, against the simulator's truth (issue 21: twins at pipe ends).

    python experiments/laser/cut_eval.py collect --cache DIR --seeds 3,9,10 [--every 10] --out F.pkl
    python experiments/laser/cut_eval.py report F.pkl [--sigmas 0,1,1.5,2,2.5,3]

``collect`` segments every ``--every``-th scan of DIR/tank-seed<N>.bag (a bag of ``replay_study.py
record``, read only) with this checkout's front-end ("up" from the true pose) and keeps, for every
refined cylinder the pipe stage cut into runs, its axis and the inputs of ``split_at_fittings``, with
the true pose of the scan; and the object segments with the distance to the nearest true object.

``report`` replays ``split_at_fittings`` on those inputs with the configuration as collected and
with ``bump_sigmas_known_radius`` set to each of ``--sigmas``, and classifies every stretch of
inliers a variant takes out of a pipe (a cut: the flagged bins between or at the end of its runs)
by the truth: at a fitting (a true object within ``--gate`` of the stretch's middle) or on a plain
pipe (on a true pipe's axis, no true object within ``--far``). It prints, per seed and variant, the
cuts at fittings and on plain pipes, and the distribution of the cuts' strength (the largest
(median - level) / (1.2533 σ / √n) of their bump bins; σ the pipe's measured scatter).
"""

from __future__ import annotations

import argparse
import pickle
from collections import Counter, defaultdict
from pathlib import Path

import numpy as np
from tank_truth import segment_distance


def _truth(mission):
    gt = mission.metadata.ground_truth
    objs = np.array([o.position for o in gt.objects])
    cls = [o.cls for o in gt.objects]
    pipes = [(np.array(p.p), np.array(p.q)) for p in gt.pipes]
    return objs, cls, pipes


def collect(args) -> None:
    from frontends.laser import pipes as P
    from frontends.laser.config import LaserConfig
    from frontends.laser.frontend import segment_scan
    from semslam.mission.bag import read_mission
    from semslam.mission.measurements import GroundTruthPose, PointCloud
    from semslam.sim import TankSimConfig

    cfg = LaserConfig.model_validate({"pipes": {"radius_prior": TankSimConfig().structure.pipe_radius_m}})
    state: dict = {}
    calls: list = []
    orig_cut, orig_split = P._cut_into_segments, P.split_at_fittings

    def cut_hook(points, normals, sq, cb, ab, rb, idx, pcfg, foreign=None, seabed=None, rays=None):
        state["cyl"] = (np.array(cb), np.array(ab), float(rb), pcfg)
        try:
            return orig_cut(points, normals, sq, cb, ab, rb, idx, pcfg, foreign, seabed, rays)
        finally:
            state.pop("cyl", None)

    def split_hook(t, residual, t_foreign, pcfg, t_around=None, open_beyond=None):
        if "cyl" in state:
            cb, ab, rb, ccfg = state["cyl"]
            calls.append(
                dict(
                    stamp=state["stamp"],
                    cb=cb,
                    ab=ab,
                    rb=rb,
                    t=np.array(t),
                    residual=np.array(residual),
                    t_foreign=np.array(t_foreign),
                    t_around=None if t_around is None else np.array(t_around),
                    cfg=ccfg,
                )
            )
        return orig_split(t, residual, t_foreign, pcfg, t_around, open_beyond)

    P._cut_into_segments, P.split_at_fittings = cut_hook, split_hook
    out = {}
    try:
        for seed in [int(s) for s in args.seeds.split(",")]:
            mission = read_mission(args.cache / f"tank-seed{seed}.bag")
            objs, cls, true_pipes = _truth(mission)
            sensor = next(s for s in mission.metadata.sensors.values() if s.kind == "laser")
            poses = {m.stamp: m for m in mission.of_type(GroundTruthPose)}
            stamps = np.array(sorted(poses))
            calls.clear()
            scans, objects = {}, []
            for c in list(mission.of_type(PointCloud))[args.every // 2 :: args.every]:
                T = poses[int(stamps[np.argmin(np.abs(stamps - c.stamp))])].matrix() @ sensor.T_BS
                state["stamp"] = c.stamp
                seg = segment_scan(c.points, cfg, up=T[:3, :3].T @ np.array([0.0, 0.0, -1.0]))
                scans[c.stamp] = T
                for ob in seg.objects:
                    x = T[:3, :3] @ ob.position + T[:3, 3]
                    d = np.linalg.norm(objs - x, axis=1)
                    objects.append(
                        dict(
                            stamp=c.stamp,
                            position=x,
                            config=ob.configuration,
                            d_true=float(d.min()),
                            truth=int(d.argmin()),
                            pipes=[float(seg.pipes[k].length) for k in ob.pipes],
                        )
                    )
            out[seed] = dict(calls=list(calls), scans=scans, objects=objects, objs=objs, cls=cls, pipes=true_pipes)
            print(f"seed {seed}: {len(scans)} scans, {len(calls)} cylinders cut, {len(objects)} objects", flush=True)
    finally:
        P._cut_into_segments, P.split_at_fittings = orig_cut, orig_split
    Path(args.out).write_bytes(pickle.dumps(out))


def cuts_of(call: dict, cfg) -> list[tuple[float, float]]:
    """The stretches (t from, t to) of a cylinder's inliers that ``split_at_fittings`` with ``cfg``
    takes out of the pipe or cuts it at: the inliers dropped (flagged bins), grouped where they lie
    within two bins of each other, and the cuts between two runs with nothing dropped between."""
    from frontends.laser.pipes import split_at_fittings

    t = call["t"]
    runs = split_at_fittings(t, call["residual"], call["t_foreign"], cfg, call["t_around"])
    kept = np.zeros(len(t), bool)
    for r in runs:
        kept[r] = True
    out = []
    dropped = np.sort(t[~kept])
    if len(dropped):
        br = np.flatnonzero(np.diff(dropped) > 2 * cfg.bump_bin) + 1
        out += [(float(g[0]), float(g[-1])) for g in np.split(dropped, br)]
    spans = sorted((float(t[r].min()), float(t[r].max())) for r in runs if len(r))
    for (_, a1), (b0, _) in zip(spans[:-1], spans[1:]):
        if not any(lo >= a1 - 1e-9 and hi <= b0 + 1e-9 for lo, hi in out):
            out.append((a1, b0))
    return out


def strength(call: dict, cfg, lo: float, hi: float) -> tuple[float, float]:
    """Over the bins of [lo, hi]: the largest (median − level) / (1.2533 σ / √n) and the largest
    (smooth mean − level) / (σ / √n3), n3 the points of the bin and its two neighbours (NaN: none)."""
    from frontends.laser.pipes import bump_profile

    prof = bump_profile(call["t"], call["residual"], cfg)
    k0 = int(np.floor((lo - prof.t0) / cfg.bump_bin))
    k1 = int(np.floor((hi - prof.t0) / cfg.bump_bin))
    k = np.arange(max(k0, 0), min(k1, len(prof.count) - 1) + 1)
    if not len(k) or not np.isfinite(prof.sigma) or prof.sigma <= 0:
        return float("nan"), float("nan")
    c3 = np.convolve(prof.count, np.ones(3), "same")
    z = (prof.median[k] - prof.level[k]) / (1.2533 * prof.sigma / np.sqrt(np.maximum(prof.count[k], 1)))
    zs = (prof.smooth[k] - prof.level[k]) / (prof.sigma / np.sqrt(np.maximum(c3[k], 1)))
    return tuple(float(np.nanmax(v)) if np.isfinite(v).any() else float("nan") for v in (z, zs))


def report(args) -> None:
    data = pickle.loads(Path(args.file).read_bytes())
    sigmas = [float(s) for s in args.sigmas.split(",")]
    for seed, d in data.items():
        objs, true_pipes = d["objs"], d["pipes"]
        counts = defaultdict(Counter)
        z = defaultdict(list)
        for call in d["calls"]:
            T = d["scans"][call["stamp"]]
            for k in sigmas:
                cfg = call["cfg"].model_copy(update={"bump_sigmas_known_radius": k})
                for lo, hi in cuts_of(call, cfg):
                    mid = call["cb"] + 0.5 * (lo + hi) * call["ab"]
                    x = T[:3, :3] @ mid + T[:3, 3]
                    d_obj = float(np.min(np.linalg.norm(objs - x, axis=1)))
                    d_pipe = min(segment_distance(x, p, q) for p, q in true_pipes)
                    if d_obj <= args.gate:
                        kind = "fitting"
                    elif d_obj > args.far and d_pipe < 0.03:
                        kind = "plain pipe"
                    else:
                        kind = "other"
                    counts[k][kind] += 1
                    if k == sigmas[0]:
                        z[kind].append(strength(call, cfg, lo, hi))
        for k in sigmas:
            print(
                f"seed {seed} bump_sigmas_known_radius {k:g}: "
                + ", ".join(f"{a} {b}" for a, b in sorted(counts[k].items()))
            )
        for kind, v in sorted(z.items()):
            for j, name in enumerate(("median", "smooth")):
                w = np.array([x[j] for x in v])
                w = w[np.isfinite(w)]
                if len(w):
                    q = np.percentile(w, [5, 10, 25, 50, 75, 90])
                    print(
                        f"  {name} strength of cuts ({kind}, {len(w)}): p5/10/25/50/75/90 "
                        + " ".join(f"{x:.2f}" for x in q)
                    )
        oc = Counter((o["config"], o["d_true"] <= args.gate) for o in d["objects"])
        print("  objects (config, true): " + ", ".join(f"{a}: {b}" for a, b in sorted(oc.items())))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="step", required=True)
    c = sub.add_parser("collect")
    c.add_argument("--cache", type=Path, required=True)
    c.add_argument("--seeds", required=True)
    c.add_argument("--every", type=int, default=10)
    c.add_argument("--out", required=True)
    r = sub.add_parser("report")
    r.add_argument("file")
    r.add_argument("--sigmas", default="0,1,1.5,2,2.5,3")
    r.add_argument("--gate", type=float, default=0.15)
    r.add_argument("--far", type=float, default=0.25)
    args = ap.parse_args(argv)
    (collect if args.step == "collect" else report)(args)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
