"""Why a fitted pipe segment stops short of its true pipe's end (issue 21, cause B of the twins).

    python experiments/laser/short_end_trace.py --bag B.bag --views TRACE.json [--min-short 0.03]

TRACE.json: the views written by ``twin_trace.py --out`` (stamp, true pipe, how far the fitted end
stops short). Each listed scan of B.bag is segmented again by this checkout's front-end ("up" and
placement from the true pose). For the true pipe of each view it splits the shortfall at its end: the
segment's end, the extreme of the refined cylinder's inliers (the part between is what
``split_at_fittings`` took off as a "fitting"), and the extreme of the structure points on the true
pipe's surface (the part beyond the inliers: points that failed the inlier test, by distance or by
normal, or were taken by another pipe or the ground), along the true axis, and prints the totals.
"""

from __future__ import annotations

import argparse
import json
from collections import Counter
from pathlib import Path

import numpy as np
from inline_eval import _config


def main(argv=None) -> int:
    from frontends.laser import pipes as P
    from frontends.laser.frontend import segment_scan
    from semslam.mission.bag import read_mission
    from semslam.mission.measurements import GroundTruthPose, PointCloud

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bag", type=Path, required=True)
    ap.add_argument("--views", type=Path, required=True)
    ap.add_argument("--min-short", type=float, default=0.03)
    ap.add_argument("--set", action="append", default=[])
    args = ap.parse_args(argv)
    views = [v for v in json.loads(args.views.read_text()) if v.get("end_free") and v["short_of_end"] >= args.min_short]
    mission = read_mission(args.bag)
    gt = mission.metadata.ground_truth
    true = {p.id: p for p in gt.pipes}
    sensor = next(s for s in mission.metadata.sensors.values() if s.kind == "laser")
    poses = {m.stamp: m for m in mission.of_type(GroundTruthPose)}
    stamps = np.array(sorted(poses))
    clouds = {c.stamp: c for c in mission.of_type(PointCloud)}
    cfg = _config(args.set)
    rec: list = []
    orig = P._cut_into_segments

    def hook(points, normals, sq, cb, ab, rb, idx, pcfg, foreign=None, seabed=None, rays=None):
        out = orig(points, normals, sq, cb, ab, rb, idx, pcfg, foreign, seabed, rays)
        rec.append((np.array(cb), np.array(ab), float(rb), np.array(idx), out, pcfg))
        return out

    P._cut_into_segments = hook
    totals = Counter()
    try:
        for v in sorted({(v["stamp"], v["true_pipe"]) for v in views}):
            stamp, pid = v
            T = poses[int(stamps[np.argmin(np.abs(stamps - stamp))])].matrix() @ sensor.T_BS
            R, t0 = T[:3, :3], T[:3, 3]
            rec.clear()
            seg = segment_scan(clouds[stamp].points, cfg, up=R.T @ np.array([0.0, 0.0, -1.0]))
            S = seg.structure_points
            tp = true[pid]
            a, b = np.array(tp.p), np.array(tp.q)
            L = float(np.linalg.norm(b - a))
            u = (b - a) / L
            W = S @ R.T + t0 - a
            tt = W @ u
            rr = np.sqrt(np.maximum((W * W).sum(1) - tt * tt, 0)) - tp.radius
            on = np.flatnonzero((np.abs(rr) < 0.012) & (tt > -0.02) & (tt < L + 0.02))
            # which end is free: the one no object meets
            objs = np.array([o.position for o in gt.objects])
            free_q = np.min(np.linalg.norm(objs - b, axis=1)) >= 0.25
            sgn = 1 if free_q else -1
            end_t = L if free_q else 0.0

            def reach(ix, on=on, sgn=sgn, tt=tt):  # how far towards the free end the points go (true axis)
                ix = np.intersect1d(ix, on)
                return float(np.max(sgn * tt[ix])) if len(ix) else np.nan

            avail = reach(on)
            best = None
            for cb, ab, rb, idx, out, pcfg in rec:
                if len(np.intersect1d(idx, on)) < 20:
                    continue
                segs = [p for p in out if len(np.intersect1d(p.inliers, on)) >= 10]
                if not segs:
                    continue
                seg_end = max(reach(p.inliers) for p in segs)
                if best is None or seg_end > best[0]:
                    best = (seg_end, reach(idx), cb, ab, rb, idx, pcfg)
            if best is None:
                print(f"{stamp} pipe {pid}: no segment on it")
                continue
            seg_end, inl_end, cb, ab, rb, idx, pcfg = best
            # points on the true surface beyond the inliers' extreme: why not inliers
            beyond = on[sgn * tt[on] > inl_end + 0.005]
            taken = np.zeros(len(S), bool)
            for p in seg.pipes:
                taken[p.inliers] = True
            x = S[beyond] - cb
            ta = x @ ab
            dist = np.sqrt(np.maximum((x * x).sum(1) - ta * ta, 0))
            radial = x - np.outer(ta, ab)
            radial /= np.maximum(np.linalg.norm(radial, axis=1), 1e-12)[:, None]
            cosn = (seg.normals[beyond] * radial).sum(1)
            why = Counter()
            for k, j in enumerate(beyond):
                if seg.on_ground[j]:
                    why["ground"] += 1
                elif taken[j] and j not in idx:
                    why["other pipe"] += 1
                elif abs(dist[k] - rb) > pcfg.distance_tolerance:
                    why["distance"] += 1
                elif cosn[k] < np.cos(np.radians(pcfg.normal_tolerance_deg)):
                    why["normal"] += 1
                else:
                    why["inlier?"] += 1
            sc = sgn * end_t
            print(
                f"{stamp} pipe {pid}: short {sc - seg_end:.3f} = cut {inl_end - seg_end:.3f} + not inliers "
                f"{avail - inl_end:.3f} + not seen {sc - avail:.3f}; beyond the inliers: {dict(why)}",
                flush=True,
            )
            totals["views"] += 1
            totals["cut > 2 cm"] += inl_end - seg_end > 0.02
            totals["not inliers > 2 cm"] += avail - inl_end > 0.02
            totals["not seen > 2 cm"] += sc - avail > 0.02
    finally:
        P._cut_into_segments = orig
    print(dict(totals))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
