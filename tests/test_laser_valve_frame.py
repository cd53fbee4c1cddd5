"""experiments/laser_real_eval.py's count of the clouds that framed each pipeline valve (stop 41)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "experiments"))

from laser_real_eval import valves_in_frame  # noqa: E402

from semslam.mission.ground_truth import GroundTruthMap, GtObject  # noqa: E402
from semslam.mission.measurements import GroundTruthPose  # noqa: E402
from semslam.mission.mission import MissionMetadata  # noqa: E402


def test_a_valve_counts_only_the_clouds_whose_frame_held_its_centre():
    # camera looking straight down (body = sensor = world axes; z down), 20° × 15° field of view;
    # valve 0 straight below at 1.3 m, valve 1 0.27 m to the side (11.7°: outside ±10°), an elbow
    # below too (not a valve), valve 2 with too few points in any cloud to count as seen
    objects = (
        GtObject(0, "Ball-Valve", (0.0, 0.0, 1.3)),
        GtObject(1, "Butterfly-Valve", (0.27, 0.0, 1.3)),
        GtObject(2, "Ball-Valve", (0.0, 0.05, 1.3)),
        GtObject(3, "Elbow", (0.0, 0.0, 1.3)),
    )
    scans = [
        {"stamp": 10, "object_points": {"0": 900, "1": 800, "2": 10, "3": 700}},
        {"stamp": 20, "object_points": {"0": 50, "1": 3000}},  # valve 0 barely seen: still framed
        {"stamp": 30, "object_points": {"1": 100}},  # the vehicle moved 0.27 m: valve 1 now straight below
    ]
    meta = MissionMetadata(
        ground_truth=GroundTruthMap(objects=objects),
        extras={"scans": scans, "simulator": {"config": {"stereo": {"fov_deg": [20.0, 15.0]}}}},
    )
    poses = {
        10: GroundTruthPose(stamp=10, sensor="gt", position=np.zeros(3)),
        20: GroundTruthPose(stamp=20, sensor="gt", position=np.zeros(3)),
        30: GroundTruthPose(stamp=30, sensor="gt", position=np.array([0.27, 0.0, 0.0])),
    }
    assert valves_in_frame(meta, poses, np.eye(4)) == {0: 2, 1: 1}
