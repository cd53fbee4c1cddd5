"""Why the odometry's NEES differs between worlds (issue 23): each accepted registration recorded with
what its covariance is made of (point-to-plane information, residual variance, inliers), its error
against the simulator's truth, the error of the navigation prior it started from, and the DVL
readings of its interval; then the NEES of covariance models on those records, per seed.

    python experiments/odometry_covariance.py record --seeds 1,2,3 --duration 200 --out /tmp/odo
    python experiments/odometry_covariance.py nees /tmp/odo/seed*.npz
    python experiments/odometry_covariance.py cauchy /tmp/odo/*.npz     # the graph's m-estimator width

``record`` runs the front-end as configured (``--config`` JSON) and keeps, per accepted scan, the
covariance it emitted; ``nees`` prints the NEES of the emitted covariance per seed with its 95 % band.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from odometry_eval import TruthInterpolator, pose_error, simulated
from scipy.optimize import minimize_scalar
from scipy.special import gammaln
from scipy.stats import chi2

import frontends.odometry.frontend as odometry_frontend
from frontends.odometry import OdometryFrontend
from frontends.odometry.matcher import ScanMatcher
from frontends.odometry.prior import NavigationPrior
from semslam.mission.measurements import DvlVelocity, GroundTruthPose, PointCloud
from semslam.sim.scenarios import resolve_config
from semslam.sim.vary import ASPECTS


class RecordingMatcher(ScanMatcher):
    """The front-end's matcher, keeping every registration and map start it makes."""

    log: list = []

    def start(self, points, pose, stamp):
        ok = super().start(points, pose, stamp)
        RecordingMatcher.log.append(("start", ok))
        return ok

    def register(self, points, predicted, stamp, rotation_cov=None, translation_cov=None):
        reg = super().register(points, predicted, stamp, rotation_cov, translation_cov)
        RecordingMatcher.log.append(("register", reg))
        return reg


def record(mission, config: dict) -> dict[str, np.ndarray]:
    items = list(mission)
    truth_B = TruthInterpolator([m for m in items if isinstance(m, GroundTruthPose)])
    dvl = [(m.stamp, m.valid) for m in items if isinstance(m, DvlVelocity)]
    dvl_t = np.array([s for s, _ in dvl])
    dvl_ok = np.array([v for _, v in dvl])
    odometry_frontend.ScanMatcher = RecordingMatcher
    RecordingMatcher.log = []
    fe = OdometryFrontend(mission.metadata, config)
    sensor = next(iter(fe.sensors))
    T_BS = mission.metadata.extrinsic(sensor)

    def truth_S(stamp):
        return truth_B(stamp) @ T_BS

    rows: dict[str, list] = {}
    map_start = None
    regs: dict[int, object] = {}
    times, walls = [], []
    # the prior's covariance is linear in hold_walk²: two side priors give it for any hold_walk
    side = {q: NavigationPrior(mission.metadata, fe.prior.horizon_ns * 1e-9, hold_walk_m_s=q) for q in (0.0, 1.0)}
    for m in items:
        for p in side.values():
            p.add(m)
        n = len(RecordingMatcher.log)
        t0, w0 = time.process_time(), time.perf_counter()
        out = fe.process(m)
        if isinstance(m, PointCloud):
            times.append(time.process_time() - t0)
            walls.append(time.perf_counter() - w0)
        for kind, what in RecordingMatcher.log[n:]:
            if kind == "start" and what:
                map_start = m.stamp
            elif kind == "register":
                regs[m.stamp] = (what, map_start)
        for z in out:
            reg, start = regs[z.stamp]
            T_true_rel = np.linalg.inv(truth_B(z.stamp_from)) @ truth_B(z.stamp)
            T_true_OS = np.linalg.inv(truth_S(start)) @ truth_S(z.stamp)
            T_true_OS_from = np.linalg.inv(truth_S(start)) @ truth_S(z.stamp_from)
            # the prior's relative motion (sensor frame) from the anchor's registered pose to the prediction
            anchor = reg.pose @ np.linalg.inv(np.linalg.inv(T_BS) @ z.relative_pose @ T_BS)
            prior_rel_S = np.linalg.inv(anchor) @ (reg.pose @ np.linalg.inv(reg.correction))
            true_rel_S = np.linalg.inv(T_true_OS_from) @ T_true_OS
            inside = (dvl_t > z.stamp_from) & (dvl_t <= z.stamp)
            row = {
                "stamp": z.stamp,
                "stamp_from": z.stamp_from,
                "map_start": start,
                "error_B": pose_error(T_true_rel, z.relative_pose),
                "covariance_B": z.covariance,
                "prior_cov_B": fe.prior.motion_covariance(z.stamp_from, z.stamp),
                "prior_cov0_B": side[0.0].motion_covariance(z.stamp_from, z.stamp),
                "prior_cov1_B": side[1.0].motion_covariance(z.stamp_from, z.stamp),
                "information_S": reg.information,
                "residual_var": reg.residual_var,
                "inliers": reg.inliers,
                "points": reg.points,
                "error_abs_S": pose_error(T_true_OS, reg.pose),
                "error_anchor_S": pose_error(T_true_OS_from, anchor),
                "error_prior_S": pose_error(true_rel_S, prior_rel_S),
                "correction": pose_error(np.eye(4), reg.correction),
                "motion_B": pose_error(np.eye(4), T_true_rel),
                "dvl_readings": int(inside.sum()),
                "dvl_valid": int((inside & dvl_ok).sum()),
                "hold_s": _longest_hold(dvl_t[dvl_ok], z.stamp_from, z.stamp),
            }
            for k, v in row.items():
                rows.setdefault(k, []).append(v)
    out = {k: np.array(v) for k, v in rows.items()}
    out["T_BS"] = T_BS
    out["prior_has_depth"] = np.array(True)
    out["ms_per_scan"] = 1e3 * np.array(times)  # CPU (process time)
    out["ms_per_scan_wall"] = 1e3 * np.array(walls)
    out["summary"] = np.array(json.dumps(fe.finish().metrics))
    return out


def _longest_hold(valid_stamps: np.ndarray, lo: int, hi: int) -> float:
    """Longest stretch of [lo, hi] (s) on a DVL velocity read before it (held through a dropout)."""
    inside = valid_stamps[(valid_stamps > lo) & (valid_stamps < hi)]
    before = valid_stamps[valid_stamps <= lo]
    edges = np.r_[before[-1] if len(before) else lo, inside, hi]
    ends = np.maximum(edges[1:], lo)
    return float(np.max(ends - np.maximum(edges[:-1], lo)) * 1e-9)


def nees_band(n: int, dof: int = 6) -> tuple[float, float]:
    return chi2.ppf(0.025, dof * n) / n, chi2.ppf(0.975, dof * n) / n


def nees(errors: np.ndarray, covariances: np.ndarray) -> np.ndarray:
    return np.einsum("ni,ni->n", errors, np.linalg.solve(covariances, errors[..., None])[..., 0])


def model_covariance(
    d,
    k: float,
    alpha: float,
    floor_m: float,
    floor_rad: float,
    walk: float = 0.02,
    beta: float = 0.0,
    c: float = 0.0,
    p: float = 1.0,
    g: float = 0.0,
    gamma: float = 0.0,
    depth: float = 1.0,
    nu: float = 0.0,
) -> np.ndarray:
    """Body-frame covariances of a model: k·σ²H⁻¹ and a floor in the sensor frame, plus α times the
    navigation prior's own covariance over the interval (the part of its error ICP leaves)."""
    from frontends.odometry.information import adjoint

    A = adjoint(d["T_BS"])
    H = d["information_S"]
    # p: how the residuals' variance scales it (1: σ²H⁻¹); g: inliers^g (1: residuals not independent)
    scale = k * d["residual_var"] ** p * d["inliers"].astype(float) ** g
    geom = scale[:, None, None] * np.linalg.inv(H)
    floor = np.diag([floor_rad**2] * 3 + [floor_m**2] * 3)
    prior = d["prior_cov0_B"] + walk**2 * (d["prior_cov1_B"] - d["prior_cov0_B"])
    if "depth_var" in d:  # the depth readings' part, apart (see _loaded)
        prior = prior.copy()
        prior[:, 5, 5] += depth * 2 * d["depth_var"]
    corr = d["correction"] ** 2  # γ: the registration's own correction to the prior, squared, per axis group
    moved = np.zeros_like(geom)
    moved[:, [0, 1, 2], [0, 1, 2]] = corr[:, :3].sum(1, keepdims=True)
    moved[:, [3, 4, 5], [3, 4, 5]] = corr[:, 3:].sum(1, keepdims=True)
    own = A @ (geom + floor + gamma * moved) @ A.T
    # β: the anchor's own registration error, when the anchor was registered (not a map start)
    registered_anchor = np.r_[False, d["stamp_from"][1:] == d["stamp"][:-1]]
    anchor = np.where(registered_anchor[:, None, None], np.concatenate([own[:1], own[:-1]]), 0.0)
    if nu > 0:  # Student-t: the scale given how far ICP moved from the prior, against the prior's covariance
        Ainv = np.linalg.inv(A)
        nis = nees(d["correction"], np.einsum("ij,njk,lk->nil", Ainv, prior, Ainv))
        own = own * ((nu + nis) / (nu + 6))[:, None, None]
    cov = own + beta * anchor + alpha * prior
    if c > 0:  # the prior's error kept where the scan's information is below the prior's (weight c)
        Ainv = np.linalg.inv(A)
        P = Ainv @ prior @ Ainv.T
        P_inv = np.linalg.inv(P) / c
        info = H / scale[:, None, None]
        J = np.linalg.solve(info + P_inv, P_inv)
        cov = cov + A @ (J @ P @ np.transpose(J, (0, 2, 1))) @ A.T
    return cov


def cauchy_loglik(d2: np.ndarray, c: float) -> np.ndarray:
    """Log-density (up to the covariance's determinant) of 6-D errors whose negative log is the Cauchy
    m-estimator's ρ(d) = c²/2·log(1 + d²/c²) on the whitened distance d: a multivariate t with
    ν = c² − 6 and scale c²/ν (normalisable for c² > 6)."""
    c2 = c * c
    return gammaln(c2 / 2) - gammaln((c2 - 6) / 2) - 3 * np.log(np.pi * c2) - c2 / 2 * np.log1p(d2 / c2)


def cauchy(files: list[Path]) -> None:
    """The Cauchy width c by likelihood on the tuning files (those not named report*), then, per file,
    the log-likelihood per registration of the Cauchy and the Gaussian, the width fitted on that file
    alone, and the kernel-weighted NEES mean E[w·d²], w = 1/(1 + d²/c²), with the 95 % band a
    consistent Gaussian's would have (4.73 for c = 5.3)."""
    d2 = {f.stem: nees(np.load(f)["error_B"], np.load(f)["covariance_B"]) for f in files}

    def width(e):
        r = minimize_scalar(lambda c: -cauchy_loglik(e, c).sum(), bounds=(2.45, 100.0), method="bounded")
        return r.x

    tuning = np.concatenate([e for k, e in d2.items() if not k.startswith("report")])
    c = width(tuning)
    print(f"c = {c:.2f} fitted on {len(tuning)} tuning registrations")
    x = chi2.rvs(6, size=400_000, random_state=0)
    wx = x / (1 + x / c**2)
    for name, e in d2.items():
        we = e / (1 + e / c**2)
        half = 1.96 * wx.std() / np.sqrt(len(e))
        gauss = -3 * np.log(2 * np.pi) - e / 2
        print(
            f"{name}: n {len(e)} loglik/n Cauchy {cauchy_loglik(e, c).mean():.2f} Gaussian {gauss.mean():.2f}, "
            f"own c {width(e):.1f}, weight < 0.5: {np.mean(e > c**2):.2f}, E[w d2] {we.mean():.2f} "
            f"(Gaussian {wx.mean():.2f}, band {wx.mean() - half:.2f}-{wx.mean() + half:.2f})"
        )


def fit(files: list[Path], model: str, objective: str = "nll") -> None:
    """Fits the model's free parameters to the tuning files (mean NEES per seed close to 6, in log)
    and prints the NEES per seed of every file with it."""
    from scipy.optimize import minimize

    data = {f: _loaded(f) for f in files}
    tuning = [f for f in files if not f.stem.startswith("report")]
    free = {
        "floor": ["floor_m", "floor_rad"],
        "leak": ["alpha", "floor_m", "floor_rad"],
        "walk": ["alpha", "floor_m", "floor_rad", "walk"],
        "anchor": ["beta", "floor_m", "floor_rad"],
        "kept": ["k", "c", "floor_m", "floor_rad"],
        "moved": ["k", "gamma", "floor_m", "floor_rad"],
        "shape": ["k", "p", "g", "floor_m", "floor_rad"],
        "shapemoved": ["k", "p", "g", "gamma", "floor_m", "floor_rad"],
        "points": ["k", "g", "floor_m", "floor_rad"],
        "pointsleak": ["k", "g", "alpha", "floor_m", "floor_rad"],
        "pointskept": ["k", "g", "c", "floor_m", "floor_rad"],
        "pointsmoved": ["k", "g", "gamma", "floor_m", "floor_rad"],
        "dvlleak": ["k", "g", "alpha", "floor_m", "floor_rad", "walk"],
        "student": ["k", "nu", "floor_m", "floor_rad"],
        "studentpoints": ["k", "g", "nu", "floor_m", "floor_rad"],
        "all": ["k", "alpha", "floor_m", "floor_rad", "walk", "beta"],
    }[model]
    fixed = {
        "k": 8.0,
        "alpha": 0.0,
        "floor_m": 0.01,
        "floor_rad": 0.008,
        "walk": 0.02,
        "beta": 0.0,
        "c": 0.0,
        "p": 1.0,
        "g": 0.0,
        "gamma": 0.0,
        "depth": 1.0,
        "nu": 0.0,
    }

    if model == "dvlleak":
        fixed["depth"] = 0.0  # the DVL's and the AHRS's part of the prior only
    linear = {"p", "g"}  # exponents may be negative; the rest are positive scales

    def params(x):
        return {**fixed, **{n: (v if n in linear else np.exp(v)) for n, v in zip(free, x)}}

    def cost(x):
        p = params(x)
        total = 0.0
        for f in tuning:
            cov = model_covariance(data[f], **p)
            e = nees(data[f]["error_B"], cov)
            if objective == "nll":  # Gaussian negative log-likelihood of every tuning registration's error
                total += np.sum(np.linalg.slogdet(cov)[1] + e)
            else:  # each tuning seed's mean NEES against 6 (the acceptance's measure), in log
                total += np.log(e.mean() / 6) ** 2
        return total if np.isfinite(total) else 1e30

    x0 = [fixed[n] if n in linear else np.log(fixed[n] if fixed[n] > 0 else 0.1) for n in free]
    best = minimize(cost, x0, method="Nelder-Mead", options={"xatol": 1e-3, "fatol": 1e-4, "maxiter": 2000})
    p = params(best.x)
    print(f"model {model}: " + ", ".join(f"{n} {v:.4g}" for n, v in p.items()) + f" (tuned on {len(tuning)} files)")
    for f in files:
        e = nees(data[f]["error_B"], model_covariance(data[f], **p))
        lo, hi = nees_band(len(e))
        inside = "in" if lo <= e.mean() <= hi else "OUT"
        print(
            f"  {f.stem}: n {len(e)} NEES mean {e.mean():.2f} band {lo:.2f}-{hi:.2f} {inside}, median {np.median(e):.2f}"
        )


def _loaded(f: Path) -> dict:
    from semslam.sim.vary import draws

    d = dict(np.load(f))
    seed = int("".join(ch for ch in f.stem if ch.isdigit()))
    d["depth_var"] = draws("tank", seed, ASPECTS).get("depth", {}).get("sigma_m", 0.02) ** 2
    if "prior_has_depth" in d:  # kept apart: the model decides how much of it counts
        for key in ("prior_cov0_B", "prior_cov1_B"):
            d[key] = d[key].copy()
            d[key][:, 5, 5] -= 2 * d["depth_var"]
    return d


def regress(files: list[Path]) -> None:
    """Which per-registration quantity explains the squared error, per sensor-frame component:
    non-negative least squares of e² on [1, the prior's variance, motion², σ²H⁻¹] over the files."""
    from scipy.optimize import nnls

    from frontends.odometry.information import adjoint

    cols = {"const": [], "prior": [], "held": [], "motion2": [], "geom": []}
    err2 = []
    for f in files:
        d = _loaded(f)
        A = np.linalg.inv(adjoint(d["T_BS"]))
        prior_S = np.einsum("ij,njk,lk->nil", A, model_covariance(d, 0.0, 1.0, 0.0, 0.0, walk=0.0), A)
        held_S = np.einsum("ij,njk,lk->nil", A, d["prior_cov1_B"] - d["prior_cov0_B"], A)
        geom = d["residual_var"][:, None, None] * np.linalg.inv(d["information_S"])
        motion_S = d["motion_B"] @ A.T
        cols["const"].append(np.ones((len(geom), 6)))
        cols["prior"].append(np.einsum("nii->ni", prior_S))
        cols["held"].append(np.einsum("nii->ni", held_S))
        cols["motion2"].append(np.repeat((motion_S[:, 3:] ** 2).sum(1, keepdims=True), 6, axis=1))
        cols["geom"].append(np.einsum("nii->ni", geom))
        err2.append(_to_S(d) ** 2)
    X = {k: np.concatenate(v) for k, v in cols.items()}
    y = np.concatenate(err2)
    names = ["rx", "ry", "rz", "tx", "ty", "tz"]
    for k in range(6):
        M = np.stack([X[c][:, k] for c in cols], axis=1)
        scale = M.std(axis=0) + 1e-30
        coef, _ = nnls(M / scale, y[:, k])
        coef = coef / scale
        fitted = M @ coef
        r2 = 1 - np.sum((y[:, k] - fitted) ** 2) / np.sum((y[:, k] - y[:, k].mean()) ** 2)
        print(
            f"  {names[k]}: "
            + ", ".join(f"{c} {v:.3g}" for c, v in zip(cols, coef))
            + f"  R² {r2:.2f}  rms {np.sqrt(y[:, k].mean()):.4f}"
        )


def _fmt(v, names) -> str:
    return " ".join(f"{n} {x:.4f}" for n, x in zip(names, v))


def _to_S(d) -> np.ndarray:
    """The relative-pose errors in the sensor frame (the body's through the inverse adjoint)."""
    from frontends.odometry.information import adjoint

    A = np.linalg.inv(adjoint(d["T_BS"]))
    return d["error_B"] @ A.T


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    rec = sub.add_parser("record")
    rec.add_argument("--seeds", default="1")
    rec.add_argument("--duration", type=float, default=200.0)
    rec.add_argument("--config", default="{}", help="front-end section as JSON")
    rec.add_argument("--out", type=Path, required=True)
    rec.add_argument("--cache", type=Path, help="keep the simulated missions here (pickled) and reuse them")
    rec.add_argument("--outage", help="START,LENGTH (s): the simulator's long DVL outage (dvl.outage_s)")
    rec.add_argument("--prefix", default="seed", help="file name before the seed: 'report' marks a seed not tuned on")
    ev = sub.add_parser("nees")
    ev.add_argument("files", nargs="+", type=Path)
    ev.add_argument("-v", "--verbose", action="store_true")
    rg = sub.add_parser("regress")
    rg.add_argument("files", nargs="+", type=Path)
    ca = sub.add_parser("cauchy", help="the graph's Cauchy width by likelihood on the files not named report*")
    ca.add_argument("files", nargs="+", type=Path)
    ft = sub.add_parser("fit", help="tune a covariance model on the files not named report*")
    ft.add_argument(
        "model",
        choices=(
            "floor",
            "leak",
            "walk",
            "anchor",
            "kept",
            "moved",
            "shape",
            "shapemoved",
            "points",
            "pointsleak",
            "pointskept",
            "pointsmoved",
            "dvlleak",
            "student",
            "studentpoints",
            "all",
        ),
    )
    ft.add_argument("files", nargs="+", type=Path)
    ft.add_argument("--objective", choices=("nll", "mean"), default="nll")
    args = ap.parse_args()
    if args.cmd == "record":
        args.out.mkdir(parents=True, exist_ok=True)
        for seed in (int(s) for s in args.seeds.split(",")):
            loops = max(args.duration - 20.0, 10.0) / 156.6667
            data = {"trajectory": {"loops": loops}}
            if args.outage:
                data["dvl"] = {"outage_s": [float(v) for v in args.outage.split(",")]}
            cfg = resolve_config("tank", seed, vary=ASPECTS, data=data)
            t0 = time.perf_counter()
            mission = simulated("tank", cfg, args.cache)
            t1 = time.perf_counter()
            r = record(mission, json.loads(args.config))
            r["sensor_sigmas"] = np.array(  # what the messages' covariances carry: the front-end may read them
                [
                    cfg.dvl.sigma_m_s,
                    np.radians(cfg.ahrs.roll_pitch_sigma_deg),
                    np.radians(cfg.ahrs.heading_sigma_deg),
                    cfg.laser.range_sigma_m,
                ]
            )
            np.savez(args.out / f"{args.prefix}{seed}.npz", **r)
            print(
                f"seed {seed}: simulated {t1 - t0:.0f} s, recorded {time.perf_counter() - t1:.0f} s, "
                f"{len(r['stamp'])} accepted, {r['summary']}",
                flush=True,
            )
        return
    if args.cmd == "regress":
        regress(args.files)
        return
    if args.cmd == "fit":
        fit(args.files, args.model, args.objective)
        return
    if args.cmd == "cauchy":
        cauchy(args.files)
        return
    names = ["rx", "ry", "rz", "tx", "ty", "tz"]
    for f in args.files:
        d = np.load(f)
        e = nees(d["error_B"], d["covariance_B"])
        lo, hi = nees_band(len(e))
        print(f"{f.stem}: n {len(e)} NEES mean {e.mean():.2f} band {lo:.2f}-{hi:.2f} median {np.median(e):.2f}")
        if args.verbose:
            sd = np.sqrt(np.einsum("nii->ni", d["covariance_B"]))
            print("  rms error B  ", _fmt(np.sqrt(np.mean(d["error_B"] ** 2, axis=0)), names))
            print("  median sigma ", _fmt(np.median(sd, axis=0), names))
            print("  rms prior err", _fmt(np.sqrt(np.mean(d["error_prior_S"] ** 2, axis=0)), names), "(S)")
            print("  rms error S  ", _fmt(np.sqrt(np.mean(_to_S(d) ** 2, axis=0)), names), "(S)")
            print(
                f"  residual sd median {np.sqrt(np.median(d['residual_var'])):.4f} inliers median {np.median(d['inliers'])}"
            )
            eS, pS = _to_S(d), d["error_prior_S"]
            slope = (eS * pS).sum(0) / (pS * pS).sum(0)
            corr = [np.corrcoef(eS[:, k], pS[:, k])[0, 1] for k in range(6)]
            print("  slope err/prior (S)", _fmt(slope, names))
            print("  corr err/prior (S) ", _fmt(corr, names))
            w, V = np.linalg.eigh(d["covariance_B"])  # ascending σ²
            proj = np.einsum("nji,nj->ni", V, d["error_B"]) ** 2 / w
            print("  NEES share by covariance eigen-direction (smallest σ first)", np.round(proj.mean(0), 2))
            print("  their σ (median)", np.round(np.sqrt(np.median(w, axis=0)), 4))
            consecutive = np.r_[False, d["stamp_from"][1:] == d["stamp"][:-1]]
            a, b = eS[1:][consecutive[1:]], eS[:-1][consecutive[1:]]
            print("  corr with previous ", _fmt([np.corrcoef(a[:, k], b[:, k])[0, 1] for k in range(6)], names))


if __name__ == "__main__":
    main()
