"""Where a pipeline valve's points go, stage by stage, in each cloud that holds it (issue 22: "every
valve mapped once"; stop 41, seed 15's valve 1).

    python experiments/laser/valve_stages.py --seed 15 [--valve 1] [--min-points 50] [--config JSON]

Simulates pipeline ``--seed`` and records, for every cloud, which of its pixels hit which fitting (the
simulator's own ray labels). Each cloud with at least ``--min-points`` valid points on a valve is
segmented with this checkout's front-end ("up" from the true pose), and the valve's raw points are
followed through the stages: kept by the preprocessing (range crop, outliers), kept as structure by the
plane removal, on the ground model, taken as inliers by each pipe segment (its length, radius, whether
it is reported, how far its nearer end stops from the valve), and in each object segment near it (its
configuration, the error of its position). The valve's place in the view: range, and its angles from
the sensor's axis (the stereo frame is ±10° × ±7.5°). ``--config``: front-end overrides (JSON; ``"pipes":
{"nominal": true}`` sets ``pipes.nominal_radii`` to the seed's true pipe radii, as ``--nominal-radii``).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

VALVES = ("Ball-Valve", "Butterfly-Valve", "3-Way-Ball-Valve")
FRAME_DEG = (10.0, 7.5)  # the pipeline stereo's half field of view, across and along the image (deg)


def record_labels(store: list) -> None:
    """Make the pipeline scene append (pixel indices, fitting ids) of the rays that hit a fitting to
    ``store``, one entry per stereo cloud (the simulator casts each cloud's rays once with normals)."""
    from semslam.sim import pipeline_scene

    cast = pipeline_scene.PipelineScene.cast_with_normals

    def recording(self, origins, dirs):
        out = cast(self, origins, dirs)
        kind, ident = out[1], out[2]
        hit = np.flatnonzero(kind == pipeline_scene.OBJECT)
        store.append((hit, ident[hit].copy()))
        return out

    pipeline_scene.PipelineScene.cast_with_normals = recording


def stages(seg, valve_px: np.ndarray, x: np.ndarray, cfg) -> dict:
    """The valve's raw points (``valve_px``, finite) through the stages of ``seg``; ``x`` the valve in {S}."""
    r2v = seg.pre.raw_to_voxel[valve_px]
    r2s = seg.raw_to_structure[valve_px]
    vox = np.unique(r2s[r2s >= 0])
    out = {
        "raw": len(valve_px),
        "pre": int((r2v >= 0).sum()),
        "struct": int((r2s >= 0).sum()),
        "vox": len(vox),
        "ground": int(seg.on_ground[vox].sum()) if seg.on_ground is not None and len(vox) else 0,
    }
    pipes = []
    taken = np.zeros(len(seg.structure_points), bool)
    for k, p in enumerate(seg.pipes):
        n = int(np.isin(vox, p.inliers).sum())
        end = min(np.linalg.norm(p.p - x), np.linalg.norm(p.q - x))
        if n or end <= 0.3:
            pipes.append(
                f"#{k} {p.length:.2f}m r{p.radius * 1000:.0f}{'h' if p.radius_held else ''} "
                f"{'rep' if p.reported(seg.pipe_config) else 'unrep'} end {end:.2f} eats {n}"
            )
        taken[p.inliers] = True
    out["pipe_eaten"] = int(taken[vox].sum()) if len(vox) else 0
    out["pipes"] = pipes
    objs = []
    for o in seg.objects:
        err = float(np.linalg.norm(o.position - x))
        n = int(np.isin(vox, o.indices).sum())
        if err <= 0.3 or n:
            objs.append(f"cfg{o.configuration} err {err:.3f} pts {len(o.indices)} valve {n}")
    out["objects"] = objs
    return out


def main(argv=None) -> int:
    from valve_trace import valve_mission

    from frontends.laser.frontend import segment_scan
    from semslam.mission.measurements import PointCloud

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=15)
    ap.add_argument("--valve", type=int, default=None)
    ap.add_argument("--min-points", type=int, default=50)
    ap.add_argument("--config", default="{}", help="front-end overrides (JSON)")
    args = ap.parse_args(argv)
    labels: list = []
    record_labels(labels)
    mission, cfg, valves, T_BS, poses, stamps = valve_mission(args.seed, args.config, args.valve)
    meta = mission.metadata
    clouds = list(mission.of_type(PointCloud))
    labels = labels[-len(clouds) :]  # the stereo clouds' casts come last, one per cloud
    t0 = clouds[0].stamp
    truth = {s["stamp"]: s for s in meta.extras["scans"]}
    attached = {o["id"]: o["pipes"] for o in meta.extras["scene"]["layout"]["objects"]}
    totals: dict[int, list] = {v: [] for v in valves}
    for m, (hit, ident) in zip(clouds, labels):
        finite = np.isfinite(np.asarray(m.points)).all(axis=1)
        px = {v: hit[(ident == v) & finite[hit]] for v in valves}
        show = [v for v in valves if len(px[v]) >= args.min_points]
        if not show:
            continue
        T = poses[int(stamps[np.argmin(np.abs(stamps - m.stamp))])] @ T_BS
        R, t = T[:3, :3], T[:3, 3]
        seg = segment_scan(m.points, cfg, up=R.T @ np.array([0.0, 0.0, -1.0]), rgb=m.rgb)
        for v in show:
            x = R.T @ (np.asarray(valves[v].position) - t)
            s = stages(seg, px[v], x, cfg)
            ax, ay = np.degrees(np.arctan2(x[0], x[2])), np.degrees(np.arctan2(x[1], x[2]))
            s["in_frame"] = abs(ax) <= FRAME_DEG[0] and abs(ay) <= FRAME_DEG[1]
            totals[v].append(s)
            seen = truth.get(m.stamp, {}).get("pipe_visible_m", {})
            s["truth_pipes"] = {k: seen.get(str(k), 0.0) for k in attached.get(v, ())}
            print(
                f"v{v} t={(m.stamp - t0) * 1e-9 + 0.5:6.1f} range {np.linalg.norm(x):.2f} ang ({ax:+5.1f},{ay:+5.1f}) "
                f"raw {s['raw']} pre {s['pre']} struct {s['struct']} vox {s['vox']} ground {s['ground']} "
                f"pipe {s['pipe_eaten']} | seen pipes {s['truth_pipes']} | pipes {s['pipes'] or '-'} | objects {s['objects'] or '-'}",
                flush=True,
            )
    for v, rows in totals.items():
        good = [any(float(o.split("err ")[1].split()[0]) <= 0.1 for o in r["objects"]) for r in rows]
        inside = [r["in_frame"] for r in rows]
        print(
            f"valve {v} ({valves[v].cls}): clouds {len(rows)} (its centre in the frame {sum(inside)}), with a view "
            f"within 0.1 m {sum(good)} (centre in the frame {sum(g and i for g, i in zip(good, inside))})"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
