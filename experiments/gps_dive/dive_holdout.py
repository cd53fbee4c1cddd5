"""Simulated dives (semslam.sim.dive) compared with the resurfacing GPS fix held out: the horizontal
error of dr, ekf and graph at that fix (metrics.json ``gps_error_last_m``), and against the truth.

    .venv/bin/python experiments/gps_dive/dive_holdout.py --seeds 0-5 [--hold-out last] [--out results.json]

Each seed draws its noise realisations and its start (``--vary start``: the pattern's centre), the
dive's parameters stay its defaults (≥ 10 min submerged, DVL dropouts 5 % in 2–8 s bursts; drawing
``trajectory`` changes the speed and can shorten the dive below 10 min). Results:
experiments/gps_dive/README.md.
"""

from __future__ import annotations

import argparse
import dataclasses
import json

import numpy as np
from scipy.spatial.transform import Rotation

from semslam.compare import run_comparison
from semslam.config import SemslamConfig
from semslam.estimation import Trajectory
from semslam.eval.gps_reference import GpsReference, HoldOut
from semslam.mission.measurements import GpsFix, GroundTruthPose
from semslam.mission.mission import Mission, MissionMetadata
from semslam.sim.dive import simulate_dive
from semslam.sim.scenarios import resolve_config

ESTIMATORS = ("dr", "ekf", "graph")


def seeds(text: str) -> list[int]:
    a, _, b = text.partition("-")
    return list(range(int(a), int(b or a) + 1))


def truth_of(mission: Mission) -> Trajectory:
    poses = list(mission.of_type(GroundTruthPose))
    return Trajectory(
        np.array([p.stamp for p in poses], np.int64),
        np.array([p.position for p in poses]),
        np.array([p.orientation for p in poses]),
    )


def truly(fix: GpsFix, mission: Mission, levers: dict) -> GpsFix:
    """``fix`` moved to the true antenna position at its stamp (the nearest true pose)."""
    truth = truth_of(mission)
    k = int(np.argmin(np.abs(truth.stamps - fix.stamp)))
    R = Rotation.from_quat(truth.orientations[k]).as_matrix()
    return dataclasses.replace(fix, position=truth.positions[k] + R @ levers[fix.sensor])


def as_recorded(mission: Mission) -> Mission:
    """The mission as a real recording: no ground-truth sensor, no truth in the stream."""
    md = mission.metadata
    sensors = {k: s for k, s in md.sensors.items() if s.kind != "ground_truth"}
    meta = MissionMetadata(md.name, sensors, None, md.extras, md.datum)
    return Mission(meta, lambda: (m for m in mission if not isinstance(m, GroundTruthPose)))


def one(seed: int, hold_out: HoldOut, vary: tuple[str, ...], overrides: dict, recorded: bool) -> dict:
    cfg = resolve_config("dive", seed, vary, overrides)
    mission = simulate_dive(cfg)
    result, metrics = run_comparison(
        as_recorded(mission) if recorded else mission,
        SemslamConfig(),
        frontends=[],
        estimators=ESTIMATORS,
        hold_out_gps=hold_out,
    )
    # the held-out fix's own horizontal error (the truth's antenna against it): the floor of any estimate's
    reference = GpsReference.hold_out(mission, hold_out)
    levers = {s.name: s.T_BS[:3, 3] for s in mission.metadata.sensors_of_kind("gps")}
    row = {
        "seed": seed,
        "submerged_s": mission.metadata.extras["dive"]["submerged_s"],
        "fix_noise_m": float(reference.errors(truth_of(mission), levers)[-1]),
    }
    # in simulation also against the truth: each estimate's antenna against the true antenna there
    true_fixes = GpsReference(reference.policy, [truly(f, mission, levers) for f in reference.fixes])
    for est in ESTIMATORS:
        e = metrics["estimators"][est]
        row[est] = {k: e[k] for k in ("gps_error_last_m", "gps_error_rmse_m", "ate_rmse_m")}
        row[est]["truth_error_last_m"] = true_fixes.metrics(result.results[est].trajectory, levers)["gps_error_last_m"]
    dr = row["dr"]["gps_error_last_m"]
    row["ratio"] = {est: row[est]["gps_error_last_m"] / dr for est in ("ekf", "graph")}
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="0-5")
    ap.add_argument("--hold-out", default="last")
    ap.add_argument("--vary", default="start", help="what each seed draws besides the noise (semslam.sim.vary)")
    ap.add_argument("--sim-config", default=None, help="YAML overriding the dive's defaults")
    ap.add_argument("--as-recorded", action="store_true", help="no ground truth: all start from the first fix")
    ap.add_argument("--out", default=None)
    args = ap.parse_args()
    overrides = {}
    if args.sim_config:
        import yaml

        overrides = yaml.safe_load(open(args.sim_config))
    rows = []
    for s in seeds(args.seeds):
        vary = tuple(filter(None, args.vary.split(",")))
        row = one(s, HoldOut.parse(args.hold_out), vary, overrides, args.as_recorded)
        rows.append(row)
        print(
            f"seed {s}: submerged {row['submerged_s'] / 60:.1f} min; fix noise {row['fix_noise_m']:.2f} m; error "
            + ", ".join(f"{e} {row[e]['gps_error_last_m']:.2f} m" for e in ESTIMATORS)
            + f"; ratio ekf {row['ratio']['ekf']:.2f}, graph {row['ratio']['graph']:.2f}; against the truth "
            + ", ".join(f"{e} {row[e]['truth_error_last_m']:.2f} m" for e in ESTIMATORS),
            flush=True,
        )
    for est in ("ekf", "graph"):
        r = np.array([row["ratio"][est] for row in rows])
        print(f"{est}/dr: median {np.median(r):.2f}, max {r.max():.2f} over {len(r)} seeds")
    if args.out:
        with open(args.out, "w") as f:
            json.dump(rows, f, indent=1)


if __name__ == "__main__":
    main()
