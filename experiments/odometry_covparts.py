"""The odometry covariance's parts per registration, and models of it fitted by likelihood (issue 23,
stop 40): each accepted registration (attitude held to the navigation's) recorded with the parts its
covariance is made of — the point-to-plane information at the solution, the residuals' variance, the
laser's range noise measured on the floor, the inlier and point counts, the navigation prior's
rotation covariance, the Student-t factor — with its error against the simulator's truth and the
candidate predictors (the motion since the last scan, the correction to the prior, the DVL's hold);
then the NEES of covariance models on those records, per seed and per block.

    python experiments/odometry_covparts.py record --seeds 1,3 --out /tmp/parts [--cache DIR] [--config JSON]
    python experiments/odometry_covparts.py fit --tuning 1,3,5 --report 19,20 /tmp/parts  # the models' NEES
    python experiments/odometry_covparts.py judge --seeds 19,20 /tmp/parts  # main against the defaults

Every model is the front-end's own (``frontends.odometry.matcher.held_covariance``) with other
coefficients: the records keep the parts, so a model is judged offline on the same registrations.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from odometry_eval import TruthInterpolator, pose_error, scenario_config, simulated
from scipy.optimize import minimize
from scipy.stats import chi2

import frontends.odometry.frontend as odometry_frontend
from frontends.odometry import OdometryFrontend
from frontends.odometry.config import CovarianceSettings
from frontends.odometry.information import adjoint
from frontends.odometry.matcher import ScanMatcher, held_covariance
from semslam.determinism import one_thread_per_library
from semslam.mission.measurements import GroundTruthPose

LOOPS_200S = (200 - 20.0) / 156.6667  # the tank's 200 s mission (earlier stops' development seeds)


class _PartsMatcher(ScanMatcher):
    """The front-end's matcher, keeping the parts of the last held covariance it made."""

    def _held_covariance(self, info, residual_var, n, icp_cov, rotation_cov, R_OS):
        self.parts = {
            "information_S": info.copy(),
            "residual_var": float(residual_var),
            "inliers": int(n),
            "range_var": np.nan if self.range_variance is None else self.range_variance,
            "rotation_cov_S": rotation_cov.copy(),
        }
        return super()._held_covariance(info, residual_var, n, icp_cov, rotation_cov, R_OS)

    def register(self, points, predicted, stamp, rotation_cov=None, translation_cov=None):
        reg = super().register(points, predicted, stamp, rotation_cov, translation_cov)
        self.parts.update(points=reg.points, correction_S=pose_error(np.eye(4), reg.correction))
        return reg


class _PartsFrontend(OdometryFrontend):
    def _tail_factor(self, reg, prior_S):
        self.tail = super()._tail_factor(reg, prior_S)
        return self.tail


def record(mission, config: dict) -> dict[str, np.ndarray]:
    items = list(mission)
    truth = TruthInterpolator([m for m in items if isinstance(m, GroundTruthPose)])
    fe = _PartsFrontend(mission.metadata, config)
    rows: dict[str, list] = {}
    odometry_frontend.ScanMatcher = _PartsMatcher  # the tracks' matchers, made at their first scan
    with one_thread_per_library():  # as in a run: the same mission gives the same registrations
        for m in items:
            for z in fe.process(m):
                track = fe._tracks[z.sensor]
                A = adjoint(mission.metadata.extrinsic(z.sensor))
                T_true = np.linalg.inv(truth(z.stamp_from)) @ truth(z.stamp)
                error_B = pose_error(T_true, z.relative_pose)
                row = {
                    **track.matcher.parts,
                    "stamp": z.stamp,
                    "stamp_from": z.stamp_from,
                    "A": A,
                    "tail": fe.tail,
                    "tail_dof": fe.config.covariance.tail_dof,
                    "covariance_B": z.covariance,
                    "error_B": error_B,
                    "error_S": np.linalg.solve(A, error_B),
                    "motion_B": pose_error(np.eye(4), T_true),
                }
                for k, v in row.items():
                    rows.setdefault(k, []).append(v)
    odometry_frontend.ScanMatcher = ScanMatcher
    return {k: np.array(v) for k, v in rows.items()}


# ---------------------------------------------------------------- models


def model_covariances(d: dict, c: CovarianceSettings, tail_rotation: bool = False) -> np.ndarray:
    """Body-frame covariances the front-end would emit with covariance settings ``c`` (attitude held);
    ``tail_rotation``: the Student-t factor multiplies the whole covariance (main before stop 40), not
    the translation's measured part alone. :func:`held_covariance` written for all the records at once
    (``check`` asserts the two agree)."""
    nu0 = float(np.ravel(d["tail_dof"])[0]) if "tail_dof" in d else 34.0  # the records' ν, 34 before stop 40's recorder
    d2 = d["tail"] * (nu0 + 6) - nu0
    tail = (c.tail_dof + d2) / (c.tail_dof + 6) if c.tail_dof > 0 else np.ones(len(d2))
    H = d["information_S"]
    H_tt_inv = np.linalg.inv(H[:, 3:, 3:])
    K = -H_tt_inv @ H[:, 3:, :3]
    eye = np.eye(3)
    rot = d["rotation_cov_S"]
    per_point = c.held_residual_scale * d["residual_var"]
    if c.range_noise_scale > 0:
        per_point = per_point + c.range_noise_scale * np.nan_to_num(d["range_var"]) * d["inliers"]
    measured = per_point[:, None, None] * H_tt_inv + eye * c.held_floor_sigma_m**2
    KR = K @ rot
    cov = np.zeros((len(H), 6, 6))
    cov[:, :3, :3] = rot
    cov[:, 3:, :3] = KR
    cov[:, :3, 3:] = np.transpose(KR, (0, 2, 1))
    cov[:, 3:, 3:] = tail[:, None, None] * measured + KR @ np.transpose(K, (0, 2, 1))
    if tail_rotation:
        cov[:, 3:, 3:] -= (tail[:, None, None] - 1) * measured
        cov = cov * tail[:, None, None]
    return d["A"] @ cov @ np.transpose(d["A"], (0, 2, 1))


def check(d: dict, c: CovarianceSettings) -> None:
    """Asserts :func:`model_covariances` is the front-end's :func:`held_covariance` on these records."""
    f = (c.tail_dof + d["tail"] * 40 - 34) / (c.tail_dof + 6)
    ours = model_covariances(d, c)
    for i in range(len(ours)):
        rv = d["range_var"][i]
        cov, part = held_covariance(
            d["information_S"][i],
            d["residual_var"][i],
            rv if np.isfinite(rv) else None,
            d["inliers"][i],
            d["rotation_cov_S"][i],
            c,
        )
        theirs = d["A"][i] @ (cov + (f[i] - 1) * part) @ d["A"][i].T
        assert np.allclose(ours[i], theirs, rtol=1e-9, atol=1e-15), i


def nees(errors: np.ndarray, cov: np.ndarray, block: slice = slice(0, 6)) -> np.ndarray:
    e, C = errors[:, block], cov[:, block, block]
    return np.einsum("ni,ni->n", e, np.linalg.solve(C, e[..., None])[..., 0])


def band(n: int, dof: int = 6) -> tuple[float, float]:
    return chi2.ppf(0.025, dof * n) / n, chi2.ppf(0.975, dof * n) / n


#: the models compared: their free coefficients (fitted in log) over main's, and whether the Student-t
#: factor multiplies the rotation too (main's)
MODELS = {
    "main": ([], True),
    "main_tail_t": ([], False),
    "residual": (["held_residual_scale", "held_floor_sigma_m"], False),
    "range": (["range_noise_scale", "held_floor_sigma_m"], False),
    "both": (["held_residual_scale", "range_noise_scale", "held_floor_sigma_m"], False),
    "both_tail_r": (["held_residual_scale", "range_noise_scale", "held_floor_sigma_m"], True),
    "both_nu": (["held_residual_scale", "range_noise_scale", "held_floor_sigma_m", "tail_dof"], False),
}
#: main's coefficients (held_scale 0.39 × (scale 8.2 · σ²H⁻¹ + floor (3.5 mm)²))
MAIN = CovarianceSettings(
    held_residual_scale=0.39 * 8.2,
    held_floor_sigma_m=0.39**0.5 * 0.0035,
    range_noise_scale=0.0,
    tail_dof=34.0,
)


def deviance(data: dict[int, dict], seeds: list[int], c: CovarianceSettings, tail_rotation: bool) -> float:
    """−2 log-likelihood (up to a constant) of the seeds' errors, Gaussian with the model's covariances."""
    total = 0.0
    for s in seeds:
        cov = model_covariances(data[s], c, tail_rotation)
        total += np.sum(np.linalg.slogdet(cov)[1] + nees(data[s]["error_B"], cov))
    return total if np.isfinite(total) else 1e30


def fitted(data: dict[int, dict], tuning: list[int], model: str, base: CovarianceSettings = MAIN) -> CovarianceSettings:
    """The model's coefficients of largest Gaussian likelihood of the tuning seeds' errors (6-DoF)."""
    free, tail_rotation = MODELS[model]

    def settings(x):
        return base.model_copy(update={k: float(np.exp(v)) for k, v in zip(free, x)})

    def cost(x):
        return deviance(data, tuning, settings(x), tail_rotation)

    if not free:
        return base

    start = {"held_floor_sigma_m": 1e-3}
    x0 = [np.log(max(getattr(base, k), start.get(k, 0.01))) for k in free]
    best = minimize(cost, x0, method="Nelder-Mead", options={"xatol": 1e-3, "fatol": 1e-3, "maxiter": 4000})
    return settings(best.x)


def table(data: dict[int, dict], per_seed: dict[int, tuple], tuning: list[int]) -> tuple[int, float]:
    """Prints per seed the 6-DoF NEES mean (and the band), the translation's and the rotation's (3-DoF,
    body frame) under its (settings, tail_rotation); returns (seeds in the band, mean |log(NEES/6)|)."""
    inside, logs = 0, []
    for s, d in data.items():
        cov = model_covariances(d, *per_seed[s])
        e6 = nees(d["error_B"], cov)
        et, er = nees(d["error_B"], cov, slice(3, 6)), nees(d["error_B"], cov, slice(0, 3))
        lo, hi = band(len(e6))
        where = "in" if lo <= e6.mean() <= hi else ("under" if e6.mean() < lo else "over")
        inside += where == "in"
        logs.append(abs(np.log(e6.mean() / 6)))
        print(
            f"  seed {s:2d}{'*' if s in tuning else ' '} n {len(e6):3d} 6-DoF {e6.mean():6.2f} (band {lo:.2f}-{hi:.2f} "
            f"{where:5s}) median {np.median(e6):5.2f}  translation {et.mean():5.2f}  rotation {er.mean():5.2f}  "
            f"range σ {np.sqrt(np.nanmedian(d['range_var'])) * 1e3:.1f} mm  residual σ "
            f"{np.sqrt(np.median(d['residual_var'])) * 1e3:.1f} mm"
        )
    print(f"  in the band: {inside} of {len(data)}, mean |log(NEES/6)| {np.mean(logs):.3f}")
    return inside, float(np.mean(logs))


def load(directory: Path, seeds: list[int]) -> dict[int, dict]:
    return {s: dict(np.load(directory / f"seed{s}.npz")) for s in seeds}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    rec = sub.add_parser("record")
    rec.add_argument("--seeds", required=True)
    rec.add_argument("--out", type=Path, required=True)
    rec.add_argument("--cache", type=Path)
    rec.add_argument("--config", default="{}", help="front-end section as JSON")
    ft = sub.add_parser("fit")
    ft.add_argument("directory", type=Path)
    ft.add_argument("--tuning", required=True, help="seeds the coefficients are fitted on")
    ft.add_argument("--report", default="", help="seeds only judged")
    ft.add_argument("--models", default=",".join(MODELS))
    ft.add_argument("--cross", action="store_true", help="also leave each tuning seed out of the fit in turn")
    jd = sub.add_parser("judge", help="main's covariance against the front-end's defaults on the same registrations")
    jd.add_argument("directory", type=Path)
    jd.add_argument("--seeds", required=True)
    args = ap.parse_args()
    if args.cmd == "record":
        args.out.mkdir(parents=True, exist_ok=True)
        for seed in (int(s) for s in args.seeds.split(",")):
            mission = simulated(
                "tank", scenario_config("tank", seed, {"trajectory": {"loops": LOOPS_200S}}), args.cache
            )
            r = record(mission, json.loads(args.config))
            np.savez(args.out / f"seed{seed}.npz", **r)
            print(f"seed {seed}: {len(r['stamp'])} accepted", flush=True)
        return
    if args.cmd == "judge":
        data = load(args.directory, [int(s) for s in args.seeds.split(",")])
        for name, c, tail_rotation in (
            ("main (7b17c54)", MAIN, True),
            ("the front-end's defaults", CovarianceSettings(), False),
        ):
            print(f"{name}: −2 log-likelihood {deviance(data, list(data), c, tail_rotation):.1f}")
            table(data, {s: (c, tail_rotation) for s in data}, [])
        return
    tuning = [int(s) for s in args.tuning.split(",")]
    report = [int(s) for s in args.report.split(",") if s]
    data = load(args.directory, tuning + report)
    for model in args.models.split(","):
        free, tail_rotation = MODELS[model]
        c = fitted(data, tuning, model)
        print(
            f"model {model} (tail on the rotation: {tail_rotation}): "
            + ", ".join(f"{k} {getattr(c, k):.4g}" for k in free)
            + f"; −2 log-likelihood on the tuning seeds {deviance(data, tuning, c, tail_rotation):.1f}"
        )
        table(data, {s: (c, tail_rotation) for s in data}, tuning)
        if args.cross and len(tuning) > 2:  # each tuning seed judged with the coefficients fitted on the others
            print("  left out, fitted on the others:")
            own = {s: (fitted(data, [t for t in tuning if t != s], model), tail_rotation) for s in tuning}
            table({s: data[s] for s in tuning}, own, [])


if __name__ == "__main__":
    main()
