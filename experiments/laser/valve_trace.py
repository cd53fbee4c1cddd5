"""Why a valve of the pipeline scenario is not mapped (issue 22: "every valve mapped once"): the object
views the laser front-end makes of it, cloud by cloud.

    python experiments/laser/valve_trace.py --seed 9 [--valve 1] [--min-points 200] [--segments] [--config JSON] [--any-class]

Simulates pipeline ``--seed`` and segments every cloud that holds at least ``--min-points`` valid
points on a valve (``--valve``: its id; default every valve) with this checkout's front-end ("up" from
the true pose). Per cloud: the valve's points, its range, the pipe segments whose fitted end lies
within 0.3 m of it (their length and how far their end stops from the valve), and the object views
within 0.2 m of it (configuration, error). Prints one line per cloud and the count of clouds with a
view. With ``--segments``, also every segment the pipe stage cut (accepted or not) whose axis passes
within 0.15 m of the valve, with the seabed test that rejected it (``small_pipe_trace.seabed_verdict``),
its colour contrast and the RANSAC round (cylinder) it was cut from ("h": its radius a nominal one held).
``--config``: front-end overrides (JSON, the ``frontends.laser`` section; ``"nominal": true`` in its
``pipes`` section sets ``pipes.nominal_radii`` to the seed's true pipe radii).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

VALVES = ("Ball-Valve", "Butterfly-Valve", "3-Way-Ball-Valve")


def record_segments(cut: list) -> None:
    """Make the pipe stage append (round, pipe, seabed verdict, colour contrast) to ``cut`` for every
    segment it cuts from a refined cylinder (the round: the cylinder's count in the scan)."""
    from small_pipe_trace import seabed_verdict

    import frontends.laser.pipe_shape as pipe_shape
    import frontends.laser.pipes as pipes_mod

    cut_into = pipes_mod._cut_into_segments
    state = {"round": 0, "seabed": None}

    def recording_cut(*a, **k):
        state["round"] += 1
        out = cut_into(*a, **k)
        for pipe in out:
            cut.append([state["round"], pipe, "untested", None])
        return out

    accept = pipe_shape.Seabed.accept

    def recording_accept(self, pipe, *a, **k):
        ok = accept(self, pipe, *a, **k)
        for row in cut:
            if row[1] is pipe:
                row[2] = "ok" if ok else seabed_verdict(pipe, self)
                if self._rgb is not None:
                    row[3] = self._contrast(pipe)
        return ok

    pipes_mod._cut_into_segments = recording_cut
    pipe_shape.Seabed.accept = recording_accept


def record_lone_ends(log: list) -> None:
    """Make ``segment_objects``' lone-end tests append (test, end, value) to ``log`` (and its in-line test
    ``gap_is_pipe``: (test, the site's centre, value))."""
    import frontends.laser.objects as objects_mod
    from frontends.laser.pipes import Rays

    def wrap(name, fn):
        def recording(*a, **k):
            value = fn(*a, **k)
            log.append((name, np.asarray(a[1], float).copy(), value))
            return value

        return recording

    for name in ("own_points", "pipe_continues", "stands_over", "sleeve_over"):
        setattr(objects_mod, name, wrap(name, getattr(objects_mod, name)))
    gap_is_pipe = objects_mod.gap_is_pipe

    def recording_gap_is_pipe(points, crop, site, *a, **k):
        value = gap_is_pipe(points, crop, site, *a, **k)
        log.append(("gap_is_pipe", np.asarray(site.center, float).copy(), value))
        return value

    objects_mod.gap_is_pipe = recording_gap_is_pipe
    seen_at = Rays.seen_at

    def recording_seen_at(self, point, radius, min_rays=3):
        value = seen_at(self, point, radius, min_rays)
        log.append(("seen_at", np.asarray(point, float).copy(), value))
        return value

    Rays.seen_at = recording_seen_at


def lone_end_tests(log: list, x: np.ndarray, reach: float = 0.3) -> list[str]:
    """The recorded tests whose point (a pipe end, or the place seen) lies within ``reach`` of ``x``."""
    return [
        f"{name} {value}@{np.linalg.norm(at - x):.2f}" for name, at, value in log if np.linalg.norm(at - x) <= reach
    ]


def near_segments(cut: list, x: np.ndarray, reach: float = 0.15) -> list[str]:
    """The recorded segments whose axis (between its ends) passes within ``reach`` of ``x``."""
    out = []
    for rnd, pipe, verdict, contrast in cut:
        t = float(np.clip((x - pipe.p) @ pipe.axis, 0.0, pipe.length))
        d = float(np.linalg.norm(pipe.p + t * pipe.axis - x))
        if d <= reach:
            end = min(np.linalg.norm(pipe.p - x), np.linalg.norm(pipe.q - x))
            c = "-" if contrast is None else f"{contrast:.0f}"
            out.append(
                f"r{rnd} {pipe.length:.2f} m r {pipe.radius * 1000:.0f}{'h' if pipe.radius_held else ''} mm axis {d:.2f} end {end:.2f} {verdict} c {c}"
            )
    return out


def valve_mission(seed: int, config: str, valve: int | None, any_class: bool = False):
    """Pipeline ``seed`` simulated; the front-end's configuration from the JSON ``config`` (``"pipes":
    {"nominal": true}``: the seed's true radii as ``pipes.nominal_radii``); its valves (``valve``: that
    one only; ``any_class``: every fitting, sockets and tees too), printed; the stereo's T_BS; the true poses T_WB by stamp and their sorted stamps."""
    from frontends.laser.config import LaserConfig
    from semslam.mission.measurements import GroundTruthPose
    from semslam.sim.pipeline_config import PipelineSimConfig
    from semslam.sim.pipeline_mission import simulate_pipeline

    mission = simulate_pipeline(PipelineSimConfig(seed=seed))
    meta = mission.metadata
    gt = meta.ground_truth
    over = json.loads(config)
    if over.get("pipes", {}).pop("nominal", False):
        over["pipes"]["nominal_radii"] = sorted({round(float(p.radius), 4) for p in gt.pipes})
    cfg = LaserConfig.model_validate(over)
    valves = {o.id: o for o in gt.objects if (any_class or o.cls in VALVES) and (valve is None or o.id == valve)}
    print("valves:", {k: (o.cls, np.round(o.position, 2).tolist()) for k, o in valves.items()}, flush=True)
    T_BS = next(s for s in meta.sensors.values() if s.kind == "laser").T_BS
    poses = {m.stamp: m.matrix() for m in mission.of_type(GroundTruthPose)}
    return mission, cfg, valves, T_BS, poses, np.array(sorted(poses))


def main(argv=None) -> int:
    from frontends.laser.frontend import segment_scan
    from semslam.mission.measurements import PointCloud

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=9)
    ap.add_argument("--valve", type=int, default=None)
    ap.add_argument("--min-points", type=int, default=200)
    ap.add_argument("--segments", action="store_true")
    ap.add_argument("--lone-ends", action="store_true")
    ap.add_argument("--config", default="{}", help="front-end overrides (JSON)")
    ap.add_argument("--any-class", action="store_true", help="every fitting (sockets, tees), not valves only")
    args = ap.parse_args(argv)
    cut: list = []  # (round, pipe, verdict, contrast) of the current cloud
    if args.segments:
        record_segments(cut)
    tests: list = []  # (test, point, value) of the current cloud's lone ends
    if args.lone_ends:
        record_lone_ends(tests)
    mission, cfg, valves, T_BS, poses, stamps = valve_mission(args.seed, args.config, args.valve, args.any_class)
    meta = mission.metadata
    points = {s["stamp"]: {int(k): v for k, v in s["object_points"].items()} for s in meta.extras["scans"]}
    with_view: dict[int, int] = {}
    clouds: dict[int, int] = {}
    for m in mission.of_type(PointCloud):
        show = [v for v in valves if points.get(m.stamp, {}).get(v, 0) >= args.min_points]
        if not show:
            continue
        T = poses[int(stamps[np.argmin(np.abs(stamps - m.stamp))])] @ T_BS
        R, t = T[:3, :3], T[:3, 3]
        cut.clear()
        tests.clear()
        seg = segment_scan(m.points, cfg, up=R.T @ np.array([0.0, 0.0, -1.0]), rgb=m.rgb)
        for v in show:
            x = R.T @ (np.asarray(valves[v].position) - t)  # the valve in {S}
            ends = []
            for pipe in seg.pipes:
                d = min(np.linalg.norm(pipe.p - x), np.linalg.norm(pipe.q - x))
                if d <= 0.3:
                    ends.append(f"{pipe.length:.2f} m, end {d:.2f} m off")
            views = [
                f"config {ob.configuration} err {np.linalg.norm(ob.position - x):.3f}"
                for ob in seg.objects
                if np.linalg.norm(ob.position - x) <= 0.2
            ]
            if args.segments:
                print(f"  valve {v} segments: {near_segments(cut, x)}")
            if args.lone_ends:
                print(f"  valve {v} lone-end tests: {lone_end_tests(tests, x)}")
            clouds[v] = clouds.get(v, 0) + 1
            with_view[v] = with_view.get(v, 0) + bool(views)
            print(
                f"valve {v} t={m.stamp} points {points[m.stamp][v]} range {np.linalg.norm(x):.2f} m | pipes ending near: "
                f"{ends or '-'} | views: {views or '-'}",
                flush=True,
            )
    for v in valves:
        print(f"valve {v} ({valves[v].cls}): clouds {clouds.get(v, 0)}, with a view {with_view.get(v, 0)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
