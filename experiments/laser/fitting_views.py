"""Object views per fitting from recorded laser observations (issue 22, stop 48): for every fitting of a
pipeline seed (valves, sockets, tees), the clouds holding at least ``--min-points`` of its points and
how many of those clouds gave an object view within 0.2 m of it (true poses), with the views'
configurations and their median distance to it; and the object views farther than 0.3 m from every
fitting ("far views"). Reads the recordings of ``experiments/laser_real_eval.py pipeline --dump DIR``
and the light missions of ``pipeline_replay.py`` (cached in the same or ``--light`` directory), so two
recordings (two front-end codes, one simulation) are compared scan by scan.

    python experiments/laser/fitting_views.py --seeds 34,15 --dump DIR [--light DIR] [--json OUT]
"""

from __future__ import annotations

import argparse
import json
import pickle
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(HERE.parent), str(HERE.parent / "estimators"), str(HERE)]

from laser_real_eval import parse_seeds  # noqa: E402
from pipeline_replay import light_mission, true_poses  # noqa: E402

NEAR, FAR = 0.2, 0.3  # m: a view of a fitting; a view of none


def fitting_views(seed: int, dump: Path, light: Path, min_points: int) -> dict:
    from semslam.observations import PointObservation

    mission = light_mission(seed, {}, light)
    meta = mission.metadata
    at = true_poses(mission)
    fittings = {o.id: (o.cls, np.asarray(o.position, float)) for o in meta.ground_truth.objects}
    ids = sorted(fittings)
    pos = np.array([fittings[k][1] for k in ids])
    framed = {k: set() for k in ids}  # stamps of the clouds with >= min_points on the fitting
    for s in meta.extras["scans"]:
        for k, v in s["object_points"].items():
            if int(v) >= min_points and int(k) in framed:
                framed[int(k)].add(int(s["stamp"]))
    views = {k: {} for k in ids}  # stamp -> (distance, configuration) of the nearest view
    far = 0
    for rec in pickle.loads((dump / f"pipeline_{seed}.pkl").read_bytes()):
        z = rec.observation
        if not isinstance(z, PointObservation):
            continue
        T = at(rec.stamp)[1]
        x = T[:3, :3] @ np.asarray(z.position) + T[:3, 3]
        d = np.linalg.norm(pos - x, axis=1)
        j = int(np.argmin(d))
        if d[j] > FAR:
            far += 1
        if d[j] <= NEAR:
            conf = z.connectivity.configuration if z.connectivity is not None else None
            prev = views[ids[j]].get(rec.stamp)
            if prev is None or d[j] < prev[0]:
                views[ids[j]][rec.stamp] = (float(d[j]), conf)
    out = {"far_views": far, "fittings": {}}
    for k in ids:
        cls = fittings[k][0]
        in_framed = {s: v for s, v in views[k].items() if s in framed[k]}
        confs: dict[str, int] = {}
        for _, c in views[k].values():
            confs[str(c)] = confs.get(str(c), 0) + 1
        out["fittings"][f"{cls} {k}"] = {
            "clouds": len(framed[k]),
            "views_in_clouds": len(in_framed),
            "views": len(views[k]),
            "median_cm": round(100 * float(np.median([v[0] for v in views[k].values()])), 1) if views[k] else None,
            "configurations": confs,
        }
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", required=True)
    ap.add_argument("--dump", type=Path, required=True)
    ap.add_argument("--light", type=Path, default=None, help="light missions' directory (default --dump)")
    ap.add_argument("--min-points", type=int, default=500)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    results = {}
    for seed in parse_seeds(args.seeds):
        results[seed] = r = fitting_views(seed, args.dump, args.light or args.dump, args.min_points)
        parts = [
            f"{name}: {f['views_in_clouds']}/{f['clouds']} (all {f['views']}, {f['median_cm']} cm, {f['configurations']})"
            if f["clouds"]
            else f"{name}: in no cloud with {args.min_points} points on it (all {f['views']} views)"
            for name, f in r["fittings"].items()
        ]
        print(f"seed {seed}: far views {r['far_views']}; " + "; ".join(parts), flush=True)
    if args.json is not None:
        args.json.write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
