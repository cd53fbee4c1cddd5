"""What recording a replay costs on the default tank mission, and what the replay holds.

    python experiments/report_replay_cost.py [--points N]

Runs the demo's comparison (dr, ekf, graph; laser front-end) with a ReplayRecorder, timing its
``step`` calls (they run on the driver's thread, between the estimators' updates), then builds and
writes the replay and prints: the recorder's time in the run, the time to write the MCAP file, its
size, and the message count, raw and zstd-compressed size of each topic.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from collections import defaultdict
from pathlib import Path

try:  # rosbags' own choice: the standard library's from Python 3.14, the backport before
    from compression import zstd
except ImportError:
    from backports import zstd

from semslam.compare import run_comparison
from semslam.demo import demo_config, demo_mission
from semslam.eval import ros_messages as rm
from semslam.eval.replay import ReplayConfig, ReplayRecorder
from semslam.mission.bag import read_mission
from semslam.pipeline import observed_by


class Timed:
    """Passes each step on to ``inner`` and adds up the time it took, and of that the time the
    estimators took to answer ``landmarks()`` (their cost, not the recorder's)."""

    def __init__(self, inner):
        self.inner, self.seconds, self.steps = inner, 0.0, 0
        self.reading = defaultdict(float)

    def step(self, stamp, measurement, observations, views):
        t0 = time.perf_counter()
        self.inner.step(stamp, measurement, observations, {n: _TimedView(v, n, self.reading) for n, v in views.items()})
        self.seconds += time.perf_counter() - t0
        self.steps += 1


class _TimedView:
    def __init__(self, view, name, reading):
        self.view, self.name, self.reading = view, name, reading

    def pose_at(self, stamp):
        return self.view.pose_at(stamp)

    def landmarks(self):
        t0 = time.perf_counter()
        out = self.view.landmarks()
        self.reading[self.name] += time.perf_counter() - t0
        return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=ReplayConfig().scan_points, help="points kept per scan")
    args = ap.parse_args()
    cfg = demo_config()
    mission = read_mission(demo_mission(progress=True), cfg.reader)
    rec = ReplayRecorder(mission.metadata, ReplayConfig(scan_points=args.points))
    timed = Timed(rec)
    t0 = time.perf_counter()
    with observed_by(timed):
        result, _ = run_comparison(mission, cfg, progress=True)
    wall = time.perf_counter() - t0
    print(f"run: {wall:.0f} s wall; recorder steps: {timed.steps}, {timed.seconds:.1f} s in them, of which")
    print("  the estimators answering landmarks(): " + ", ".join(f"{n} {t:.1f} s" for n, t in timed.reading.items()))
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "replay.mcap"
        t0 = time.perf_counter()
        rec.write(path, result)
        print(f"write: {time.perf_counter() - t0:.1f} s; replay.mcap {path.stat().st_size / 1e6:.2f} MB")
    raw = defaultdict(list)
    for _, topic, msg in rec.messages(result):
        raw[topic].append(rm.serialize(msg))
    print(f"{'topic':32s} {'messages':>8s} {'raw MB':>8s} {'zstd MB':>8s}")
    for topic in sorted(raw):
        blob = b"".join(raw[topic])
        print(f"{topic:32s} {len(raw[topic]):8d} {len(blob) / 1e6:8.2f} {len(zstd.compress(blob)) / 1e6:8.2f}")


if __name__ == "__main__":
    main()
