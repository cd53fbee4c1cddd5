"""Bag reading speed: 100 PointCloud2 messages of 100 000 points (x, y, z, intensity float32).

Writes the bag once per format (ROS 1 .bag, ROS 2 sqlite3 directory, ROS 2 .mcap) in a temporary
directory, then streams it through ``read_mission`` (deserialisation + vectorised PointCloud2
decoding + Measurement construction) several times and prints the median throughput in MB/s of
message data (the serialized message bytes stored in the bag). Target: ≥ 200 MB/s. The page cache
is warm after the first run, so this measures the reader, not the disk.

``--tank`` instead times a whole mission read (opening: probe, binding, stamps; then every
measurement) of the default tank mission (``semslam demo``'s, simulated once and cached), and
``--mission PATH`` of any bag: median wall and CPU time over the runs.

    python experiments/bench_bag_read.py [--messages 100] [--points 100000] [--runs 5]
    python experiments/bench_bag_read.py --tank [--runs 5]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from semslam.mission import Mission, MissionMetadata, PointCloud, SensorInfo
from semslam.mission.bag import read_mission, write_mission
from semslam.mission.bag_reader import open_bag


def make_mission(n_messages: int, n_points: int) -> Mission:
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(n_points, 3)).astype(np.float32)
    inten = rng.random(n_points).astype(np.float32)
    clouds = [
        PointCloud(10**9 + k * 10**8, "laser", points=pts + np.float32(k), intensity=inten) for k in range(n_messages)
    ]
    meta = MissionMetadata(name="bench", sensors={"laser": SensorInfo("laser", "laser", topic="/laser/points")})
    return Mission.from_measurements(meta, clouds)


def message_bytes(path: Path) -> int:
    with open_bag(path) as reader:
        return sum(len(raw) for _, _, raw in reader.messages())


def time_mission(path: Path, runs: int) -> None:
    walls, cpus = [], []
    for _ in range(runs):
        t, c = time.perf_counter(), time.process_time()
        n = sum(1 for _ in read_mission(path))
        walls.append(time.perf_counter() - t)
        cpus.append(time.process_time() - c)
    print(
        f"{path.name}: {n} measurements, median wall {statistics.median(walls):.3f} s, "
        f"CPU {statistics.median(cpus):.3f} s over {runs} runs (CPU min {min(cpus):.3f}, max {max(cpus):.3f})"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--messages", type=int, default=100)
    ap.add_argument("--points", type=int, default=100_000)
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--tank", action="store_true", help="time reading the default tank mission")
    ap.add_argument("--mission", type=Path, help="time reading this bag")
    args = ap.parse_args()
    if args.tank or args.mission:
        from semslam.demo import demo_mission

        time_mission(args.mission or demo_mission(progress=True), args.runs)
        return

    mission = make_mission(args.messages, args.points)
    with tempfile.TemporaryDirectory(dir=".") as tmp:
        for label, name in (("ROS 1 .bag", "b.bag"), ("ROS 2 sqlite3", "b_ros2"), ("ROS 2 .mcap", "b.mcap")):
            path = write_mission(mission, Path(tmp) / name)
            size = message_bytes(path)
            times = []
            for _ in range(args.runs):
                t = time.perf_counter()
                n = sum(len(m.points) for m in read_mission(path))
                times.append(time.perf_counter() - t)
            assert n == args.messages * args.points, n
            med = statistics.median(times)
            print(
                f"{label:14s} {args.messages} msgs × {args.points} pts, {size / 1e6:.1f} MB message data: "
                f"median {med:.3f} s over {args.runs} runs (min {min(times):.3f}, max {max(times):.3f}) "
                f"→ {size / 1e6 / med:.0f} MB/s"
            )


if __name__ == "__main__":
    main()
