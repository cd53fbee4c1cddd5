"""The laser front-end's observations against the simulator's truth, per class (issue 21): bias and
spread of an object's centre and of a pipe's axis, in the sensor's viewing geometry, and whether the
declared covariances cover the residuals (mean NIS; 3 for objects if they do).

    python experiments/estimators/laser_bias.py --seeds 1-4 --cache DIR

Reads the observations ``replay_study.py record`` kept (the laser's carry no ``truth_id``: each is
given the true landmark nearest to it, placed with the true pose) and the true trajectory of the mission (placed with the true pose of the observation's stamp, so
that only the front-end's error remains). Objects: residual r = (observed - true centre) in {S};
"along" is its component on the viewing ray (sensor to true centre; > 0: farther than the centre),
"across" the rest. Pipes: the observed segment's ends' offset from the true axis, "along" is its
component on the ray from the sensor perpendicular to the axis (> 0: the fitted axis lies beyond the
true one), with the angle between the axes.
"""

from __future__ import annotations

import argparse
import pickle
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

from semslam.observations import LineObservation, PointObservation


def _truth_poses(bag: Path):
    from semslam.demo import demo_config
    from semslam.estimators import create_estimator
    from semslam.mission.bag import read_mission
    from semslam.pipeline import run_pipeline

    config = demo_config()
    mission = read_mission(bag, config.reader)
    dr = create_estimator("dr", mission.metadata, config)
    result = run_pipeline(mission, [dr], [], frontend_process=False)
    return result.truth, mission.metadata


def _pose_at(truth, stamp: int) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    i = int(np.clip(np.searchsorted(truth.stamps, stamp), 1, len(truth.stamps) - 1))
    i = i - 1 if stamp - truth.stamps[i - 1] < truth.stamps[i] - stamp else i
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat(truth.orientations[i]).as_matrix()
    T[:3, 3] = truth.positions[i]
    return T


def _truth_of(z, T_WS: np.ndarray, objects: dict, pipes: dict, gate_m: float = 0.15, angle_deg: float = 15.0):
    """The true object (centre within ``gate_m``) or pipe (segment's middle within ``gate_m`` of the
    axis and inside the pipe, within ``angle_deg``) the observation, placed with the true pose, shows."""
    if isinstance(z, PointObservation):
        w = T_WS[:3, :3] @ z.position + T_WS[:3, 3]
        best = min(objects.values(), key=lambda g: np.linalg.norm(w - np.asarray(g.position)), default=None)
        return best if best is not None and np.linalg.norm(w - np.asarray(best.position)) < gate_m else None
    if not isinstance(z, LineObservation):
        return None
    a, b = (T_WS[:3, :3] @ e + T_WS[:3, 3] for e in (z.p, z.q))
    m, u = 0.5 * (a + b), (b - a) / np.linalg.norm(b - a)
    for g in pipes.values():
        p, q = np.asarray(g.p), np.asarray(g.q)
        d = (q - p) / np.linalg.norm(q - p)
        t = (m - p) @ d
        if 0 <= t <= np.linalg.norm(q - p) and np.linalg.norm(m - p - t * d) < gate_m:
            if np.degrees(np.arccos(min(1.0, abs(u @ d)))) < angle_deg:
                return g
    return None


def residuals(obs_path: Path, bag: Path) -> dict:
    """Per class (object class, or "pipe"): rows of (along, across, nis) for objects and (along,
    across, angle_deg) for pipes."""
    payload = pickle.loads(obs_path.read_bytes())
    truth, metadata = _truth_poses(bag)
    gt = metadata.ground_truth
    objects = {o.id: o for o in gt.objects}
    pipes = {p.id: p for p in gt.pipes}
    rows: dict[str, list] = defaultdict(list)
    for by_stamp in payload["observations"].values():
        for stamp, obs in by_stamp.items():
            T_WB = _pose_at(truth, stamp)
            for z in obs:
                T_WS = T_WB @ metadata.extrinsic(z.sensor)
                T_SW = np.linalg.inv(T_WS)
                g = _truth_of(z, T_WS, objects, pipes)
                if g is None:
                    continue
                if isinstance(z, PointObservation):
                    c_S = T_SW[:3, :3] @ np.asarray(g.position) + T_SW[:3, 3]
                    r = z.position - c_S
                    ray = c_S / np.linalg.norm(c_S)
                    along = float(r @ ray)
                    nis = float(r @ np.linalg.solve(z.covariance, r))
                    rows[g.cls].append((along, float(np.linalg.norm(r - along * ray)), nis))
                else:
                    p = T_SW[:3, :3] @ np.asarray(g.p) + T_SW[:3, 3]
                    q = T_SW[:3, :3] @ np.asarray(g.q) + T_SW[:3, 3]
                    d = (q - p) / np.linalg.norm(q - p)
                    for e in (z.p, z.q):
                        foot = p + ((e - p) @ d) * d
                        ray = foot - (foot @ d) * d  # from the sensor, perpendicular to the axis
                        ray /= np.linalg.norm(ray)
                        off = e - foot
                        along = float(off @ ray)
                        u = (z.q - z.p) / np.linalg.norm(z.q - z.p)
                        angle = float(np.degrees(np.arccos(min(1.0, abs(u @ d)))))
                        rows["pipe"].append((along, float(np.linalg.norm(off - along * ray)), angle))
    return rows


def main() -> None:
    sys.path.insert(0, str(Path(__file__).parent))
    from replay_study import _paths

    from semslam.study.plan import parse_seeds

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=parse_seeds, required=True)
    ap.add_argument("--cache", type=Path, required=True)
    args = ap.parse_args()
    rows: dict[str, list] = defaultdict(list)
    for seed in args.seeds:
        bag, obs = _paths(args.cache, "tank", seed)
        if obs.exists():
            for k, v in residuals(obs, bag).items():
                rows[k].extend(v)
    print("class                n    along mean/median/std (mm)   across median (mm)   NIS mean/median | angle")
    for k, v in sorted(rows.items()):
        a = np.array(v)
        if k == "pipe":
            third = f"angle median {np.median(a[:, 2]):.1f} deg"
        else:
            third = f"{np.mean(a[:, 2]):.1f}/{np.median(a[:, 2]):.1f}"
        print(
            f"{k:18s} {len(a):5d}   {1e3 * a[:, 0].mean():6.1f}/{1e3 * np.median(a[:, 0]):6.1f}/{1e3 * a[:, 0].std():5.1f}"
            f"        {1e3 * np.median(a[:, 1]):6.1f}            {third}"
        )


if __name__ == "__main__":
    main()
