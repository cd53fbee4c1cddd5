"""The laser's object position error against range, per connectivity configuration, against the truth
(issues 21 and 22: lone-end objects' error grows with range while their reported σ does not).

    python experiments/laser/object_range_eval.py collect --cache DIR --seeds 3,13 --every 4 --out /tmp/objrange.json [--set K=V]
    python experiments/laser/object_range_eval.py report /tmp/objrange.json [--seeds 5,7]

``collect`` reads DIR/tank-seed<N>.bag (``semslam study`` / ``replay_study.py record`` bags, with
their ground truth), segments every ``--every``-th scan (and every scan of the first ``--first-s``
seconds: the dive, when the rack is seen from 4-5 m) with this checkout's front-end ("up" and the
placement in the world from the true pose; the tank's radius prior, as the demo sets it) and stores,
per object view with a true object within ``--gate``: its configuration, range, the error
(estimate − truth) in {S} split into the object's box frame (along its first pipe, positive away from
the pipe's end, i.e. beyond the truth; across it horizontally; up) and along the line of sight
(positive: farther than the truth), the reported σ in those directions, and the normalised squared
error e' Σ⁻¹ e (NIS, 3 degrees of freedom: 7.81 is the 95 % bound, 3 the mean of a consistent σ).
``report`` prints per configuration and range band: views, median horizontal error, mean and median of
each component (a bias shows as a mean away from zero), their σ, median and mean NIS and the share
above 7.81.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from laser_real_eval import parse_seeds  # noqa: E402

BANDS = (0.0, 2.0, 3.0, 4.0, 5.0, 9.0)
NIS95 = 7.815  # χ²(3) 95 %


def _config(overrides: list[str]):
    from frontends.laser.config import LaserConfig
    from semslam.sim import TankSimConfig

    data: dict = {"pipes": {"radius_prior": TankSimConfig().structure.pipe_radius_m}}
    for item in overrides:
        key, value = item.split("=", 1)
        section, name = key.split(".")
        data.setdefault(section, {})[name] = json.loads(value)
    return LaserConfig.model_validate(data)


def view_row(ob, truth_S: np.ndarray, up: np.ndarray, seg=None) -> dict:
    """One object view's error components (see the module's doc) from its position, covariance and
    first pipe direction (all {S}) and the true position in {S}; with the scan's segmentation
    ``seg``, for a lone end (configuration 1) also where along the pipe's outward axis (from its
    fitted end, m) the object's points reach (2nd and 98th percentiles, as the centre is taken), the
    truth lies, and how many points it has."""
    e = ob.position - truth_S
    outward = -ob.directions[0]  # away from the pipe's end
    u = up - (up @ outward) * outward
    u /= max(np.linalg.norm(u), 1e-12)
    across = np.cross(u, outward)
    los = ob.position / max(np.linalg.norm(ob.position), 1e-12)
    C = ob.covariance
    row = {
        "config": int(ob.configuration),
        "range": float(np.linalg.norm(ob.position)),
        "err": float(np.linalg.norm(e)),
        "along": float(e @ outward),
        "across": float(e @ across),
        "up": float(e @ u),
        "los": float(e @ los),
        "s_along": float(np.sqrt(outward @ C @ outward)),
        "s_across": float(np.sqrt(across @ C @ across)),
        "s_los": float(np.sqrt(los @ C @ los)),
        "nis": float(e @ np.linalg.solve(C, e)),
    }
    # horizontal error (in the world, "up" from the true pose)
    row["horiz"] = float(np.linalg.norm(e - (e @ up) * up))
    row["los_out"] = float(los @ outward)  # > 0: the sensor looks past the pipe's end onto the object
    row["n_obj"] = len(ob.indices)
    if seg is not None and ob.pipes:
        lengths = [float(np.linalg.norm(seg.pipes[i].q - seg.pipes[i].p)) for i in ob.pipes]
        row.update(pipe_len=min(lengths), n_pipe=min(len(seg.pipes[i].inliers) for i in ob.pipes))
    if seg is not None and ob.configuration == 1 and ob.pipes:
        pipe = seg.pipes[ob.pipes[0]]
        end = min((pipe.p, pipe.q), key=lambda x: float(np.linalg.norm(x - ob.position)))
        X = np.take(seg.structure_points, ob.indices, axis=0) - end
        t = X @ outward
        lo, hi = np.percentile(t, [2, 98])
        row.update(lo=float(lo), hi=float(hi), t_true=float((truth_S - end) @ outward), n=len(t))
        # candidates: where along the axis the object's points off the pipe's cylinder lie (a body,
        # a branch port, a handle: about the fitting's centre whatever its class)
        rad = np.sqrt(np.maximum(np.einsum("ij,ij->i", X, X) - t * t, 0.0))
        for margin in (0.015, 0.025):
            off = t[(rad > pipe.radius + margin) & (t > -0.03)]
            if len(off) >= 5:
                a, b = np.percentile(off, [2, 98])
                row[f"off_med_{int(1000 * margin)}"] = float(np.median(off))
                row[f"off_mid_{int(1000 * margin)}"] = float(0.5 * (a + b))
                row[f"off_n_{int(1000 * margin)}"] = len(off)
    return row


def collect(
    cache: Path, seeds: list[int], every: int, gate: float, overrides: list[str], out: Path, first_s: float = 0.0
) -> None:
    from frontends.laser.frontend import segment_scan
    from semslam.mission.bag import read_mission
    from semslam.mission.measurements import GroundTruthPose, PointCloud

    cfg = _config(overrides)
    rows: list[dict] = json.loads(out.read_text()) if out.exists() else []
    done = {r["seed"] for r in rows}
    for seed in seeds:
        if seed in done:
            continue
        mission = read_mission(cache / f"tank-seed{seed}.bag")
        gt = mission.metadata.ground_truth
        sensor = next(s for s in mission.metadata.sensors.values() if s.kind == "laser")
        objs = np.array([o.position for o in gt.objects])
        poses = {m.stamp: m for m in mission.of_type(GroundTruthPose)}
        stamps = np.array(sorted(poses))
        n0 = len(rows)
        clouds = list(mission.of_type(PointCloud))
        start = clouds[0].stamp if clouds else 0
        for k, c in enumerate(clouds):
            if (k - every // 2) % every and c.stamp - start > 1e9 * first_s:
                continue
            T = poses[int(stamps[np.argmin(np.abs(stamps - c.stamp))])].matrix() @ sensor.T_BS
            R, t = T[:3, :3], T[:3, 3]
            up = R.T @ np.array([0.0, 0.0, -1.0])
            seg = segment_scan(c.points, cfg, up=up)
            for ob in seg.objects:
                d = np.linalg.norm(objs - (R @ ob.position + t), axis=1)
                j = int(d.argmin())
                if d[j] > gate:
                    continue
                row = view_row(ob, R.T @ (objs[j] - t), up, seg)
                row.update(seed=seed, stamp=int(c.stamp), truth=int(gt.objects[j].id), cls=gt.objects[j].cls)
                row["t"] = (c.stamp - start) / 1e9
                rows.append(row)
        out.write_text(json.dumps(rows))
        print(f"seed {seed}: {len(rows) - n0} object views", flush=True)


def band_table(rows: list[dict], title: str) -> None:
    print(title)
    print(
        "| config | range (m) | views | horiz. median | along mean / median | across mean / median | up mean | "
        "los mean | σ along / across | horiz. p90 | NIS median / mean | NIS > 7.81 |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for config in sorted({r["config"] for r in rows}):
        for lo, hi in zip(BANDS[:-1], BANDS[1:]):
            sel = [r for r in rows if r["config"] == config and lo <= r["range"] < hi]
            if len(sel) < 5:
                continue

            def col(key, sel=sel):
                return np.array([r[key] for r in sel])

            nis = col("nis")
            cm = 100.0
            print(
                f"| {config} | {lo:g}-{hi:g} | {len(sel)} | {cm * np.median(col('horiz')):.2f} | "
                f"{cm * col('along').mean():+.2f} / {cm * np.median(col('along')):+.2f} | "
                f"{cm * col('across').mean():+.2f} / {cm * np.median(col('across')):+.2f} | "
                f"{cm * col('up').mean():+.2f} | {cm * col('los').mean():+.2f} | "
                f"{cm * np.median(col('s_along')):.2f} / {cm * np.median(col('s_across')):.2f} | "
                f"{cm * np.percentile(col('horiz'), 90):.2f} | {np.median(nis):.2f} / {nis.mean():.1f} | "
                f"{(nis > NIS95).mean():.2f} |"
            )


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    c = sub.add_parser("collect")
    c.add_argument("--cache", type=Path, required=True)
    c.add_argument("--seeds", required=True)
    c.add_argument("--every", type=int, default=4)
    c.add_argument("--gate", type=float, default=0.15)
    c.add_argument("--out", type=Path, required=True)
    c.add_argument("--set", action="append", default=[], help="section.key=value (JSON value)")
    c.add_argument("--first-s", type=float, default=0.0, help="every scan of the mission's first seconds (the dive)")
    r = sub.add_parser("report")
    r.add_argument("path", type=Path)
    r.add_argument("--seeds", default=None)
    args = ap.parse_args(argv)
    if args.cmd == "collect":
        collect(args.cache, parse_seeds(args.seeds), args.every, args.gate, args.set, args.out, args.first_s)
    else:
        rows = json.loads(args.path.read_text())
        if args.seeds:
            keep = set(parse_seeds(args.seeds))
            rows = [r for r in rows if r["seed"] in keep]
        band_table(rows, f"{args.path} seeds {sorted({r['seed'] for r in rows})}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
