"""Do the laser's declared covariances cover its errors, in the EKF's own measurement models? Every
recorded observation (``replay_study.py record``) is compared with the true landmark it shows, placed
with the true pose, so only the front-end's error remains: objects by their position in {S} (3 dof),
pipes by the filter's line innovation (orthonormal error, 4 dof: 3 of direction and moment, 1 of
distance ρ) with the filter's R. A declared covariance that covers the errors gives NIS / dof ≈ 1
(mean) and 0.79 / 0.84 (median, 3 / 4 dof).

    python experiments/estimators/ekf_observation_nis.py --seeds 8,10 --cache DIR
"""

from __future__ import annotations

import argparse
import pickle
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np
from scipy.stats import chi2

sys.path.insert(0, str(Path(__file__).parent))

from laser_bias import _pose_at, _truth_of, _truth_poses  # noqa: E402
from replay_study import _paths  # noqa: E402

from semslam.ekf import geometry as geo  # noqa: E402
from semslam.ekf import models as mdl  # noqa: E402
from semslam.observations import PointObservation  # noqa: E402


def nis_rows(obs_path: Path, bag: Path) -> dict[str, list[tuple[float, float]]]:
    """Per kind ("object:<class>", "pipe"): rows of (NIS, segment length or 0)."""
    payload = pickle.loads(obs_path.read_bytes())
    truth, metadata = _truth_poses(bag)
    gt = metadata.ground_truth
    objects = {o.id: o for o in gt.objects}
    pipes = {p.id: p for p in gt.pipes}
    rows: dict[str, list] = defaultdict(list)
    for by_stamp in payload["observations"].values():
        for stamp, obs in by_stamp.items():
            T_WB = _pose_at(truth, stamp)
            x = np.zeros(mdl.NX)
            x[:3], x[3:6] = T_WB[:3, 3], geo.euler(T_WB[:3, :3])
            for z in obs:
                T_BS = metadata.extrinsic(z.sensor)
                g = _truth_of(z, T_WB @ T_BS, objects, pipes)
                if g is None:
                    continue
                R_BS, t_BS = T_BS[:3, :3], T_BS[:3, 3]
                if isinstance(z, PointObservation):
                    h = mdl.point_measurement(x, np.asarray(g.position), R_BS, t_BS)[0]
                    r = z.position - h
                    rows[f"object:{g.cls}"].append((float(r @ np.linalg.solve(z.covariance, r)), 0.0))
                else:
                    p, q = np.asarray(g.p), np.asarray(g.q)
                    d = (q - p) / np.linalg.norm(q - p)
                    l_true = geo.line_params(np.cross(p, d), d)
                    model = mdl.LineObservationModel.from_endpoints(z.p, z.q, z.covariance)
                    nu, _, _, R = mdl.line_innovation(x, l_true, model, R_BS, t_BS)
                    rows["pipe"].append((float(nu @ np.linalg.solve(R, nu)), float(np.linalg.norm(z.q - z.p))))
    return rows


def main() -> None:
    from semslam.study.plan import parse_seeds

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=parse_seeds, required=True)
    ap.add_argument("--cache", type=Path, required=True)
    args = ap.parse_args()
    rows: dict[str, list] = defaultdict(list)
    for seed in args.seeds:
        bag, obs = _paths(args.cache, "tank", seed)
        if obs.exists():
            for k, v in nis_rows(obs, bag).items():
                rows[k].extend(v)
    print("kind                     n   NIS/dof mean  median  p90    share > χ²(0.99)")
    for k, v in sorted(rows.items()):
        a = np.array(v)[:, 0]
        dof = 4 if k == "pipe" else 3
        print(
            f"{k:22s} {len(a):5d}   {a.mean() / dof:8.2f}  {np.median(a) / dof:6.2f}  "
            f"{np.quantile(a, 0.9) / dof:6.2f}   {np.mean(a > chi2.ppf(0.99, dof)):.3f}"
        )
    if rows.get("pipe"):
        a = np.array(rows["pipe"])
        for lo, hi in ((0, 0.3), (0.3, 0.6), (0.6, 1.0), (1.0, 10.0)):
            m = (a[:, 1] >= lo) & (a[:, 1] < hi)
            if m.any():
                print(
                    f"  pipe segments {lo:.1f}-{hi:.1f} m: n {m.sum():5d}  NIS/dof mean {a[m, 0].mean() / 4:.2f} "
                    f"median {np.median(a[m, 0]) / 4:.2f}"
                )


if __name__ == "__main__":
    main()
