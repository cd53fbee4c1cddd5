"""The pipe segments of chosen pipeline clouds, with what may tell a fitting's body fitted as a pipe
(issue 22, stop 42: a valve's body or lever reported as a short pipe across the line).

    python experiments/laser/cross_probe.py --seed 15 --times 129.5,133.0 [--cache DIR] [--config JSON]

Simulates pipeline ``--seed`` once (the chosen clouds, their true sensor poses and the simulator's ray
labels cached in ``--cache``), segments each chosen cloud with this checkout's front-end ("up" from the
true pose, the seed's true radii as ``pipes.nominal_radii``) and prints per segment: length, radius
(held or fitted), reported or not, lying on the ground or not and its axis height, its angle to the
scan's longest segment and the distance from its axis to that segment, the share of its inliers
on a fitting, the seabed, a rock, a pipe (the simulator's ray labels), and its placement against the truth (on a true pipe or not, the nearest
fitting's distance). ``--times``: seconds from the mission's start, as the stop 41 notes give them.
"""

from __future__ import annotations

import argparse
import json
import pickle
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(HERE), str(HERE.parent)]


def clouds_at(seed: int, times: list[float], cache: Path) -> tuple[dict, list[dict]]:
    """(metadata as needed, per chosen time: points, rgb, T_WS, stamp, the hit kind per pixel)."""
    path = cache / f"clouds_{seed}_{'_'.join(f'{t:g}' for t in times)}.pkl"
    if path.exists():
        return pickle.loads(path.read_bytes())
    from semslam.mission.measurements import GroundTruthPose, PointCloud
    from semslam.sim import pipeline_scene
    from semslam.sim.pipeline_config import PipelineSimConfig
    from semslam.sim.pipeline_mission import simulate_pipeline

    labels: list = []  # per cast: the hit kind of every ray (seabed, rock, pipe, object)
    cast = pipeline_scene.PipelineScene.cast_with_normals

    def recording(self, origins, dirs):
        out = cast(self, origins, dirs)
        labels.append(np.asarray(out[1]).copy())
        return out

    pipeline_scene.PipelineScene.cast_with_normals = recording
    mission = simulate_pipeline(PipelineSimConfig(seed=seed))
    meta = mission.metadata
    clouds = list(mission.of_type(PointCloud))
    labels = labels[-len(clouds) :]
    T_BS = next(s for s in meta.sensors.values() if s.kind == "laser").T_BS
    poses = {m.stamp: m.matrix() for m in mission.of_type(GroundTruthPose)}
    stamps = np.array(sorted(poses))
    t0 = clouds[0].stamp
    out = []
    for t in times:
        k = int(np.argmin([abs((m.stamp - t0) * 1e-9 + 0.5 - t) for m in clouds]))
        m = clouds[k]
        lab = labels[k]
        T = poses[int(stamps[np.argmin(np.abs(stamps - m.stamp))])] @ T_BS
        out.append({"t": t, "stamp": m.stamp, "points": m.points, "rgb": m.rgb, "T_WS": T, "label": lab})
    gt = meta.ground_truth
    info = {"gt": gt, "radii": sorted({round(float(p.radius), 4) for p in gt.pipes})}
    cache.mkdir(parents=True, exist_ok=True)
    path.write_bytes(pickle.dumps((info, out)))
    return info, out


def main(argv=None) -> int:
    from frontends.laser.config import LaserConfig
    from frontends.laser.evaluation import matching_pipe
    from frontends.laser.frontend import segment_scan
    from frontends.laser.pipe_shape import axis_height

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, required=True)
    ap.add_argument("--times", required=True)
    ap.add_argument("--cache", type=Path, default=Path("/tmp/cross_probe"))
    ap.add_argument("--config", default="{}", help="front-end overrides (JSON)")
    args = ap.parse_args(argv)
    times = [float(x) for x in args.times.split(",")]
    info, clouds = clouds_at(args.seed, times, args.cache)
    gt = info["gt"]
    over = json.loads(args.config)
    over.setdefault("pipes", {})["nominal_radii"] = info["radii"]
    cfg = LaserConfig.model_validate(over)
    objects = np.array([o.position for o in gt.objects], float).reshape(-1, 3)
    for c in clouds:
        T = c["T_WS"]
        R, t = T[:3, :3], T[:3, 3]
        seg = segment_scan(c["points"], cfg, up=R.T @ np.array([0.0, 0.0, -1.0]), rgb=c["rgb"])
        pipes = seg.pipes
        print(f"t={c['t']}: {len(pipes)} segments, {len(seg.objects)} objects", flush=True)
        if not pipes:
            continue
        longest = max(range(len(pipes)), key=lambda k: pipes[k].length)
        raw_of = seg.raw_indices
        for k, p in enumerate(pipes):
            P = np.stack([p.p, p.q]) @ R.T + t
            g = matching_pipe(P[0], P[1], gt.pipes)
            mid = P.mean(axis=0)
            h = axis_height(p, seg.ground) if seg.ground is not None else None
            lab = c["label"][raw_of(p.inliers)]
            kinds = np.bincount(lab[(lab >= 0) & (lab < 4)], minlength=4) / max(len(lab), 1)
            L = pipes[longest]
            ang = float(np.degrees(np.arccos(min(1.0, abs(p.axis @ L.axis)))))
            # distance of this segment's middle from the longest segment's axis line, and the
            # longest segment's parameter there (beyond its ends: < 0 or > length)
            m_s = 0.5 * (p.p + p.q) - L.p
            tl = float(m_s @ L.axis)
            dl = float(np.linalg.norm(m_s - tl * L.axis))
            print(
                f"  [{k}] len {p.length:.3f} r {1000 * p.radius:.1f}{'H' if p.radius_held else ''} "
                f"rep {p.reported(seg.pipe_config)} obj_only {p.objects_only} between {p.between_fittings} "
                f"axis_h {h if h is None else round(h, 3)} inl {len(p.inliers)} on_fitting "
                f"{kinds[3]:.2f} (seabed {kinds[0]:.2f} rock {kinds[1]:.2f} pipe {kinds[2]:.2f}) | vs longest: angle {ang:.0f} mid off {dl:.3f} "
                f"t {tl:.2f}/{L.length:.2f} | truth: {'pipe ' + str(g.id) if g else 'NONE'}, fitting "
                f"{np.linalg.norm(objects - mid, axis=1).min():.3f} m",
                flush=True,
            )
        for o in seg.objects:
            print(
                f"  object at {np.round(R @ o.position + t, 2)} conf {o.configuration} pipes {o.pipes} "
                f"err {np.linalg.norm(objects - (R @ o.position + t), axis=1).min():.3f}"
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
