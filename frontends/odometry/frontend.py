"""The laser odometry front-end: relative poses between scans, from kiss-icp, where the navigation
sensors agree (BUGWRIGHT2 D4.2)."""

from __future__ import annotations

import logging
from collections import Counter
from typing import ClassVar

import numpy as np

from frontends.odometry.config import OdometryConfig
from frontends.odometry.consistency import FRESH_DVL_S, PathAgreement
from frontends.odometry.information import (
    adjoint,
    mahalanobis2,
    tangent,
    translation_given_rotation,
    translation_only,
)
from frontends.odometry.matcher import ScanMatcher
from frontends.odometry.prior import NavigationPrior
from semslam.errors import validated
from semslam.mission.measurements import Attitude, Depth, DvlVelocity, Measurement, PointCloud
from semslam.mission.mission import MissionMetadata
from semslam.observations import Observation, OdometryObservation
from semslam.registry import Frontend, FrontendSummary

log = logging.getLogger(__name__)


class _Track:
    """One laser sensor's registration state: its map and the last scan it placed."""

    def __init__(self, cfg: OdometryConfig):
        self.matcher = ScanMatcher(cfg)
        self.last_stamp: int | None = None  # the last scan placed in the map frame
        self.last_pose: np.ndarray | None = None  # its T_OS (registered, or predicted if rejected)
        self.anchor_stamp: int | None = None  # the last scan whose registration was accepted (or the first)
        self.anchor_pose: np.ndarray | None = None
        self.rejections = 0  # rejected registrations since the last accepted one
        self.velocity_B: np.ndarray | None = None  # body velocity of the last accepted registration (m/s)
        self.anchor_dvl_fresh = False  # a fresh DVL reading at the anchor's stamp (the prior measured, not held)


class OdometryFrontend(Frontend):
    """Consumes point clouds (and the navigation sensors, for its prior); emits one
    :class:`OdometryObservation` per accepted registration: the body's motion from the last
    accepted scan to this one, with the registration's covariance in the body frame."""

    config_model: ClassVar[type] = OdometryConfig
    name: ClassVar[str] = "odometry"
    consumes: ClassVar[tuple[type, ...]] = (PointCloud, Attitude, DvlVelocity, Depth)
    uses_view: ClassVar[bool] = False  # its prior is its own: runs in a process of its own

    def __init__(self, metadata: MissionMetadata, config: dict | OdometryConfig | None = None):
        self.config = validated(OdometryConfig, config, "frontends.odometry")
        self.metadata = metadata
        self.prior = NavigationPrior(
            metadata,
            horizon_s=self.config.max_interval_s + 5.0,
            hold_walk_m_s=self.config.covariance.hold_walk_m_s,
            gyro_sigma_rad_s=self.config.covariance.gyro_sigma_rad_s,
        )
        self.sensors = set(self.config.sensors) or {s.name for s in metadata.sensors_of_kind("laser")}
        self._tracks: dict[str, _Track] = {}
        self.counts: Counter[str] = Counter()
        self.path = PathAgreement()

    def process(self, measurement: Measurement, view=None) -> list[Observation]:
        if not isinstance(measurement, PointCloud):
            self.prior.add(measurement)
            return []
        if measurement.sensor not in self.sensors:
            return []
        self.counts["scans"] += 1
        track = self._tracks.setdefault(measurement.sensor, _Track(self.config))
        return self._register(track, measurement)

    def _register(self, track: _Track, scan: PointCloud) -> list[Observation]:
        T_BS = self.metadata.extrinsic(scan.sensor)
        if self.prior.pose_at(scan.stamp) is None:
            self.counts["no_prior"] += 1
            return []
        stale = track.last_stamp is None or (scan.stamp - track.last_stamp) * 1e-9 > self.config.max_interval_s
        motion = None if stale else self.prior.motion(track.last_stamp, scan.stamp)
        if motion is None or track.matcher.empty or track.rejections >= self.config.restart_after:
            self._start(track, scan)
            return []
        motion = self._dropout_motion(track, motion, scan.stamp)
        predicted = track.last_pose @ np.linalg.inv(T_BS) @ motion @ T_BS
        A = adjoint(T_BS)
        prior_S = self._prior_cov_S(A, track.anchor_stamp, scan.stamp)
        reg = track.matcher.register(
            scan.points,
            predicted,
            scan.stamp,
            None if prior_S is None else prior_S[:3, :3],
            None if prior_S is None else prior_S[3:, 3:],
        )
        track.last_stamp = scan.stamp
        if reg.rejected is not None:
            track.last_pose = predicted  # the chain goes on with the prior; the map is untouched
            track.rejections += 1
            self.counts[f"rejected_{reg.rejected}"] += 1
            return []
        track.last_pose, track.rejections = reg.pose, 0
        relative_S = np.linalg.inv(track.anchor_pose) @ reg.pose
        stamp_from = track.anchor_stamp
        track.anchor_stamp, track.anchor_pose = scan.stamp, reg.pose
        self.counts["accepted"] += 1
        relative_B = T_BS @ relative_S @ np.linalg.inv(T_BS)
        self._compare_path(track, relative_B, stamp_from, scan.stamp)
        track.velocity_B = relative_B[:3, 3] / ((scan.stamp - stamp_from) * 1e-9)
        cov_B = A @ self._tail_scaled(reg, prior_S) @ A.T
        if self.config.factor_rotation == "free":
            cov_B = translation_only(cov_B)
        elif self.config.factor_rotation == "conditional":
            cov_B = translation_given_rotation(cov_B)
        return [
            OdometryObservation(
                scan.stamp,
                scan.sensor,
                stamp_from=stamp_from,
                relative_pose=relative_B,
                covariance=(cov_B + cov_B.T) / 2,
            )
        ]

    def _compare_path(self, track: _Track, relative_B: np.ndarray, stamp_from: int, stamp: int) -> None:
        """Adds the pair to the path check when the DVL was fresh at both its ends."""
        fresh = self._dvl_fresh(stamp)
        if fresh and track.anchor_dvl_fresh:
            prior = self.prior.motion(stamp_from, stamp)
            start = self.prior.pose_at(stamp_from)
            if prior is not None and start is not None:
                self.path.add(relative_B[:3, 3], prior[:3, 3], start[:3, :3])
        track.anchor_dvl_fresh = fresh

    def _dvl_fresh(self, stamp: int) -> bool:
        """A DVL reading at most ``FRESH_DVL_S`` old at ``stamp``: the prior's motion there is measured, not held."""
        age = self.prior.dvl_age_s(stamp)
        return age is not None and 0.0 <= age <= FRESH_DVL_S

    def _dropout_motion(self, track: _Track, motion: np.ndarray, stamp: int) -> np.ndarray:
        """``motion`` (the prior's, since the track's last scan), its translation the last accepted registration's
        body velocity times the interval where ``dropout_motion`` says so and the DVL has been lost for long."""
        age = self.prior.dvl_age_s(stamp)
        if (
            self.config.dropout_motion != "odometry"
            or track.velocity_B is None
            or age is None
            or age <= self.config.dropout_after_s
        ):
            return motion
        out = motion.copy()
        out[:3, 3] = track.velocity_B * ((stamp - track.last_stamp) * 1e-9)
        return out

    def _prior_cov_S(self, A: np.ndarray, stamp_from: int | None, stamp: int) -> np.ndarray | None:
        """The navigation prior's covariance of the sensor's motion since ``stamp_from`` (the map's last accepted
        scan; 6×6, rotation then translation, sensor frame; ``A`` the extrinsic's adjoint): the registration's
        attitude where it is held to the AHRS's, and the gate's and the Student-t scaling's yardstick."""
        prior_B = None if stamp_from is None else self.prior.motion_covariance(stamp_from, stamp)
        if prior_B is None:
            return None
        A_inv = np.linalg.inv(A)
        return A_inv @ prior_B @ A_inv.T

    def _tail_scaled(self, reg, prior_S: np.ndarray | None) -> np.ndarray:
        """The registration's covariance (sensor frame) with its part that ICP's disagreement with the prior
        makes (``Registration.tail_part``: with the attitude held, the translation's measured part; the
        rotation is the prior's own) times :meth:`_tail_factor`."""
        factor = self._tail_factor(reg, prior_S)
        part = reg.covariance if reg.tail_part is None else reg.tail_part
        return reg.covariance + (factor - 1.0) * part

    def _tail_factor(self, reg, prior_S: np.ndarray | None) -> float:
        """(ν + d²)/(ν + 6), d² the correction ICP made to the prior, under ``prior_S``, the prior's covariance
        over the same interval (:meth:`_prior_cov_S`; 1 without the scaling or a prior)."""
        nu = self.config.covariance.tail_dof
        if nu <= 0 or prior_S is None:
            return 1.0
        d2 = mahalanobis2(tangent(reg.correction), prior_S)
        return 1.0 if d2 is None else (nu + d2) / (nu + 6)

    def _start(self, track: _Track, scan: PointCloud) -> None:
        """A new local map anchored at this scan (first scan, long gap, or lost overlap); a scan too
        sparse to anchor one leaves the map empty until the next."""
        track.velocity_B = None
        start = np.eye(4)  # the map frame: the navigation frame's axes (z down, the vertical), at this scan
        start[:3, :3] = self.prior.pose_at(scan.stamp)[:3, :3] @ self.metadata.extrinsic(scan.sensor)[:3, :3]
        track.last_stamp, track.last_pose = scan.stamp, start
        track.rejections = 0
        track.anchor_dvl_fresh = self._dvl_fresh(scan.stamp)
        if track.matcher.start(scan.points, start, scan.stamp):
            track.anchor_stamp, track.anchor_pose = scan.stamp, start
            self.counts["map_starts"] += 1
        else:
            self.counts["rejected_sparse"] += 1

    def finish(self, view=None) -> FrontendSummary:
        c = self.counts
        rejected = {k.removeprefix("rejected_"): v for k, v in sorted(c.items()) if k.startswith("rejected_")}
        refused = sum(rejected.values())
        if refused > c["accepted"]:  # the run still ends well, with little odometry in it: say so
            log.warning(
                "semslam: warning: odometry front-end: %d of %d scans refused (%s), %d accepted: the odometry "
                "constrains little of this mission (the clouds' stamps against the navigation's, or the gate "
                "frontends.odometry.gate)",
                refused,
                c["scans"],
                ", ".join(f"{k} {v}" for k, v in rejected.items()),
                c["accepted"],
            )
        ratio = self.path.ratio
        if self.path.disagrees:  # each pair passed its gate, yet the odometry will pull the trajectory
            log.warning(
                "semslam: warning: odometry front-end: the accepted registrations travel %.0f %% of the horizontal "
                "path the DVL measured over the same %d scan pairs (%.1f m), more than a DVL's scale error: the "
                "odometry's factors will pull the trajectory along the track (registrations biased towards no "
                "motion, as over a featureless seabed, or a wrong extrinsic); with a working DVL, consider running "
                "without the odometry front-end (experiments/odometry/README.md, stop 51)",
                100 * ratio,
                self.path.pairs,
                self.path.path,
            )
        return FrontendSummary(
            section="odometry",
            metrics={
                "scans": c["scans"],
                "accepted": c["accepted"],
                "rejected": rejected,
                "map_starts": c["map_starts"],
                "without_prior": c["no_prior"],
                "path_ratio_to_dvl": ratio,
            },
        )
