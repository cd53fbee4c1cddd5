"""Where the graph's offset across the pipeline comes from (issue 22, seed 23's 5 cm): the laser
observations that ``experiments/laser_real_eval.py pipeline --dump DIR`` recorded, replayed through
dead reckoning and the graph on the mission simulated again (``--sim``: e.g. no gyro bias) with
optional estimator settings (``--config``), as ``pipeline_replay.py`` does.

    python experiments/laser/heading_trace.py --seeds 23 --dump DIR [--sim JSON] [--config JSON] [--json OUT]

Prints, by tenths of the mission: the graph's and dead reckoning's position error across the line
and their heading (yaw) error; then the position error across the line that each one's heading
error alone would have made (the true horizontal velocity turned by the yaw error, integrated), so
that the heading's share and the rest's (DVL, the map's pull) stand apart; the truth's gyro bias and
heading-bias drift beside the graph's final gyro-bias estimate; and the map scores.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(HERE), str(HERE.parent), str(HERE.parent / "estimators")]

from laser_real_eval import map_scores, offsets_split, parse_seeds  # noqa: E402
from pipeline_replay import line_frame, replay, replay_arguments  # noqa: E402


def _yaw(R: np.ndarray) -> np.ndarray:
    return np.arctan2(R[..., 1, 0], R[..., 0, 0])


def heading_split(traj, truth_T: dict, across: np.ndarray) -> dict:
    """Per pose of ``traj``: the position error across the line (m), the yaw error (rad) and the
    across-line error that the yaw error alone makes (m): Σ (R_z(δψ) − I) v_true dt, projected."""
    from scipy.spatial.transform import Rotation

    stamps = np.array(sorted(truth_T))
    k = np.searchsorted(stamps, traj.stamps).clip(0, len(stamps) - 1)
    T = np.array([truth_T[int(s)] for s in stamps[k]])
    err = (traj.positions - T[:, :3, 3]) @ across
    dyaw = np.angle(np.exp(1j * (_yaw(Rotation.from_quat(traj.orientations).as_matrix()) - _yaw(T[:, :3, :3]))))
    dp = np.diff(T[:, :3, 3], axis=0, prepend=T[:1, :3, 3])  # the true displacement between poses
    c, s = np.cos(dyaw), np.sin(dyaw)
    turned = np.stack([c * dp[:, 0] - s * dp[:, 1], s * dp[:, 0] + c * dp[:, 1], dp[:, 2]], axis=1)
    from_heading = np.cumsum((turned - dp) @ across)
    return {"across": err, "yaw": dyaw, "from_heading": from_heading}


def main(argv=None) -> int:
    args = replay_arguments(__doc__.splitlines()[0], "23").parse_args(argv)
    from semslam.mission.measurements import GroundTruthPose

    out = {}
    for seed in parse_seeds(args.seeds):
        results, mission, _ = replay(seed, args.dump, json.loads(args.sim), json.loads(args.config))
        meta = mission.metadata
        truth_T = {m.stamp: m.matrix() for m in mission.of_type(GroundTruthPose)}
        _, _, across = line_frame(meta.ground_truth)
        graph, dr = results["graph"], results["dr"]
        g, d = heading_split(graph.trajectory, truth_T, across), heading_split(dr.trajectory, truth_T, across)
        t = (graph.trajectory.stamps - graph.trajectory.stamps[0]) * 1e-9
        td = (dr.trajectory.stamps - dr.trajectory.stamps[0]) * 1e-9
        rows = []
        for i in np.linspace(0, len(t) - 1, 11).astype(int):
            j = int(np.argmin(np.abs(td - t[i])))
            rows.append(
                {
                    "t_s": round(float(t[i]), 1),
                    "graph_across_cm": round(100 * float(g["across"][i]), 1),
                    "graph_from_heading_cm": round(100 * float(g["from_heading"][i]), 1),
                    "graph_yaw_mdeg": round(1000 * float(np.degrees(g["yaw"][i])), 0),
                    "dr_across_cm": round(100 * float(d["across"][j]), 1),
                    "dr_from_heading_cm": round(100 * float(d["from_heading"][j]), 1),
                    "dr_yaw_mdeg": round(1000 * float(np.degrees(d["yaw"][j])), 0),
                }
            )
        truth = {m.stamp: np.asarray(m.position, float) for m in mission.of_type(GroundTruthPose)}
        scores = map_scores(graph.landmarks, meta.ground_truth, meta.extras["scans"])
        scores.update(offsets_split(graph.landmarks, meta.ground_truth, graph.trajectory, truth))
        est = graph.history.get("gyro_bias_rad_s")
        sig = graph.history.get("gyro_bias_sigma_rad_s")
        out[seed] = {
            "over_time": rows,
            "graph_yaw_error_median_mdeg": round(1000 * float(np.degrees(np.median(g["yaw"]))), 0),
            "dr_yaw_error_median_mdeg": round(1000 * float(np.degrees(np.median(d["yaw"]))), 0),
            "gyro_bias_true_rad_s": meta.extras.get("gyro_bias_rad_s"),
            "gyro_bias_graph_rad_s": None if est is None else [float(x) for x in est],
            "gyro_bias_graph_sigma_rad_s": None if sig is None else [float(x) for x in sig],
            "heading_bias_final_true_rad": meta.extras.get("heading_bias_final_rad"),
            "within_5cm": scores["pipe_within_5cm_share"],
            "pose_error_horizontal_median_m": scores["pose_error_horizontal_median_m"],
        }
        o = out[seed]
        print(
            f"seed {seed}: within 5 cm {o['within_5cm']:.3f}, pose error horizontal {o['pose_error_horizontal_median_m']:.3f} m, "
            f"yaw error median graph {o['graph_yaw_error_median_mdeg']:.0f} dr {o['dr_yaw_error_median_mdeg']:.0f} mdeg; "
            f"gyro bias true {np.round(np.array(o['gyro_bias_true_rad_s'] or [np.nan] * 3) * 1e6, 1)} graph "
            f"{np.round(np.array(o['gyro_bias_graph_rad_s'] or [np.nan] * 3) * 1e6, 1)} "
            f"± {np.round(np.array(o['gyro_bias_graph_sigma_rad_s'] or [np.nan] * 3) * 1e6, 1)} µrad/s; "
            f"heading bias at the end {1000 * np.degrees(o['heading_bias_final_true_rad'] or 0):.0f} mdeg",
        )
        print("\n".join(f"   {r}" for r in rows), flush=True)
        if args.json is not None:  # after each seed: an interrupted run keeps what it measured
            args.json.write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
