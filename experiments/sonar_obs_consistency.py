"""Consistency of the sonar's observations against the simulator's truth, per kind.

    python experiments/sonar_obs_consistency.py record BAG OUT_DIR [CONFIG|default]
        semslam compare of the bag (default estimators) writing OUT_DIR/metrics.json and
        OUT_DIR/sonar_obs.pkl: every observation of the sonar front-end with its stamp, the graph's
        pose at it, the ground truth (trajectory, structures, pipes) and the sonar's mount.
    python experiments/sonar_obs_consistency.py surveys OUT_DIR [SEED ...]
        the same for the test surveys of tests/test_sonar_frontend.py (two 18 m lines, seeds 23-26 by
        default; graph + sonar, recognition's final pass off), one OUT_DIR/sNN/sonar_obs.pkl each.
    python experiments/sonar_obs_consistency.py table OUT_DIR [OUT_DIR ...]
        per kind and field: the observation's residual at the TRUE poses/landmarks against its declared
        covariance (NIS, its median against the χ² median, the share inside the 95% χ² band), and the
        mean residual (a bias), with a line over all fields.

Kinds and residuals:
* ``swath`` (window registration → OdometryObservation): δ = Log(T_rel,true⁻¹ T_rel,obs) (rotation
  then translation, in the later anchor's frame); NIS on the translation (3 DoF; a direction the
  registration could not see has σ ``uninformative_sigma_m`` and adds ~0: its DoF counted out) and
  the rotation's separately;
* ``structure`` (StructureObservation T_SM): δ = Log(T_SM,true⁻¹ T_SM,obs) (model side, the
  registration's convention), NIS on the translation (3 DoF) and rotation (3 DoF);
* ``pipe`` (LineObservation): each endpoint's distance from the true pipe's axis, perpendicular to
  it (2 DoF per endpoint, the declared lateral covariance); the true pipe is the one nearest to the
  observation placed with the true pose (the detector puts the axis at the pipe-centre depth).
"""

from __future__ import annotations

import json
import pickle
import sys
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

KINDS = ("swath", "structure", "pipe")


def _inv(T):
    Ti = np.eye(4)
    Ti[:3, :3] = T[:3, :3].T
    Ti[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return Ti


def _rz(a: float) -> np.ndarray:
    T = np.eye(4)
    T[:2, :2] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
    return T


def _log(T):
    """(rotation vector, translation) of a small transform (the translation unrotated: first order)."""
    return Rotation.from_matrix(T[:3, :3]).as_rotvec(), T[:3, 3].copy()


def _dumper(rec: list[dict]):
    """A pipeline observer appending every sonar observation to ``rec``."""
    from semslam.observations import LineObservation, OdometryObservation, StructureObservation

    class Dump:
        def step(self, stamp, measurement, observations, views):
            for name, obs in observations:
                if name != "sonar":
                    continue
                for o in obs:
                    if isinstance(o, OdometryObservation):
                        rec.append(
                            dict(
                                kind="swath",
                                stamp=o.stamp,
                                stamp_from=o.stamp_from,
                                T=o.relative_pose,
                                cov=o.covariance,
                            )
                        )
                    elif isinstance(o, StructureObservation):
                        rec.append(dict(kind="structure", stamp=o.stamp, model=o.model, T=o.pose, cov=o.covariance))
                    elif isinstance(o, LineObservation):
                        rec.append(dict(kind="pipe", stamp=o.stamp, p=o.p, q=o.q, cov=o.covariance, radius=o.radius))

    return Dump()


def _save(out: Path, rec: list[dict], truth, metadata, results=None) -> None:
    gt = metadata.ground_truth
    data = dict(
        obs=rec,
        trajectories={
            k: dict(stamps=np.asarray(r.trajectory.stamps), positions=np.asarray(r.trajectory.positions))
            for k, r in (results or {}).items()
        },
        truth=dict(
            stamps=np.asarray(truth.stamps),
            positions=np.asarray(truth.positions),
            orientations=np.asarray(truth.orientations),
        ),
        structures=[(s.model, np.asarray(s.position, float), np.asarray(s.orientation, float)) for s in gt.structures],
        pipes=[(np.asarray(p.p, float), np.asarray(p.q, float), p.radius) for p in gt.pipes],
        T_BS=np.asarray(metadata.extrinsic("sonar"), float),
    )
    out.mkdir(parents=True, exist_ok=True)
    with open(out / "sonar_obs.pkl", "wb") as f:
        pickle.dump(data, f)


def record(bag: Path, out: Path, config: str = "default") -> None:
    from semslam.commands.mission_input import checked_mission
    from semslam.compare import run_comparison
    from semslam.config import SemslamConfig, load_config
    from semslam.pipeline import observed_by

    out.mkdir(parents=True, exist_ok=True)
    rec: list[dict] = []
    cfg = SemslamConfig() if config == "default" else load_config(Path(config))
    mission, names, _ = checked_mission(bag, cfg, None, "")
    with observed_by(_dumper(rec)):
        result, metrics = run_comparison(mission, cfg, names)
    (out / "metrics.json").write_text(json.dumps(metrics, default=str, indent=1))
    _save(out, rec, result.truth, mission.metadata, result.results)
    print("SUMMARY", json.dumps({k: round(v["ate_rmse_m"], 4) for k, v in metrics["estimators"].items()}))


def surveys(out: Path, seeds: list[int]) -> None:
    from frontends.sonar import SonarFrontend
    from semslam.config import SemslamConfig
    from semslam.estimators import create_estimator
    from semslam.pipeline import run_pipeline

    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository, for its tests' survey
    from tests.test_sonar_frontend import _survey  # the tests' own survey, so that the numbers are theirs

    for seed in seeds:
        m = _survey(seed)
        rec: list[dict] = []
        est = create_estimator("graph", m.metadata, SemslamConfig())
        fe = SonarFrontend(m.metadata, {"recognition": {"final_pass": False}})
        res = run_pipeline(m, [est], [fe], observers=[_dumper(rec)])
        _save(out / f"s{seed}", rec, res.truth, m.metadata, res.results)
        print(seed, {k: sum(1 for r in rec if r["kind"] == k) for k in KINDS})


class Truth:
    def __init__(self, d: dict):
        self.stamps = d["stamps"]
        self.R = Rotation.from_quat(d["orientations"]).as_matrix()
        self.t = d["positions"]

    def T(self, stamp: int) -> np.ndarray:
        """T_WB at ``stamp`` (the nearest sample; the truth is at 20 Hz or more, the observations at swath stamps)."""
        i = int(np.clip(np.searchsorted(self.stamps, stamp), 1, len(self.stamps) - 1))
        if abs(self.stamps[i - 1] - stamp) < abs(self.stamps[i] - stamp):
            i -= 1
        T = np.eye(4)
        T[:3, :3] = self.R[i]
        T[:3, 3] = self.t[i]
        return T


def _nis(r: np.ndarray, C: np.ndarray, informative: float = 1.0) -> tuple[float, int]:
    """r'C⁻¹r over the directions whose σ is below ``informative`` (m), and their count."""
    w, V = np.linalg.eigh(0.5 * (C + C.T))
    keep = np.sqrt(np.maximum(w, 0)) < informative
    y = V.T @ r
    return float(np.sum(y[keep] ** 2 / w[keep])), int(keep.sum())


def residuals(data: dict) -> dict[str, list[dict]]:
    truth = Truth(data["truth"])
    T_BS = data["T_BS"]
    out: dict[str, list[dict]] = {k: [] for k in KINDS}
    for o in data["obs"]:
        if o["kind"] == "swath":
            T_rel = _inv(truth.T(o["stamp_from"])) @ truth.T(o["stamp"])
            w, v = _log(_inv(T_rel) @ o["T"])
            C = o["cov"]
            nis_t, dof = _nis(v, C[3:, 3:], informative=1.0)
            nis_r, _ = _nis(w, C[:3, :3], informative=np.inf)
            # the residual in {W} (north, east, down): what the registration measured, a world shift
            R_j = truth.T(o["stamp"])[:3, :3]
            # NIS along each of the covariance's axes, smallest σ first (the depth offset's floor, then
            # the informative north/east direction's): which of them is overconfident
            ew, EV = np.linalg.eigh(0.5 * (C[3:, 3:] + C[3:, 3:].T))
            axes = (EV.T @ v) ** 2 / ew
            out["swath"].append(
                dict(
                    stamp=o["stamp"],
                    r=R_j @ v,
                    rot=w,
                    nis=nis_t,
                    dof=dof,
                    nis_rot=nis_r,
                    nis_axis0=float(axes[0]),
                    nis_axis1=float(axes[1]) if np.sqrt(ew[1]) < 1.0 else None,
                )
            )
        elif o["kind"] == "structure":
            match = [s for s in data["structures"] if s[0] == o["model"]]
            if not match:
                continue
            T_WS = truth.T(o["stamp"]) @ T_BS
            best = None
            for _, pos, quat in match:
                T_WM = np.eye(4)
                T_WM[:3, :3] = Rotation.from_quat(quat).as_matrix()
                T_WM[:3, 3] = pos
                T_SM = _inv(T_WS) @ T_WM
                d = np.linalg.norm(T_SM[:3, 3] - o["T"][:3, 3])
                if best is None or d < best[0]:
                    best = (d, T_SM, T_WM)
            _, T_SM, T_WM = best
            # a symmetric model (a PLET end for end, a manifold): the truth's turn nearest the observation
            w, v = min(
                (_log(_inv(T_SM @ _rz(k * np.pi / 2)) @ o["T"]) for k in range(4)), key=lambda wv: np.linalg.norm(wv[0])
            )
            C = o["cov"]
            nis_t, _ = _nis(v, C[3:, 3:], informative=np.inf)
            nis_r, _ = _nis(w, C[:3, :3], informative=np.inf)
            out["structure"].append(
                dict(stamp=o["stamp"], model=o["model"], r=T_WM[:3, :3] @ v, rot=w, nis=nis_t, dof=3, nis_rot=nis_r)
            )
        elif o["kind"] == "pipe":
            T_WS = truth.T(o["stamp"]) @ T_BS
            P = (T_WS[:3, :3] @ np.stack([o["p"], o["q"]]).T).T + T_WS[:3, 3]
            best = None
            for a, b, rad in data["pipes"]:
                u = (b - a) / np.linalg.norm(b - a)
                perp = [(x - a) - np.dot(x - a, u) * u for x in P]
                d = float(np.mean([np.linalg.norm(p) for p in perp]))
                if best is None or d < best[0]:
                    best = (d, u, perp, rad)
            d, u, perp, rad = best
            if d > 0.5:  # another feature (a structure's edge before its recognition), not this pipe
                out["pipe"].append(dict(stamp=o["stamp"], false=True, r=np.full(3, np.nan), nis=np.nan, dof=0))
                continue
            C = T_WS[:3, :3] @ o["cov"][:3, :3] @ T_WS[:3, :3].T  # the endpoint's covariance in {W}
            Pp = np.eye(3) - np.outer(u, u)
            nis, dof = 0.0, 0
            for e in perp:
                w_, V = np.linalg.eigh(Pp @ C @ Pp)
                V2 = V[:, 1:]  # the two directions perpendicular to the axis
                y = V2.T @ e
                nis += float(np.sum(y**2 / w_[1:]))
                dof += 2
            out["pipe"].append(
                dict(
                    stamp=o["stamp"],
                    false=False,
                    r=np.mean(perp, axis=0),
                    nis=nis,
                    dof=dof,
                    sigma=float(np.sqrt(w_[1:].mean())),
                )
            )
    return out


def summary(rows: list[dict]) -> dict | None:
    rows = [r for r in rows if not r.get("false") and r["dof"] > 0]
    if not rows:
        return None
    nis = np.array([r["nis"] for r in rows])
    dof = np.array([r["dof"] for r in rows])
    lo, hi = chi2.ppf(0.025, dof), chi2.ppf(0.975, dof)
    r = np.array([r["r"] for r in rows])
    return dict(
        n=len(rows),
        nis_over_dof_median=float(np.median(nis / dof)),
        nis_over_dof_mean=float(np.mean(nis / dof)),
        chi2_median_over_dof=float(np.median(chi2.ppf(0.5, dof) / dof)),
        in_band=float(np.mean((nis >= lo) & (nis <= hi))),
        above_band=float(np.mean(nis > hi)),
        mean_r=r.mean(0).tolist(),
        rms_r=np.sqrt((r**2).mean(0)).tolist(),
        nis_axis_medians=[
            float(np.median([x[k] for x in rows if x[k] is not None])) for k in ("nis_axis0", "nis_axis1")
        ]
        if "nis_axis0" in rows[0]
        else None,
        nis_rot_over3_median=float(np.median([x["nis_rot"] for x in rows if "nis_rot" in x]) / 3)
        if any("nis_rot" in x for x in rows)
        else None,
    )


def table(dirs: list[Path]) -> None:
    every: dict[str, list[dict]] = {k: [] for k in KINDS}
    print(
        "| field | kind | n | NIS/dof median (χ² median/dof) | NIS/dof mean | in 95% band | above | mean residual N,E,D [mm] | RMS N,E,D [mm] | rot NIS/3 |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    for d in dirs:
        p = d / "sonar_obs.pkl"
        if not p.exists():
            continue
        with open(p, "rb") as f:
            data = pickle.load(f)
        res = residuals(data)
        for k in KINDS:
            every[k] += res[k]
            s = summary(res[k])
            if s is None:
                print(f"| {d.name} | {k} | 0 | | | | | | |")
                continue
            _row(d.name, k, s, res[k])
    for k in KINDS:
        s = summary(every[k])
        if s is not None:
            _row("all", k, s, every[k])


def _row(name: str, kind: str, s: dict, rows: list[dict]) -> None:
    n_false = sum(1 for r in rows if r.get("false"))
    mm = lambda v: ", ".join(f"{1000 * x:.0f}" for x in v)  # noqa: E731
    rot = "" if s["nis_rot_over3_median"] is None else f"{s['nis_rot_over3_median']:.2f}"
    if s["nis_axis_medians"] is not None:  # a swath registration: along its covariance's axes
        a0, a1 = s["nis_axis_medians"]
        rot += f"; smallest-σ axis NIS {a0:.2f}, next {a1:.2f} (χ² 0.45)"
    print(
        f"| {name} | {kind} | {s['n']}{f' (+{n_false} far)' if n_false else ''} | {s['nis_over_dof_median']:.2f} ({s['chi2_median_over_dof']:.2f}) | "
        f"{s['nis_over_dof_mean']:.2f} | "
        f"{s['in_band']:.2f} | {s['above_band']:.2f} | {mm(s['mean_r'])} | {mm(s['rms_r'])} | {rot} |"
    )


if __name__ == "__main__":
    if len(sys.argv) >= 4 and sys.argv[1] == "record":
        record(Path(sys.argv[2]), Path(sys.argv[3]), sys.argv[4] if len(sys.argv) > 4 else "default")
    elif len(sys.argv) >= 3 and sys.argv[1] == "surveys":
        surveys(Path(sys.argv[2]), [int(a) for a in sys.argv[3:]] or [23, 24, 25, 26])
    elif len(sys.argv) >= 3 and sys.argv[1] == "table":
        table([Path(a) for a in sys.argv[2:]])
    else:
        sys.exit(__doc__)
