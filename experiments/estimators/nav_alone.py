"""The graph's navigation alone against dead reckoning on a field's bag (issue 21, stop 44).

Runs dead reckoning and the graph on a bag WITHOUT front-ends (no landmark: the graph smooths the same
readings dead reckoning integrates), with one component of the graph's navigation changed by a named
variant (configuration keys, dotted), and writes per run: the ATEs, the horizontal and yaw error per
50 s of each estimator, and the graph's final gyro bias against the mission summary's truth.
``table`` prints field × variant (graph ATE / DR ATE).

    python experiments/estimators/nav_alone.py run BAG OUT --variant main
    python experiments/estimators/nav_alone.py table OUT
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from semslam.commands.mission_input import checked_mission
from semslam.compare import run_comparison
from semslam.config import SemslamConfig

# One component of the graph's navigation changed at a time (dotted configuration keys).
VARIANTS: dict[str, dict] = {
    "main": {},
    "nolink": {"motion.gyro_link": False},
    "nogbias": {"sensors.gyro_bias_sigma_rad_s": 0.0},
    "nohrate": {"sensors.heading_bias_rate_sigma_rad_per_s": 0.0},
    "nohbias": {"sensors.heading_bias_walk_rad_per_sqrt_s": 0.0},
    "rate_x3": {"motion.angular_rate_sigma_rad_s": "x3"},
    "rate_d3": {"motion.angular_rate_sigma_rad_s": "/3"},
    "accel_x3": {"motion.accel_sigma_m_s2": 0.06},
    "accel_d3": {"motion.accel_sigma_m_s2": 0.02 / 3},
    "nowindow": {"graph.window_s": 1e5},
    "kf_025": {"graph.keyframe_max_interval_s": 0.25},
    "kf_3": {"graph.keyframe_max_interval_s": 3.0},
    "batch": {"graph.batch": True},
}
# Stop 44's "gyro_dvl" variants (a monkeypatch turning the DVL samples by the gyro) are gone: since stop 45 the
# backend does it (semslam.backend.navigation.NavigationBuffer.dvl_turn), and "nolink" turns it off with the link.
BIN_S = 50.0


def config_for(variant: str, metadata) -> SemslamConfig:
    """The default configuration with ``variant``'s keys set; "x3"/"/3" scale the mission's rate density."""
    data = SemslamConfig().model_dump()
    for key, value in VARIANTS[variant].items():
        if value in ("x3", "/3"):
            base = SemslamConfig().motion.angular_rate_density(metadata)
            value = base * 3 if value == "x3" else base / 3
        section, name = key.split(".")
        data[section][name] = value
    return SemslamConfig.model_validate(data)


def yaw(q: np.ndarray) -> np.ndarray:
    return Rotation.from_quat(q).as_euler("ZYX")[:, 0]


def over_time(traj, truth) -> dict:
    """Horizontal position error and yaw error (rad) against the truth, RMS per BIN_S bin."""
    R_true, p_true = truth.poses_at(traj.stamps)
    t = (traj.stamps - traj.stamps[0]) * 1e-9
    e_h = np.linalg.norm((traj.positions - p_true)[:, :2], axis=1)
    y_true = Rotation.from_matrix(R_true).as_euler("ZYX")[:, 0]
    e_y = np.angle(np.exp(1j * (yaw(traj.orientations) - y_true)))
    bins = (t // BIN_S).astype(int)
    out = {"t0_s": [], "horizontal_m": [], "yaw_rad": []}
    for b in np.unique(bins):
        m = bins == b
        out["t0_s"].append(b * BIN_S)
        out["horizontal_m"].append(float(np.sqrt((e_h[m] ** 2).mean())))
        out["yaw_rad"].append(float(np.mean(e_y[m])))
    return out


def run(bag: Path, out: Path, variant: str) -> dict:
    cfg0 = SemslamConfig()
    mission, _, _ = checked_mission(bag, cfg0, None, "")
    cfg = config_for(variant, mission.metadata)
    result, metrics = run_comparison(mission, cfg, [], estimators=("dr", "graph"))
    summary = mission.metadata.extras or {}  # the simulator's summary: the truth of the sensors' biases
    rec = {
        "bag": str(bag),
        "variant": variant,
        "overrides": VARIANTS[variant],
        "ate": {k: v["ate_rmse_m"] for k, v in metrics["estimators"].items()},
        "nees": {k: v.get("nees_mean") for k, v in metrics["estimators"].items()},
        "over_time": {k: over_time(r.trajectory, result.truth) for k, r in result.results.items()},
        "gyro_bias_true_rad_s": summary.get("gyro_bias_rad_s"),
        "heading_bias_final_true_rad": summary.get("heading_bias_final_rad"),
    }
    hist = result.results["graph"].history
    for key in ("gyro_bias_rad_s", "gyro_bias_sigma_rad_s"):
        if key in hist:
            rec[f"graph_{key}"] = [float(x) for x in hist[key]]
    for key in ("heading_bias", "heading_bias_rate", "gyro_bias"):  # dead reckoning's final estimates
        if key in result.results["dr"].history:
            _, x, sigma = result.results["dr"].history[key]
            rec[f"dr_final_{key}"] = [np.asarray(x)[-1].tolist(), np.asarray(sigma)[-1].tolist()]
    rec["dvl_dropouts"] = summary.get("dvl_dropouts")
    out.mkdir(parents=True, exist_ok=True)
    arrays = {}
    for name, r in result.results.items():  # each trajectory and the truth at its stamps, for plots
        arrays[f"{name}_stamps"] = r.trajectory.stamps
        arrays[f"{name}_positions"] = r.trajectory.positions
        arrays[f"{name}_orientations"] = r.trajectory.orientations
        arrays[f"{name}_truth"] = result.truth.poses_at(r.trajectory.stamps)[1]
    np.savez_compressed(out / f"{variant}.npz", **arrays)
    (out / f"{variant}.json").write_text(json.dumps(rec, indent=1, default=str))
    return rec


def table(out: Path) -> None:
    """Field × variant: graph ATE (graph/DR) in each run's own pairing; then per variant over the fields it
    ran on: the sums of graph and DR ATE, the median graph/DR and on how many fields the graph is worse."""
    runs: dict[str, dict[str, dict]] = {}
    for f in sorted(out.glob("*/*.json")):
        rec = json.loads(f.read_text())
        runs.setdefault(f.parent.name, {})[rec["variant"]] = rec
    variants = [v for v in VARIANTS if any(v in r for r in runs.values())]
    print("| field | DR ATE [m] (main) | " + " | ".join(variants) + " |")
    print("|---" * (len(variants) + 2) + "|")
    for field, r in runs.items():
        dr = r["main"]["ate"]["dr"] if "main" in r else float("nan")
        cells = [
            f"{r[v]['ate']['graph']:.3f} ({r[v]['ate']['graph'] / r[v]['ate']['dr']:.2f})" if v in r else ""
            for v in variants
        ]
        print(f"| {field} | {dr:.3f} | " + " | ".join(cells) + " |")
    print()
    for v in variants:
        g = np.array([r[v]["ate"]["graph"] for r in runs.values() if v in r])
        d = np.array([r[v]["ate"]["dr"] for r in runs.values() if v in r])
        print(
            f"{v}: n={len(g)} graph sum {g.sum():.3f} DR sum {d.sum():.3f} median graph/DR {np.median(g / d):.3f} "
            f"graph worse on {(g > d).sum()}"
        )


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run")
    r.add_argument("bag", type=Path)
    r.add_argument("out", type=Path)
    r.add_argument("--variant", default="main", choices=sorted(VARIANTS))
    t = sub.add_parser("table")
    t.add_argument("out", type=Path)
    a = p.parse_args()
    if a.cmd == "run":
        rec = run(a.bag, a.out, a.variant)
        print("SUMMARY", a.variant, json.dumps({k: round(v, 4) for k, v in rec["ate"].items()}))
    else:
        table(a.out)


if __name__ == "__main__":
    main()
