"""How much of each estimator's unaligned error on a tank world is the map's rigid offset (issue 21).

In a tank nothing observes the absolute position after the start: the map inherits the position error
that the dead reckoning had when its first landmarks were seen, and both estimators take that from the
same readings. This reads the dumps of ``replay_study.py run --dump DIR`` and prints, per world and
estimator, the ATE unaligned, with the estimator's mean position error removed (translation-only
alignment), and SE(3)-aligned, the horizontal mean offset, and the time of the first laser landmark
view with the DVL's invalid time before it; then the graph/EKF paired ratios of the three (median and
its bootstrap 95 % interval, as `semslam study` computes them).

    python experiments/estimators/replay_study.py run --cache DIR --seeds 0,3 --estimators graph,ekf --dump D
    python experiments/estimators/offset_share.py D --cache DIR
"""

from __future__ import annotations

import argparse
import pickle
from pathlib import Path

import numpy as np

from semslam.eval.metrics import umeyama
from semslam.mission.bag_reader import read_mission
from semslam.mission.measurements import DvlVelocity
from semslam.study.stats import paired_ratio

KINDS = ("unaligned", "offset removed", "SE(3)")


def errors(traj, truth) -> dict:
    """The three ATEs (m) of one trajectory against the truth and its horizontal mean offset."""
    _, p_true = truth.poses_at(traj.stamps)
    e = traj.positions - p_true
    R, t = umeyama(traj.positions, p_true)
    aligned = traj.positions @ R.T + t - p_true
    rms = lambda x: float(np.sqrt((x**2).sum(1).mean()))  # noqa: E731
    return {
        "unaligned": rms(e),
        "offset removed": rms(e - e.mean(0)),
        "SE(3)": rms(aligned),
        "offset": float(np.linalg.norm(e.mean(0)[:2])),
    }


def first_view_and_dvl_gap(cache: Path, stem: str) -> tuple[float, float]:
    """(s from the start to the first laser landmark view, s of invalid DVL before it)."""
    obs = pickle.loads((cache / f"{stem}.obs.pkl").read_bytes())["observations"].get("laser", {})
    views = [s for s, v in obs.items() if any(type(x).__name__ in ("PointObservation", "LineObservation") for x in v)]
    mission = read_mission(cache / f"{stem}.bag")
    stamps, valid = zip(*[(m.stamp, m.valid) for m in mission if isinstance(m, DvlVelocity)])
    stamps, valid = np.array(stamps), np.array(valid)
    t0 = mission.recording_start or stamps[0]
    t1 = min(views) if views else stamps[-1]
    before = stamps < t1
    dt = np.diff(stamps[before], append=t1) if before.any() else np.array([])
    return (t1 - t0) * 1e-9, float(dt[~valid[before]].sum() * 1e-9)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("dump", type=Path, help="the --dump directory of replay_study.py run")
    ap.add_argument("--cache", type=Path, required=True, help="the bags and recorded observations")
    args = ap.parse_args()
    rows = {}
    for f in sorted(args.dump.glob("*.result.pkl"), key=lambda f: int(f.name.split("seed")[1].split(".")[0])):
        keep, truth = pickle.loads(f.read_bytes())
        stem = f.name.removesuffix(".result.pkl")
        rows[stem] = {est: errors(traj, truth) for est, (traj, _) in keep.items() if est in ("graph", "ekf")}
        rows[stem]["first_view"] = first_view_and_dvl_gap(args.cache, stem)
    print(
        "world | first view (s), DVL invalid before (s) | graph: unaligned, offset removed, SE(3), offset (cm) | EKF: same"
    )
    for stem, r in rows.items():
        cols = [" ".join(f"{r[est][k] * 100:5.2f}" for k in (*KINDS, "offset")) for est in ("graph", "ekf")]
        print(f"{stem} | {r['first_view'][0]:5.1f} {r['first_view'][1]:5.1f} | {cols[0]} | {cols[1]}")
    for k in KINDS:
        g = [r["graph"][k] for r in rows.values()]
        e = [r["ekf"][k] for r in rows.values()]
        pr = paired_ratio(g, e)
        lo, hi = pr["median_ci95"] or (np.nan, np.nan)
        print(
            f"{k:15s} graph median {np.median(g) * 100:.2f} cm, EKF {np.median(e) * 100:.2f}; graph/EKF median "
            f"{pr['median']:.3f} [{lo:.3f}, {hi:.3f}], graph worse on {sum(a > b for a, b in zip(g, e))}/{len(g)}"
        )
    share = [1 - (r["graph"]["offset removed"] / r["graph"]["unaligned"]) ** 2 for r in rows.values()]
    print(f"share of the graph's unaligned squared error that is its mean offset: median {np.median(share):.2f}")


if __name__ == "__main__":
    main()
