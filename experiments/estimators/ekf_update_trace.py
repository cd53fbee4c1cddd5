"""Which updates move the EKF's vehicle (and its map) where: every change of the vehicle position, by
what made it, on a recorded mission (``replay_study.py record``'s cache).

Each step of the filter is tagged (prediction; AHRS, depth, DVL, odometry; a map update and the kinds
it paired; a promotion; a merge) and its change of the vehicle position logged, with the mean change
of the mapped objects' positions; a map update's change is split into each paired feature's share
(its rows of K ν). Printed per window of ``--window`` s between ``--from`` and ``--to``: the sum of
Δ(axis) by tag, the vehicle's error on that axis against the truth and the mapped objects' mean error
(nearest true object); then the features whose updates moved the vehicle most over the span.

    python experiments/estimators/ekf_update_trace.py --cache DIR --seed 94 [--axis 1] [--from 0 --to 60]
        [--variant ekf.key=value,...]
"""

from __future__ import annotations

import argparse
import pickle
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository root

from experiments.estimators.replay_study import RecordedFrontend, _config, _paths  # noqa: E402
from semslam.ekf import EkfEstimator  # noqa: E402
from semslam.ekf import batch as bt  # noqa: E402
from semslam.ekf import geometry as geo  # noqa: E402
from semslam.ekf.filter import EkfState  # noqa: E402
from semslam.ekf.models import NX  # noqa: E402
from semslam.mission.measurements import DvlVelocity, GroundTruthPose  # noqa: E402


class Trace:
    """The tagged steps of one EKF run: ``rows`` (stamp, tag, Δp (3), mean Δ of the objects (3) or None),
    ``shares`` (stamp, feature id, kind, Δp (3)) of map updates, ``truth`` (stamp → true position)."""

    def __init__(
        self,
        est: EkfEstimator,
        drop: int | None = None,
        refresh_deg: float | None = None,
        watch=None,
        first_from_views: bool = False,
    ):
        self.est = est
        self.watch = watch  # a feature id: each of its updates logged in ``watched``
        self.watched: list = []  # (stamp, ν, ∂ν/∂p used, ∂ν/∂p at the current estimate, NIS)
        self.refreshed: list = []  # (stamp, pipe id) whose first estimate was re-taken
        self.pending: list | None = None  # the map update under way: (feature id, kind, rows) per pair
        self.tag = "predict"
        self.rows: list = []
        self.shares: list = []
        self.truth: dict[int, np.ndarray] = {}
        self.first: dict[int, float] = {}  # feature id → stamp it entered
        nav, fmap = est.nav, est.map
        process, update, promote, merge, odometry = nav.process, fmap.update, fmap.promote, fmap.merge, nav.odometry
        trace = self

        def process_(m):
            if isinstance(m, GroundTruthPose):
                trace.truth[m.stamp] = np.array(m.position)
            trace.tag = type(m).__name__
            if isinstance(m, DvlVelocity) and not np.any(m.velocity) and m.covariance[2, 2] >= 0.5:
                trace.tag = "DvlRest"
            process(m)
            trace.tag = "predict"

        def odometry_(z):
            trace.tag = "Odometry"
            odometry(z)
            trace.tag = "predict"

        def update_(paired):
            if drop is not None:  # a variant: that feature's pairings ignored
                paired = [q for q in paired if q[1] != drop]
                if not paired:
                    return
            feats = {f.id: f for f in fmap.features}
            if refresh_deg is not None:  # a variant: a pipe's first estimate re-taken once it has turned
                x = nav.state.x
                for _, lid, _ in paired:
                    f = feats[lid]
                    if f.kind != "pipe":
                        continue
                    d0, d1 = geo.line_plucker(f.l_first)[1], geo.line_plucker(x[f.cols])[1]
                    if np.degrees(np.arccos(min(1.0, abs(d0 @ d1)))) > refresh_deg:
                        f.l_first = x[f.cols].copy()
                        trace.refreshed.append((nav.t, lid))
            if watch is not None:
                trace.watch_pairs(paired, feats)
            kinds = sorted({feats[lid].kind for _, lid, _ in paired})
            trace.tag = "map:" + "+".join(kinds)
            # each paired feature's share of the vehicle's Δp (its rows of K ν): taken where the stacked
            # update reaches the state (the rows in the pairs' order)
            trace.pending = [(lid, feats[lid].kind, len(p.innovation)) for _, lid, p in paired]
            update(paired)
            trace.pending = None
            trace.tag = "predict"

        def promote_(track):
            trace.tag = "promote"
            lid = promote(track)
            trace.first[lid] = nav.t
            f = fmap.feature(lid)
            if first_from_views and f.kind == "pipe":  # a variant: the Jacobians' point fitted to every view
                pts = np.concatenate([v.world for v in track.views])
                c = pts.mean(axis=0)
                d = np.linalg.svd(pts - c)[2][0]
                d_now = geo.line_plucker(nav.state.x[f.cols])[1]
                d = d if d @ d_now >= 0 else -d
                f.l_first = geo.line_params(np.cross(c - f.anchor, d), d)
            trace.tag = "predict"
            return lid

        def merge_(keep, drop, constrain):
            trace.tag = "merge" + ("C" if constrain else "")
            merge(keep, drop, constrain)
            trace.tag = "predict"

        nav.process, nav.odometry = process_, odometry_
        fmap.update, fmap.promote, fmap.merge = update_, promote_, merge_

    def split(self, state: EkfState, nu: np.ndarray, cols: np.ndarray, H: np.ndarray, R: np.ndarray) -> None:
        """Each pending pair's share of the vehicle's Δp in this stacked update: K's position rows on its rows of ν."""
        P = state.P
        cols = np.asarray(cols)
        Kp = P[:3][:, cols] @ H.T @ np.linalg.inv(H @ P[np.ix_(cols, cols)] @ H.T + R)
        by: dict[int, np.ndarray] = {}
        kinds = {}
        r = 0
        for lid, kind, d in self.pending:
            by[lid] = by.get(lid, np.zeros(3)) + Kp[:, r : r + d] @ nu[r : r + d]
            kinds[lid] = kind
            r += d
        for lid, dp in by.items():
            self.shares.append((self.est.nav.t, lid, kinds[lid], dp))

    def watch_pairs(self, paired, feats) -> None:
        """Log each pairing of the watched feature (a pipe): ν, ∂ν/∂y with the Jacobians the filter
        uses and with those at the current estimate, NIS."""
        nav, fmap = self.est.nav, self.est.map
        x, P = nav.state.x, nav.state.P
        for z, lid, p in paired:
            f = feats[lid]
            if lid != self.watch or f.kind != "pipe":
                continue
            o = fmap._prepared[id(z)]
            ln = o.line
            args = (ln.U[None], np.array([ln.rho]), ln.d[None], ln.cov[None], o.R_BS, o.t_BS)
            H_cur = bt.line_innovations(x[:NX], x[f.cols][None], *args, anchors=f.anchor[None])[1][0]
            cols = np.r_[np.arange(NX), f.cols]
            H = np.hstack([p.H_x, p.H_l])
            S = H @ P[np.ix_(cols, cols)] @ H.T + p.R
            nis = float(p.innovation @ np.linalg.solve(S, p.innovation))
            self.watched.append((nav.t, p.innovation.copy(), p.H_x[:, :3].copy(), H_cur[:, :3].copy(), nis))

    def objects_mean(self) -> np.ndarray | None:
        ids, X = self.est.map.objects()
        return X.mean(axis=0) if len(ids) else None

    def log(self, before_p: np.ndarray, before_o: np.ndarray | None, n_obj: int) -> None:
        nav = self.est.nav
        after_o = self.objects_mean() if n_obj else None
        same = n_obj and len(self.est.map.objects()[0]) == n_obj
        do = after_o - before_o if same and before_o is not None else None
        self.rows.append((nav.t, self.tag, nav.state.xv[:3] - before_p, do))


_TRACE: list[Trace] = []  # the trace the EkfState patches report to


def _patch() -> None:
    """Wrap EkfState's steps that change the state so that each logs its change to the trace."""

    def wrap(fn, reads_map: bool, tag: str | None = None):
        def inner(self, *a, **k):
            tr = _TRACE[-1] if _TRACE else None
            if tr is None or tr.est.nav.state is not self:
                return fn(self, *a, **k)
            p = self.xv[:3].copy()
            if reads_map and tr.pending:
                tr.split(self, *a)
            n_obj, o = 0, None
            if reads_map:
                n_obj = len(tr.est.map.objects()[0])
                o = tr.objects_mean() if n_obj else None
            out = fn(self, *a, **k)
            saved = tr.tag
            tr.tag = tag or saved
            tr.log(p, o, n_obj)
            tr.tag = saved
            return out

        return inner

    EkfState.predict_vehicle = wrap(EkfState.predict_vehicle, False, "predict")
    EkfState.update_vehicle = wrap(EkfState.update_vehicle, False)
    EkfState.update = wrap(EkfState.update, True)
    EkfState.augment = wrap(EkfState.augment, False)


def run(cache: Path, seed: int, sets: dict, scenario: str = "tank", **options) -> tuple[Trace, object]:
    from semslam.compare import estimators_input
    from semslam.config import SemslamConfig
    from semslam.mission.bag import read_mission
    from semslam.pipeline import run_pipeline

    base = _config(None, scenario)
    data = base.model_dump()
    for key, value in sets.items():
        sec, fld = key.split(".", 1)
        data[sec][fld] = value
    config = SemslamConfig.model_validate(data)
    bag, obs_path = _paths(cache, scenario, seed)
    payload = pickle.loads(obs_path.read_bytes())
    mission = read_mission(bag, config.reader)
    fes = [
        RecordedFrontend(n, payload["observations"].get(n, {}), payload["summaries"].get(n)) for n in payload["names"]
    ]
    est = EkfEstimator(mission.metadata, config)
    tr = Trace(est, **options)
    _TRACE.append(tr)
    _patch()
    gt = mission.metadata.ground_truth
    tr.true_objects = np.array([g.position for g in gt.objects]) if gt else np.zeros((0, 3))
    run_pipeline(
        estimators_input(mission, config),
        [est],
        fes,
        view_estimator=est.name,
        keep_observations=False,
        frontend_process=False,
    )
    return tr, est


def main() -> None:
    import yaml

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cache", type=Path, required=True)
    ap.add_argument("--seed", type=int, required=True)
    ap.add_argument("--axis", type=int, default=1, help="0 north, 1 east, 2 down")
    ap.add_argument("--from", dest="t0", type=float, default=0.0)
    ap.add_argument("--to", dest="t1", type=float, default=60.0)
    ap.add_argument("--window", type=float, default=5.0)
    ap.add_argument("--variant", default="", help="section.key=value,...")
    ap.add_argument("--drop", type=int, help="a variant: this feature's pairings ignored")
    ap.add_argument(
        "--refresh-deg", type=float, help="a variant: a pipe's first estimate re-taken when turned this far"
    )
    ap.add_argument(
        "--first-from-views",
        action="store_true",
        help="a variant: a pipe's Jacobians at a line fitted to all its track's views",
    )
    ap.add_argument("--watch", type=int, help="log each pairing of this pipe (ν, ∂ν/∂p on the axis, NIS, Δ)")
    args = ap.parse_args()
    sets = {}
    for kv in filter(None, args.variant.split(",")):
        k, v = kv.split("=", 1)
        sets[k] = yaml.safe_load(v)
    tr, est = run(
        args.cache,
        args.seed,
        sets,
        drop=args.drop,
        refresh_deg=args.refresh_deg,
        watch=args.watch,
        first_from_views=args.first_from_views,
    )
    ax = args.axis
    ts = np.array(sorted(tr.truth))
    tp = np.array([tr.truth[t] for t in ts])
    start = tr.rows[0][0]
    # the vehicle's estimate after each step (cumulative Δ from the recorded trajectory)
    traj = est.nav._traj
    tt, xx = np.array(traj["t"]), np.array(traj["x"])[:, :3]

    def err_at(t):
        k = int(np.clip(np.searchsorted(tt, t, side="right") - 1, 0, len(tt) - 1))
        j = int(np.clip(np.searchsorted(ts, tt[k]), 0, len(ts) - 1))
        return xx[k, ax] - tp[j, ax]

    edges = np.arange(args.t0, args.t1 + 1e-9, args.window)
    tags = sorted({r[1] for r in tr.rows})
    print(
        f"seed {args.seed} axis {ax} variant {sets or 'none'}: Σ Δ (mm) of the vehicle by step, per window (predict: less the true motion)"
    )
    print("  window     err0   err1  " + " ".join(f"{t[:11]:>11s}" for t in tags) + "  map:obj Δ(mm)")
    for a, b in zip(edges[:-1], edges[1:]):
        lo, hi = start + a * 1e9, start + b * 1e9
        sel = [r for r in tr.rows if lo <= r[0] < hi]
        s = defaultdict(float)
        so = 0.0
        for _, tag, dp, do in sel:
            s[tag] += dp[ax]
            if do is not None:
                so += do[ax]
        ja, jb = (int(np.clip(np.searchsorted(ts, v), 0, len(ts) - 1)) for v in (lo, hi))
        s["predict"] -= tp[jb, ax] - tp[ja, ax]  # the prediction's error: less the true motion
        print(
            f"  {a:4.0f}-{b:<4.0f} {err_at(lo) * 1e3:6.0f} {err_at(hi) * 1e3:6.0f}  "
            + " ".join(f"{s[t] * 1e3:11.1f}" for t in tags)
            + f"  {so * 1e3:8.1f}"
        )
    lo, hi = start + args.t0 * 1e9, start + args.t1 * 1e9
    by = defaultdict(float)
    kind = {}
    for t, lid, k, dp in tr.shares:
        if lo <= t < hi:
            by[lid] += dp[ax]
            kind[lid] = k
    print(f"features moving the vehicle most on axis {ax} over {args.t0:.0f}-{args.t1:.0f}s (mm; entered at s):")
    for lid, v in sorted(by.items(), key=lambda kv: -abs(kv[1]))[:12]:
        print(f"  {kind[lid]}{lid:<4d} {v * 1e3:8.1f}  entered {(tr.first.get(lid, start) - start) * 1e-9:6.1f}")
    if tr.watched:
        dy = defaultdict(float)
        for t, lid, _, dp in tr.shares:
            if lid == args.watch:
                dy[t] += dp[ax]
        print(
            f"pipe{args.watch}'s pairings: t, ν (r1 r2 r3 ρ), ∂ν/∂(axis) used | at the current estimate, NIS, Δ(axis) mm"
        )
        for t, nu, h_used, h_cur, nis in tr.watched:
            if lo <= t < hi:
                print(
                    f"  {(t - start) * 1e-9:6.2f} {np.round(nu, 3)} {np.round(h_used[:, ax], 3)} | {np.round(h_cur[:, ax], 3)} "
                    f"NIS {nis:5.1f} {dy[t] * 1e3:6.1f}"
                )
    e = xx - tp[np.clip(np.searchsorted(ts, tt), 0, len(ts) - 1)]
    Pp = np.array(traj["P"])[:, :3, :3]
    nees = np.einsum("ni,ni->n", e, np.linalg.solve(Pp, e[..., None])[..., 0]).mean()
    print(
        f"position RMSE {np.sqrt((e**2).sum(axis=1).mean()):.3f} m, NEES {nees:.1f}, pipes re-linearised "
        f"{len(tr.refreshed)}"
    )
    # mapped objects' errors (nearest true object) at the end
    ids, X = est.map.objects()
    if len(ids) and len(tr.true_objects):
        d = np.linalg.norm(X[:, None] - tr.true_objects[None], axis=2).argmin(axis=1)
        e = X - tr.true_objects[d]
        print(f"objects at the end: mean error (m) {np.round(e.mean(axis=0), 3)}, vehicle error {err_at(tt[-1]):.3f}")


if __name__ == "__main__":
    main()
