"""Benchmark of the graph back-end (not a test).

1. The default mission (the tank simulator when available, else a tank-like synthetic circle:
   490 s, 245 scans at 0.5 Hz, 20 objects, 12 pipes, DVL dropouts) with the oracle front-end:
   per-update wall time median / p95 over several runs, and the whole-mission batch (LM) time.
2. A long synthetic lawnmower mission (≥ 2 h, ≥ 2000 landmarks): per-update cost against map size,
   to show it stays flat as the map grows.
3. Factor cost: linearisation time of every domain factor (the CustomFactors: line, DVL displacement and
   smoothed displacement, biased attitude, gyro with its bias, heading-bias drift; the built-ins: object point,
   depth) against plain built-ins of the same size.

Run: ``python experiments/bench_graph.py [--runs 3] [--long-hours 2] [--skip-long] [--window-s 130] [--out F.json]``
(with ``--out``, the long mission's cost per 600 s is also plotted to ``F_long.png``; ``--plot F.json`` redraws
it; ``--window-s`` sets the default mission's ``graph.window_s``, so that its window slides and their cost is
reported: the tank's 490 s stay inside the default 600 s window).
Timings on a shared machine are noisy: report medians.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import gtsam
import numpy as np

from frontends.oracle import OracleFrontend
from semslam.backend.graph import GraphEstimator
from semslam.config import SemslamConfig

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository root: tests.support

from tests.support.synthetic_mission import (  # noqa: E402
    SyntheticConfig,
    dead_reckoning,
    ground_truth_positions,
    landmark_report,
    position_errors,
    run_graph,
    simulate,
)


def default_mission():
    try:
        from semslam.sim import TankSimConfig, simulate_tank

        return simulate_tank(TankSimConfig()), "tank"
    except ImportError:
        cfg = SyntheticConfig(duration_s=490.0, dropouts=((100.0, 20.0), (300.0, 15.0)), ahrs_yaw_bias_rad=0.0, seed=0)
        return simulate(cfg), "synthetic-circle-490s"


def summarize(res, mission) -> dict:
    t = np.asarray(res.update_times_s) * 1e3
    kinds = np.array(res.history.get("update_kinds", ["?"] * len(t)))
    gs, gp = ground_truth_positions(mission)
    e = position_errors(res.trajectory.stamps, res.trajectory.positions, gs, gp)
    eo = position_errors(res.online_trajectory.stamps, res.online_trajectory.positions, gs, gp)
    cpu = np.asarray(res.history.get("update_cpu_s", []), float) * 1e3  # per update, CPU ms of the process
    out = {
        "update_ms_median": float(np.median(t)),
        "update_ms_p95": float(np.percentile(t, 95)),
        "update_cpu_ms_median": float(np.median(cpu)) if len(cpu) else None,
        "update_cpu_ms_p95": float(np.percentile(cpu, 95)) if len(cpu) else None,
        **{  # per kind of update (a keyframe; a scan's observations), wall and CPU
            f"{short}_update_{unit}_{stat}": (float(fn(x[kinds == kind])) if (kinds == kind).any() and len(x) else None)
            for short, kind in (("keyframe", "keyframe"), ("obs", "observations"))
            for unit, x in (("ms", t), ("cpu_ms", cpu))
            for stat, fn in (("median", np.median), ("p95", lambda v: np.percentile(v, 95)))
        },
        "n_updates": int(len(t)),
        "n_landmarks": len(res.landmarks),
        "ate_rmse_m": float(np.sqrt(np.mean(e**2))),
        "online_ate_rmse_m": float(np.sqrt(np.mean(eo**2))),
        "batch_time_s": res.history.get("batch_time_s"),
    }
    slides = _slide_summary(res.history.get("window_slides", []))
    if slides:
        out.update({f"slide_{k}": v for k, v in slides.items()})
    if mission.metadata.ground_truth is not None:
        rep = landmark_report(res, mission.metadata.ground_truth)
        out["landmark_median_error_m"] = rep.median_error_m
        out["duplicated"] = len(rep.duplicated)
        out["wrongly_merged"] = len(rep.wrongly_merged)
    return out


def bench_default(runs: int, window_s: float | None = None) -> dict:
    mission, name = default_mission()
    config = SemslamConfig(graph={"window_s": window_s}) if window_s else SemslamConfig()
    gs, gp = ground_truth_positions(mission)
    ts, p = dead_reckoning(mission)
    dr = float(np.sqrt(np.mean(position_errors(ts, p, gs, gp) ** 2)))
    rows = []
    for r in range(runs):
        fe = OracleFrontend(mission.metadata, {"seed": r})
        t0, c0 = time.perf_counter(), time.process_time()
        res = run_graph(mission, config, [fe], batch=True)
        row = summarize(res, mission)
        row["wall_s"] = time.perf_counter() - t0
        row["cpu_s"] = time.process_time() - c0
        rows.append(row)
        print(f"  run {r}: {json.dumps(row)}", flush=True)
    keys = [k for k in rows[0] if isinstance(rows[0][k], (int, float)) and rows[0][k] is not None]
    return {
        "mission": name,
        "dr_ate_rmse_m": dr,
        "runs": runs,
        **{k: float(np.median([x[k] for x in rows])) for k in keys},
    }


def bench_long(hours: float) -> dict:
    duration = hours * 3600.0
    cfg = SyntheticConfig(
        duration_s=duration,
        path="lawnmower",
        lane_length_m=120.0,
        lane_spacing_m=5.0,
        n_lanes=8,
        n_objects=1600,
        n_pipes=500,
        n_structures=5,
        min_separation_m=0.8,
        gt_rate_hz=5.0,
        ahrs_rate_hz=10.0,
        dropouts=tuple((s, 20.0) for s in np.arange(600.0, duration, 900.0)),
        ahrs_yaw_bias_rad=0.0,
        seed=11,
    )
    t0 = time.perf_counter()
    mission = simulate(cfg)
    gt = mission.metadata.ground_truth
    print(
        f"  long mission simulated in {time.perf_counter() - t0:.1f} s: {len(gt.objects)} objects, {len(gt.pipes)} pipes",
        flush=True,
    )
    fe = OracleFrontend(mission.metadata, {"seed": 0})
    t0, c0 = time.perf_counter(), time.process_time()
    est = GraphEstimator(mission.metadata, SemslamConfig(graph={"covariance_in_result": False}))
    view, next_report = est.view(), 600.0
    start, windows, i0 = None, [], 0
    for m in mission:
        start = m.stamp if start is None else start
        est.process_measurement(m)
        if isinstance(m, fe.consumes):
            obs = fe.process(m, view)
            if obs:
                est.process_observations(m.stamp, obs)
        if (m.stamp - start) * 1e-9 >= next_report:
            # The updates of the last 600 s of mission (keyframes and observations).
            recent = est.updates.array()["wall_s"][i0:] * 1e3
            i0 = len(est.updates)
            w = {
                "t_s": next_report,
                "landmarks": len(est.map),
                "n_updates": len(recent),
                "ms_median": float(np.median(recent)),
                "ms_p95": float(np.percentile(recent, 95)),
                "wall_s": time.perf_counter() - t0,
                "cpu_s": time.process_time() - c0,
            }
            windows.append(w)
            print(
                f"    t={next_report:6.0f} s  landmarks={w['landmarks']:5d}  updates of the last 600 s ({len(recent)}): "
                f"median {w['ms_median']:.1f} ms  p95 {w['ms_p95']:.1f} ms  wall {w['wall_s']:.0f} s  cpu {w['cpu_s']:.0f} s",
                flush=True,
            )
            next_report += 600.0
    res = est.finish()
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    t = np.asarray(res.update_times_s) * 1e3
    n = np.asarray(res.update_n_landmarks)
    kinds = np.array(res.history["update_kinds"])
    obs = kinds == "observations"
    # Per-update cost by map size: deciles of the mission.
    bins = []
    for chunk_t, chunk_n in zip(np.array_split(t[obs], 10), np.array_split(n[obs], 10)):
        bins.append(
            {
                "landmarks": int(chunk_n.max()),
                "ms_median": float(np.median(chunk_t)),
                "ms_p95": float(np.percentile(chunk_t, 95)),
            }
        )
    return {
        "duration_h": hours,
        "wall_s": wall,
        "cpu_s": cpu,
        "n_landmarks": len(res.landmarks),
        "n_keyframes": len(res.trajectory),
        "update_ms_median": float(np.median(t)),
        "update_ms_p95": float(np.percentile(t, 95)),
        "by_map_size": bins,
        "update_ms_max": float(t.max()),
        "window_slides": _slide_summary(res.history.get("window_slides", [])),
        "window_returns": res.history.get("window_returns"),
        "by_600s": windows,
        **{
            k: v
            for k, v in summarize(res, mission).items()
            if k in ("ate_rmse_m", "landmark_median_error_m", "duplicated", "wrongly_merged")
        },
    }


def _slide_summary(slides: list[dict]) -> dict | None:
    """How often the window slid, what it cost and how large its separator was."""
    if not slides:
        return None
    sec = np.array([s["seconds"] for s in slides]) * 1e3
    cpu = np.array([s.get("cpu_seconds", np.nan) for s in slides]) * 1e3  # CPU of the process
    cov = np.array([s.get("covariance_seconds", 0.0) for s in slides]) * 1e3  # what left keeps its covariance
    sep = np.array([s["separator"] for s in slides])
    return {
        "n": len(slides),
        "ms_median": float(np.median(sec)),
        "ms_max": float(sec.max()),
        "cpu_ms_median": float(np.median(cpu)),
        "cpu_ms_max": float(cpu.max()),
        "covariance_ms_median": float(np.median(cov)),
        "separator_median": float(np.median(sep)),
        "separator_max": int(sep.max()),
        "left_landmarks": int(sum(s["left_landmarks"] for s in slides)),
    }


def bench_factor_cost(n: int = 5000) -> dict:
    """Linearisation cost per factor (µs, wall and CPU, median of 5 × n): every domain factor
    against built-ins of similar size."""
    from factors.geometry import so3_exp
    from factors.landmarks import LineAnchor, line_factor, point_factor
    from factors.navigation import (
        DisplacementIntegral,
        DvlPreintegrator,
        biased_attitude_factor,
        depth_factor,
        displacement_factor,
        gyro_rotation_factor,
        heading_bias_drift_factor,
        smoothed_displacement_factor,
    )

    rng = np.random.default_rng(0)
    x, y, l, p, vi, vj, b, g, kd, kb1, kd1 = (gtsam.symbol(c, 0) for c in "xylpvwbgdce")
    values = gtsam.Values()
    values.insert(x, gtsam.Pose3(gtsam.Rot3.Expmap(rng.normal(size=3)), rng.normal(size=3)))
    values.insert(y, gtsam.Pose3(gtsam.Rot3.Expmap(rng.normal(size=3)), rng.normal(size=3)))
    values.insert(l, rng.normal(size=3))
    values.insert(p, rng.normal(size=4) * 0.1)
    values.insert(vi, rng.normal(size=3))
    values.insert(vj, rng.normal(size=3))
    values.insert(b, np.array([0.01]))
    values.insert(g, rng.normal(size=3) * 1e-3)
    for key, val in ((kd, -0.004), (kb1, 0.011), (kd1, 0.003)):
        values.insert(key, np.array([val]))
    T_BS = np.eye(4)
    T_BS[:3, 3] = [0.6, 0.0, 0.3]
    d = DisplacementIntegral(
        dt=1.0,
        c=rng.normal(size=3),
        A=0.2 * np.eye(3),
        B=0.3 * gtsam.Rot3.Expmap(rng.normal(size=3)).matrix(),
        cov=np.eye(3) * 1e-4,
        n_samples=4,
        last_sample_age=0.1,
        last_sample=None,
    )
    pre = DvlPreintegrator(0.0, np.eye(3), accel_sigma=0.05, attitude_sigma=0.002)
    for t in (0.2, 0.4, 0.6, 0.8):  # a 1 s interval at the tank's 5 Hz DVL
        pre.add(t, so3_exp(rng.normal(size=3) * 0.01), rng.normal(size=3) * 0.3, np.eye(3) * 1e-4)
    huber = gtsam.noiseModel.mEstimator.Huber.Create(1.345)
    anchor = LineAnchor.from_points(np.zeros(3), np.array([1.0, 0.2, 0.1]))
    noise3 = gtsam.noiseModel.Isotropic.Sigma(3, 0.02)
    factors = {
        "line_factor (CustomFactor, 4)": line_factor(
            x, p, anchor, np.array([0.1, 0.2, 1.0]), np.array([0.5, 0.1, 1.1]), np.eye(4) * 1e-4, T_BS, huber
        ),
        "displacement_factor (CustomFactor, 3)": displacement_factor(x, y, vi, vj, d),
        "smoothed_displacement_factor (CustomFactor, 9)": smoothed_displacement_factor(
            x, y, vi, vj, pre.smoothed(1.0, so3_exp(rng.normal(size=3) * 0.01))
        ),
        "heading_bias_drift_factor (CustomFactor, 2)": heading_bias_drift_factor(b, kd, kb1, kd1, 1.0, 1e-4, 1e-6),
        "biased_attitude_factor (CustomFactor, 3)": biased_attitude_factor(
            x, b, gtsam.Rot3.Expmap(rng.normal(size=3)).matrix(), np.eye(3) * 1e-4
        ),
        "gyro_rotation_factor (CustomFactor, 3)": gyro_rotation_factor(
            x, y, g, gtsam.Rot3.Expmap(rng.normal(size=3) * 0.1).matrix(), -np.eye(3), np.zeros(3), 1e-3
        ),
        "depth_factor (built-in GPSFactorArm, 1)": depth_factor(x, 2.0, 1e-4, np.array([-0.5, 0.0, -0.1])),
        "point_factor (built-in BearingRangeFactor3D, 3)": point_factor(
            x, l, np.ones(3), np.eye(3) * 4e-4, np.eye(4), huber
        ),
        "BetweenFactorPose3 (6)": gtsam.BetweenFactorPose3(
            x, y, gtsam.Pose3(), gtsam.noiseModel.Isotropic.Sigma(6, 0.1)
        ),
        "PriorFactorPoint3 (3)": gtsam.PriorFactorPoint3(l, np.zeros(3), noise3),
    }
    out = {}
    for name, f in factors.items():
        walls, cpus = [], []
        for _ in range(5):
            t0, c0 = time.perf_counter(), time.process_time()
            for _ in range(n):
                f.linearize(values)
            walls.append((time.perf_counter() - t0) / n * 1e6)
            cpus.append((time.process_time() - c0) / n * 1e6)
        out[name] = {"wall_us": float(np.median(walls)), "cpu_us": float(np.median(cpus))}
    return {"linearize_us": out}


def plot_long(long: dict, png: str) -> None:
    """The long mission's cost per update for each 600 s of mission (median and p95) beside the
    map's size: flat cost while the map grows is what the window is for."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    w = long["by_600s"]
    t = np.array([x["t_s"] for x in w]) / 3600.0
    fig, ax = plt.subplots(figsize=(8, 4))
    ax.plot(t, [x["ms_median"] for x in w], "o-", label="median")
    ax.plot(t, [x["ms_p95"] for x in w], "s--", label="p95")
    ax.set_xlabel("mission time [h] (end of each 600 s)")
    ax.set_ylabel("graph update [ms]")
    ax.set_ylim(0, 1.3 * max(x["ms_p95"] for x in w))  # room for the legend above the curves
    ax2 = ax.twinx()
    ax2.plot(t, [x["landmarks"] for x in w], color="0.5", label="landmarks")
    ax2.set_ylabel("landmarks mapped")
    ax2.set_ylim(0, 1.3 * max(x["landmarks"] for x in w))
    lines = ax.get_legend_handles_labels()[0] + ax2.get_legend_handles_labels()[0]
    ax.legend(lines, [h.get_label() for h in lines], loc="upper center", ncol=3)
    ax.grid(alpha=0.3)
    slides = long.get("window_slides") or {}
    ax.set_title(
        f"{long['duration_h']:g} h lawnmower: {long['n_keyframes']} keyframes, {long['n_landmarks']} landmarks, "
        f"{slides.get('n', 0)} window slides",
        fontsize=10,
    )
    fig.tight_layout()
    fig.savefig(png, dpi=110)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--long-hours", type=float, default=2.0)
    ap.add_argument("--skip-long", action="store_true")
    ap.add_argument("--skip-default", action="store_true")
    ap.add_argument(
        "--window-s", type=float, default=None, help="the default mission's graph.window_s (e.g. 130: five slides)"
    )
    ap.add_argument(
        "--out", default=None, help="write the numbers as JSON here (and the long mission's cost as PNG beside it)"
    )
    ap.add_argument("--plot", default=None, metavar="JSON", help="only plot the long mission of an earlier --out")
    a = ap.parse_args()
    if a.plot:
        plot_long(json.load(open(a.plot))["long"], a.plot.removesuffix(".json") + "_long.png")
        return
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=1, user_api="blas")  # as run_pipeline does: small matrices, no thread contention
    report = {}
    print("factor cost ...", flush=True)
    report["factor_cost"] = bench_factor_cost()
    print(json.dumps(report["factor_cost"], indent=1), flush=True)
    if not a.skip_default:
        print("default mission ...", flush=True)
        report["default"] = bench_default(a.runs, a.window_s)
        print(json.dumps(report["default"], indent=1), flush=True)
    if not a.skip_long:
        print("long mission ...", flush=True)
        report["long"] = bench_long(a.long_hours)
        print(json.dumps(report["long"], indent=1), flush=True)
    if a.out:
        with open(a.out, "w") as fh:
            json.dump(report, fh, indent=1)
        if "long" in report:
            plot_long(report["long"], a.out.removesuffix(".json") + "_long.png")


if __name__ == "__main__":
    main()
