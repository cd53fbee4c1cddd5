"""What the sonar front-end emits, and where the graph departs, on one field's bag (issue 21, stop 46).

Runs ``semslam compare``'s comparison (default configuration, the bag's default front-ends) in this process
and writes to OUT/NAME.pkl: every observation the front-ends emitted (kind, stamp, the numbers that place it),
the front-end's summary, each estimator's trajectory with the truth at its stamps, the ATEs, and the fused
attitude every keyframe took (stamp, R, covariance, readings). ``diff`` compares two such runs: the first
observation that differs, the error over time of both and the fused attitudes' covariance ratio. Run each code
from its own copy (``PYTHONPATH=/copy``): this script changes nothing in the estimators.

    python experiments/estimators/sonar_trace.py run BAG OUT NAME
    python experiments/estimators/sonar_trace.py diff OUT/A.pkl OUT/B.pkl
    python experiments/estimators/sonar_trace.py pair STUDY_A STUDY_B

``pair`` prints two studies' missions side by side (from each mission's ``study_mission.json``, so a study still
running shows what it has): graph and EKF ATE, structures found, pipes mapped, and the sums over the missions
both have.
"""

from __future__ import annotations

import argparse
import json
import pickle
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from semslam.commands.mission_input import checked_mission
from semslam.compare import run_comparison
from semslam.config import SemslamConfig
from semslam.observations import LineObservation, OdometryObservation, PointObservation, StructureObservation

BIN_S = 25.0


def observation_row(frontend: str, stamp: int, z) -> tuple:
    """(front-end, driver stamp, kind, own stamp, what it names, its numbers) of one observation."""
    if isinstance(z, StructureObservation):
        return frontend, stamp, "structure", z.stamp, z.model, np.asarray(z.pose, float)[:3, :].ravel()
    if isinstance(z, OdometryObservation):
        return frontend, stamp, "odometry", z.stamp, str(z.stamp_from), np.asarray(z.relative_pose)[:3, :].ravel()
    if isinstance(z, LineObservation):
        return frontend, stamp, "line", z.stamp, ",".join(z.connected_models), np.r_[z.p, z.q]
    if isinstance(z, PointObservation):
        return frontend, stamp, "point", z.stamp, "", np.asarray(z.position, float)
    return frontend, stamp, type(z).__name__, z.stamp, "", np.zeros(0)


def record_fused() -> list:
    """Every fused attitude a keyframe takes: (t, R_WB, covariance, readings)."""
    from semslam.backend import navigation as nav

    taken: list = []
    take = nav.NavigationBuffer.take_fused_attitude

    def patched(self, t):
        out = take(self, t)
        if out is not None:
            taken.append((t, out[0].copy(), out[1].copy(), out[2]))
        return out

    nav.NavigationBuffer.take_fused_attitude = patched
    return taken


def record_sonar() -> tuple[list, dict]:
    """The sonar front-ends made in this process, and the pose each swath was placed with (stamp → T_WB)."""
    from frontends.sonar.frontend import SonarFrontend

    made: list = []
    placed: dict = {}
    init, process = SonarFrontend.__init__, SonarFrontend.process

    def patched_init(self, *args, **kwargs):
        init(self, *args, **kwargs)
        made.append(self)

    def patched_process(self, measurement, view=None):
        out = process(self, measurement, view)
        T = self._pose_cache.get(measurement.stamp)
        if T is not None:
            placed[measurement.stamp] = np.asarray(T, float).copy()
        return out

    SonarFrontend.__init__, SonarFrontend.process = patched_init, patched_process
    return made, placed


def sonar_record(made: list, placed: dict) -> dict:
    """The patches (id, anchor stamp, first and last swath stamps, heading change, track), every window
    registration tried (window anchor patch, reference patch, outcome) and the swaths' placements."""
    if not made:
        return {}
    fe = made[-1]
    return {
        "patches": [
            (p.id, int(p.anchor_stamp), int(p.stamps[0]), int(p.stamps[-1]), float(p.heading_change), float(p.track_m))
            for p in fe.patches
        ],
        "windows": list(fe.windows.log),
        "placed": placed,
    }


def run(bag: Path, out: Path, name: str) -> None:
    taken = record_fused()
    made, placed = record_sonar()
    cfg = SemslamConfig()
    mission, _, _ = checked_mission(bag, cfg, None, "")
    result, metrics = run_comparison(mission, cfg, None, frontend_workers=1)
    rec = {
        "ate": {k: v["ate_rmse_m"] for k, v in metrics["estimators"].items()},
        "metrics": json.loads(json.dumps(metrics, default=str)),
        "observations": [observation_row(o.frontend, o.stamp, o.observation) for o in result.observations],
        "fused": taken,
        "summaries": json.loads(json.dumps(metrics.get("sonar"), default=str)),
        "trajectories": {},
    }
    for est, r in result.results.items():
        R_true, p_true = result.truth.poses_at(r.trajectory.stamps)
        rec["trajectories"][est] = (r.trajectory.stamps, r.trajectory.positions, p_true)
        rec.setdefault("orientations", {})[est] = (r.trajectory.orientations, R_true)
    rec["sonar"] = sonar_record(made, placed)
    rec["history"] = {k: v for k, v in result.results["graph"].history.items() if "bias" in k}
    out.mkdir(parents=True, exist_ok=True)
    with open(out / f"{name}.pkl", "wb") as f:
        pickle.dump(rec, f)
    print("SUMMARY", name, {k: round(v, 4) for k, v in rec["ate"].items()})


def diff(a_path: Path, b_path: Path) -> None:
    a, b = (pickle.load(open(p, "rb")) for p in (a_path, b_path))
    print("ATE", {k: (round(a["ate"][k], 4), round(b["ate"][k], 4)) for k in a["ate"]})
    oa, ob = a["observations"], b["observations"]
    t0 = min(o[1] for o in oa) if oa else 0
    kinds = sorted({o[2] for o in oa + ob})
    for k in kinds:
        print(k, sum(o[2] == k for o in oa), sum(o[2] == k for o in ob))
    first = None
    for i, (x, y) in enumerate(zip(oa, ob)):
        same = x[:5] == y[:5] and len(x[5]) == len(y[5]) and np.allclose(x[5], y[5], atol=1e-3)
        if not same:
            first = i
            break
    if first is None and len(oa) != len(ob):
        first = min(len(oa), len(ob))
    print("first differing observation (beyond 1 mm / 1e-3):", first)
    if first is not None:
        for o in (oa[first : first + 3], ob[first : first + 3]):
            for x in o:
                print(
                    "  ",
                    x[0],
                    f"{(x[1] - t0) * 1e-9:.1f}s",
                    x[2],
                    f"{(x[3] - t0) * 1e-9:.1f}s",
                    x[4],
                    np.round(x[5], 3),
                )
            print("  --")
    # the largest numeric difference over the common prefix with identical identities
    dmax = []
    for x, y in zip(oa, ob):
        if x[:5] != y[:5] or len(x[5]) != len(y[5]):
            break
        dmax.append(float(np.abs(x[5] - y[5]).max()) if len(x[5]) else 0.0)
    if dmax:
        print(f"identical-identity prefix: {len(dmax)} observations, max numeric diff {max(dmax):.2e}")
    for est in ("graph", "ekf"):
        print(f"{est}: horizontal error RMS per {BIN_S:.0f} s (A, B)")
        rows = []
        for rec in (a, b):
            st, p, pt = rec["trajectories"][est]
            t = (st - t0) * 1e-9
            e = np.linalg.norm((p - pt)[:, :2], axis=1)
            bins = (t // BIN_S).astype(int)
            rows.append({int(k): float(np.sqrt((e[bins == k] ** 2).mean())) for k in np.unique(bins)})
        yaws = []
        for rec in (a, b):
            st = rec["trajectories"][est][0]
            t = (st - t0) * 1e-9
            bins = (t // BIN_S).astype(int)
            if "orientations" not in rec:
                yaws.append({})
                continue
            q, R_true = rec["orientations"][est]
            e = _yaw(Rotation.from_quat(q).as_matrix()) - _yaw(R_true)
            e = np.degrees(np.angle(np.exp(1j * e)))
            yaws.append({int(k): float(e[bins == k].mean()) for k in np.unique(bins)})
        print("   t0[s]  horizontal RMS A, B [m]   mean yaw error A, B [deg]")
        for k in sorted(set(rows[0]) | set(rows[1])):
            print(
                f"  {k * BIN_S:6.0f} {rows[0].get(k, np.nan):.3f} {rows[1].get(k, np.nan):.3f}"
                f"   {yaws[0].get(k, np.nan):+.3f} {yaws[1].get(k, np.nan):+.3f}"
            )
    fa, fb = a["fused"], b["fused"]
    n = min(len(fa), len(fb))
    if n:
        ratio = np.array([np.diag(fb[i][2]) / np.diag(fa[i][2]) for i in range(n) if fa[i][0] == fb[i][0]])
        ang = np.array(
            [np.linalg.norm(np.array(_log(fa[i][1].T @ fb[i][1]))) for i in range(n) if fa[i][0] == fb[i][0]]
        )
        print(
            f"fused attitudes: {len(fa)} / {len(fb)}; same stamps {len(ratio)} of the first {n}; "
            f"covariance B/A per axis median {np.median(ratio, axis=0).round(4)}, max {ratio.max(axis=0).round(4)}; "
            f"rotation B vs A median {np.median(ang) * 1e6:.2f} µrad, max {ang.max() * 1e6:.2f} µrad"
        )


def pair(a_dir: Path, b_dir: Path) -> None:
    def load(d: Path) -> dict:
        out = {}
        for f in sorted(d.glob("*/study_mission.json")):
            rec = json.loads(f.read_text())
            out[f.parent.name] = rec["summary"]
        return out

    a, b = load(a_dir), load(b_dir)
    both = sorted(set(a) & set(b))
    print(
        "| field | graph ATE A → B [m] | EKF ATE A → B [m] | graph/EKF A → B | structures A → B | pipes graph A → B |"
    )
    print("|---|---|---|---|---|---|")
    sums = np.zeros(4)
    for m in both:
        ga, gb = (x["estimators"]["graph"]["ate_rmse_m"] for x in (a[m], b[m]))
        ea, eb = (x["estimators"]["ekf"]["ate_rmse_m"] for x in (a[m], b[m]))
        pa, pb = (x["estimators"]["graph"]["n_pipes"] for x in (a[m], b[m]))
        sa, sb = a[m]["structures_found"], b[m]["structures_found"]
        sums += [ga, gb, ea, eb]
        print(
            f"| {m} | {ga:.3f} → {gb:.3f} | {ea:.3f} → {eb:.3f} | {ga / ea:.2f} → {gb / eb:.2f} | {sa} → {sb} | {pa} → {pb} |"
        )
    if both:
        ra = [a[m]["estimators"]["graph"]["ate_rmse_m"] / a[m]["estimators"]["ekf"]["ate_rmse_m"] for m in both]
        rb = [b[m]["estimators"]["graph"]["ate_rmse_m"] / b[m]["estimators"]["ekf"]["ate_rmse_m"] for m in both]
        better = sum(
            b[m]["estimators"]["graph"]["ate_rmse_m"] < a[m]["estimators"]["graph"]["ate_rmse_m"] for m in both
        )
        print(
            f"n={len(both)}: graph sum {sums[0]:.3f} → {sums[1]:.3f}, EKF sum {sums[2]:.3f} → {sums[3]:.3f}, "
            f"median graph/EKF {np.median(ra):.3f} → {np.median(rb):.3f}, graph better in B on {better}"
        )
    print("only in A:", sorted(set(a) - set(b)), "only in B:", sorted(set(b) - set(a)))


def _yaw(R: np.ndarray) -> np.ndarray:
    return np.arctan2(R[:, 1, 0], R[:, 0, 0])


def _log(R: np.ndarray) -> np.ndarray:
    return Rotation.from_matrix(R).as_rotvec()


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="cmd", required=True)
    commands = {"run": (run, ("bag", "out", "name")), "diff": (diff, ("a", "b")), "pair": (pair, ("a", "b"))}
    for name, (_, args) in commands.items():
        sp = sub.add_parser(name)
        for arg in args:
            sp.add_argument(arg, type=str if arg == "name" else Path)
    a = p.parse_args()
    fn, args = commands[a.cmd]
    fn(*(getattr(a, arg) for arg in args))


if __name__ == "__main__":
    main()
