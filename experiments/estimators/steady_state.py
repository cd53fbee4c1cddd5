"""What the graph's steady-state pose error is made of (issue 21, stop 40): the recorded laser
observations replayed through the graph with one input made exact at a time, and the error of each
run split by axis, by vehicle frame and by time.

    python experiments/estimators/steady_state.py run --cache /tmp/s39/all --seeds 0,3 \
        --perfect dvl --dump DIR
    python experiments/estimators/steady_state.py analyse DIR [DIR ...] --cache /tmp/s39/all

``--perfect`` replaces, from the mission's true trajectory (its 50 Hz ground-truth poses,
interpolated), one input by its exact value, keeping the declared covariances: ``dvl`` (the body
velocity at the DVL plus ω × lever arm, in the DVL's frame; dropouts stay dropouts), ``ahrs`` (R_WS
and ω_S without noise or heading bias), ``depth`` (z of the pressure sensor), ``laser`` (each
recorded observation matched to its true landmark as laser_bias.py matches it and replaced by the
truth in the sensor frame: an object's centre, a pipe segment's ends projected on the true axis;
unmatched ones kept). ``--drop depth`` removes the depth readings. ``analyse`` takes the part of
each run from ``--from`` s on (after the descent), aligns it on its own (SE(3)) and prints its RMS
error per world x/y/z and along-track / across-track / vertical (the true heading), the share of
slow error (a 10 s moving mean) and, for the exact-nothing runs, the error at keyframes with a scan
against those without and how much of the horizontal error the attitude error times the lever to
the scan's landmarks predicts.
"""

from __future__ import annotations

import argparse
import pickle
from pathlib import Path

import numpy as np
from replay_study import RecordedFrontend, _config, _paths
from scipy.spatial.transform import Rotation, Slerp


class TrueMotion:
    """The mission's true trajectory, interpolated: T_WB, v_W and ω_B at any stamp."""

    def __init__(self, mission):
        from semslam.mission.measurements import GroundTruthPose

        rows = [(m.stamp, m.position, m.orientation) for m in mission if isinstance(m, GroundTruthPose)]
        self.stamps = np.array([r[0] for r in rows], dtype=np.int64)
        self.t = (self.stamps - self.stamps[0]) * 1e-9
        self.p = np.array([r[1] for r in rows])
        self.slerp = Slerp(self.t, Rotation.from_quat([r[2] for r in rows]))

    def _s(self, stamp: int) -> float:
        return float(np.clip((stamp - self.stamps[0]) * 1e-9, self.t[0], self.t[-1]))

    def pose(self, stamp: int) -> np.ndarray:
        s = self._s(stamp)
        T = np.eye(4)
        T[:3, :3] = self.slerp([s]).as_matrix()[0]
        T[:3, 3] = [np.interp(s, self.t, self.p[:, i]) for i in range(3)]
        return T

    def rates(self, stamp: int, h: float = 0.01) -> tuple[np.ndarray, np.ndarray]:
        """(v_W, ω_B) by central differences over ±h s."""
        s = self._s(stamp)
        a, b = max(s - h, self.t[0]), min(s + h, self.t[-1])
        pa = np.array([np.interp(a, self.t, self.p[:, i]) for i in range(3)])
        pb = np.array([np.interp(b, self.t, self.p[:, i]) for i in range(3)])
        Ra, Rb = self.slerp([a, b])
        return (pb - pa) / (b - a), (Ra.inv() * Rb).as_rotvec() / (b - a)


def exact_stream(mission, truth: TrueMotion, perfect: set[str], drop: set[str]):
    """``mission`` with the named inputs exact (or dropped): a new Mission streaming the bag."""
    from dataclasses import replace

    from semslam.mission.measurements import Attitude, Depth, DvlVelocity
    from semslam.mission.mission import Mission

    md = mission.metadata

    def one(m):
        if isinstance(m, Depth):
            if "depth" in drop:
                return None
            if "depth" in perfect:
                T = truth.pose(m.stamp)
                return replace(m, depth=float((T[:3, :3] @ md.extrinsic(m.sensor)[:3, 3] + T[:3, 3])[2]))
        if isinstance(m, DvlVelocity) and "dvl" in perfect and m.valid:
            T_BS = md.extrinsic(m.sensor)
            R_WB = truth.pose(m.stamp)[:3, :3]
            v_W, w_B = truth.rates(m.stamp)
            v_B = R_WB.T @ v_W + np.cross(w_B, T_BS[:3, 3])
            return replace(m, velocity=T_BS[:3, :3].T @ v_B)
        if isinstance(m, Attitude) and "ahrs" in perfect:
            R_BS = md.extrinsic(m.sensor)[:3, :3]
            R_WS = truth.pose(m.stamp)[:3, :3] @ R_BS
            _, w_B = truth.rates(m.stamp)
            rate = None if m.angular_rate is None else R_BS.T @ w_B
            return replace(m, orientation=Rotation.from_matrix(R_WS).as_quat(), angular_rate=rate)
        return m

    def stream():
        for m in mission:
            out = one(m)
            if out is not None:
                yield out

    seen = Mission(md, stream)
    seen.dropped, seen.invalid = mission.dropped, mission.invalid
    return seen


def exact_observations(payload: dict, truth: TrueMotion, metadata) -> dict:
    """The recorded laser observations with each matched one replaced by its true value."""
    from dataclasses import replace

    from laser_bias import _truth_of

    from semslam.observations import PointObservation

    gt = metadata.ground_truth
    objects, pipes = {o.id: o for o in gt.objects}, {p.id: p for p in gt.pipes}
    out = {}
    for name, by_stamp in payload["observations"].items():
        out[name] = {}
        for stamp, obs in by_stamp.items():
            kept = []
            for z in obs:
                T_WS = truth.pose(stamp) @ metadata.extrinsic(z.sensor)
                g = _truth_of(z, T_WS, objects, pipes)
                if g is not None:
                    T_SW = np.linalg.inv(T_WS)
                    if isinstance(z, PointObservation):
                        z = replace(z, position=T_SW[:3, :3] @ np.asarray(g.position) + T_SW[:3, 3])
                    else:
                        p = T_SW[:3, :3] @ np.asarray(g.p) + T_SW[:3, 3]
                        d = T_SW[:3, :3] @ (np.asarray(g.q) - np.asarray(g.p))
                        d /= np.linalg.norm(d)
                        z = replace(z, p=p + ((z.p - p) @ d) * d, q=p + ((z.q - p) @ d) * d)
                kept.append(z)
            out[name][stamp] = kept
    return out


def run(args) -> None:
    import time

    from semslam.compare import estimators_input
    from semslam.estimators import create_estimator
    from semslam.mission.bag import read_mission
    from semslam.pipeline import run_pipeline

    config = _config(None, "tank")
    perfect, drop = set(args.perfect.split(",")) - {""}, set(args.drop.split(",")) - {""}
    Path(args.dump).mkdir(parents=True, exist_ok=True)
    for seed in args.seeds:
        t0 = time.perf_counter()
        bag, obs_path = _paths(args.cache, "tank", seed)
        payload = pickle.loads(obs_path.read_bytes())
        mission = read_mission(bag, config.reader)
        truth = TrueMotion(mission)
        observations = payload["observations"]
        if "laser" in perfect:
            observations = exact_observations(payload, truth, mission.metadata)
        fes = [RecordedFrontend(n, observations.get(n, {}), payload["summaries"].get(n)) for n in payload["names"]]
        ests = [create_estimator(e, mission.metadata, config) for e in args.estimators.split(",")]
        seen = estimators_input(exact_stream(mission, truth, perfect, drop), config)
        result = run_pipeline(seen, ests, fes, view_estimator=ests[0].name, frontend_process=False)
        keep = {n: (r.trajectory, r.landmarks) for n, r in result.results.items()}
        (Path(args.dump) / f"{bag.stem}.result.pkl").write_bytes(pickle.dumps((keep, result.truth)))
        print(
            f"{bag.stem} perfect={sorted(perfect)} drop={sorted(drop)} ({time.perf_counter() - t0:.0f} s)", flush=True
        )


def _late_aligned(traj, truth, start_s: float):
    """(t, estimate aligned on the late part, truth positions, R_align, truth rows, estimate rows)."""
    from semslam.eval.metrics import _associated, umeyama

    ti, ei = _associated(traj, truth, 0.05)
    ti, ei = np.asarray(ti), np.asarray(ei)
    t = (truth.stamps[ti] - truth.stamps[0]) * 1e-9
    late = t >= start_s
    ti, ei, t = ti[late], ei[late], t[late]
    p, q = traj.positions[ei], truth.positions[ti]
    R, tt = umeyama(p, q)
    return t, p @ R.T + tt, q, R, ti, ei


def _rms(x) -> float:
    return float(np.sqrt(np.mean(np.square(x)))) * 1000  # mm


def decompose(traj, truth, start_s: float) -> dict:
    """RMS (mm) of the late, self-aligned error: total, x/y/z, along/across/vertical, slow share."""
    t, p, q, R, ti, ei = _late_aligned(traj, truth, start_s)
    e = p - q
    yaw = Rotation.from_quat(truth.orientations[ti]).as_euler("ZYX")[:, 0]
    along = e[:, 0] * np.cos(yaw) + e[:, 1] * np.sin(yaw)
    across = -e[:, 0] * np.sin(yaw) + e[:, 1] * np.cos(yaw)
    # the slow part: the mean over ±5 s (by time, so that the EKF's 7 ms poses and the graph's 1 s
    # keyframes are split alike), on the samples at least 5 s from either end
    c = np.vstack([np.zeros(3), np.cumsum(e, axis=0)])
    lo, hi = np.searchsorted(t, t - 5.0), np.searchsorted(t, t + 5.0, side="right")
    inner = (t >= t[0] + 5.0) & (t <= t[-1] - 5.0)
    slow = ((c[hi] - c[lo]) / (hi - lo)[:, None])[inner]
    return {
        "total": _rms(np.linalg.norm(e, axis=1)),
        "x": _rms(e[:, 0]),
        "y": _rms(e[:, 1]),
        "z": _rms(e[:, 2]),
        "along": _rms(along),
        "across": _rms(across),
        "slow": _rms(np.linalg.norm(slow, axis=1)),
        "fast": _rms(np.linalg.norm(e[inner] - slow, axis=1)),
    }


def attitude_lever(traj, truth, start_s: float, payload: dict, metadata) -> dict:
    """At the keyframes that carry a scan: the horizontal error against -δθ × lever (lever: the true
    body-to-landmark-centroid vector of the scan's observations), and scan vs no-scan keyframes."""
    t, p, q, R, ti, ei = _late_aligned(traj, truth, start_s)
    e = p - q
    scans = {}
    for name, by_stamp in payload["observations"].items():
        T_BS = metadata.extrinsic(name) if name in metadata.sensors else np.eye(4)
        for stamp, obs in by_stamp.items():
            pts = [z.position for z in obs if hasattr(z, "position") and z.position is not None]
            pts += [0.5 * (z.p + z.q) for z in obs if hasattr(z, "p") and getattr(z, "p", None) is not None]
            if pts:
                scans[stamp] = T_BS[:3, :3] @ np.mean(pts, axis=0) + T_BS[:3, 3]
    stamps = traj.stamps[ei]
    has = np.array([s in scans for s in stamps])
    R_est = Rotation.from_matrix(R) * Rotation.from_quat(traj.orientations[ei])
    R_true = Rotation.from_quat(truth.orientations[ti])
    dth = (R_est * R_true.inv()).as_rotvec()  # world-frame attitude error
    pred, tilt = np.zeros_like(e), np.zeros_like(e)
    for i in np.flatnonzero(has):
        lever_W = R_true[i].as_matrix() @ scans[stamps[i]]
        pred[i] = -np.cross(dth[i], lever_W)
        tilt[i] = -np.cross(np.r_[dth[i, :2], 0.0], lever_W)  # roll/pitch only
    h = has
    resid = e[h, :2] - pred[h, :2]
    return {
        "scan_kf": _rms(np.linalg.norm(e[h], axis=1)),
        "noscan_kf": _rms(np.linalg.norm(e[~h], axis=1)),
        "n_scan": int(h.sum()),
        "z_scan": _rms(e[h, 2]),
        "z_noscan": _rms(e[~h, 2]),
        "roll_pitch_mrad": _rms(dth[:, :2]),
        "yaw_mrad": _rms(dth[:, 2]),
        "horiz": _rms(np.linalg.norm(e[h, :2], axis=1)),
        "pred": _rms(np.linalg.norm(pred[h, :2], axis=1)),
        "pred_tilt": _rms(np.linalg.norm(tilt[h, :2], axis=1)),
        "after": _rms(np.linalg.norm(resid, axis=1)),
        "lever_m": float(np.median([np.linalg.norm(v) for v in scans.values()])),
    }


def analyse(args) -> None:
    from semslam.mission.bag import read_mission

    config = _config(None, "tank")
    keys = ("total", "x", "y", "z", "along", "across", "slow", "fast")
    print("run | world | est | " + " | ".join(keys) + "   (mm, late part self-aligned)")
    for d in args.dirs:
        for f in sorted(Path(d).glob("*.result.pkl")):
            keep, truth = pickle.loads(f.read_bytes())
            for est, (traj, _) in keep.items():
                r = decompose(traj, truth, args.start)
                print(f"{Path(d).name} | {f.stem.split('.')[0]} | {est} | " + " | ".join(f"{r[k]:.2f}" for k in keys))
                if args.lever and est == "graph":
                    bag, obs_path = _paths(args.cache, "tank", int(f.stem.split("seed")[1].split(".")[0]))
                    md = read_mission(bag, config.reader).metadata
                    a = attitude_lever(traj, truth, args.start, pickle.loads(obs_path.read_bytes()), md)
                    print("    lever: " + ", ".join(f"{k} {v:.2f}" for k, v in a.items()))


def table(args) -> None:
    """One markdown row per world: the graph's late self-aligned RMS (mm) in each run directory (the
    first is the reference), each run's share of the reference's squared error removed, and medians."""
    runs = [Path(d) for d in args.dirs]
    worlds = sorted({f.name for f in runs[0].glob("*.result.pkl")}, key=lambda n: int(n.split("seed")[1].split(".")[0]))
    cell = {}
    for d in runs:
        for w in worlds:
            if (d / w).exists():
                keep, truth = pickle.loads((d / w).read_bytes())
                cell[d.name, w] = decompose(keep["graph"][0], truth, args.start)[args.key]
    print("| world | " + " | ".join(d.name for d in runs) + " |")
    print("|---" * (len(runs) + 1) + "|")
    share = {d.name: [] for d in runs[1:]}
    for w in worlds:
        ref = cell[runs[0].name, w]
        row = [f"{ref:.2f}"]
        for d in runs[1:]:
            v = cell.get((d.name, w))
            if v is None:
                row.append("-")
                continue
            share[d.name].append(1 - v**2 / ref**2)
            row.append(f"{v:.2f} ({100 * share[d.name][-1]:.0f} %)")
        print(f"| {w.split('.')[0].removeprefix('tank-')} | " + " | ".join(row) + " |")
    med = [f"{np.median([cell[runs[0].name, w] for w in worlds]):.2f}"]
    med += [f"{100 * np.median(share[d.name]):.0f} %" if share[d.name] else "-" for d in runs[1:]]
    print("| median (share of the squared error) | " + " | ".join(med) + " |")


def main() -> None:
    from semslam.study.plan import parse_seeds

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="step", required=True)
    r = sub.add_parser("run")
    r.add_argument("--cache", type=Path, required=True)
    r.add_argument("--seeds", type=parse_seeds, required=True)
    r.add_argument("--perfect", default="", help="comma list of dvl, ahrs, depth, laser")
    r.add_argument("--drop", default="", help="comma list: depth")
    r.add_argument("--estimators", default="graph")
    r.add_argument("--dump", required=True)
    a = sub.add_parser("analyse")
    a.add_argument("dirs", nargs="+")
    a.add_argument("--cache", type=Path, default=Path("/tmp/s39/all"))
    a.add_argument("--start", type=float, default=40.0, help="the late part begins here (s)")
    a.add_argument("--lever", action="store_true", help="also the attitude × lever test (reads the bags)")
    t = sub.add_parser("table")
    t.add_argument("dirs", nargs="+")
    t.add_argument("--start", type=float, default=40.0)
    t.add_argument("--key", default="total", help="total, x, y, z, along, across, slow, fast")
    args = ap.parse_args()
    {"run": run, "analyse": analyse, "table": table}[args.step](args)


if __name__ == "__main__":
    main()
