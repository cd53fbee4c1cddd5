"""Where an estimator's error against truth comes from, on recorded front-end observations (issue 21,
stop 39): the position error over time, its mean (the rigid shift) and the mapped objects' mean
offset, for the estimators given, with the landmark observations of a time span left out.

    python experiments/estimators/graph_vs_ekf.py --cache DIR --seeds 81,73 [--estimators graph,ekf,dr]
        [--drop-before S] [--drop-after S] [--every 5] [--gaps 1]

DIR holds replay_study.py's recordings (<scenario>-seed<N>.bag, .obs.pkl); the configuration is the
study's (demo) one. ``--drop-before S``: no landmark observation from the mission's first S seconds
(``--drop-after S`` likewise from S on), so their effect on the shift is seen. ``--gaps S``: for each
DVL dropout of S seconds or longer, the error each estimator gathered across it and the errors of the
readings at its edges (stop 40).
"""

from __future__ import annotations

import argparse
import pickle
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from replay_study import RecordedFrontend, _config, _paths  # noqa: E402


def still_until(mission) -> int:
    """The stamp at which the true vehicle has first moved 1 mm horizontally from its start."""
    from semslam.mission.measurements import GroundTruthPose

    start = None
    for m in mission:
        if isinstance(m, GroundTruthPose):
            p = np.asarray(m.position, float)[:2]
            start = p if start is None else start
            if np.linalg.norm(p - start) > 1e-3:
                return m.stamp
    raise ValueError("the vehicle never moves")


def dvl_gaps(mission, min_s: float = 1.0) -> list[dict]:
    """The DVL's dropouts of ``min_s`` or longer: the last valid reading before (``t0``) and the first
    after (``t1``), stamps in ns, and those readings' errors against the truth in {W} (horizontal
    velocity, m/s; the truth's velocity by central differences of its positions)."""
    from scipy.spatial.transform import Rotation

    from semslam.mission.measurements import DvlVelocity, GroundTruthPose

    gt_t, gt_p, gt_R, dvl = [], [], [], []
    for m in mission:
        if isinstance(m, GroundTruthPose):
            gt_t.append(m.stamp)
            gt_p.append(np.asarray(m.position, float))
            gt_R.append(Rotation.from_quat(m.orientation).as_matrix())
        elif isinstance(m, DvlVelocity):
            dvl.append((m.stamp, m.valid and m.is_finite(), np.asarray(m.velocity, float), m.sensor))
    gt_t, gt_p = np.array(gt_t), np.array(gt_p)
    v_W = np.gradient(gt_p, gt_t * 1e-9, axis=0)

    def error_W(stamp, v_S, sensor):
        k = int(np.clip(np.searchsorted(gt_t, stamp), 0, len(gt_t) - 1))
        R_BS = mission.metadata.extrinsic(sensor)[:3, :3]
        return (gt_R[k] @ R_BS @ v_S - v_W[k])[:2]

    valid = [d for d in dvl if d[1]]
    gaps = []
    for a, b in zip(valid[:-1], valid[1:]):
        if (b[0] - a[0]) * 1e-9 >= min_s:
            gaps.append({"t0": a[0], "t1": b[0], "err0": error_W(a[0], a[2], a[3]), "err1": error_W(b[0], b[2], b[3])})
    return gaps


def held_at_rest(mission, until: int, sigma_m_s: float):
    """Oracle: ``mission`` with every DVL reading before ``until`` replaced by the start at rest's
    zero x/y readings (semslam.mission.rest: every PERIOD_S, σ ``sigma_m_s``, none along z)."""
    from semslam.mission.measurements import DvlVelocity
    from semslam.mission.mission import Mission
    from semslam.mission.rest import PERIOD_S, VERTICAL_SIGMA_M_S

    dvl = mission.metadata.sensors_of_kind("dvl")[0].name
    R_BS = mission.metadata.extrinsic(dvl)[:3, :3]
    cov_S = R_BS.T @ np.diag([sigma_m_s**2, sigma_m_s**2, VERTICAL_SIGMA_M_S**2]) @ R_BS
    period = int(PERIOD_S * 1e9)

    def stream():
        due = None
        for m in mission:
            if m.stamp < until:
                if isinstance(m, DvlVelocity):
                    continue
                due = m.stamp + period if due is None else due
                if m.stamp >= due:
                    yield DvlVelocity(m.stamp, dvl, velocity=np.zeros(3), covariance=cov_S)
                    due = m.stamp + period
            yield m

    return Mission(mission.metadata, stream)


STILL_CHI2 = 16.27  # χ²(3) at 0.999


def held_while_still(mission, window: int):
    """``mission`` with a zero-velocity test of the DVL at the start: while the mean of the last
    ``window`` valid readings (and the newest alone) is consistent with zero velocity (χ²(3) ≤
    STILL_CHI2 with the readings' declared covariance), each reading's horizontal body velocity is
    taken as exactly zero (its vertical and its covariance kept), and a dropout is bridged by zero
    readings every PERIOD_S; from the first reading that fails, the DVL is passed through unchanged."""
    from semslam.mission.measurements import DvlVelocity
    from semslam.mission.mission import Mission
    from semslam.mission.rest import PERIOD_S

    dvl = mission.metadata.sensors_of_kind("dvl")[0].name
    R_BS = mission.metadata.extrinsic(dvl)[:3, :3]
    period = int(PERIOD_S * 1e9)
    info = {}

    def zeroed(v_S):
        v_B = R_BS @ v_S
        v_B[:2] = 0.0
        return R_BS.T @ v_B

    def stream():
        holding, recent, due, cov = True, [], None, None
        for m in mission:
            if holding and isinstance(m, DvlVelocity) and m.sensor == dvl:
                if m.valid and m.is_finite():
                    v, cov = np.asarray(m.velocity, float), np.asarray(m.covariance, float)
                    recent = (recent + [(v, cov)])[-window:]
                    mean = np.mean([r[0] for r in recent], axis=0)
                    mean_cov = np.sum([r[1] for r in recent], axis=0) / len(recent) ** 2
                    one = v @ np.linalg.solve(cov, v)
                    joint = mean @ np.linalg.solve(mean_cov, mean)
                    if max(one, joint) > STILL_CHI2:
                        holding = False
                        info["until"] = m.stamp
                        yield m
                        continue
                    due = m.stamp + period
                    yield DvlVelocity(m.stamp, m.sensor, velocity=zeroed(v), covariance=cov)
                continue  # an invalid reading while still: bridged below
            if holding and cov is not None and due is not None and m.stamp >= due:
                yield DvlVelocity(m.stamp, dvl, velocity=np.zeros(3), covariance=cov)
                due = m.stamp + period
            yield m

    return Mission(mission.metadata, stream), info


def run_filtered(bag: Path, obs_path: Path, config, estimators: list[str], keep_stamp, hold_sigma=None, still=None):
    """The estimators on the recording, fed only the observations whose stamp ``keep_stamp`` accepts
    (the front-end summary's last observations are dropped with the rest when it rejects the end);
    with ``hold_sigma``, the DVL replaced by zero readings until the true vehicle moves (held_at_rest)."""
    from semslam.compare import estimators_input
    from semslam.estimators import create_estimator
    from semslam.mission.bag import read_mission
    from semslam.pipeline import run_pipeline

    payload = pickle.loads(obs_path.read_bytes())
    mission = read_mission(bag, config.reader)
    if hold_sigma is not None:
        until = still_until(mission)
        print(f"  held at rest until {(until - next(iter(mission)).stamp) * 1e-9:.1f} s", flush=True)
        mission = held_at_rest(mission, until, hold_sigma)
    start = next(iter(mission)).stamp
    if still is not None:
        mission, info = held_while_still(mission, still)
    fes = []
    for n in payload["names"]:
        obs = {s: v for s, v in payload["observations"].get(n, {}).items() if keep_stamp(s)}
        fes.append(RecordedFrontend(n, obs, payload["summaries"].get(n)))
    ests = [create_estimator(n, mission.metadata, config) for n in estimators]
    seen = estimators_input(mission, config)
    result = run_pipeline(seen, ests, fes, view_estimator=estimators[0], frontend_process=False)
    if still is not None:
        print(
            f"  still until {(info['until'] - start) * 1e-9:.1f} s (the DVL's zero-velocity test)"
            if "until" in info
            else "  still to the end",
            flush=True,
        )
    return result, mission.metadata


def describe(name: str, traj, landmarks, truth_traj, truth_map, every: float, until: float, gaps=()) -> list[str]:
    _, pt = truth_traj.poses_at(traj.stamps)
    e = traj.positions - pt
    t = (traj.stamps - truth_traj.stamps[0]) * 1e-9
    shift = e.mean(0)
    rest = np.sqrt(np.mean(np.sum((e - shift) ** 2, 1)))
    ate = np.sqrt(np.mean(np.sum(e**2, 1)))
    rows = [f"  {name}: ATE {ate * 100:.2f} cm, shift {_v(shift)} cm, rest {rest * 100:.2f} cm"]
    marks = [tt for tt in np.arange(0.0, until + 1e-9, every) if tt <= t[-1]]
    at = [f"{tt:.0f}:{_v(e[min(np.searchsorted(t, tt), len(t) - 1)])}" for tt in marks]
    rows.append("    e(t) cm: " + " ".join(at))
    for (
        g
    ) in gaps:  # the error the estimator gathered across each DVL dropout (from the reading before it to the one after)
        e0, e1 = (np.array([np.interp(s, traj.stamps, e[:, i]) for i in range(2)]) for s in (g["t0"], g["t1"]))
        t0, t1 = ((s - truth_traj.stamps[0]) * 1e-9 for s in (g["t0"], g["t1"]))
        rows.append(
            f"    DVL gap {t0:.1f}–{t1:.1f} s: error gathered across it {_v(e1 - e0)} cm (the edge readings' "
            f"errors {_v(g['err0'] * 10, '+.1f')} / {_v(g['err1'] * 10, '+.1f')} mm/s in x,y of {{W}})"
        )
    objs = [lm for lm in landmarks if lm.kind == "object"]
    if objs and truth_map.objects:
        G = np.array([g.position for g in truth_map.objects], float)
        d = np.array([lm.position - G[np.argmin(np.linalg.norm(G - lm.position, axis=1))] for lm in objs])
        rows.append(
            f"    objects ({len(objs)}): mean offset {_v(d.mean(0))} cm, spread {_v(d.std(0), '.2f')} cm, "
            f"median |error| {np.median(np.linalg.norm(d, axis=1)) * 100:.2f} cm"
        )
    return rows


def _v(x, spec="+.2f") -> str:
    return ",".join(format(float(c) * 100, spec) for c in x[:3])


def main() -> None:
    from semslam.study.plan import parse_seeds

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cache", type=Path, required=True)
    ap.add_argument("--scenario", default="tank")
    ap.add_argument("--seeds", type=parse_seeds, required=True)
    ap.add_argument("--config")
    ap.add_argument("--estimators", default="graph,ekf")
    ap.add_argument("--drop-before", type=float, default=0.0, help="no landmark observation before S s")
    ap.add_argument("--drop-after", type=float, default=None, help="no landmark observation from S s on")
    ap.add_argument("--every", type=float, default=5.0, help="print the error every S s")
    ap.add_argument("--until", type=float, default=60.0, help="... up to S s")
    ap.add_argument(
        "--hold", type=float, help="oracle: DVL replaced by zero x/y readings of this σ until the truth moves"
    )
    ap.add_argument("--still-test", type=int, help="the DVL's zero-velocity test at the start over this many readings")
    ap.add_argument(
        "--gaps", type=float, help="for each DVL dropout of this many seconds or longer: the error gathered across it"
    )
    ap.add_argument("--dump", type=Path, help="pickle each mission's trajectories, maps and true trajectory here")
    args = ap.parse_args()
    config = _config(args.config, args.scenario)
    estimators = args.estimators.split(",")
    for seed in args.seeds:
        bag, obs_path = _paths(args.cache, args.scenario, seed)
        if not obs_path.exists():
            sys.exit(f"{obs_path}: not recorded")
        from semslam.mission.bag import read_mission

        start = next(iter(read_mission(bag, config.reader))).stamp
        lo = start + int(args.drop_before * 1e9)
        hi = None if args.drop_after is None else start + int(args.drop_after * 1e9)

        def keep(s, lo=lo, hi=hi):
            return s >= lo and (hi is None or s < hi)

        result, metadata = run_filtered(bag, obs_path, config, estimators, keep, args.hold, args.still_test)
        gaps = [] if args.gaps is None else dvl_gaps(read_mission(bag, config.reader), args.gaps)
        if args.dump:
            keep_ = {n: (r.trajectory, r.landmarks) for n, r in result.results.items()}
            (args.dump / f"{bag.stem}.result.pkl").write_bytes(pickle.dumps((keep_, result.truth)))
        print(
            f"{bag.stem} (observations kept from {args.drop_before:g} s to {args.drop_after or 'the end'})", flush=True
        )
        for est in estimators:
            r = result.results[est]
            for row in describe(
                est, r.trajectory, r.landmarks, result.truth, metadata.ground_truth, args.every, args.until, gaps
            ):
                print(row, flush=True)


if __name__ == "__main__":
    main()
