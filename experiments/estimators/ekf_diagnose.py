"""Where the EKF loses its consistency: the EKF alone on a recorded mission (the front-end's observations
kept by ``replay_study.py record``), instrumented.

For each mission it prints
- the normalised innovation squared (NIS) per update type against its χ² expectation: DVL (and the
  start-at-rest readings apart), depth, AHRS, objects, pipes; mean NIS / dof (1 if consistent) and
  the share above the 99 % χ² quantile (0.01 if consistent); the NIS is taken before each update with
  the filter's own covariance;
- the vehicle's 3-DoF position NEES over time (per window of ``--window`` s: mean NEES, the updates
  and the events of that window: landmarks promoted, duplicates merged, DVL readings missing);
- each new landmark's error at its initialisation against its covariance (object NEES, 3 dof).

    python experiments/estimators/ekf_diagnose.py --cache DIR --seeds 8,10 [--config F] [--set ekf.key=value]
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np
from scipy.stats import chi2

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository root

from experiments.estimators.replay_study import RecordedFrontend, _config, _paths  # noqa: E402
from semslam.ekf import EkfEstimator  # noqa: E402
from semslam.ekf.models import NX  # noqa: E402
from semslam.eval.map_quality import nees_band  # noqa: E402
from semslam.mission.measurements import DvlVelocity, GroundTruthPose  # noqa: E402
from semslam.observations import LineObservation, PointObservation  # noqa: E402


class Probe:
    """Wraps an EkfEstimator's navigation updates, map updates, promotions and merges to record what
    each did: ``nis`` rows (stamp, type, NIS, dof), ``events`` (stamp, text)."""

    def __init__(self, est: EkfEstimator, truth_objects: dict[int, np.ndarray], truth_pipes: dict | None = None):
        self.est = est
        self.nis: list[tuple[int, str, float, int]] = []
        self.events: list[tuple[int, str]] = []
        self.init_nees: list[tuple[int, float, float]] = []  # (stamp, NEES, error m) of new objects
        self.truth_objects = truth_objects
        self.kind = "?"
        self.dvl_stamps: list[int] = []
        self.shrink: list[tuple[int, str, float]] = []  # (stamp, what, drop of the position variance's trace m²)
        self.truth_pipes = truth_pipes or {}
        self.gt_poses: dict[int, np.ndarray] = {}  # stamp → T_WB
        self.identity: dict[int, int | None] = {}  # landmark → the truth its first view showed
        self.pairs: list[tuple[int, str, bool | None, float]] = []  # (stamp, kind, right truth?, NIS)
        nav, fmap = est.nav, est.map
        process, nav_update = nav.process, nav._nav_update
        update, promote, merge = fmap.update, fmap.promote, fmap.merge

        def process_(m):
            self.kind = type(m).__name__
            if isinstance(m, GroundTruthPose):
                self.gt_poses[m.stamp] = m.matrix()
            if isinstance(m, DvlVelocity):
                rest = not np.any(m.velocity) and m.covariance[2, 2] >= 0.5  # semslam.mission.rest's readings
                self.kind = "DvlRest" if rest else ("Dvl" if m.valid and m.is_finite() else "DvlInvalid")
                if self.kind == "Dvl":
                    self.dvl_stamps.append(m.stamp)
            process(m)

        def nav_update_(u):
            P = nav.state.Pvv
            k = u.H.shape[1]
            S = u.H @ P[:k, :k] @ u.H.T + u.R
            self.nis.append(
                (nav.t, self.kind, float(u.innovation @ np.linalg.solve(S, u.innovation)), len(u.innovation))
            )
            nav_update(u)

        def update_(paired):
            P = nav.state.P
            before = np.trace(P[:3, :3])
            for z, lid, p in paired:
                f = fmap.feature(lid)
                cols = np.r_[np.arange(NX), f.cols]
                H = np.hstack([p.H_x, p.H_l])
                S = H @ P[np.ix_(cols, cols)] @ H.T + p.R
                nis = float(p.innovation @ np.linalg.solve(S, p.innovation))
                self.nis.append((nav.t, f.kind, nis, len(p.innovation)))
                truth, mine = self.truth_of(z), self.identity.get(lid)
                self.pairs.append((nav.t, f.kind, None if truth is None or mine is None else truth == mine, nis))
            kinds = sorted({fmap.feature(lid).kind for _, lid, _ in paired})
            update(paired)
            self.shrink.append((nav.t, "+".join(kinds), before - np.trace(nav.state.P[:3, :3])))

        def promote_(track):
            lid = promote(track)
            f = fmap.feature(lid)
            self.identity[lid] = self.truth_of(track.views[-1].z)
            self.events.append((nav.t, f"+{f.kind}{lid}({len(track.views)}v,t{self.identity[lid]})"))
            if f.kind == "object" and self.truth_objects:
                x, P = nav.state.x[f.cols], nav.state.P[np.ix_(f.cols, f.cols)]
                tid, g = min(self.truth_objects.items(), key=lambda kv: np.linalg.norm(kv[1] - x))
                e = x - g
                self.init_nees.append((nav.t, float(e @ np.linalg.solve(P, e)), float(np.linalg.norm(e))))
            return lid

        def merge_(keep, drop, constrain):
            nis = fmap.difference_nis(keep, drop)
            kind = fmap.feature(keep).kind
            self.events.append((nav.t, f"merge {kind}{drop}->{keep}{' C' if constrain else ''} nis={nis:.1f}"))
            before = np.trace(nav.state.P[:3, :3])
            merge(keep, drop, constrain)
            self.shrink.append(
                (nav.t, f"merge {kind}{' C' if constrain else ''}", before - np.trace(nav.state.P[:3, :3]))
            )

        nav.process, nav._nav_update = process_, nav_update_
        fmap.update, fmap.promote, fmap.merge = update_, promote_, merge_

    def truth_of(self, z) -> int | None:
        """The true landmark an observation shows (placed with the true pose of its time): the nearest
        true object within 0.15 m, or true pipe within 0.1 m of both ends' lines; None if none."""
        if not self.gt_poses:
            return None
        stamps = np.fromiter(self.gt_poses, np.int64)
        k = int(np.argmin(np.abs(stamps - z.stamp)))
        if abs(stamps[k] - z.stamp) > 60_000_000:
            return None
        T = self.gt_poses[int(stamps[k])] @ self.est.metadata.extrinsic(z.sensor)
        if isinstance(z, PointObservation) and self.truth_objects:
            w = T[:3, :3] @ z.position + T[:3, 3]
            tid, g = min(self.truth_objects.items(), key=lambda kv: np.linalg.norm(kv[1] - w))
            return tid if np.linalg.norm(g - w) < 0.15 else None
        if isinstance(z, LineObservation) and self.truth_pipes:
            ends = np.array([z.p, z.q]) @ T[:3, :3].T + T[:3, 3]
            best, cost = None, 0.1
            for tid, (a, b) in self.truth_pipes.items():
                d = (b - a) / np.linalg.norm(b - a)
                r = ends - a
                c = np.linalg.norm(r - np.outer(r @ d, d), axis=1).max()
                if c < cost:
                    best, cost = tid, c
            return best
        return None


def nis_table(rows) -> dict:
    by = defaultdict(list)
    for _, kind, nis, d in rows:
        by[(kind, d)].append(nis)
    out = {}
    for (kind, d), v in sorted(by.items()):
        v = np.array(v)
        out[f"{kind}/{d}"] = {
            "n": len(v),
            "mean_per_dof": float(v.mean() / d),
            "median_per_dof": float(np.median(v) / d),
            "share_above_99": float(np.mean(v > chi2.ppf(0.99, d))),
        }
    return out


def nees_series(result, truth) -> tuple[np.ndarray, np.ndarray]:
    """(stamps, NEES, error, covariance) of the 3-D position at the trajectory's stamps with a true pose within 50 ms."""
    est = result.trajectory
    idx = np.clip(np.searchsorted(truth.stamps, est.stamps), 1, len(truth.stamps) - 1)
    left = (est.stamps - truth.stamps[idx - 1]) < (truth.stamps[idx] - est.stamps)
    idx = np.where(left, idx - 1, idx)
    ok = np.abs(truth.stamps[idx] - est.stamps) <= 50_000_000
    e = est.positions[ok] - truth.positions[idx[ok]]
    P = est.position_cov[ok]
    return est.stamps[ok], np.einsum("ni,ni->n", e, np.linalg.solve(P, e[..., None])[..., 0]), e, P


def run_one(bag: Path, obs_path: Path, variants: dict, window_s: float, timeline: bool) -> dict:
    """Every variant (name → (config, attributes set on the filter's map)) of the EKF on one recorded
    mission, in one pass (the same measurements and observations, in the same order)."""
    import pickle

    from semslam.compare import estimators_input
    from semslam.eval.outputs import build_metrics
    from semslam.mission.bag import read_mission
    from semslam.pipeline import run_pipeline

    payload = pickle.loads(obs_path.read_bytes())
    config0 = next(iter(variants.values()))[0]
    mission = read_mission(bag, config0.reader)
    fes = [
        RecordedFrontend(n, payload["observations"].get(n, {}), payload["summaries"].get(n)) for n in payload["names"]
    ]
    gt = mission.metadata.ground_truth
    ests, probes = [], {}
    for name, (config, attrs) in variants.items():
        est = EkfEstimator(mission.metadata, config)
        est.name = name
        for k, v in attrs.items():
            setattr(est.map, k, v)
        probes[name] = Probe(
            est,
            {g.id: np.array(g.position) for g in (gt.objects if gt else ())},
            {g.id: (np.array(g.p), np.array(g.q)) for g in (gt.pipes if gt else ())},
        )
        ests.append(est)
    seen = estimators_input(mission, config0)
    result = run_pipeline(seen, ests, fes, view_estimator=ests[0].name, keep_observations=False, frontend_process=False)
    all_metrics = build_metrics(result, mission.metadata)["estimators"]
    out = {}
    for name, probe in probes.items():
        out[name] = report(bag.stem, name, all_metrics[name], probe, result, window_s, timeline)
    return out


def _f(v) -> str:
    return "-" if v is None else f"{v:.4f}"


def report(stem: str, name: str, metrics: dict, probe: Probe, result, window_s: float, timeline: bool) -> dict:
    t, nees, err, Ppos = nees_series(result.results[name], result.truth)
    t0 = t[0]
    lo, hi = nees_band()
    print(
        f"{stem} [{name}]: ATE {metrics['ate_rmse_m']:.3f} NEES {metrics['nees_mean']:.2f} objects {metrics['n_objects']} "
        f"(d{metrics['object_duplicates']} m{metrics['object_missed']} f{metrics['object_false']}, once "
        f"{metrics['objects_once']}) pipes {metrics['n_pipes']}/{metrics['pipe_seen']} (d{metrics['pipe_duplicates']} "
        f"m{metrics['pipe_missed']}) err o/p {_f(metrics['object_median_error_m'])}/{_f(metrics['pipe_median_error_m'])} "
        f"runtime {metrics['runtime_s']:.0f}s"
    )
    table = nis_table(probe.nis)
    for k, v in table.items():
        print(
            f"  NIS {k:14s} n {v['n']:6d}  mean/dof {v['mean_per_dof']:7.2f}  median/dof {v['median_per_dof']:6.2f}  "
            f">99%: {v['share_above_99']:.3f}"
        )
    for kind in ("object", "pipe"):
        rows = [r for r in probe.pairs if r[1] == kind]
        wrong = [r for r in rows if r[2] is False]
        known = [r for r in rows if r[2] is not None]
        if rows:
            print(
                f"  {kind} pairings {len(rows)}: truth known {len(known)}, wrong {len(wrong)}"
                + (f" (NIS median {np.median([r[3] for r in wrong]):.1f})" if wrong else "")
                + (f"; first wrong at {(wrong[0][0] - t0) * 1e-9:.0f}s" if wrong else "")
            )
    if probe.init_nees:
        a = np.array([r[1] for r in probe.init_nees])
        print(f"  new objects: NEES at initialisation mean {a.mean():.1f} median {np.median(a):.1f} (3 if consistent)")
    by = defaultdict(float)
    for _, what, d in probe.shrink:
        by[what] += d
    print("  position variance removed (trace, m²) by: " + ", ".join(f"{k} {v:.4f}" for k, v in sorted(by.items())))
    for s_, what, d in sorted(probe.shrink, key=lambda r: -r[2])[:8]:
        print(f"    {(s_ - t0) * 1e-9:6.1f}s {what}: {d:.5f}")
    sd = np.sqrt(np.trace(Ppos, axis1=1, axis2=2))
    dvl = np.array(probe.dvl_stamps)
    edges = np.arange(t0, t[-1] + 1, int(window_s * 1e9))
    rows_t = np.array([r[0] for r in probe.nis])
    rows_k = np.array([r[1] for r in probe.nis])
    rows_v = np.array([r[2] / r[3] for r in probe.nis])
    for a, b in zip(edges[:-1], edges[1:]) if timeline else ():
        w = (t >= a) & (t < b)
        if not w.any():
            continue
        sel = (rows_t >= a) & (rows_t < b)
        parts = []
        for kind in ("Dvl", "object", "pipe"):
            m = sel & (rows_k == kind)
            parts.append(f"{kind} {m.sum():3d}/{rows_v[m].mean() if m.any() else 0:5.2f}")
        gaps = np.diff(dvl[(dvl >= a) & (dvl < b)]) * 1e-9
        ev = [e for s, e in probe.events if a <= s < b]
        print(
            f"  {(a - t0) * 1e-9:6.0f}s NEES {nees[w].mean():8.1f} |e| {np.linalg.norm(err[w], axis=1).mean():.3f} "
            f"σ {sd[w].mean():.3f}  "
            + "  ".join(parts)
            + f"  DVL gap {gaps.max() if len(gaps) else window_s:4.1f}s  "
            + " ".join(ev)[:160]
        )
    return {
        "metrics": metrics,
        "nis": table,
        "nees_band": [lo, hi],
        "nees_t": ((t - t0) * 1e-9).tolist(),
        "nees": nees.tolist(),
        "events": [((s - t0) * 1e-9, e) for s, e in probe.events],
        "init_nees": probe.init_nees,
    }


def main() -> None:
    import yaml

    from semslam.config import SemslamConfig
    from semslam.study.plan import parse_seeds

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default="tank")
    ap.add_argument("--seeds", type=parse_seeds, required=True)
    ap.add_argument("--cache", type=Path, required=True)
    ap.add_argument("--config")
    ap.add_argument(
        "--variant",
        action="append",
        default=[],
        help="name:section.key=value,... (config) or name:map.attr=value (the filter's map); repeatable; "
        "none: the configuration as it is",
    )
    ap.add_argument("--window", type=float, default=10.0)
    ap.add_argument("--timeline", action="store_true", help="print the NEES and updates per window")
    ap.add_argument("--out", help="write the series and tables here (JSON)")
    args = ap.parse_args()
    base = _config(args.config, args.scenario)
    variants = {}
    for spec in args.variant or ["ekf:"]:
        name, _, sets = spec.partition(":")
        data, attrs = base.model_dump(), {}
        for kv in filter(None, sets.split(",")):
            key, value = kv.split("=", 1)
            sec, field = key.split(".", 1)
            if sec == "map":
                attrs[field] = yaml.safe_load(value)
            else:
                data[sec][field] = yaml.safe_load(value)
        variants[name] = (SemslamConfig.model_validate(data), attrs)
    out = {}
    for seed in args.seeds:
        bag, obs_path = _paths(args.cache, args.scenario, seed)
        out[bag.stem] = run_one(bag, obs_path, variants, args.window, args.timeline)
    if args.out:
        Path(args.out).write_text(json.dumps(out, default=float))


if __name__ == "__main__":
    main()
