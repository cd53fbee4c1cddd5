"""GPS fixes in the graph: a position factor on a keyframe at each fix (GTSAM's ``GPSFactorArm``: the
antenna at T_WB · t_BA, t_BA the GPS sensor's extrinsic), and the start pose from the first fix when
the mission has no ground truth (:class:`semslam.mission.gps_start.GpsStart`)."""

from __future__ import annotations

from collections.abc import Callable

import gtsam
import numpy as np

from semslam.backend.keyframes import Keyframes
from semslam.backend.session import IsamSession
from semslam.backend.window import X
from semslam.mission.gps_start import GpsStart
from semslam.mission.measurements import GpsFix, GroundTruthPose, Measurement
from semslam.mission.mission import MissionMetadata


def gps_factor(key: int, fix: GpsFix, t_BA: np.ndarray) -> gtsam.GPSFactorArm:
    """The antenna of pose ``key`` at lever arm ``t_BA`` measured at the fix, with its covariance."""
    model = gtsam.noiseModel.Gaussian.Covariance(np.asarray(fix.covariance, float))
    return gtsam.GPSFactorArm(key, np.asarray(fix.position, float), np.asarray(t_BA, float), model)


class GraphGps:
    """The graph's GPS: ``starts(m)`` makes the first keyframe (or waits for the first fix to make it),
    ``take(fix, keyframe_for)`` starts the graph at the first fix or ties a later one to a keyframe
    (``keyframe_for(stamp)``: a new keyframe at the fix, or the one it falls on; None: out of the window)."""

    def __init__(
        self,
        metadata: MissionMetadata,
        initial_pose: str,
        keyframes: Keyframes,
        session: IsamSession,
        diagnostics: list[str],
    ):
        self.start = GpsStart(metadata, initial_pose)
        self.keyframes = keyframes
        self.session = session
        self.diagnostics = diagnostics

    def starts(self, m: Measurement) -> bool:
        """When the first keyframe is due at ``m``: True if the GPS took it (waits for the first fix,
        or made it from the fix), False if the graph starts without (ground truth, the origin)."""
        if self.start.holds(m):
            return True
        if self.start.fix is None or not self.start.waits:
            return False
        self._start_at(m.stamp)
        return True

    def take(self, fix: GpsFix, keyframe_for: Callable[[int], int | None]) -> None:
        kf = self.keyframes
        if not kf.stamps:
            if not self.start.holds(fix) and self.start.is_start(fix) and kf.nav.attitude is not None:
                self._start_at(fix.stamp)
            elif not self.start.waits:
                self.diagnostics.append(f"{fix.stamp}: GPS fix before the first keyframe, not used")
            return
        k = keyframe_for(fix.stamp)
        if k is None:
            self.diagnostics.append(f"{fix.stamp}: GPS fix older than the smoothing window, dropped")
            return
        factor = gps_factor(X(k), fix, self.start.lever(fix.sensor))
        self.session.commit([(factor, None)], gtsam.Values(), kf.anchor(), stamp=fix.stamp)
        kf.refresh()
        kf.renew_online(k)

    def _start_at(self, stamp: int) -> None:
        """Keyframe 0 at ``stamp``: its pose prior the first fix less the lever arm turned by the AHRS
        attitude, with the fix's horizontal σ (the depth factor fixes the depth). Keyframes take a
        start pose only as a first GroundTruthPose: the fix's is handed to them as one."""
        kf = self.keyframes
        R, _ = kf.nav.attitude_at(stamp * 1e-9)
        position, sigma = self.start.pose(R)
        q = gtsam.Rot3(R).toQuaternion()
        kf.initial_gt = GroundTruthPose(stamp, self.start.fix.sensor, position, [q.x(), q.y(), q.z(), q.w()])
        kf.initial = kf.initial.model_copy(update={"position_sigma_m": float(np.sqrt(np.mean(sigma[:2] ** 2)))})
        kf.first(stamp)
