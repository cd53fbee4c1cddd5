"""Where a mission without ground truth starts: at its first GPS fix (what the graph, the EKF and dead
reckoning share, so that all start alike).

When the mission has a GPS and no ground truth, and ``initial.pose`` is ``first_ground_truth``, the
start waits for the first fix, at most :data:`START_WAIT_S` after the first AHRS reading, and is the
fix less the lever arm of the antenna (t_BA, the GPS sensor's extrinsic) turned by the AHRS attitude,
with the fix's σ per axis. That fix is then not used again. Without a fix in time: the origin.
"""

from __future__ import annotations

import numpy as np

from semslam.mission.measurements import Attitude, GpsFix, Measurement
from semslam.mission.mission import MissionMetadata

START_WAIT_S = 10.0  # how long the start waits for a first fix after the first AHRS reading (s)


def starts_from_fixes(metadata: MissionMetadata, initial_pose: str) -> bool:
    """The estimators start from the first GPS fix: the mission has a GPS and no ground truth."""
    return (
        initial_pose == "first_ground_truth"
        and bool(metadata.sensors_of_kind("gps"))
        and not metadata.sensors_of_kind("ground_truth")
    )


class GpsStart:
    """The start pose from the first fix: ``holds(m)`` while the start waits for it, ``pose(R_WB)``
    the start position and its σ once it came."""

    def __init__(self, metadata: MissionMetadata, initial_pose: str):
        self.metadata = metadata
        self.waits = starts_from_fixes(metadata, initial_pose)
        self.fix: GpsFix | None = None
        self.first_ahrs: int | None = None

    def lever(self, sensor: str) -> np.ndarray:
        """The antenna's lever arm t_BA (m, {B}) of GPS sensor ``sensor``."""
        return self.metadata.extrinsic(sensor)[:3, 3]

    def holds(self, m: Measurement) -> bool:
        """Before the start, for each measurement: True while the start waits for the first fix."""
        if isinstance(m, GpsFix) and self.fix is None:
            self.fix = m
        elif isinstance(m, Attitude) and self.first_ahrs is None:
            self.first_ahrs = m.stamp
        late = self.first_ahrs is not None and (m.stamp - self.first_ahrs) * 1e-9 > START_WAIT_S
        if self.waits and self.fix is None and late:
            self.waits = False  # no fix in time: the origin
        return self.waits and self.fix is None

    def is_start(self, fix: GpsFix) -> bool:
        """``fix`` is the one the start was taken from (not to be used again)."""
        return self.waits and fix is self.fix

    def pose(self, R_WB: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """(body position, its σ per axis) from the first fix and the attitude R_WB; None: no fix."""
        if not self.waits or self.fix is None:
            return None
        sigma = np.sqrt(np.diag(np.asarray(self.fix.covariance, float)))
        return np.asarray(self.fix.position, float) - R_WB @ self.lever(self.fix.sensor), sigma
