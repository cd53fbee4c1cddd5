"""Per-update cost of the EKF-SLAM against the number of mapped landmarks (10 … 2000).

For each map size N (2/3 objects, 1/3 pipes, spread over the floor around the vehicle), one feature
update is timed: a scan batch of 2 object and 2 pipe observations of mapped features, through the
scan's linearisation (with the Euclidean pre-gate), JCBB, the joint Joseph-form update and the
uncertainty-volume history, after a navigation step whose compressed effect on the map is applied
then (once per scan, however many navigation steps). That navigation step (one AHRS measurement:
predict + attitude update, vehicle-only) is timed as well: it does not grow with the map. The state
has n = 9 + 3 N_obj + 4 N_pipe entries; the update is O(n²) in time and the covariance O(n²) in
memory. Medians over ``--reps`` repetitions.

    python experiments/bench_ekf.py [--sizes 10,20,...] [--reps 7] [--png experiments/out/bench_ekf.png]
"""

from __future__ import annotations

import os

# One BLAS thread: on a shared machine, threaded BLAS on these matrix sizes is slower and erratic.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from scipy.spatial.transform import Rotation  # noqa: E402

from semslam.config import SemslamConfig  # noqa: E402
from semslam.ekf import EkfEstimator  # noqa: E402
from semslam.ekf import geometry as geo  # noqa: E402
from semslam.ekf import models as mdl  # noqa: E402
from semslam.mapping import association as assoc_module  # noqa: E402
from semslam.mapping.tracks import Track, TrackView  # noqa: E402
from semslam.mission.measurements import Attitude, GroundTruthPose  # noqa: E402
from semslam.observations import LineObservation, PointObservation  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository root: tests.support

from tests.support.ekf_mission import simulate_circling  # noqa: E402


def build(n_landmarks: int, seed: int = 0):
    """An initialised EKF with ``n_landmarks`` features, and the truth of the features near the vehicle."""
    rng = np.random.default_rng(seed)
    meta = simulate_circling(seed=seed, duration_s=1.0, with_features=False).metadata
    est = EkfEstimator(meta, SemslamConfig())
    est.process_measurement(
        GroundTruthPose(0, "gt", position=np.array([0.0, 0.0, 2.0]), orientation=np.array([0.0, 0.0, 0.0, 1.0]))
    )
    T = meta.sensors["laser"].T_BS
    R_BS, t_BS = T[:3, :3], T[:3, 3]
    R, t, _, _ = mdl.sensor_pose(est.nav.state.xv, R_BS, t_BS)
    n_pipes = n_landmarks // 3
    side = np.sqrt(n_landmarks) * 1.5  # ~1.5 m between features
    # two objects and two pipes under the sensor (re-observed by the timed scans), the rest spread out
    centres = np.column_stack([rng.uniform(-side / 2, side / 2, (n_landmarks, 2)), np.full(n_landmarks, 4.5)])
    centres[:4, :2] = [[0.8, 0.3], [-0.8, 0.3], [0.0, 1.2], [0.0, -1.2]]
    is_pipe = np.zeros(n_landmarks, bool)
    is_pipe[2:4] = True
    is_pipe[4 : 4 + max(0, n_pipes - 2)] = True
    objects, pipes = [], []
    for c, pipe in zip(centres, is_pipe):
        if pipe:
            a = rng.uniform(0, np.pi)
            d = np.array([np.cos(a), np.sin(a), 0.0])
            pw, qw = c - 0.6 * d, c + 0.6 * d
            o = LineObservation(0, "laser", p=(pw - t) @ R, q=(qw - t) @ R, covariance=np.eye(6) * 4e-4)
            pipes.append((pw, qw))
        else:
            o = PointObservation(0, "laser", position=(c - t) @ R, covariance=np.eye(3) * 9e-4)
            objects.append(c)
        est.map.begin()
        world, cov, prepared = est.map.place(o)
        lid = est.map.promote(Track(-1, prepared.kind, views=[TrackView(0, o, world, cov, prepared)]))
        if prepared.kind == "pipe":
            est.book.extent(lid).add(world, 0.02)
    near_obj = sorted(objects, key=lambda c: np.linalg.norm(c[:2]))[:2]
    near_pipe = sorted(pipes, key=lambda pq: np.linalg.norm((pq[0] + pq[1])[:2]))[:2]
    return est, (R, t), near_obj, near_pipe, rng


def batch(stamp, R, t, objs, pipes, rng):
    out = [
        PointObservation(stamp, "laser", position=(c - t) @ R + rng.normal(0, 0.03, 3), covariance=np.eye(3) * 9e-4)
        for c in objs
    ]
    for pw, qw in pipes:
        out.append(
            LineObservation(
                stamp,
                "laser",
                p=(pw - t) @ R + rng.normal(0, 0.02, 3),
                q=(qw - t) @ R + rng.normal(0, 0.02, 3),
                covariance=np.eye(6) * 4e-4,
            )
        )
    return out


def bench(n_landmarks: int, reps: int) -> dict:
    est, (R, t), objs, pipes, rng = build(n_landmarks)
    n_state = est.nav.state.n
    t_assoc, t_update = [], []
    orig_jcbb, orig_update = assoc_module.jcbb, est.map.update

    def timed_assoc(*args, **kwargs):  # the scan's linearisation is timed with the update, not here
        t0 = time.perf_counter()
        r = orig_jcbb(*args, **kwargs)
        t_assoc.append(time.perf_counter() - t0)
        return r

    def timed_update(paired):
        t0 = time.perf_counter()
        orig_update(paired)
        t_update.append(time.perf_counter() - t0)

    import semslam.mapping.builder as builder_module

    builder_module.jcbb, est.map.update = timed_assoc, timed_update
    totals, paired, preds = [], [], []
    q = Rotation.from_matrix(geo.rot(0.0, 0.0, 0.0) @ est.metadata.sensors["ahrs"].T_BS[:3, :3]).as_quat()
    for k in range(reps):
        # a navigation step (AHRS: predict + update; vehicle-only, compressed), then a scan: its update
        # also applies the pending navigation steps to the whole map (once per scan)
        m = Attitude(int((k + 1) * 5e7), "ahrs", orientation=q, covariance=np.eye(3) * 1e-4, angular_rate=np.zeros(3))
        t0 = time.perf_counter()
        est.process_measurement(m)
        preds.append(time.perf_counter() - t0)
        before = sum(est.book.n_views(f.id) for f in est.map.features)
        t0 = time.perf_counter()
        est.process_observations(m.stamp, batch(m.stamp, R, t, objs, pipes, rng))
        totals.append(time.perf_counter() - t0)
        paired.append(sum(est.book.n_views(f.id) for f in est.map.features) - before)
    builder_module.jcbb = orig_jcbb
    return {
        "landmarks": n_landmarks,
        "state": n_state,
        "paired": int(np.median(paired)),
        "update_ms": 1e3 * np.median(totals),
        "assoc_ms": 1e3 * np.median(t_assoc),
        "joseph_ms": 1e3 * np.median(t_update) if t_update else float("nan"),
        "nav_ms": 1e3 * np.median(preds),
    }


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="10,20,50,100,200,500,1000,2000")
    ap.add_argument("--reps", type=int, default=7)
    ap.add_argument("--png", default="experiments/out/bench_ekf.png")
    args = ap.parse_args()
    rows = []
    print(
        f"{'landmarks':>9} {'state n':>8} {'paired':>6} {'update ms':>10} {'JCBB ms':>9} {'Joseph ms':>10} {'nav ms':>8}"
    )
    for n in map(int, args.sizes.split(",")):
        r = bench(n, args.reps)
        rows.append(r)
        print(
            f"{r['landmarks']:9d} {r['state']:8d} {r['paired']:6d} {r['update_ms']:10.2f} {r['assoc_ms']:9.2f} "
            f"{r['joseph_ms']:10.2f} {r['nav_ms']:8.3f}",
            flush=True,
        )
    if args.png:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        Path(args.png).parent.mkdir(parents=True, exist_ok=True)
        L = [r["landmarks"] for r in rows]
        fig, ax = plt.subplots(figsize=(6, 4))
        ax.loglog(L, [r["update_ms"] for r in rows], "o-", label="feature update (total)")
        ax.loglog(L, [r["joseph_ms"] for r in rows], "s--", label="joint Joseph update")
        ax.loglog(L, [r["assoc_ms"] for r in rows], "^--", label="JCBB association")
        ax.loglog(L, [r["nav_ms"] for r in rows], "v:", label="AHRS predict + update")
        ax.set_xlabel("mapped landmarks")
        ax.set_ylabel("time per update (ms, median)")
        ax.set_title("EKF-SLAM per-update cost")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend()
        fig.tight_layout()
        fig.savefig(args.png, dpi=120)
        print(f"curve: {args.png}")


if __name__ == "__main__":
    main()
