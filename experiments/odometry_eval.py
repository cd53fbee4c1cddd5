"""Laser odometry against ground truth on simulated missions (the tank's, or the pipeline's stereo
clouds over a natural seabed): how many registrations the gate accepts and why it rejects the others,
the error of the accepted relative poses, their NEES against the front-end's covariance (6-DoF: the
95% χ² band of the mean over n registrations), and the time per scan (wall and CPU).

    python experiments/odometry_eval.py [--seeds 0,1] [--duration 120] [--config JSON] [--profile N]
    python experiments/odometry_eval.py --scenario pipeline --seeds 1 [--outage 40,60] [--cache DIR]
    python experiments/odometry_eval.py --seeds 9 --duration 200 --pairs /tmp/pairs  # one JSON line per pair
"""

from __future__ import annotations

import argparse
import cProfile
import hashlib
import json
import pickle
import pstats
import time
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation, Slerp
from scipy.stats import chi2

from frontends.odometry import OdometryFrontend
from frontends.odometry.config import STEREO_SEABED
from semslam.determinism import one_thread_per_library
from semslam.mission.measurements import GroundTruthPose, PointCloud
from semslam.mission.mission import Mission
from semslam.sim.scenarios import resolve_config, scenario
from semslam.sim.vary import ASPECTS


def scenario_config(name: str, seed: int, data: dict):
    """The simulator's configuration of ``seed`` (its world drawn by the seed: the tank's varied aspects)
    with ``data`` over it."""
    return resolve_config(name, seed, ASPECTS if name == "tank" else (), data=data)


def simulated(name: str, cfg, cache: Path | None = None) -> Mission:
    """The simulated mission of scenario ``name`` and configuration ``cfg``, from ``cache`` when it was
    simulated before."""
    key = hashlib.sha1(cfg.model_dump_json().encode()).hexdigest()[:16]  # the scenarios' models differ
    path = cache / f"{key}.pkl" if cache else None
    if path is not None and path.exists():
        metadata, items = pickle.loads(path.read_bytes())
        return Mission.from_measurements(metadata, items)
    mission = scenario(name).simulator()(cfg)
    if path is not None:
        cache.mkdir(parents=True, exist_ok=True)
        path.write_bytes(pickle.dumps((mission.metadata, list(mission))))
    return mission


class TruthInterpolator:
    def __init__(self, poses: list[GroundTruthPose]):
        self.t = np.array([p.stamp for p in poses], np.int64)
        self.p = np.array([p.position for p in poses])
        self.slerp = Slerp(self.t.astype(float), Rotation.from_quat([p.orientation for p in poses]))

    def __call__(self, stamp: int) -> np.ndarray:
        T = np.eye(4)
        T[:3, :3] = self.slerp(float(stamp)).as_matrix()
        T[:3, 3] = [np.interp(stamp, self.t, self.p[:, k]) for k in range(3)]
        return T


def pose_error(T_true: np.ndarray, T_meas: np.ndarray) -> np.ndarray:
    """ξ with T_meas = T_true·Exp(ξ), (rotation, translation), to first order."""
    E = np.linalg.inv(T_true) @ T_meas
    return np.concatenate([Rotation.from_matrix(E[:3, :3]).as_rotvec(), E[:3, 3]])


def evaluate(
    mission, config: dict | None = None, window: tuple[int, int] | None = None, pairs: list | None = None
) -> dict:
    """The summary; with ``window`` (stamps), also the NEES of the registrations ending inside it and outside;
    ``pairs`` (a list) receives one record per accepted registration (its error, σ and NEES by block)."""
    items = list(mission)
    truth = TruthInterpolator([m for m in items if isinstance(m, GroundTruthPose)])
    fe = OdometryFrontend(mission.metadata, config or {})
    obs, times, cpu = [], [], []
    with one_thread_per_library():  # as in a run: the same mission gives the same registrations
        for m in items:
            t0, c0 = time.perf_counter(), time.process_time()
            out = fe.process(m)
            if isinstance(m, PointCloud):
                times.append(time.perf_counter() - t0)
                cpu.append(time.process_time() - c0)
            obs += out
    errors, nees, nees_rot, nees_trans = [], [], [], []
    for z in obs:
        xi = pose_error(np.linalg.inv(truth(z.stamp_from)) @ truth(z.stamp), z.relative_pose)
        errors.append(xi)
        nees.append(float(xi @ np.linalg.solve(z.covariance, xi)))
        nees_rot.append(float(xi[:3] @ np.linalg.solve(z.covariance[:3, :3], xi[:3])))
        nees_trans.append(float(xi[3:] @ np.linalg.solve(z.covariance[3:, 3:], xi[3:])))
        if pairs is not None:
            pairs.append(
                {
                    "stamp": z.stamp,
                    "stamp_from": z.stamp_from,
                    "error": xi.tolist(),  # body frame: rotation (rad), translation (m)
                    "sigma": np.sqrt(np.diag(z.covariance)).tolist(),
                    "nees": nees[-1],
                    "nees_rotation": nees_rot[-1],
                    "nees_translation": nees_trans[-1],
                }
            )
    errors = np.array(errors).reshape(-1, 6)
    n = len(nees)
    band = (chi2.ppf(0.025, 6 * n) / n, chi2.ppf(0.975, 6 * n) / n) if n else (None, None)
    summary = fe.finish().metrics
    if window is not None and n:
        inside = np.array([window[0] <= z.stamp <= window[1] for z in obs])
        nees_a = np.array(nees)
        summary["nees_mean_in_window"] = float(np.mean(nees_a[inside])) if inside.any() else None
        summary["nees_mean_outside_window"] = float(np.mean(nees_a[~inside])) if (~inside).any() else None
        summary["accepted_in_window"] = int(inside.sum())
    return {
        **summary,
        "rotation_error_deg_median": float(np.degrees(np.median(np.linalg.norm(errors[:, :3], axis=1)))) if n else None,
        "translation_error_m_median": float(np.median(np.linalg.norm(errors[:, 3:], axis=1))) if n else None,
        "translation_error_m_max": float(np.max(np.linalg.norm(errors[:, 3:], axis=1))) if n else None,
        "nees_mean": float(np.mean(nees)) if n else None,
        "nees_band_95": band,
        "nees_median": float(np.median(nees)) if n else None,
        "nees_rotation_mean": float(np.mean(nees_rot)) if n else None,
        "nees_translation_mean": float(np.mean(nees_trans)) if n else None,
        "sigma_rotation_deg_median": float(
            np.degrees(np.median([np.sqrt(np.trace(z.covariance[:3, :3])) for z in obs]))
        )
        if n
        else None,
        "sigma_translation_m_median": float(np.median([np.sqrt(np.trace(z.covariance[3:, 3:])) for z in obs]))
        if n
        else None,
        "ms_per_scan_median": 1e3 * float(np.median(times)),
        "ms_per_scan_p95": 1e3 * float(np.percentile(times, 95)),
        "cpu_ms_per_scan_median": 1e3 * float(np.median(cpu)),
        "cpu_ms_per_scan_p95": 1e3 * float(np.percentile(cpu, 95)),
        "cpu_s_total": float(np.sum(cpu)),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", choices=("tank", "pipeline"), default="tank")
    ap.add_argument("--seeds", default="0")
    ap.add_argument("--duration", type=float, default=120.0, help="tank mission length (s; the pipeline's: its passes)")
    ap.add_argument("--outage", help="START,LENGTH (s): the simulator's long DVL outage (dvl.outage_s)")
    ap.add_argument(
        "--config", default=None, help="front-end section as JSON (default: the tank's defaults, STEREO_SEABED)"
    )
    ap.add_argument("--cache", type=Path, help="keep the simulated missions here (pickled) and reuse them")
    ap.add_argument("--sim", default="{}", help="simulator overrides as JSON (sections merged over the seed's draws)")
    ap.add_argument("--pairs", type=Path, help="write each seed's registrations to DIR/seed<N>.jsonl (error, σ, NEES)")
    ap.add_argument("--profile", type=int, default=0, help="print this many functions by own CPU time")
    args = ap.parse_args()
    config = json.loads(args.config) if args.config else STEREO_SEABED if args.scenario == "pipeline" else {}
    for seed in (int(s) for s in args.seeds.split(",")):
        data = json.loads(args.sim)
        if args.scenario == "tank":  # the default speed, not the default loops squeezed
            data["trajectory"] = {"loops": max(args.duration - 20.0, 10.0) / 156.6667} | data.get("trajectory", {})
        window = None
        if args.outage:
            start, length = (float(v) for v in args.outage.split(","))
            data["dvl"] = data.get("dvl", {}) | {"outage_s": [start, length]}
        mission = simulated(args.scenario, scenario_config(args.scenario, seed, data), args.cache)
        if args.outage:
            t0 = next(iter(mission)).stamp
            window = (t0 + int(start * 1e9), t0 + int((start + length) * 1e9))
        profiler = cProfile.Profile(time.process_time) if args.profile else None
        if profiler:
            profiler.enable()
        pairs = [] if args.pairs else None
        r = evaluate(mission, config, window, pairs)
        if args.pairs:
            args.pairs.mkdir(parents=True, exist_ok=True)
            (args.pairs / f"seed{seed}.jsonl").write_text("".join(json.dumps(p) + "\n" for p in pairs))
        print(f"seed {seed}: " + json.dumps(r), flush=True)
        if profiler:
            profiler.disable()
            pstats.Stats(profiler).sort_stats("tottime").print_stats(args.profile)


if __name__ == "__main__":
    main()
