"""Issue 22's acceptance numbers: the laser front-end on the tank (no worse than before) and on the
simulated pipeline on a natural seabed (stereo noise).

``tank``: for each seed, the tank mission is simulated in memory and run through the laser
front-end and dr / ekf / graph as ``semslam demo`` runs them (``semslam.demo.demo_config``); prints
and stores the graph's objects / pipes mapped against the ground truth seen, duplicates, landmark
and object median errors, ATE.

``pipeline``: for each seed, the pipeline mission (``semslam.sim.pipeline_mission``) is simulated in
memory; every scan goes through the laser front-end alone and is scored against the scan's ground
truth (which pipe was seen, over how much length): pipe line observations in the scans where at
least 0.2 m of pipe is visible, false pipe observations per scan, radius error; then the whole
mission runs through the graph (``semslam.compare.run_comparison``) and the mapped pipeline is
scored along its length (the distance of points along the mapped pipes to the true axes, and
along the true axes' seen parts to the mapped pipes) and valves mapped (each exactly once).

    python experiments/laser_real_eval.py tank --seeds 0-10 [--ekf] [--json experiments/out/laser_real_tank.json]
    python experiments/laser_real_eval.py pipeline --seeds 100-102 [--json ...] [--scans-only]

The tank part imports only what existed before issue 22, so that ``PYTHONPATH=<old checkout>``
runs it on the code before the change (the baseline).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import time
from pathlib import Path

import numpy as np

TANK_KEYS = (
    "n_objects",
    "n_pipes",
    "landmark_duplicates",
    "landmark_spurious",
    "landmark_median_error_m",
    "object_median_error_m",
    "pipe_median_error_m",
    "ate_rmse_m",
)


def parse_seeds(text: str) -> list[int]:
    """ "0,10-19" → [0, 10, 11, ..., 19]."""
    out: list[int] = []
    for part in text.split(","):
        a, _, b = part.partition("-")
        out += list(range(int(a), int(b) + 1)) if b else [int(a)]
    return out


def tank_seed(seed: int, overrides: dict | None = None, estimators: tuple[str, ...] = ("graph",)) -> dict:
    """The demo's comparison on tank mission ``seed`` as ``semslam study --scenario tank`` draws it
    (every aspect varied; seed 0 the default mission), laser front-end ``overrides`` merged into the
    demo's section: the ``estimators``' map numbers."""
    from semslam.compare import run_comparison
    from semslam.demo import demo_config
    from semslam.sim.scenarios import resolve_config
    from semslam.sim.simulate import simulate_tank
    from semslam.sim.vary import ASPECTS

    t0 = time.perf_counter()
    mission = simulate_tank(resolve_config("tank", seed, ASPECTS))
    cfg = demo_config()
    if overrides:
        laser = cfg.frontends.get("laser", {})
        merged = {**laser, **{k: {**laser.get(k, {}), **v} for k, v in overrides.items()}}
        cfg = cfg.model_copy(update={"frontends": {**cfg.frontends, "laser": merged}})
    _, metrics = run_comparison(mission, cfg, ["laser"], estimators=("dr", *estimators), frontend_workers=1)
    est = metrics["estimators"]
    out = {n: {k: est[n].get(k) for k in TANK_KEYS} for n in estimators}
    out["gt_objects"] = metrics["mission"]["gt_objects"]
    out["gt_pipes"] = metrics["mission"]["gt_pipes"]
    out["sem_f1"] = (metrics.get("recognition") or {}).get("SEM", {}).get("f1")
    out["seconds"] = round(time.perf_counter() - t0, 1)
    return out


def tank_line(seed: int, r: dict) -> str:
    g = r["graph"]
    return (
        f"tank seed {seed}: graph objects {g['n_objects']}/{r['gt_objects']} pipes {g['n_pipes']}/{r['gt_pipes']} "
        f"duplicates {g['landmark_duplicates']} spurious {g['landmark_spurious']} "
        f"landmark median {g['landmark_median_error_m']:.4f} m object median {g['object_median_error_m']:.4f} m "
        f"ATE {g['ate_rmse_m']:.4f} "
        + (f"| ekf objects {r['ekf']['n_objects']} dup {r['ekf']['landmark_duplicates']} " if "ekf" in r else "")
        + f"| SEM F1 {r['sem_f1']} ({r['seconds']} s)"
    )


VALVES = ("Ball-Valve", "Butterfly-Valve", "3-Way-Ball-Valve")
VALVE_SEEN_POINTS = 500  # a valve counts as seen when some cloud holds this many valid points on it
VALVE_GATE_M = 0.2  # a mapped object within this of a valve is that valve's
PIPE_GATE_M = 0.05  # "within 5 cm of truth along its length"


def _segment_distance(P: np.ndarray, truth_pipes) -> np.ndarray:
    """Distance (m) of each point to the nearest true pipe axis segment."""
    out = np.full(len(P), np.inf)
    for g in truth_pipes:
        gp, gq = np.asarray(g.p, float), np.asarray(g.q, float)
        L = np.linalg.norm(gq - gp)
        a = (gq - gp) / L
        t = np.clip((P - gp) @ a, 0.0, L)
        out = np.minimum(out, np.linalg.norm(P - gp - np.outer(t, a), axis=1))
    return out


def map_scores(landmarks, gt, scans: list[dict]) -> dict:
    """The graph's pipeline map against the truth: the distance to the true axes of points every
    centimetre along the mapped pipes (median, 95th percentile, maximum, share within 5 cm), the
    share of the seen true pipe length (the spans of the clouds that showed >= 0.2 m of a pipe)
    with a mapped pipe within 5 cm, the pipes mapped; each valve seen (≥ 500 points in a
    cloud) mapped by how many objects (within 0.2 m), the same for the other fittings (sockets,
    tees), and the objects near no fitting."""
    pipes = [lm for lm in landmarks if lm.kind == "pipe" and lm.p is not None]
    samples = [
        lm.p + np.outer(np.arange(0, 1.0001, 0.01 / max(np.linalg.norm(lm.q - lm.p), 0.01)), lm.q - lm.p)
        for lm in pipes
    ]
    along = np.concatenate(samples) if samples else np.zeros((0, 3))
    d = _segment_distance(along, gt.pipes) if len(along) else np.zeros(0)
    # coverage: every cm of each true pipe that some cloud saw (within the spans of the clouds that
    # showed >= 0.2 m of it), and of those the ones with a mapped pipe within 5 cm
    seen: dict[int, list] = {}
    for s in scans:
        for k, v in s["pipe_visible_m"].items():
            if v >= 0.2:
                seen.setdefault(int(k), []).append(s["pipe_seen_span_m"][k])
    covered, total = 0, 0
    per_pipe: dict[int, dict] = {}
    mapped_pts = [(np.asarray(lm.p), np.asarray(lm.q)) for lm in pipes]
    for g in gt.pipes:
        if g.id not in seen:
            continue
        gp, gq = np.asarray(g.p, float), np.asarray(g.q, float)
        s_along = np.arange(0.0, np.linalg.norm(gq - gp), 0.01)
        in_view = np.zeros(len(s_along), bool)
        for a, b in seen[g.id]:
            in_view |= (s_along >= a) & (s_along <= b)
        pts = gp + np.outer(s_along[in_view], (gq - gp) / np.linalg.norm(gq - gp))
        near = np.zeros(len(pts), bool)
        for p, q in mapped_pts:
            L = np.linalg.norm(q - p)
            a = (q - p) / L
            t = (pts - p) @ a
            inside = (t >= 0) & (t <= L)
            near |= inside & (np.linalg.norm(pts - p - np.outer(t, a), axis=1) <= PIPE_GATE_M)
        covered += int(near.sum())
        total += len(pts)
        per_pipe[g.id] = {
            "length_m": round(float(np.linalg.norm(gq - gp)), 3),
            "seen_m": round(0.01 * len(pts), 2),
            "covered": round(float(near.mean()), 3) if len(pts) else None,
        }
    objects = np.array([lm.position for lm in landmarks if lm.kind == "object"]).reshape(-1, 3)
    points = {}
    for s in scans:
        for k, v in s["object_points"].items():
            points[int(k)] = max(points.get(int(k), 0), v)
    valves = {}
    for o in gt.objects:
        if o.cls in VALVES and points.get(o.id, 0) >= VALVE_SEEN_POINTS:
            valves[o.id] = int((np.linalg.norm(objects - np.asarray(o.position), axis=1) <= VALVE_GATE_M).sum())
    others = {}  # the other fittings (sockets, tees, flanges...), by class and id, as the valves
    for o in gt.objects:
        if o.cls not in VALVES and points.get(o.id, 0) >= VALVE_SEEN_POINTS:
            n = int((np.linalg.norm(objects - np.asarray(o.position), axis=1) <= VALVE_GATE_M).sum())
            others[f"{o.cls} {o.id}"] = n
    fittings = np.array([o.position for o in gt.objects]).reshape(-1, 3)
    stray = [
        lm.id
        for lm in landmarks
        if lm.kind == "object" and (not len(fittings) or np.linalg.norm(fittings - lm.position, axis=1).min() > 0.3)
    ]
    return {
        "pipes_mapped": len(pipes),
        "pipe_error_median_m": float(np.median(d)) if len(d) else None,
        "pipe_error_p95_m": float(np.percentile(d, 95)) if len(d) else None,
        "pipe_error_max_m": float(d.max()) if len(d) else None,
        "pipe_within_5cm_share": float((d <= PIPE_GATE_M).mean()) if len(d) else None,
        "seen_pipe_length_covered": covered / total if total else None,
        "seen_pipes": per_pipe,
        "mapped_pipes": [
            {
                "length_m": round(float(np.linalg.norm(lm.q - lm.p)), 3),
                "error_median_m": round(float(np.median(e)), 3),
                "error_max_m": round(float(e.max()), 3),
            }
            for lm, e in zip(
                pipes, np.split(d, np.cumsum([len(x) for x in samples])[:-1]) if pipes else [], strict=True
            )
        ],
        "valves_seen": len(valves),
        "valves_mapped_once": sum(v == 1 for v in valves.values()),
        "valve_counts": valves,
        "other_fittings_seen": len(others),
        "other_fittings_mapped_once": sum(v == 1 for v in others.values()),
        "other_fitting_counts": others,
        "objects_mapped": len(objects),
        "objects_far_from_any_fitting": len(stray),
    }


def offsets_split(landmarks, gt, trajectory, truth_positions: dict) -> dict:
    """What the mapped pipes' error is made of: the median signed offset (m) of the points along them
    from their nearest true axis, vertical (down +) and sideways (horizontal, across the axis), and
    the graph's own position error at its poses (median vertical, median horizontal): a map offset
    that the trajectory shares is the estimate's drift, one it does not is the observations'."""
    pipes = [lm for lm in landmarks if lm.kind == "pipe" and lm.p is not None]
    vert, side = [], []
    for lm in pipes:
        for x in lm.p + np.outer(np.linspace(0.0, 1.0, 21), lm.q - lm.p):
            best = None
            for g in gt.pipes:
                gp, gq = np.asarray(g.p, float), np.asarray(g.q, float)
                L = np.linalg.norm(gq - gp)
                a = (gq - gp) / L
                v = x - gp - np.clip((x - gp) @ a, 0.0, L) * a
                if best is None or np.linalg.norm(v) < np.linalg.norm(best[0]):
                    best = (v, a)
            v, a = best
            across = np.cross(a, [0.0, 0.0, 1.0])
            vert.append(v[2])
            side.append(v @ across / max(np.linalg.norm(across), 1e-9))
    stamps = np.array(sorted(truth_positions))
    k = np.searchsorted(stamps, trajectory.stamps).clip(0, len(stamps) - 1)
    err = trajectory.positions - np.array([truth_positions[int(s)] for s in stamps[k]])
    return {
        "map_offset_vertical_median_m": float(np.median(vert)) if vert else None,
        "map_offset_sideways_abs_median_m": float(np.median(np.abs(side))) if side else None,
        "pose_error_vertical_median_m": float(np.median(err[:, 2])),
        "pose_error_horizontal_median_m": float(np.median(np.linalg.norm(err[:, :2], axis=1))),
    }


def valves_in_frame(meta, poses: dict, T_BS: np.ndarray) -> dict[int, int]:
    """Per valve seen (as :func:`map_scores` counts them): the clouds whose frame held the valve's
    centre (its direction from the camera within the simulated stereo's field of view, true poses).
    A view-based front-end places an object from what its clouds show: a valve whose centre no
    cloud framed is seen only in part, at the view's edge (pipeline seed 15's valve 1, stop 41)."""
    half = np.radians(np.asarray(meta.extras["simulator"]["config"]["stereo"]["fov_deg"], float)) / 2.0
    stamps = np.array(sorted(poses))
    points: dict[int, int] = {}
    for s in meta.extras["scans"]:
        for k, v in s["object_points"].items():
            points[int(k)] = max(points.get(int(k), 0), v)
    valves = {o.id: np.asarray(o.position, float) for o in meta.ground_truth.objects if o.cls in VALVES}
    out = {k: 0 for k in valves if points.get(k, 0) >= VALVE_SEEN_POINTS}
    for s in meta.extras["scans"]:
        T = poses[int(stamps[np.argmin(np.abs(stamps - s["stamp"]))])].matrix() @ T_BS
        for k in out:
            if int(s["object_points"].get(str(k), 0)) == 0:
                continue
            x = T[:3, :3].T @ (valves[k] - T[:3, 3])
            if x[2] > 0 and np.all(np.abs(np.arctan2(x[:2], x[2])) <= half):
                out[k] += 1
    return out


def relative_to_trajectory(landmarks, gt, trajectory, truth_positions: dict) -> dict:
    """The mapped pipes' error once the graph's own position error is taken out: every mapped pipe
    shifted by minus the median (per axis) of the graph's position error at its poses, then scored
    as :func:`map_scores` scores them (median, 95th percentile, share within 5 cm). A map within 5 cm
    this way but not unshifted is off by the trajectory's offset (drift no pipe can tell), not by
    its observations."""
    stamps = np.array(sorted(truth_positions))
    k = np.searchsorted(stamps, trajectory.stamps).clip(0, len(stamps) - 1)
    offset = np.median(trajectory.positions - np.array([truth_positions[int(s)] for s in stamps[k]]), axis=0)
    pipes = [lm for lm in landmarks if lm.kind == "pipe" and lm.p is not None]
    along = [
        lm.p - offset + np.outer(np.arange(0, 1.0001, 0.01 / max(np.linalg.norm(lm.q - lm.p), 0.01)), lm.q - lm.p)
        for lm in pipes
    ]
    d = _segment_distance(np.concatenate(along), gt.pipes) if along else np.zeros(0)
    return {
        "pose_error_median_vector_m": [round(float(x), 4) for x in offset],
        "pipe_error_median_m_pose_offset_removed": float(np.median(d)) if len(d) else None,
        "pipe_error_p95_m_pose_offset_removed": float(np.percentile(d, 95)) if len(d) else None,
        "pipe_within_5cm_share_pose_offset_removed": float((d <= PIPE_GATE_M).mean()) if len(d) else None,
    }


def pipeline_seed(
    seed: int, overrides: dict, scans_only: bool, dump: Path | None = None, nominal_radii: bool = False
) -> dict:
    """The pipeline mission of ``seed``: per-scan scores of the laser front-end's pipe observations
    and (unless ``scans_only``) the graph's map against the truth. ``nominal_radii``: the front-end
    is given the seed's true pipe radii as ``pipes.nominal_radii`` (what an inspection knows)."""
    from frontends.laser.evaluation import score_pipe_observations
    from semslam.compare import run_comparison
    from semslam.config import SemslamConfig
    from semslam.mission.measurements import GroundTruthPose
    from semslam.observations import LineObservation
    from semslam.sim.pipeline_config import PipelineSimConfig
    from semslam.sim.pipeline_mission import simulate_pipeline

    t0 = time.perf_counter()
    mission = simulate_pipeline(PipelineSimConfig(seed=seed))
    meta = mission.metadata
    if nominal_radii:
        radii = sorted({round(float(p.radius), 4) for p in meta.ground_truth.pipes})
        overrides = {**overrides, "pipes": {**overrides.get("pipes", {}), "nominal_radii": radii}}
    cfg = SemslamConfig(frontends={"laser": overrides})
    estimators = ("dr",) if scans_only else ("dr", "ekf", "graph")
    result, metrics = run_comparison(mission, cfg, ["laser"], estimators=estimators)
    poses = {m.stamp: m for m in mission.of_type(GroundTruthPose)}
    stamps = np.array(sorted(poses))
    sensor = next(s for s in meta.sensors.values() if s.kind == "laser")
    lines: dict[int, list] = {}
    for rec in result.observations:
        if isinstance(rec.observation, LineObservation):
            lines.setdefault(rec.stamp, []).append(rec.observation)
    views = []
    for s in meta.extras["scans"]:
        near = stamps[np.argmin(np.abs(stamps - s["stamp"]))]
        T_WS = poses[near].matrix() @ sensor.T_BS
        views.append((T_WS, lines.get(s["stamp"], []), {int(k): v for k, v in s["pipe_visible_m"].items()}))
    out = {"scans": score_pipe_observations(views, meta.ground_truth.pipes)}
    if not scans_only:
        graph = result.results["graph"]
        out["map"] = map_scores(graph.landmarks, meta.ground_truth, meta.extras["scans"])
        truth = {s: np.asarray(m.position, float) for s, m in poses.items()}
        out["map"].update(offsets_split(graph.landmarks, meta.ground_truth, graph.trajectory, truth))
        out["map"].update(relative_to_trajectory(graph.landmarks, meta.ground_truth, graph.trajectory, truth))
        out["map"]["valve_clouds_centre_in_frame"] = valves_in_frame(meta, poses, sensor.T_BS)
        out["map"]["beyond_5cm"] = beyond_5cm(graph, meta.ground_truth, truth)
        g = metrics["estimators"]["graph"]
        out["graph"] = {k: g.get(k) for k in TANK_KEYS}
    if dump is not None:  # the observations, to replay the back-end on them without the front-end
        import pickle

        dump.mkdir(parents=True, exist_ok=True)
        (dump / f"pipeline_{seed}.pkl").write_bytes(pickle.dumps(result.observations))
        light = dump / f"light_{seed}_{LIGHT_KEY}.pkl"  # pipeline_replay.py's cache of the mission
        if not light.exists():
            light.write_bytes(pickle.dumps(light_items(mission)))
    out["laser_s_per_scan"] = result.timing_s.get("frontend:laser", 0.0) / max(len(views), 1)
    out["seconds"] = round(time.perf_counter() - t0, 1)
    return out


# pipeline_replay.light_mission's cache key of the unchanged simulator (no overrides)
LIGHT_KEY = hashlib.sha1(json.dumps({}, sort_keys=True).encode()).hexdigest()[:8]


def light_items(mission) -> tuple:
    """(metadata, measurements with the clouds emptied): what ``pipeline_replay.light_mission`` caches."""
    import dataclasses

    from semslam.mission.measurements import PointCloud

    empty = np.zeros((0, 3), np.float32)
    items = [
        dataclasses.replace(m, points=empty, intensity=None, rgb=None) if isinstance(m, PointCloud) else m
        for m in mission
    ]
    return mission.metadata, items


def beyond_5cm(graph, gt, truth_positions: dict) -> dict:
    """The mapped pipes' length beyond 5 cm of truth by cause (``experiments/laser/beyond_5cm.py``)."""
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parent / "laser"))
    from beyond_5cm import split_beyond

    stamps = np.array(sorted(truth_positions))
    k = np.searchsorted(stamps, graph.trajectory.stamps).clip(0, len(stamps) - 1)
    offset = np.median(graph.trajectory.positions - np.array([truth_positions[int(s)] for s in stamps[k]]), axis=0)
    r = split_beyond(graph.landmarks, gt, offset)
    return {k: r[k] for k in ("mapped_m", "beyond_m", "beyond_by_cause_m")}


def pipeline_line(seed: int, r: dict) -> str:
    s = r["scans"]
    text = (
        f"pipeline seed {seed}: scans {s['scans']}, with >= 0.2 m of pipe {s['scans_pipe_visible']}, detected "
        f"{s['scans_pipe_detected']} ({s['detection_rate']:.2f}), false per scan {s['false_per_scan']:.3f}, radius "
        f"error median {1000 * (s['radius_error_median_m'] or float('nan')):.1f} mm"
    )
    if "map" in r:
        m = r["map"]
        text += (
            f" | map: pipes {m['pipes_mapped']}, error median {m['pipe_error_median_m']:.3f} p95 {m['pipe_error_p95_m']:.3f} "
            f"max {m['pipe_error_max_m']:.3f} m, within 5 cm {m['pipe_within_5cm_share']:.2f}, "
            f"seen length covered {m['seen_pipe_length_covered']:.2f}, valves mapped once {m['valves_mapped_once']}/"
            f"{m['valves_seen']} {m['valve_counts']} (clouds framing each {m['valve_clouds_centre_in_frame']}), "
            f"other fittings mapped once {m['other_fittings_mapped_once']}/{m['other_fittings_seen']} "
            f"{m['other_fitting_counts']}, "
            f"objects {m['objects_mapped']} "
            f"(far from any fitting {m['objects_far_from_any_fitting']}); map offset vertical "
            f"{m['map_offset_vertical_median_m']:.3f} sideways {m['map_offset_sideways_abs_median_m']:.3f} m, pose "
            f"error vertical {m['pose_error_vertical_median_m']:.3f} horizontal {m['pose_error_horizontal_median_m']:.3f} m"
            f" | pose offset (median) {m['pose_error_median_vector_m']} m removed: pipe error median "
            f"{m['pipe_error_median_m_pose_offset_removed']:.3f} p95 {m['pipe_error_p95_m_pose_offset_removed']:.3f} m, "
            f"within 5 cm {m['pipe_within_5cm_share_pose_offset_removed']:.2f}"
            f" | beyond 5 cm {m['beyond_5cm']['beyond_m']} of {m['beyond_5cm']['mapped_m']} m: "
            f"{m['beyond_5cm']['beyond_by_cause_m']}"
        )
    return text + f" ({r['seconds']} s)"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scenario", choices=("tank", "pipeline"))
    ap.add_argument("--seeds", default="0")
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--dump", type=Path, default=None, help="pipeline: pickle each seed's observations here")
    ap.add_argument("--ekf", action="store_true", help="tank: the EKF too (default the graph alone)")
    ap.add_argument("--scans-only", action="store_true", help="pipeline: the per-scan scores only (no graph)")
    ap.add_argument(
        "--no-axis-refit",
        action="store_true",
        help="segments' axes as before the geometric refit (principal direction)",
    )
    ap.add_argument("--config", default="{}", help="laser front-end overrides (JSON, frontends.laser section)")
    ap.add_argument(
        "--nominal-radii", action="store_true", help="pipeline: the seed's true pipe radii as pipes.nominal_radii"
    )
    args = ap.parse_args(argv)
    if args.no_axis_refit:
        from frontends.laser import pipes

        pipes.refine_cylinder = lambda pts, c, a, r, cfg: (c, a, r)
        import semslam.pipeline

        semslam.pipeline.runs_in_process = lambda fe: False  # in this process, where the patch holds
    results = {}
    for seed in parse_seeds(args.seeds):
        if args.scenario == "tank":
            results[seed] = r = tank_seed(seed, json.loads(args.config), ("graph", "ekf") if args.ekf else ("graph",))
            print(tank_line(seed, r) if all(v is not None for v in r["graph"].values()) else r, flush=True)
        else:
            results[seed] = r = pipeline_seed(
                seed, json.loads(args.config), args.scans_only, args.dump, args.nominal_radii
            )
            print(pipeline_line(seed, r), flush=True)
        if args.json is not None:  # after each seed: a long run interrupted keeps what it measured
            args.json.parent.mkdir(parents=True, exist_ok=True)
            args.json.write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    np.set_printoptions(precision=4)
    raise SystemExit(main())
