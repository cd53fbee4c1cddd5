"""Does holding a nominal pipe radius find narrow-arc pipes without admitting the seabed (issue 22,
stop 38)? The pipeline scenario's clouds segmented with the true poses ("up" from the true pose),
once with the default front-end and once with ``pipes.nominal_radii`` set to the seed's true line
radii (what an inspection knows of its pipeline), in one process on the same clouds.

    python experiments/laser/narrow_arc_eval.py --seeds 4,9,15 [--every 3] [--json OUT]

Clouds: every ``--every``-th, plus every cloud with >= 200 valid points on a valve. Per seed and
configuration: the reported pipe segments (``Pipe.reported``), those on a true pipe and those on none
(``evaluation.matching_pipe``: 10°, 5 cm, as ``laser_real_eval.py``), how many of each hold a nominal
radius, the radius error of those on a pipe (all, and the free fits alone); the sampled clouds with
>= 0.2 m of a pipe in view and with a segment on it; the valve clouds with an object view within
0.1 m of the valve. Per valve cloud with ``--valves``: one line each (segments ending near, views).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

VALVES = ("Ball-Valve", "Butterfly-Valve", "3-Way-Ball-Valve")


def _parse_seeds(text: str) -> list[int]:
    out: list[int] = []
    for part in text.split(","):
        a, _, b = part.partition("-")
        out += list(range(int(a), int(b or a) + 1))
    return out


def _off_line(x: np.ndarray, truth_pipes) -> float:
    """Distance (m) from ``x`` to the nearest true pipe's axis segment."""
    best = np.inf
    for g in truth_pipes:
        p, q = np.asarray(g.p, float), np.asarray(g.q, float)
        a = q - p
        t = float(np.clip((x - p) @ a / max(a @ a, 1e-12), 0.0, 1.0))
        best = min(best, float(np.linalg.norm(p + t * a - x)))
    return best


def held_detail(pp, seg) -> list:
    """[length m, arc deg, bow mm, free radius mm (fit_cylinder), the same and its standard error mm
    (free_radius)] of
    a segment with a held radius: the free radius is the circle fit of its inliers about its axis."""
    from frontends.laser.config import PipeConfig
    from frontends.laser.pipe_shape import arc_span_deg, bow
    from frontends.laser.pipes import fit_cylinder, free_radius

    pts = seg.structure_points
    b, _ = bow(pp, pts)
    free = fit_cylinder(
        np.take(pts, pp.inliers, axis=0), np.take(seg.normals, pp.inliers, axis=0), pp.axis, PipeConfig()
    )
    r_free, se = free_radius(np.take(pts, pp.inliers, axis=0), pp.p, pp.axis)
    return [
        round(pp.length, 3),
        round(arc_span_deg(pp, pts), 1),
        round(1000 * b, 2),
        round(1000 * free[2], 1),
        round(1000 * r_free, 1),
        round(1000 * se, 1),
    ]


def seed_scores(seed: int, every: int, show_valves: bool) -> dict:
    from frontends.laser.config import LaserConfig
    from frontends.laser.evaluation import matching_pipe
    from frontends.laser.frontend import segment_scan
    from semslam.mission.measurements import GroundTruthPose, PointCloud
    from semslam.sim.pipeline_config import PipelineSimConfig
    from semslam.sim.pipeline_mission import simulate_pipeline

    mission = simulate_pipeline(PipelineSimConfig(seed=seed))
    meta = mission.metadata
    gt = meta.ground_truth
    radii = sorted({round(float(p.radius), 4) for p in gt.pipes})
    configs = {
        "default": LaserConfig(),
        "nominal": LaserConfig.model_validate({"pipes": {"nominal_radii": radii}}),
    }
    valves = {o.id: np.asarray(o.position, float) for o in gt.objects if o.cls in VALVES}
    fittings = [np.asarray(o.position, float) for o in gt.objects]
    T_BS = next(s for s in meta.sensors.values() if s.kind == "laser").T_BS
    poses = {m.stamp: m.matrix() for m in mission.of_type(GroundTruthPose)}
    stamps = np.array(sorted(poses))
    scans = {s["stamp"]: s for s in meta.extras["scans"]}
    out = {
        name: {
            "clouds": 0,
            "clouds_pipe_visible": 0,
            "clouds_detected": 0,
            "reported": 0,
            "false": 0,
            "held_on": 0,
            "held_false": 0,
            "radius_err": [],
            "radius_err_free": [],
            "valve_clouds": 0,
            "valve_clouds_with_view": 0,
            "object_views": 0,
            "object_views_far": 0,
            "object_views_held": 0,
            "object_views_far_held": 0,
            "held": [],
        }
        for name in configs
    }
    for k, m in enumerate(mission.of_type(PointCloud)):
        info = scans.get(m.stamp, {})
        on_valve = [v for v in valves if info.get("object_points", {}).get(str(v), 0) >= 200]
        if k % every and not on_valve:
            continue
        T = poses[int(stamps[np.argmin(np.abs(stamps - m.stamp))])] @ T_BS
        R, t = T[:3, :3], T[:3, 3]
        visible = {int(i): v for i, v in info.get("pipe_visible_m", {}).items() if v >= 0.2}
        for name, cfg in configs.items():
            seg = segment_scan(m.points, cfg, up=R.T @ np.array([0.0, 0.0, -1.0]), rgb=m.rgb)
            o = out[name]
            hit = set()
            for pp in seg.pipes:
                if not pp.reported(seg.pipe_config):
                    continue
                o["reported"] += 1
                P = np.stack([pp.p, pp.q]) @ R.T + t
                g = matching_pipe(P[0], P[1], gt.pipes)
                if g is None:
                    o["false"] += 1
                    o["held_false"] += pp.radius_held
                    if pp.radius_held:
                        off = [round(_off_line(x, gt.pipes), 3) for x in P]
                        o["held"].append(["off"] + held_detail(pp, seg) + off)
                    continue
                hit.add(g.id)
                o["held_on"] += pp.radius_held
                if pp.radius_held:
                    o["held"].append(["on"] + held_detail(pp, seg))
                o["radius_err"].append(abs(pp.radius - g.radius))
                if not pp.radius_held:
                    o["radius_err_free"].append(abs(pp.radius - g.radius))
            for ob in seg.objects:
                x = R @ ob.position + t
                o["object_views"] += 1
                far = min(np.linalg.norm(x - f) for f in fittings) > 0.3
                o["object_views_far"] += bool(far)
                ends = [
                    (min(np.linalg.norm(pp.p - ob.position), np.linalg.norm(pp.q - ob.position)), pp)
                    for pp in seg.pipes
                ]
                by_held = bool(ends) and min(ends, key=lambda e: e[0])[1].radius_held
                o["object_views_held"] += bool(by_held)
                o["object_views_far_held"] += bool(far and by_held)
            if k % every == 0:
                o["clouds"] += 1
                if visible:
                    o["clouds_pipe_visible"] += 1
                    o["clouds_detected"] += bool(set(visible) & hit)
            for v in on_valve:
                x = R.T @ (valves[v] - t)
                views = [ob for ob in seg.objects if np.linalg.norm(ob.position - x) <= 0.1]
                o["valve_clouds"] += 1
                o["valve_clouds_with_view"] += bool(views)
                if show_valves:
                    ends = [
                        f"{pp.length:.2f}{'h' if pp.radius_held else ''}@"
                        f"{min(np.linalg.norm(pp.p - x), np.linalg.norm(pp.q - x)):.2f}"
                        for pp in seg.pipes
                        if min(np.linalg.norm(pp.p - x), np.linalg.norm(pp.q - x)) <= 0.3
                    ]
                    print(f"  seed {seed} {name} valve {v} t={m.stamp} pipes ending near {ends} views {len(views)}")
    for o in out.values():
        for key in ("radius_err", "radius_err_free"):
            e = np.array(o.pop(key))
            o[key + "_median_mm"] = round(1000 * float(np.median(e)), 2) if len(e) else None
            o[key + "_p90_mm"] = round(1000 * float(np.percentile(e, 90)), 2) if len(e) else None
    out["radii"] = radii
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="15")
    ap.add_argument("--every", type=int, default=3)
    ap.add_argument("--valves", action="store_true", help="one line per valve cloud")
    ap.add_argument("--held", action="store_true", help="one line per reported segment with a held radius")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    results = {}
    for seed in _parse_seeds(args.seeds):
        results[seed] = r = seed_scores(seed, args.every, args.valves)
        for name in ("default", "nominal"):
            o = r[name]
            print(
                f"seed {seed} radii {r['radii']} {name}: clouds {o['clouds']} with pipe {o['clouds_pipe_visible']} detected "
                f"{o['clouds_detected']} | reported {o['reported']} false {o['false']} (held: on {o['held_on']}, "
                f"false {o['held_false']}) | radius err median {o['radius_err_median_mm']} p90 {o['radius_err_p90_mm']} mm"
                f" (free fits {o['radius_err_free_median_mm']}) | valve clouds {o['valve_clouds']} with a view "
                f"{o['valve_clouds_with_view']} | object views {o['object_views']} far from any fitting "
                f"{o['object_views_far']} (nearest pipe end held: {o['object_views_held']}, far {o['object_views_far_held']})",
                flush=True,
            )
            for row in o["held"] if args.held else []:
                print("   held", row)
        if args.json:
            args.json.write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
