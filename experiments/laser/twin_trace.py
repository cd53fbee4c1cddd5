"""Trace the graph's object twins of a run back to the laser front-end's views (issue 21).

    python experiments/laser/twin_trace.py --bag B.bag --run DIR [--every 1] [--near 0.15] [--set K=V]

DIR: an output directory of ``semslam compare`` / ``study`` (its map_graph.json) for the mission in
B.bag (ground truth and true poses read from it). A mapped object is a *twin* when a true object is
nearer to it than 0.5 m but another mapped object is nearer to that truth (within 0.15 m), *false*
with no true object within 0.5 m. Every ``--every``-th scan is segmented again by this checkout's
front-end with "up" from the true pose; each object view within ``--near`` of a twin (views placed
with the true poses) is printed with how it was made: its configuration, the pipe end it sits at
(how far the fitted end stops before the true pipe's end, and whether that true end is free: no
fitting), its points off the pipe's cylinder (the lone-end "body") labelled by the nearest true
thing (a true pipe's surface, a true object, the floor), and the lone-end tail test's verdict.
A summary per twin counts the views by cause.
"""

from __future__ import annotations

import argparse
import json
from collections import Counter
from pathlib import Path

import numpy as np
from inline_eval import _config


def twins(map_objects: list[dict], truth: np.ndarray, gate: float = 0.15, far: float = 0.5) -> list[dict]:
    """Mapped objects that are not the one mapped object of their nearest truth: (map entry, truth
    index, distance)."""
    near: dict[int, list] = {}
    out = []
    for o in map_objects:
        d = np.linalg.norm(truth - np.asarray(o["position"]), axis=1)
        i = int(d.argmin())
        if d[i] > far:
            out.append(dict(entry=o, truth=i, d=float(d[i]), kind="false"))
        else:
            near.setdefault(i, []).append((float(d[i]), o))
    for i, lst in near.items():
        lst.sort(key=lambda a: a[0])
        rest = lst[1:] if lst[0][0] <= gate else lst
        out += [dict(entry=o, truth=i, d=d, kind="twin") for d, o in rest]
    return out


def label_points(X: np.ndarray, gt, floor_depth: float) -> Counter:
    """Where world points lie: on a true pipe's surface (within 1.5 cm), near a true object's centre
    (within 0.15 m), on the floor (within 3 cm of its depth), else elsewhere."""
    lab = Counter()
    objs = np.array([o.position for o in gt.objects])
    for x in X:
        best = None
        for p in gt.pipes:
            a, b = np.array(p.p), np.array(p.q)
            d = b - a
            s = float(np.clip((x - a) @ d / (d @ d), 0, 1))
            r = abs(np.linalg.norm(x - a - s * d) - p.radius)
            if r < 0.015 and (best is None or r < best[0]):
                best = (r, f"pipe {p.id}")
        do = np.linalg.norm(objs - x, axis=1)
        if best is None and do.min() < 0.15:
            best = (0, f"object {int(do.argmin())}")
        if best is None and abs(x[2] - floor_depth) < 0.03:
            best = (0, "floor")
        lab[best[1] if best else "elsewhere"] += 1
    return lab


def main(argv=None) -> int:
    from frontends.laser import objects as O
    from frontends.laser.frontend import segment_scan
    from semslam.mission.bag import read_mission
    from semslam.mission.measurements import GroundTruthPose, PointCloud

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bag", type=Path, required=True)
    ap.add_argument("--run", type=Path, required=True)
    ap.add_argument("--every", type=int, default=1)
    ap.add_argument("--near", type=float, default=0.15)
    ap.add_argument("--floor-depth", type=float, default=5.0)
    ap.add_argument("--set", action="append", default=[], help="section.key=value of the front-end's configuration")
    ap.add_argument("--out", type=Path, help="write the views as JSON")
    args = ap.parse_args(argv)
    mission = read_mission(args.bag)
    gt = mission.metadata.ground_truth
    truth = np.array([o.position for o in gt.objects])
    found = twins(json.loads((args.run / "map_graph.json").read_text())["objects"], truth)
    for t in found:
        e = t["entry"]
        print(
            f"{t['kind']} map {e['id']} {e['class']} n_obs {e['n_observations']} pipes {e['connected_pipes']} "
            f"at {np.round(e['position'], 3).tolist()}: {t['d']:.3f} m from truth {t['truth']} ({gt.objects[t['truth']].cls})"
        )
    if not found:
        return 0
    where = np.array([t["entry"]["position"] for t in found])
    true_pipes = [(np.array(p.p), np.array(p.q), p) for p in gt.pipes]
    has_fitting = {
        (p.id, k): any(
            p.id in o.pipes and np.linalg.norm(np.array(o.position) - np.array(end)) < 0.25 for o in gt.objects
        )
        for p in gt.pipes
        for k, end in enumerate((p.p, p.q))
    }
    sensor = next(s for s in mission.metadata.sensors.values() if s.kind == "laser")
    poses = {m.stamp: m for m in mission.of_type(GroundTruthPose)}
    stamps = np.array(sorted(poses))
    cfg = _config(args.set)
    views: list[dict] = []
    for c in list(mission.of_type(PointCloud))[:: args.every]:
        T = poses[int(stamps[np.argmin(np.abs(stamps - c.stamp))])].matrix() @ sensor.T_BS
        R, t0 = T[:3, :3], T[:3, 3]
        seg = segment_scan(c.points, cfg, up=R.T @ np.array([0.0, 0.0, -1.0]))
        S = seg.structure_points
        for ob in seg.objects:
            x = R @ ob.position + t0
            d = np.linalg.norm(where - x, axis=1)
            k = int(d.argmin())
            if d[k] > args.near:
                continue
            v = dict(twin=int(found[k]["entry"]["id"]), stamp=int(c.stamp), config=ob.configuration, d=float(d[k]))
            v["pipes"] = [round(seg.pipes[i].length, 3) for i in ob.pipes]
            if len(ob.pipes) == 1 or ob.configuration == 1:
                pipe = seg.pipes[ob.pipes[0]]
                # the pipe end the object sits at, and its outward direction
                ends = [(pipe.p, -pipe.axis), (pipe.q, pipe.axis)]
                end, out = min(ends, key=lambda eo: np.linalg.norm(eo[0] - ob.position))
                ew, ow = R @ end + t0, R @ out
                # the true pipe this fitted end lies on, and how far before its true end it stops
                best = min(
                    (
                        (
                            min(
                                np.linalg.norm(
                                    ew - a - np.clip((ew - a) @ (b - a) / ((b - a) @ (b - a)), 0, 1) * (b - a)
                                ),
                                9,
                            ),
                            p,
                            a,
                            b,
                        )
                        for a, b, p in true_pipes
                    ),
                    key=lambda r: r[0],
                )
                _, tp, a, b = best
                kend = int(ow @ (b - a) > 0)
                true_end = b if kend else a
                v["true_pipe"] = tp.id
                v["short_of_end"] = float((true_end - ew) @ ow)
                v["end_free"] = not has_fitting[(tp.id, kend)]
                P = np.take(S, ob.indices, axis=0)
                tt, rad = O.along_and_off_axis(P, end, out)
                off = rad > pipe.radius + cfg.objects.own_margin
                v["own_off"] = int(off.sum())
                v["own_beyond"] = int((tt > cfg.objects.own_beyond).sum())
                v["body_labels"] = dict(label_points(P[off] @ R.T + t0, gt, args.floor_depth))
                level, sigma = O.surface_level(pipe, S)
                beyond = tt > cfg.objects.own_beyond
                v["wider"] = bool(
                    O.wider_stretch(tt[beyond] - cfg.objects.own_beyond, rad[beyond] - level, sigma, cfg.objects)
                )
                v["beyond_offset_med"] = float(np.median(rad[beyond] - level)) if beyond.any() else None
            views.append(v)
            print(json.dumps(v), flush=True)
    print("summary:")
    for t in found:
        mine = [v for v in views if v["twin"] == t["entry"]["id"]]
        n = Counter(
            f"config {v['config']}"
            + (
                f", {'free' if v['end_free'] else 'fitted'} end, "
                + ("body" if v["own_off"] >= cfg.objects.min_own_points else "wider" if v["wider"] else "neither")
                if "end_free" in v
                else ""
            )
            for v in mine
        )
        print(f"  map {t['entry']['id']} ({t['kind']}, n_obs {t['entry']['n_observations']}): {dict(n)}")
    if args.out:
        args.out.write_text(json.dumps(views))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
