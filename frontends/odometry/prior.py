"""The navigation prior: the body motion between two stamps as the DVL, the AHRS and the depth
sensor predict it, integrated by the front-end itself (so it needs no estimator and may run ahead
of them in a process of its own).

Attitude is the AHRS's (its slowly drifting heading bias cancels over a few seconds); the position
integrates the DVL's body velocity rotated by it; depth readings replace the integrated depth.
During a DVL dropout the last valid body velocity is held: underwater vehicles keep their speed
through a short loss of bottom lock, and the registration's gate absorbs the rest.
"""

from __future__ import annotations

import bisect
from collections import deque

import numpy as np
from scipy.spatial.transform import Rotation

from semslam.mission.measurements import Attitude, Depth, DvlVelocity, Measurement
from semslam.mission.mission import MissionMetadata

NS = 1e-9


class NavigationPrior:
    """Dead reckoning in a local frame {D} (NED axes, arbitrary origin) kept over ``horizon_s``."""

    def __init__(self, metadata: MissionMetadata, horizon_s: float = 60.0):
        self.metadata = metadata
        self.horizon_ns = int(horizon_s * 1e9)
        self._stamps: deque[int] = deque()
        self._poses: deque[np.ndarray] = deque()  # T_DB (4×4) at each stamp
        self._R_WB: np.ndarray | None = None
        self._v_B = np.zeros(3)
        self._p = np.zeros(3)
        self._t: int | None = None
        self._depth_offset: float | None = None  # depth sensor's z in {D} − its reading, set once

    def add(self, m: Measurement) -> None:
        """Feed a navigation measurement (others are ignored); stamps must not go backwards."""
        if not isinstance(m, (Attitude, DvlVelocity, Depth)):
            return
        self._advance(m.stamp)
        T_BS = self.metadata.extrinsic(m.sensor)
        if isinstance(m, Attitude):
            R_WS = Rotation.from_quat(np.asarray(m.orientation, float)).as_matrix()
            self._R_WB = R_WS @ T_BS[:3, :3].T
        elif isinstance(m, DvlVelocity):
            if m.valid and np.isfinite(m.velocity).all():
                self._v_B = T_BS[:3, :3] @ np.asarray(m.velocity, float)  # the lever arm's ω×r is mm/s here
        elif self._R_WB is not None:  # depth: the sensor's z in {D} is its reading plus a fixed offset
            z_sensor = self._p[2] + (self._R_WB @ T_BS[:3, 3])[2]
            if self._depth_offset is None:
                self._depth_offset = z_sensor - m.depth
            self._p[2] += m.depth + self._depth_offset - z_sensor
        self._store()

    def _advance(self, stamp: int) -> None:
        if self._t is not None and self._R_WB is not None and stamp > self._t:
            self._p = self._p + self._R_WB @ self._v_B * ((stamp - self._t) * NS)
        self._t = stamp if self._t is None else max(self._t, stamp)

    def _store(self) -> None:
        if self._R_WB is None or self._t is None:
            return
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = self._R_WB, self._p
        self._stamps.append(self._t)
        self._poses.append(T)
        while self._stamps and self._stamps[0] < self._t - self.horizon_ns:
            self._stamps.popleft()
            self._poses.popleft()

    def pose_at(self, stamp: int) -> np.ndarray | None:
        """T_DB at ``stamp``: the last stored pose before it, carried on at the current velocity;
        None before the first attitude or when ``stamp`` is older than the horizon."""
        if not self._stamps or stamp < self._stamps[0]:
            return None
        i = bisect.bisect_right(self._stamps, stamp) - 1
        T = self._poses[i].copy()
        T[:3, 3] += T[:3, :3] @ self._v_B * ((stamp - self._stamps[i]) * NS)
        return T

    def motion(self, stamp_from: int, stamp_to: int) -> np.ndarray | None:
        """T_B(from),B(to) predicted by the navigation sensors, or None if either end is unknown."""
        a, b = self.pose_at(stamp_from), self.pose_at(stamp_to)
        if a is None or b is None:
            return None
        return np.linalg.inv(a) @ b
