"""The odometry's relative poses chained over ``--delta`` seconds against the truth (issue 23's outage RPE):
how the error of a chain of consecutive registrations grows with its length (a random walk, √n, or less:
scan-to-map registrations share their map, so consecutive errors may cancel), against what the graph
believes of it (the consecutive covariances summed, as independent between-factors are), inside a DVL
outage and outside. Also the error along the motion (a scale bias grows linearly, not as √n).

    python experiments/odometry_chain.py --seeds 2 --loops 1.3 --start 100 [--outage 90] [--delta 10] [--cache DIR]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from odometry_eval import TruthInterpolator, pose_error, scenario_config, simulated

from frontends.odometry import OdometryFrontend
from frontends.odometry.information import adjoint
from frontends.odometry.matcher import ScanMatcher
from semslam.determinism import one_thread_per_library
from semslam.mission.measurements import GroundTruthPose


def registrations(mission, config: dict | None = None, record: dict | None = None) -> list:
    """The front-end's observations over ``mission`` (as in a run's worker); ``record`` (a dict) receives, per
    accepted scan's stamp, kiss-icp's correspondence σ and the correction ICP made to the prior (m)."""
    fe = OdometryFrontend(mission.metadata, config or {})
    obs, last = [], {}
    register = ScanMatcher.register

    def recorded(self, points, predicted, stamp, rotation_cov=None, translation_cov=None):
        sigma = self.kiss.adaptive_threshold.get_threshold()  # the σ this registration runs with
        reg = register(self, points, predicted, stamp, rotation_cov, translation_cov)
        last[stamp] = (float(sigma), float(np.linalg.norm(reg.correction[:3, 3])))
        return reg

    ScanMatcher.register = recorded
    try:
        with one_thread_per_library():
            for m in mission:
                obs += fe.process(m)
    finally:
        ScanMatcher.register = register
    if record is not None:
        record.update({z.stamp: last[z.stamp] for z in obs})
    return obs


def chains(obs: list, truth: TruthInterpolator, delta_s: float) -> list[dict]:
    """Every run of consecutive registrations (each starting where the last ended) spanning ≥ ``delta_s``:
    its composed relative pose's error against the truth and the covariance of independent factors."""
    out = []
    for a in range(len(obs)):
        T, S, t0 = np.eye(4), np.zeros((6, 6)), obs[a].stamp_from
        for b in range(a, len(obs)):
            z = obs[b]
            if b > a and z.stamp_from != obs[b - 1].stamp:
                break  # a map restart or a rejection broke the chain
            # T_0,b = T_0,b-1 · T_b-1,b: the covariance (right perturbation) moves through Ad(T_b-1,b)⁻¹
            A = adjoint(np.linalg.inv(z.relative_pose))
            S = A @ S @ A.T + z.covariance
            T = T @ z.relative_pose
            if (z.stamp - t0) * 1e-9 >= delta_s:
                truth_rel = np.linalg.inv(truth(t0)) @ truth(z.stamp)
                xi = pose_error(truth_rel, T)
                motion = truth_rel[:3, 3]
                along = motion / max(np.linalg.norm(motion), 1e-9)
                out.append(
                    {
                        "from": t0,
                        "to": z.stamp,
                        "n": b - a + 1,
                        "error": xi,
                        "trans_err": float(np.linalg.norm(xi[3:])),
                        "along_err": float(xi[3:] @ along),
                        "distance": float(np.linalg.norm(motion)),
                        "nees": float(xi @ np.linalg.solve(S, xi)),
                        "nees_trans": float(xi[3:] @ np.linalg.solve(S[3:, 3:], xi[3:])),
                        "sigma_trans": float(np.sqrt(np.trace(S[3:, 3:]))),
                    }
                )
                break
    return out


def summary(obs, truth, delta_s, window, record: dict) -> dict:
    single = []
    for z in obs:
        xi = pose_error(np.linalg.inv(truth(z.stamp_from)) @ truth(z.stamp), z.relative_pose)
        single.append(
            {
                "to": z.stamp,
                "trans_err": float(np.linalg.norm(xi[3:])),
                "sigma_trans": float(np.sqrt(np.trace(z.covariance[3:, 3:]))),
                "icp_sigma": record[z.stamp][0],
                "correction": record[z.stamp][1],
            }
        )
    ch = chains(obs, truth, delta_s)
    row = {}
    inside = lambda r: window[0] <= r["to"] <= window[1]  # noqa: E731
    for name, sel in (("all", lambda r: True), ("outage", inside), ("outside", lambda r: not inside(r))):
        s = [r for r in single if sel(r)]
        c = [r for r in ch if sel(r) and (name != "outage" or r["from"] >= window[0])]
        if not s or not c:
            continue
        rms1 = float(np.sqrt(np.mean([r["trans_err"] ** 2 for r in s])))
        rmsn = float(np.sqrt(np.mean([r["trans_err"] ** 2 for r in c])))
        n = float(np.mean([r["n"] for r in c]))
        row[name] = {
            "registrations": len(s),
            "single_trans_rmse_mm": 1e3 * rms1,
            "single_sigma_rms_mm": 1e3 * float(np.sqrt(np.mean([r["sigma_trans"] ** 2 for r in s]))),
            "icp_sigma_median_mm": 1e3 * float(np.median([r["icp_sigma"] for r in s])),
            "correction_median_mm": 1e3 * float(np.median([r["correction"] for r in s])),
            "chains": len(c),
            "chain_len_mean": n,
            "chain_trans_rmse_mm": 1e3 * rmsn,
            "random_walk_rmse_mm": 1e3 * rms1 * np.sqrt(n),
            "chain_sigma_rms_mm": 1e3 * float(np.sqrt(np.mean([r["sigma_trans"] ** 2 for r in c]))),
            "chain_nees_mean": float(np.mean([r["nees"] for r in c])),
            "chain_nees_trans_mean": float(np.mean([r["nees_trans"] for r in c])),
            "chain_along_mean_mm": 1e3 * float(np.mean([r["along_err"] for r in c])),
            "chain_along_rmse_mm": 1e3 * float(np.sqrt(np.mean([r["along_err"] ** 2 for r in c]))),
            "chain_distance_mean_m": float(np.mean([r["distance"] for r in c])),
        }
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="0")
    ap.add_argument("--loops", type=float, default=3.0)
    ap.add_argument("--start", type=float, default=200.0)
    ap.add_argument("--outage", type=float, default=90.0)
    ap.add_argument("--delta", type=float, default=10.0)
    ap.add_argument("--cache", type=Path)
    ap.add_argument("--config", help="odometry section as JSON")
    args = ap.parse_args()
    config = json.loads(args.config) if args.config else None
    for seed in (int(s) for s in args.seeds.split(",")):
        data = {
            "dvl": {"outage_s": [args.start, args.outage]},
            "trajectory": {"loops": args.loops, "look_away_s": None},
        }
        mission = simulated("tank", scenario_config("tank", seed, data), args.cache)
        truth = TruthInterpolator([m for m in mission if isinstance(m, GroundTruthPose)])
        t0 = next(iter(mission)).stamp
        window = (t0 + int(args.start * 1e9), t0 + int((args.start + args.outage) * 1e9))
        record: dict = {}
        obs = registrations(mission, config, record)
        print(f"seed {seed}: {json.dumps(summary(obs, truth, args.delta, window, record))}", flush=True)


if __name__ == "__main__":
    main()
