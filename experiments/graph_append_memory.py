"""What the graph appends a keyframe or an update over a long survey, before (lists, ``gtsam.Values``)
and now (``FrozenValues``, ``OnlinePoses``, a ``SpillLog`` of timings): RSS and Python's traced
allocations after the appends, one structure per fresh process.

    python experiments/graph_append_memory.py            # all six, 7,201 keyframes, 20,000 updates
    python experiments/graph_append_memory.py online-list --keyframes 3601
"""

from __future__ import annotations

import argparse
import gc
import os
import subprocess
import sys
import time
import tracemalloc

import gtsam
import numpy as np

KINDS = ("frozen-values", "frozen-rows", "online-list", "online-spill", "timing-lists", "timing-spill")
X, V, B = gtsam.symbol_shorthand.X, gtsam.symbol_shorthand.V, gtsam.symbol_shorthand.B


def rss_mb() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 1e6


def keyframe_values(k: int, pose: gtsam.Pose3, rng) -> gtsam.Values:
    v = gtsam.Values()
    v.insert(X(k), pose)
    v.insert(V(k), rng.normal(size=3))
    v.insert(B(k), rng.normal(size=1))
    return v


def measure(kind: str, n_keyframes: int, n_updates: int) -> str:
    from semslam.backend.graph import UPDATE_ROW
    from semslam.backend.keyframes import OnlinePoses
    from semslam.backend.window import FrozenValues
    from semslam.estimation import SpillLog

    rng = np.random.default_rng(0)
    poses = [gtsam.Pose3(gtsam.Rot3.Expmap(rng.normal(size=3)), rng.normal(size=3)) for _ in range(64)]
    gc.collect()
    tracemalloc.start()
    r0 = rss_mb()
    if kind == "frozen-values":
        keep = gtsam.Values()
        for k in range(n_keyframes):
            keep.insert_or_assign(keyframe_values(k, poses[k % 64], rng))
    elif kind == "frozen-rows":
        keep = FrozenValues()
        for k in range(n_keyframes):
            keep.insert_or_assign(keyframe_values(k, poses[k % 64], rng), [X(k), V(k), B(k)])
    elif kind == "online-list":
        keep = []
        for k in range(n_keyframes):
            p = gtsam.Pose3(poses[k % 64].rotation(), poses[k % 64].translation())
            keep.append((10**18 + k, p, rng.normal(size=(3, 3))))
    elif kind == "online-spill":
        keep = OnlinePoses()
        for k in range(n_keyframes):
            keep.append(10**18 + k, poses[k % 64], rng.normal(size=(3, 3)))
    elif kind == "timing-lists":
        keep = ([], [], [], [])
        for i in range(n_updates):
            keep[0].append(time.perf_counter() - 1.0)
            keep[1].append(time.process_time() - 0.5)
            keep[2].append(i // 1000)
            keep[3].append("keyframe")
    else:
        keep = SpillLog(UPDATE_ROW)
        for i in range(n_updates):
            keep.append(time.perf_counter() - 1.0, time.process_time() - 0.5, i // 1000, 1)
    gc.collect()
    traced, _ = tracemalloc.get_traced_memory()
    assert keep is not None
    return f"{kind}: RSS +{rss_mb() - r0:.2f} MB, traced {traced / 1e6:.2f} MB"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("kinds", nargs="*", default=list(KINDS), help=", ".join(KINDS))
    ap.add_argument("--keyframes", type=int, default=7201, help="the 2-hour survey's")
    ap.add_argument("--updates", type=int, default=20000)
    args = ap.parse_args()
    if unknown := set(args.kinds) - set(KINDS):
        ap.error(f"unknown: {', '.join(sorted(unknown))}")
    if len(args.kinds) == 1:
        print(measure(args.kinds[0], args.keyframes, args.updates))
        return
    for kind in args.kinds:  # a fresh process each: what one leaves in malloc's arenas is not the next's
        cmd = [sys.executable, __file__, kind, "--keyframes", str(args.keyframes), "--updates", str(args.updates)]
        subprocess.run(cmd, check=True)


if __name__ == "__main__":
    main()
