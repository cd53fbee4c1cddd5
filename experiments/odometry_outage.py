"""What laser odometry buys during a long DVL outage (issue 23): the tank mission (or the pipeline's,
``--scenario pipeline``: stereo clouds of a rocky seabed) with the DVL
silenced for ``--outage`` seconds (``dvl.outage_s``) while the vehicle works by the structure, run through the graph
with and without the odometry front-end (its factors with and without their m-estimator), beside the laser front-end's landmarks and without them
(navigation only). Prints the relative position error over
``--delta`` seconds inside the outage (RPE), the ATE over the mission and inside the outage, and
the odometry's NEES over the mission.

    python experiments/odometry_outage.py [--seeds 0] [--start 200] [--outage 90] [--loops 3]
    python experiments/odometry_outage.py --scenario pipeline --seeds 1 --start 40 --outage 60 [--cache DIR]
    python experiments/odometry_outage.py --seeds 0 --starts 20,110,200,300,390 --shared  # placements of the outage

``--shared``: one pipeline feeds three graphs, one with the odometry's factors, one without them (the laser
graph gets the very same landmark observations: a paired comparison, and the laser front-end runs once) and one
with them as ``factor_rotation: free`` emits them (the translation alone), and the odometry's NEES (6-DoF, and
the translation's 3-DoF) is taken on the observations of that run (no second pass of the front-end).
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
from pathlib import Path

import numpy as np
from odometry_eval import TruthInterpolator, evaluate, pose_error, scenario_config, simulated
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from frontends.odometry.config import STEREO_SEABED
from frontends.odometry.information import translation_only
from semslam.config import SemslamConfig
from semslam.demo import demo_config
from semslam.estimators import create_estimator
from semslam.mission.measurements import GroundTruthPose
from semslam.mission.mission import Mission
from semslam.observations import OdometryObservation
from semslam.pipeline import run_pipeline
from semslam.registry import create_frontends


def _interp(stamps, positions, t):
    return np.stack([np.interp(t, stamps, positions[:, k]) for k in range(3)], axis=1)


def errors(result, truth, lo: int, hi: int, delta_s: float) -> dict:
    tr = result.trajectory
    gt = _interp(truth.stamps, truth.positions, tr.stamps)
    inside = (tr.stamps >= lo) & (tr.stamps <= hi)
    e = np.linalg.norm(tr.positions - gt, axis=1)
    t = tr.stamps[inside]
    pairs = [(a, b) for a, b in zip(t, t + int(delta_s * 1e9)) if b <= hi]
    rpe = []
    for a, b in pairs:
        est = _interp(tr.stamps, tr.positions, np.array([a, b]))
        true = _interp(truth.stamps, truth.positions, np.array([a, b]))
        rpe.append(np.linalg.norm((est[1] - est[0]) - (true[1] - true[0])))
    return {
        "ate_rmse_m": float(np.sqrt(np.mean(e**2))),
        "ate_outage_rmse_m": float(np.sqrt(np.mean(e[inside] ** 2))),
        "ate_outside_rmse_m": float(np.sqrt(np.mean(e[~inside] ** 2))),
        "ate_max_m": float(np.max(e)),
        "rpe_outage_rmse_m": float(np.sqrt(np.mean(np.square(rpe)))) if rpe else None,
    }


def run(
    mission: Mission,
    frontends: list[str],
    gaussian: bool = False,
    odometry: dict | None = None,
    graph: dict | None = None,
    oracle_bias: bool = False,
    odometry_over_demo: dict | None = None,
):
    """The graph on ``mission`` with ``frontends``: the tank's demo configuration, or (``odometry`` given)
    the defaults with that odometry section (the pipeline: no known pipe radius); ``graph``: keys of the graph's
    section over it; ``oracle_bias``: the odometry's observations reach the graph with the simulator's true gyro
    bias taken out of their rotation (a diagnostic: no estimator knows it); ``odometry_over_demo``: the odometry's
    section over the tank's demo configuration (the laser's as in the default run)."""
    cfg = demo_config() if odometry is None else SemslamConfig(frontends={"odometry": odometry})
    if odometry_over_demo is not None:
        cfg = SemslamConfig(frontends={**cfg.frontends, "odometry": odometry_over_demo})
    if graph:
        cfg.graph = cfg.graph.model_copy(update=graph)
    if gaussian:  # the odometry factors without their m-estimator
        cfg.graph = cfg.graph.model_copy(update={"odometry_cauchy_k": {}})
    ests = [create_estimator("graph", mission.metadata, cfg)]
    if oracle_bias:
        b_true = true_bias(mission)
        ests = [
            _fed(
                ests[0],
                "graph",
                lambda obs: [_bias_removed(z, b_true) if isinstance(z, OdometryObservation) else z for z in obs],
            )
        ]
    fes = create_frontends(frontends, mission.metadata, cfg.frontends)
    return run_pipeline(mission, ests, fes)


def _fed(estimator, name: str, change):
    """``estimator`` renamed ``name``, given each stamp's observations through ``change``."""
    estimator.name = name
    feed = estimator.process_observations
    estimator.process_observations = lambda stamp, obs: feed(stamp, change(obs))
    return estimator


def _free_rotation(obs: list) -> list:
    """The odometry's observations as ``factor_rotation: free`` emits them (the translation alone)."""
    return [
        replace(z, covariance=translation_only(z.covariance)) if isinstance(z, OdometryObservation) else z for z in obs
    ]


def run_shared(mission: Mission, odometry: dict | None = None):
    """One pipeline (laser and odometry front-ends) into three graphs: "laser+odometry", "laser", the latter
    given every observation but the odometry's (what a laser-only run gives it), and "free": the odometry's
    observations with their rotation freed (``factor_rotation: free``: the translation alone). The tank's demo
    configuration, with ``odometry`` as the odometry's section if given."""
    demo = demo_config()
    cfg = demo if odometry is None else SemslamConfig(frontends={**demo.frontends, "odometry": odometry})
    with_odo = create_estimator("graph", mission.metadata, cfg)
    without = _fed(
        create_estimator("graph", mission.metadata, cfg),
        "laser",
        lambda obs: [z for z in obs if not isinstance(z, OdometryObservation)],
    )
    free = _fed(create_estimator("graph", mission.metadata, cfg), "free", _free_rotation)
    fes = create_frontends(["laser", "odometry"], mission.metadata, cfg.frontends)
    return run_pipeline(mission, [with_odo, without, free], fes)


def nees_of(mission: Mission, observations: list, lo: int, hi: int) -> dict:
    """The odometry observations' 6-DoF NEES against the truth: mean over the mission (its 95 % band),
    inside [lo, hi] and outside."""
    truth = TruthInterpolator([m for m in mission if isinstance(m, GroundTruthPose)])
    nees, nees_t, nees_r, inside = [], [], [], []
    for z in observations:
        xi = pose_error(np.linalg.inv(truth(z.stamp_from)) @ truth(z.stamp), z.relative_pose)
        nees.append(float(xi @ np.linalg.solve(z.covariance, xi)))
        nees_t.append(float(xi[3:] @ np.linalg.solve(z.covariance[3:, 3:], xi[3:])))
        nees_r.append(float(xi[:3] @ np.linalg.solve(z.covariance[:3, :3], xi[:3])))
        inside.append(lo <= z.stamp <= hi)
    nees, nees_t, inside, n = np.array(nees), np.array(nees_t), np.array(inside), len(nees)
    given = nees - np.array(nees_r)  # the translation's NEES given the rotation (the 6-DoF's less the rotation's)
    return {
        "nees_translation_given_rotation_mean": float(given.mean()) if n else None,
        "nees_translation_given_rotation_outside_window": float(given[~inside].mean()) if (~inside).any() else None,
        # the translation's 3-DoF NEES (its marginal: what a factor with the rotation freed carries), its band
        "nees_translation_mean": float(nees_t.mean()) if n else None,
        "nees_translation_band_95": [chi2.ppf(0.025, 3 * n) / n, chi2.ppf(0.975, 3 * n) / n] if n else None,
        "nees_translation_in_window": float(nees_t[inside].mean()) if inside.any() else None,
        "accepted": n,
        "accepted_in_window": int(inside.sum()),
        "nees_mean": float(nees.mean()) if n else None,
        "nees_band_95": [chi2.ppf(0.025, 6 * n) / n, chi2.ppf(0.975, 6 * n) / n] if n else None,
        "nees_mean_in_window": float(nees[inside].mean()) if inside.any() else None,
        "nees_mean_outside_window": float(nees[~inside].mean()) if (~inside).any() else None,
    }


def _bias_removed(z: OdometryObservation, bias_rad_s: np.ndarray) -> OdometryObservation:
    """``z`` with its rotation turned by Exp(−b·T) (T its interval): what the graph's factor measures at the bias b
    when ``graph.odometry_gyro_bias`` lists its sensor's kind (that key lives only in 0372d41, s49-odomgraph)."""
    P = np.eye(4)
    P[:3, :3] = Rotation.from_rotvec(-np.asarray(bias_rad_s) * (z.stamp - z.stamp_from) * 1e-9).as_matrix()
    return replace(z, relative_pose=z.relative_pose @ P)


def true_bias(mission: Mission) -> np.ndarray | None:
    """The simulator's gyro bias in the body frame (rad/s; it draws it in the AHRS's axes), None if not simulated."""
    b_S = mission.metadata.extras.get("gyro_bias_rad_s")
    ahrs = mission.metadata.sensors_of_kind("ahrs")
    return ahrs[0].T_BS[:3, :3] @ np.asarray(b_S) if b_S is not None and ahrs else None


def graph_bias_nees(mission: Mission, result, lo: int, hi: int) -> dict:
    """The run's odometry observations' 6-DoF NEES against the truth as emitted ("raw": a BetweenFactorPose3's
    measurement), with the graph's final gyro-bias estimate taken out of their rotation ("graph": the
    bias-taking factor's measurement at that estimate) and with the simulator's true bias taken out ("truth": a
    diagnostic); the biases in the body frame (rad/s)."""
    odo = [r.observation for r in result.observations if isinstance(r.observation, OdometryObservation)]
    hist = result.results["graph"].history
    b_graph = np.asarray(hist.get("gyro_bias_rad_s", np.zeros(3)), float)
    b_true = true_bias(mission)
    out = {"raw": nees_of(mission, odo, lo, hi), "graph_bias_rad_s": b_graph.tolist()}
    out["graph"] = nees_of(mission, [_bias_removed(z, b_graph) for z in odo], lo, hi)
    if b_true is not None:
        out["true_bias_rad_s"] = b_true.tolist()
        out["truth"] = nees_of(mission, [_bias_removed(z, b_true) for z in odo], lo, hi)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", choices=("tank", "pipeline"), default="tank")
    ap.add_argument("--seeds", default="0")
    ap.add_argument("--start", type=float, default=200.0, help="outage start (s from the mission start)")
    ap.add_argument("--outage", type=float, default=90.0, help="outage length (s)")
    ap.add_argument("--delta", type=float, default=10.0, help="RPE interval (s)")
    ap.add_argument("--loops", type=float, default=3.0, help="tank loops (the pipeline flies its passes)")
    ap.add_argument("--cache", type=Path, help="keep the simulated missions here (pickled) and reuse them")
    ap.add_argument("--config", help="odometry section as JSON (default: the tank's defaults, STEREO_SEABED)")
    ap.add_argument(
        "--look-away",
        action="store_true",
        help="the vehicle turns its back on the rack through the outage (trajectory.look_away_s, turns inside it)",
    )
    ap.add_argument(
        "--variants",
        default="laser;laser+odometry;laser+odometry/gaussian;navigation;odometry",
        help="front-end sets, ';'-separated ('/gaussian': the odometry factors without their Cauchy m-estimator)",
    )
    ap.add_argument(
        "--odometry", help="the odometry's section as JSON over the tank's demo configuration (--config: over none)"
    )
    ap.add_argument("--graph", help="keys of the graph's section as JSON (e.g. '{\"window_s\": 130}')")
    ap.add_argument(
        "--oracle-bias",
        action="store_true",
        help="the odometry's observations reach the graph with the simulator's true gyro bias taken out (diagnostic)",
    )
    ap.add_argument("--starts", help="several outage starts (s, ','-separated): one row per seed and start")
    ap.add_argument(
        "--shared",
        action="store_true",
        help="laser and laser+odometry from one pipeline (two graphs; NEES from its observations); --variants ignored",
    )
    ap.add_argument("--no-nees", action="store_true", help="skip the odometry's NEES (odometry_covariance measures it)")
    args = ap.parse_args()
    pipeline = args.scenario == "pipeline"
    odometry = json.loads(args.config) if args.config else STEREO_SEABED if pipeline else None
    graph = json.loads(args.graph) if args.graph else None
    starts = [float(v) for v in args.starts.split(",")] if args.starts else [args.start]
    for seed, start in ((int(s), st) for s in args.seeds.split(",") for st in starts):
        args.start = start
        data = {"dvl": {"outage_s": [args.start, args.outage]}}  # each seed its world, with a long DVL outage
        if not pipeline:
            data["trajectory"] = {
                "loops": args.loops,
                "look_away_s": [args.start, args.outage] if args.look_away else None,
            }
        mission = simulated(args.scenario, scenario_config(args.scenario, seed, data), args.cache)
        t0 = next(iter(mission)).stamp
        lo, hi = t0 + int(args.start * 1e9), t0 + int((args.start + args.outage) * 1e9)
        row = {"start_s": args.start}
        if args.shared:
            result = run_shared(mission, json.loads(args.odometry) if args.odometry else odometry)
            for name, key in (("laser", "laser"), ("laser+odometry", "graph"), ("laser+odometry/free", "free")):
                row[name] = errors(result.results[key], result.truth, lo, hi, args.delta)
            row["laser+odometry"]["odometry"] = result.frontend_summaries["odometry"].metrics
            odo = [r.observation for r in result.observations if isinstance(r.observation, OdometryObservation)]
            row["odometry_nees"] = nees_of(mission, odo, lo, hi)
            for name in ("laser+odometry", "laser+odometry/free"):
                row[f"rpe_ratio {name} / laser"] = row[name]["rpe_outage_rmse_m"] / row["laser"]["rpe_outage_rmse_m"]
            print(f"seed {seed}: {json.dumps(row)}", flush=True)
            continue
        if not args.no_nees and any("odometry" in name for name in args.variants.split(";")):
            # the registrations alone against the truth (the same scans and prior as in the pipeline's worker)
            ev = evaluate(mission, odometry, window=(lo, hi))
            keys = ("nees_mean", "nees_band_95", "nees_median", "accepted", "accepted_in_window")
            keys += ("nees_mean_in_window", "nees_mean_outside_window", "cpu_ms_per_scan_median", "cpu_ms_per_scan_p95")
            row["odometry_nees"] = {k: ev[k] for k in keys}
        for name in args.variants.split(";"):
            sets, _, kernel = name.partition("/")
            fes = [f for f in sets.split("+") if f and f != "navigation"]
            oracle = args.oracle_bias and "odometry" in fes
            over = json.loads(args.odometry) if args.odometry else None
            result = run(
                mission, fes, kernel == "gaussian", odometry, graph, oracle_bias=oracle, odometry_over_demo=over
            )
            row[name] = errors(result.results["graph"], result.truth, lo, hi, args.delta)
            if "odometry" in result.frontend_summaries:
                row[name]["odometry"] = result.frontend_summaries["odometry"].metrics
                row[name]["odometry_nees_bias"] = graph_bias_nees(mission, result, lo, hi)
        for a, b in (("laser", "laser+odometry"), ("laser", "laser+odometry/gaussian"), ("navigation", "odometry")):
            if a in row and b in row:
                row[f"rpe_ratio {b} / {a}"] = row[b]["rpe_outage_rmse_m"] / row[a]["rpe_outage_rmse_m"]
        print(f"seed {seed}: {json.dumps(row)}", flush=True)


if __name__ == "__main__":
    main()
