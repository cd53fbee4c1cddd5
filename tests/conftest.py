"""Shared fixtures."""

from __future__ import annotations

import signal

import numpy as np
import pytest

# A suite started in the background (`cmd &` in a script) inherits SIGINT ignored, and so would every
# command a test starts: the tests that send Ctrl-C to a command would see it ignored. Handled here,
# SIGINT is back to its default in those commands (an ignored signal survives exec, a handled one not).
signal.signal(signal.SIGINT, signal.default_int_handler)


# The longest files first: the suite runs whole files in two processes (pyproject's addopts), and a
# long file drawn last would keep one process busy while the other has nothing left.
LONGEST_FILES = (
    "test_study.py",
    "test_graph_window.py",
    "test_odometry_frontend.py",
    "test_gps_dive.py",
    "test_memory_pipeline.py",
    "test_laser_real.py",
    "test_frontend_process.py",
    "test_sonar_frontend.py",
    "test_signals.py",
)


def pytest_collection_modifyitems(items):
    def rank(item):
        name = item.path.name
        return LONGEST_FILES.index(name) if name in LONGEST_FILES else len(LONGEST_FILES)

    items.sort(key=rank)  # stable: the order within a file and among the others is kept


@pytest.fixture
def sample_mission():
    """Factory: a small Mission with every measurement type, sidecar metadata and ground truth.

    ``sample_mission(seconds=2.0)``: DVL 5 Hz (with a dropout), AHRS 20 Hz, depth 8 Hz, laser 2 Hz,
    sonar 4 Hz, ground truth 10 Hz, all starting at t = 100 s.
    """
    from semslam.mission import (
        Attitude,
        Depth,
        DvlVelocity,
        GroundTruthMap,
        GroundTruthPose,
        GtObject,
        GtPipe,
        Mission,
        MissionMetadata,
        PointCloud,
        SensorInfo,
        SonarSwath,
    )

    def make(seconds: float = 2.0, seed: int = 0):
        rng = np.random.default_rng(seed)
        t0 = 100_000_000_000
        ms = []

        def stamps(rate):
            return [t0 + int(round(k * 1e9 / rate)) for k in range(int(seconds * rate))]

        for k, t in enumerate(stamps(5)):
            valid = k not in (3, 4)
            ms.append(
                DvlVelocity(
                    t,
                    "dvl",
                    velocity=rng.normal(size=3) if valid else np.full(3, np.nan),
                    covariance=np.diag([1e-4, 2e-4, 3e-4]) if valid else np.full((3, 3), np.nan),
                    valid=valid,
                    beam_valid=(True, True, True, valid) if valid else (True, False, False, False),
                    altitude=None if k == 1 else 2.0 + 0.1 * k,
                )
            )
        for k, t in enumerate(stamps(20)):
            ms.append(
                Attitude(
                    t,
                    "ahrs",
                    orientation=rng.normal(size=4),
                    covariance=np.diag([1e-4, 1e-4, 4e-4]),
                    angular_rate=rng.normal(size=3) if k % 2 else None,
                )
            )
        for t in stamps(8):
            ms.append(Depth(t, "depth", depth=rng.uniform(1, 20), variance=rng.uniform(1e-4, 1e-2)))
        for k, t in enumerate(stamps(2)):
            n = 200 + k
            ms.append(
                PointCloud(
                    t,
                    "laser",
                    points=rng.normal(size=(n, 3)).astype(np.float32),
                    intensity=rng.random(n).astype(np.float32) if k % 2 == 0 else None,
                )
            )
        for k, t in enumerate(stamps(4)):
            grid = np.float32(-1.2) + np.arange(128) * np.float64(np.float32(0.02))
            keep = np.sort(rng.choice(128, 90, replace=False))
            ms.append(
                SonarSwath(
                    t,
                    "sonar",
                    angles=grid[keep],
                    ranges=rng.uniform(0.5, 30, keep.size).astype(np.float32),
                    intensities=rng.random(keep.size).astype(np.float32) if k % 2 else None,
                )
            )
        for t in stamps(10):
            q = rng.normal(size=4)
            ms.append(GroundTruthPose(t, "gt", position=rng.normal(size=3), orientation=q / np.linalg.norm(q)))
        T = np.eye(4)
        T[:3, 3] = (0.3, -0.1, 0.25)
        meta = MissionMetadata(
            name="sample",
            sensors={
                "dvl": SensorInfo("dvl", "dvl", topic="/nav/dvl", T_BS=T),
                "ahrs": SensorInfo("ahrs", "ahrs", topic="/nav/imu"),
                "depth": SensorInfo("depth", "depth", topic="/nav/pressure"),
                "laser": SensorInfo("laser", "laser", topic="/laser/points", T_BS=np.diag([1.0, -1, -1, 1])),
                "sonar": SensorInfo("sonar", "sonar", topic="/sonar/swath"),
                "gt": SensorInfo("gt", "ground_truth", topic="/ground_truth"),
            },
            ground_truth=GroundTruthMap(
                classes=("valve", "elbow"),
                objects=(GtObject(1, "valve", (1.0, 2.0, 3.0), pipes=(7,)),),
                pipes=(GtPipe(7, (0.0, 0.0, 3.0), (1.0, 2.0, 3.0), 0.05),),
                seen_objects=(1,),
            ),
            extras={"noise": {"dvl_sigma_m_s": 0.01}, "seed": seed},
        )
        return Mission.from_measurements(meta, ms)

    return make
