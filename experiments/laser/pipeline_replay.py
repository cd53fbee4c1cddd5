"""Why the graph's pipeline map is off (issue 22): the laser observations that
``experiments/laser_real_eval.py pipeline --dump DIR`` recorded, fed again to the graph on the same
mission, simulated again with optional changes (``--sim``, e.g. no AHRS heading-bias drift) or run
with other estimator settings (``--config``), so that only what is changed differs.

    python experiments/laser/pipeline_replay.py --seeds 6 --dump DIR [--sim JSON] [--config JSON]

Prints the map scores of ``laser_real_eval.py`` and where the error lies: per mapped pipe its length,
the true pipe it lies on, its median signed offset across the true axis (horizontal, and vertical),
the stamp of its first view and the graph's pose error across and along the line at that stamp; and
the graph's pose error across the line along the mission (by tenths of the mission's time).
"""

from __future__ import annotations

import argparse
import json
import pickle
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(HERE.parent), str(HERE.parent / "estimators")]

from laser_real_eval import map_scores, offsets_split, parse_seeds  # noqa: E402
from replay_study import RecordedFrontend  # noqa: E402


def light_mission(seed: int, sim: dict, cache: Path):
    """The pipeline mission of ``seed`` (simulator overrides ``sim``) with its clouds emptied (the
    observations are recorded), cached in ``cache``: a replay then costs the graph's time alone."""
    import dataclasses
    import hashlib

    from semslam.mission.measurements import PointCloud
    from semslam.mission.mission import Mission
    from semslam.sim.pipeline_config import PipelineSimConfig
    from semslam.sim.pipeline_mission import simulate_pipeline
    from semslam.sim.vary import merge_into

    key = hashlib.sha1(json.dumps(sim, sort_keys=True).encode()).hexdigest()[:8]
    path = cache / f"light_{seed}_{key}.pkl"
    if path.exists():
        meta, items = pickle.loads(path.read_bytes())
        return Mission.from_measurements(meta, items)
    sim_cfg = PipelineSimConfig.model_validate(merge_into(PipelineSimConfig(seed=seed).model_dump(), sim))
    mission = simulate_pipeline(sim_cfg)
    empty = np.zeros((0, 3), np.float32)
    items = [
        dataclasses.replace(m, points=empty, intensity=None, rgb=None) if isinstance(m, PointCloud) else m
        for m in mission
    ]
    path.write_bytes(pickle.dumps((mission.metadata, items)))
    return Mission.from_measurements(mission.metadata, items)


def true_poses(mission):
    """A function of a stamp: the true body pose T_WB nearest to it and the laser's pose T_WS then."""
    from semslam.mission.measurements import GroundTruthPose

    poses = {m.stamp: m.matrix() for m in mission.of_type(GroundTruthPose)}
    stamps = np.array(sorted(poses))
    T_BS = next(s for s in mission.metadata.sensors.values() if s.kind == "laser").T_BS

    def at(stamp: int) -> tuple[np.ndarray, np.ndarray]:
        T_WB = poses[int(stamps[np.argmin(np.abs(stamps - stamp))])]
        return T_WB, T_WB @ T_BS

    return at


def true_directions(mission, by_stamp) -> dict:
    """The recorded observations with each line observation on a true pipe turned, about its
    midpoint (placed with the true pose), onto the true pipe's direction: what the map would be with
    the front-end's direction errors removed and everything else kept."""
    import dataclasses

    from frontends.laser.evaluation import matching_pipe
    from semslam.observations import LineObservation

    meta = mission.metadata
    pose_at = true_poses(mission)
    out = {}
    for stamp, obs in by_stamp.items():
        T = pose_at(stamp)[1]
        new = []
        for z in obs:
            g = None
            if isinstance(z, LineObservation):
                P = np.stack([z.p, z.q]) @ T[:3, :3].T + T[:3, 3]
                g = matching_pipe(P[0], P[1], meta.ground_truth.pipes)
            if g is None:
                new.append(z)
                continue
            ga = np.subtract(g.q, g.p) / np.linalg.norm(np.subtract(g.q, g.p))
            ga = ga * np.sign((P[1] - P[0]) @ ga)
            m, half = P.mean(axis=0), 0.5 * np.linalg.norm(P[1] - P[0])
            Q = np.stack([m - half * ga, m + half * ga]) - T[:3, 3]
            Q = Q @ T[:3, :3]  # back into the sensor frame
            new.append(dataclasses.replace(z, p=Q[0], q=Q[1]))
        out[stamp] = new
    return out


def replay(seed: int, dump: Path, sim: dict, config: dict, fix_directions: bool = False, estimator: str = "graph"):
    """The graph (or ``estimator``) on ``seed``'s recorded laser observations: (results by estimator,
    mission, observations by stamp)."""
    from semslam.compare import estimators_input
    from semslam.config import SemslamConfig
    from semslam.estimators import create_estimator
    from semslam.pipeline import run_pipeline

    mission = light_mission(seed, sim, dump)
    cfg = SemslamConfig.model_validate(config)
    by_stamp: dict[int, list] = {}
    for rec in pickle.loads((dump / f"pipeline_{seed}.pkl").read_bytes()):
        by_stamp.setdefault(rec.stamp, []).append(rec.observation)
    if fix_directions:
        by_stamp = true_directions(mission, by_stamp)
    fes = [RecordedFrontend("laser", by_stamp, None)]
    ests = [create_estimator(n, mission.metadata, cfg) for n in ("dr", estimator)]
    result = run_pipeline(estimators_input(mission, cfg), ests, fes, view_estimator="graph", frontend_process=False)
    return result.results, mission, by_stamp


def line_frame(gt) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The main line's start, unit direction and horizontal unit across it: the direction that holds
    most of the true pipes' length (the main line is straight; a branch can be its longest single
    pipe: seed 19), from the start of the longest pipe along it."""
    d = [np.subtract(g.q, g.p) for g in gt.pipes]
    w, V = np.linalg.eigh(sum(np.outer(v, v) / np.linalg.norm(v) for v in d))
    g = max(
        (g for g, v in zip(gt.pipes, d) if abs(v @ V[:, -1]) >= np.cos(np.radians(10)) * np.linalg.norm(v)),
        key=lambda g: np.linalg.norm(np.subtract(g.q, g.p)),
    )
    p, q = np.asarray(g.p, float), np.asarray(g.q, float)
    a = (q - p) / np.linalg.norm(q - p)
    across = np.cross([0.0, 0.0, 1.0], a)
    return p, a, across / np.linalg.norm(across)


def first_views(by_stamp: dict, graph, truth_T: dict, T_BS: np.ndarray) -> dict[int, int]:
    """Each mapped pipe's first view stamp: the earliest line observation that, placed with the true
    pose, lies within 5 cm of the mapped pipe's axis and 10 deg of its direction (approximate: the
    map is off by up to a few cm)."""
    from semslam.observations import LineObservation

    stamps = np.array(sorted(truth_T))
    out: dict[int, int] = {}
    pipes = [lm for lm in graph.landmarks if lm.kind == "pipe" and lm.p is not None]
    for s in sorted(by_stamp):
        T = truth_T[int(stamps[np.argmin(np.abs(stamps - s))])] @ T_BS
        for z in by_stamp[s]:
            if not isinstance(z, LineObservation):
                continue
            m = 0.5 * (z.p + z.q)
            mid = T[:3, :3] @ m + T[:3, 3]
            u = T[:3, :3] @ (z.q - z.p)
            u /= np.linalg.norm(u)
            for lm in pipes:
                if lm.id in out:
                    continue
                a = (lm.q - lm.p) / np.linalg.norm(lm.q - lm.p)
                t = (mid - lm.p) @ a
                d = np.linalg.norm(mid - lm.p - t * a)
                inside = -0.2 <= t <= np.linalg.norm(lm.q - lm.p) + 0.2
                if inside and d < 0.08 and abs(u @ a) > np.cos(np.deg2rad(10)):
                    out[lm.id] = int(s)
    return out


def explain(graph, mission, by_stamp, dr=None) -> dict:
    from semslam.mission.measurements import GroundTruthPose

    meta = mission.metadata
    gt = meta.ground_truth
    o, a, across = line_frame(gt)
    truth_T = {m.stamp: m.matrix() for m in mission.of_type(GroundTruthPose)}
    sensor = next(s for s in meta.sensors.values() if s.kind == "laser")
    stamps = np.array(sorted(truth_T))
    traj = graph.trajectory
    k = np.searchsorted(stamps, traj.stamps).clip(0, len(stamps) - 1)
    err = traj.positions - np.array([truth_T[int(s)][:3, 3] for s in stamps[k]])
    err_across, err_along = err @ across, err @ a
    dr_across = None
    if dr is not None:  # dead reckoning's error across the line at the graph's stamps
        dr_pos = dr.trajectory.poses_at(traj.stamps)[1]
        dr_across = (dr_pos - np.array([truth_T[int(s)][:3, 3] for s in stamps[k]])) @ across
    t = (traj.stamps - traj.stamps[0]) * 1e-9
    tenths = [
        {
            "t_s": round(float(t[i]), 1),
            "along_line_m": round(float((traj.positions[i] - o) @ a), 2),
            "across_cm": round(100 * float(err_across[i]), 1),
            "along_cm": round(100 * float(err_along[i]), 1),
            **({"dr_across_cm": round(100 * float(dr_across[i]), 1)} if dr_across is not None else {}),
        }
        for i in np.linspace(0, len(t) - 1, 11).astype(int)
    ]
    first = first_views(by_stamp, graph, truth_T, sensor.T_BS)
    rows = []
    for lm in (lm for lm in graph.landmarks if lm.kind == "pipe" and lm.p is not None):
        xs = lm.p + np.outer(np.linspace(0.0, 1.0, 21), lm.q - lm.p)
        best = []
        for g in gt.pipes:
            gp, gq = np.asarray(g.p, float), np.asarray(g.q, float)
            L = np.linalg.norm(gq - gp)
            ga = (gq - gp) / L
            v = xs - gp - np.outer(np.clip((xs - gp) @ ga, 0.0, L), ga)
            best.append((np.median(np.linalg.norm(v, axis=1)), g.id, v, ga))
        _, gid, v, ga = min(best, key=lambda b: b[0])
        side = np.cross([0.0, 0.0, 1.0], ga)
        side /= np.linalg.norm(side)
        s0 = first.get(lm.id)
        i0 = int(np.argmin(np.abs(traj.stamps - s0))) if s0 is not None else None
        rows.append(
            {
                "id": lm.id,
                "truth": gid,
                "length_m": round(float(np.linalg.norm(lm.q - lm.p)), 2),
                "from_m": round(float(min((lm.p - o) @ a, (lm.q - o) @ a)), 2),
                "to_m": round(float(max((lm.p - o) @ a, (lm.q - o) @ a)), 2),
                "side_cm": round(100 * float(np.median(v @ side)), 1),
                "side_ends_cm": [round(100 * float(v[0] @ side), 1), round(100 * float(v[-1] @ side), 1)],
                "vert_cm": round(100 * float(np.median(v[:, 2])), 1),
                "angle_deg": round(
                    float(np.degrees(np.arccos(min(1.0, abs((lm.q - lm.p) @ ga) / np.linalg.norm(lm.q - lm.p))))), 2
                ),
                "views": lm.n_observations,
                "first_view_t_s": round(float(t[i0]), 1) if i0 is not None else None,
                "pose_err_across_cm_then": round(100 * float(err_across[i0]), 1) if i0 is not None else None,
            }
        )
    return {"pose_error_over_time": tenths, "pipes": sorted(rows, key=lambda r: r["from_m"])}


def observation_bias(mission, by_stamp) -> dict:
    """The line observations placed with the true poses against the true pipe they lie on, by true
    pipe and by pass (the camera looking along the pipe's direction or against it): how many, the
    median signed yaw of their direction from the true axis (deg, about down), their median signed
    horizontal offset across it and vertical offset (mm, at their midpoints)."""
    from frontends.laser.evaluation import matching_pipe
    from semslam.observations import LineObservation

    meta = mission.metadata
    gt = meta.ground_truth
    pose_at = true_poses(mission)
    rows: dict[tuple, list] = {}
    for stamp, obs in by_stamp.items():
        T_WB, T = pose_at(stamp)
        for z in obs:
            if not isinstance(z, LineObservation):
                continue
            P = np.stack([z.p, z.q]) @ T[:3, :3].T + T[:3, 3]
            g = matching_pipe(P[0], P[1], gt.pipes)
            if g is None:
                continue
            gp, gq = np.asarray(g.p, float), np.asarray(g.q, float)
            ga = (gq - gp) / np.linalg.norm(gq - gp)
            u = P[1] - P[0]
            u = u / np.linalg.norm(u) * np.sign(u @ ga)
            side = np.cross([0.0, 0.0, 1.0], ga)
            side /= np.linalg.norm(side)
            mid = P.mean(axis=0) - gp
            off = mid - (mid @ ga) * ga
            yaw = np.degrees(np.arcsin(np.clip(np.cross(ga, u)[2], -1, 1)))
            forward = "with" if T_WB[:3, 0] @ ga > 0 else "against"
            rows.setdefault((g.id, forward), []).append((yaw, 1000 * off @ side, 1000 * off[2]))
    return {
        f"{k[0]} {k[1]}": {
            "n": len(v),
            "yaw_deg": round(float(np.median([r[0] for r in v])), 3),
            "side_mm": round(float(np.median([r[1] for r in v])), 1),
            "down_mm": round(float(np.median([r[2] for r in v])), 1),
        }
        for k, v in sorted(rows.items())
    }


def misses(mission, by_stamp) -> dict:
    """The scans that showed >= 0.2 m of a pipe without a line observation on it (placed with the
    true pose, as ``laser_real_eval`` scores them), by true pipe: how many scans showed it, how many
    missed it, the visible length in the missed scans, and the nearest observation's miss (its
    largest end distance from that pipe's axis, and its angle), when the scan had observations."""
    from frontends.laser.evaluation import matching_pipe
    from semslam.observations import LineObservation

    meta = mission.metadata
    gt = meta.ground_truth
    pose_at = true_poses(mission)
    by_pipe: dict[int, dict] = {}
    for s in meta.extras["scans"]:
        T = pose_at(s["stamp"])[1]
        segs = [
            np.stack([z.p, z.q]) @ T[:3, :3].T + T[:3, 3]
            for z in by_stamp.get(s["stamp"], [])
            if isinstance(z, LineObservation)
        ]
        hit = {g.id for P in segs if (g := matching_pipe(P[0], P[1], gt.pipes)) is not None}
        for k, v in s["pipe_visible_m"].items():
            if v < 0.2:
                continue
            row = by_pipe.setdefault(int(k), {"scans": 0, "missed": 0, "visible_missed_m": [], "nearest": []})
            row["scans"] += 1
            if int(k) in hit:
                continue
            row["missed"] += 1
            row["visible_missed_m"].append(round(float(v), 2))
            g = next(g for g in gt.pipes if g.id == int(k))
            gp, gq = np.asarray(g.p, float), np.asarray(g.q, float)
            ga = (gq - gp) / np.linalg.norm(gq - gp)
            near = []
            for P in segs:
                rel = P - gp
                d = np.linalg.norm(rel - np.outer(rel @ ga, ga), axis=1).max()
                u = (P[1] - P[0]) / np.linalg.norm(P[1] - P[0])
                near.append((round(100 * float(d), 1), round(float(np.degrees(np.arccos(min(1.0, abs(u @ ga))))), 1)))
            row["nearest"].append(min(near) if near else None)
    radius = {g.id: round(float(g.radius), 3) for g in gt.pipes}
    return {k: {**v, "radius_m": radius.get(k)} for k, v in sorted(by_pipe.items())}


def replay_arguments(description: str, seeds: str) -> argparse.ArgumentParser:
    """The arguments of a replay tool: ``--seeds``, ``--dump``, ``--sim``, ``--config``, ``--json``."""
    ap = argparse.ArgumentParser(description=description)
    ap.add_argument("--seeds", default=seeds)
    ap.add_argument("--dump", type=Path, required=True)
    ap.add_argument("--sim", default="{}", help="pipeline simulator overrides (JSON, nested sections)")
    ap.add_argument("--config", default="{}", help="semslam configuration overrides (JSON)")
    ap.add_argument("--json", type=Path, default=None)
    return ap


def main(argv=None) -> int:
    ap = replay_arguments(__doc__.splitlines()[0], "6")
    ap.add_argument(
        "--true-directions", action="store_true", help="turn each line observation onto its true pipe's direction"
    )
    args = ap.parse_args(argv)
    out = {}
    for seed in parse_seeds(args.seeds):
        from semslam.mission.measurements import GroundTruthPose

        results, mission, by_stamp = replay(
            seed, args.dump, json.loads(args.sim), json.loads(args.config), args.true_directions
        )
        graph = results["graph"]
        meta = mission.metadata
        scores = map_scores(graph.landmarks, meta.ground_truth, meta.extras["scans"])
        truth = {m.stamp: np.asarray(m.position, float) for m in mission.of_type(GroundTruthPose)}
        scores.update(offsets_split(graph.landmarks, meta.ground_truth, graph.trajectory, truth))
        why = explain(graph, mission, by_stamp, results.get("dr"))
        out[seed] = {
            "map": scores,
            **why,
            "misses": misses(mission, by_stamp),
            "bias": observation_bias(mission, by_stamp),
        }
        print(
            f"seed {seed}: error median {scores['pipe_error_median_m']:.3f} p95 {scores['pipe_error_p95_m']:.3f} m, "
            f"within 5 cm {scores['pipe_within_5cm_share']:.2f}, covered {scores['seen_pipe_length_covered']:.2f}, "
            f"valves once {scores['valves_mapped_once']}/{scores['valves_seen']}, pose error horizontal median "
            f"{scores['pose_error_horizontal_median_m']:.3f} m",
            flush=True,
        )
        for r in why["pose_error_over_time"]:
            print("   pose", r)
        for r in why["pipes"]:
            print("   pipe", r)
        for k, r in out[seed]["bias"].items():
            print(f"   observations of true pipe {k}:", r)
        for k, r in out[seed]["misses"].items():
            print(f"   misses of true pipe {k}:", r)
        if args.json is not None:
            args.json.write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
