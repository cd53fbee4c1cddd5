"""Mission model: measurement types, the Mission, ground truth, and rosbag reading/writing."""

from semslam.mission.geodesy import Geodetic
from semslam.mission.ground_truth import GroundTruthMap, GtObject, GtPipe, GtStructure
from semslam.mission.measurements import (
    MEASUREMENT_TYPES,
    Attitude,
    Depth,
    DvlVelocity,
    GpsFix,
    GroundTruthPose,
    Measurement,
    PointCloud,
    SonarSwath,
)
from semslam.mission.mission import Mission, MissionMetadata, SensorInfo, SensorStats

__all__ = [
    "MEASUREMENT_TYPES",
    "Attitude",
    "Depth",
    "DvlVelocity",
    "Geodetic",
    "GpsFix",
    "GroundTruthMap",
    "GroundTruthPose",
    "GtObject",
    "GtPipe",
    "GtStructure",
    "Measurement",
    "Mission",
    "MissionMetadata",
    "PointCloud",
    "SensorInfo",
    "SensorStats",
    "SonarSwath",
]
