"""The navigation prior: the body motion between two stamps as the DVL, the AHRS and the depth
sensor predict it, integrated by the front-end itself (so it needs no estimator and may run ahead
of them in a process of its own).

Attitude is the AHRS's (its slowly drifting heading bias cancels over a few seconds); the position
integrates the DVL's body velocity rotated by it (the head's velocity less its lever arm's ω × t_BS, with the
AHRS's last angular rate; without rates the lever arm is ignored); depth readings replace the integrated depth. The
rotation between two stamps is the AHRS's angular rate integrated when its readings carry one: its
white noise integrates to σ_ω·√(dt·T) (0.04° over a 2 s scan interval at the simulator's 0.002 rad/s and
20 Hz), where the difference of two attitude readings carries both readings' errors (0.7° of heading).
During a DVL dropout the last valid body velocity is held: underwater vehicles keep their speed
through a short loss of bottom lock, and the registration's gate absorbs the rest.

It also keeps how uncertain that motion is (``motion_covariance``), from the covariances the DVL,
AHRS and depth messages carry: over [a, b] inside the hold of one velocity reading (taken at h),
the reading's error moves the position by σ_v·(b − a), and the velocity's random walk since h
(``hold_walk_m_s``: small between 5 Hz readings, large deep in a dropout) by
q²·((a − h)(b − a)² + (b − a)³/3) in variance; holds of different readings are independent.
"""

from __future__ import annotations

import bisect
from collections import deque

import numpy as np

from factors.geometry import quat_to_rot, so3_exp  # numpy only (scalars: the prior turns at every AHRS reading)
from semslam.mission.measurements import Attitude, Depth, DvlVelocity, Measurement
from semslam.mission.mission import MissionMetadata

NS = 1e-9


class NavigationPrior:
    """Dead reckoning in a local frame {D} (NED axes, arbitrary origin) kept over ``horizon_s``."""

    def __init__(
        self,
        metadata: MissionMetadata,
        horizon_s: float = 60.0,
        hold_walk_m_s: float = 0.02,
        gyro_sigma_rad_s: float | None = None,
    ):
        self.metadata = metadata
        self.hold_walk = hold_walk_m_s  # σ of the body velocity's random walk over 1 s held (m/s/√s)
        self.horizon_ns = int(horizon_s * 1e9)
        self._stamps: deque[int] = deque()
        self._poses: deque[np.ndarray] = deque()  # T_DB (4×4) at each stamp
        # (R_GB, ω_B) at each stamp: the angular rate integrated ({G} arbitrary) and the rate then held
        self._gyro: deque[tuple[np.ndarray, np.ndarray] | None] = deque()
        self._R_GB: np.ndarray | None = None
        self._w_B: np.ndarray | None = None  # the last angular rate (body frame), None without one
        self._gyro_var = None if gyro_sigma_rad_s is None else gyro_sigma_rad_s**2  # per reading (rad²/s²)
        self._rates: deque[np.ndarray] = deque(maxlen=3)  # the last readings' rates, for their noise
        self._rate_curvature = [0.0, 0]  # Σ‖ω_k+1 − 2ω_k + ω_k−1‖², count
        self._gyro_dt = 0.0  # the interval between attitude readings (s)
        self._R_WB: np.ndarray | None = None
        self._v_B = np.zeros(3)
        self._p = np.zeros(3)
        self._t: int | None = None
        self._t0: int | None = None  # the first measurement's stamp
        self._first_reading: int | None = None  # the first valid DVL reading's stamp (kept past the horizon)
        self._depth_offset: float | None = None  # depth sensor's z in {D} − its reading, set once
        self._holds: deque[tuple[int, float]] = deque()  # (stamp, per-axis variance m²/s²) of each valid reading
        self._var_att = np.zeros(3)  # the AHRS's roll, pitch, yaw variances (rad²)
        self._var_depth = 0.0  # the depth reading's variance (m²)
        self._attitude_stamp: int | None = None

    def add(self, m: Measurement) -> None:
        """Feed a navigation measurement (others are ignored); stamps must not go backwards."""
        if not isinstance(m, (Attitude, DvlVelocity, Depth)):
            return
        self._advance(m.stamp)
        T_BS = self.metadata.extrinsic(m.sensor)
        if isinstance(m, Attitude):
            R_WS = quat_to_rot(m.orientation)
            self._R_WB = R_WS @ T_BS[:3, :3].T
            self._var_att = np.clip(np.diag(np.asarray(m.covariance, float)), 0.0, None)
            self._rate(m, T_BS)
        elif isinstance(m, DvlVelocity):
            if m.valid and np.isfinite(m.velocity).all():
                # the head moves with v_B + ω × t_BS: aft of the origin it swings sideways in every turn
                # (0.25 m × 0.1 rad/s is 2.5 cm/s), so the last angular rate's part is taken out
                self._v_B = T_BS[:3, :3] @ np.asarray(m.velocity, float)
                if self._w_B is not None:
                    self._v_B = self._v_B - np.cross(self._w_B, T_BS[:3, 3])
                var_v = float(np.trace(np.asarray(m.covariance, float))) / 3
                self._holds.append((m.stamp, var_v if np.isfinite(var_v) and var_v > 0 else 0.0))
                self._first_reading = m.stamp if self._first_reading is None else self._first_reading
        elif self._R_WB is not None:  # depth: the sensor's z in {D} is its reading plus a fixed offset
            self._var_depth = m.variance if np.isfinite(m.variance) and m.variance > 0 else 0.0
            z_sensor = self._p[2] + (self._R_WB @ T_BS[:3, 3])[2]
            if self._depth_offset is None:
                self._depth_offset = z_sensor - m.depth
            self._p[2] += m.depth + self._depth_offset - z_sensor
        self._store()

    def _advance(self, stamp: int) -> None:
        if self._t is not None and self._R_WB is not None and stamp > self._t:
            self._p = self._p + self._R_WB @ self._v_B * ((stamp - self._t) * NS)
            if self._R_GB is not None and self._w_B is not None:
                self._R_GB = self._R_GB @ so3_exp(self._w_B * ((stamp - self._t) * NS))
        self._t = stamp if self._t is None else max(self._t, stamp)
        self._t0 = stamp if self._t0 is None else self._t0

    def _rate(self, m: Attitude, T_BS: np.ndarray) -> None:
        """Takes the reading's angular rate (held until the next reading); without one the gyro
        rotation stops (and ``motion`` falls back to the attitude readings)."""
        if m.angular_rate is None or not np.isfinite(m.angular_rate).all():
            self._R_GB = self._w_B = None
            return
        w_B = T_BS[:3, :3] @ np.asarray(m.angular_rate, float)
        if self._R_GB is None or self._w_B is None:
            self._R_GB = self._R_WB.copy()
        elif self._attitude_stamp is not None:
            # the last interval was integrated at the previous reading's rate: make it the trapezoid's
            # (at a 1.7° wobble the held rate alone is off by ~0.07° over a 2 s scan interval)
            self._gyro_dt = (m.stamp - self._attitude_stamp) * NS
            self._R_GB = self._R_GB @ so3_exp((w_B - self._w_B) * self._gyro_dt / 2)
        self._attitude_stamp = m.stamp
        self._w_B = w_B
        self._rates.append(w_B)
        if len(self._rates) == 3:
            self._rate_curvature[0] += float(np.sum((self._rates[2] - 2 * self._rates[1] + self._rates[0]) ** 2))
            self._rate_curvature[1] += 1

    def gyro_variance(self) -> float:
        """Per-axis variance of one rate reading (rad²/s²): the configured one, or estimated from the
        readings' second differences (6σ² for white noise; a vehicle's rate curves far less over 0.1 s)
        once there are 20 of them (until then a conservative 0.01 rad/s)."""
        if self._gyro_var is not None:
            return self._gyro_var
        total, n = self._rate_curvature
        return total / (18 * n) if n >= 20 else 1e-4

    def _displacement_variance(self, a: int, b: int) -> float:
        """Variance (m² per axis) of the DVL-integrated displacement over [a, b]: per held reading,
        its own error over the part of [a, b] it covers and the velocity's random walk since it was
        read. Before the first reading the velocity is the start's zero, walking since the first measurement
        (a vehicle descending without bottom lock moves: its displacement is not known to a millimetre)."""
        q2, total = self.hold_walk**2, 0.0
        first = b if self._first_reading is None else self._first_reading
        if self._t0 is not None and min(b, first) > max(a, self._t0):
            lo, hi = max(a, self._t0), min(b, first)
            age, span = (lo - self._t0) * NS, (hi - lo) * NS
            total += q2 * (age * span**2 + span**3 / 3)
        starts = [h for h, _ in self._holds]
        k = max(bisect.bisect_right(starts, a) - 1, 0)
        for i in range(k, len(self._holds)):
            h, var_v = self._holds[i]
            end = self._holds[i + 1][0] if i + 1 < len(self._holds) else b
            lo, hi = max(a, h), min(b, end)
            if hi <= lo:
                if h >= b:
                    break
                continue
            age, span = (lo - h) * NS, (hi - lo) * NS
            total += var_v * span**2 + q2 * (age * span**2 + span**3 / 3)
        return total

    def _store(self) -> None:
        if self._R_WB is None or self._t is None:
            return
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = self._R_WB, self._p
        self._stamps.append(self._t)
        self._poses.append(T)
        self._gyro.append(None if self._R_GB is None else (self._R_GB.copy(), self._w_B.copy()))
        while self._stamps and self._stamps[0] < self._t - self.horizon_ns:
            self._stamps.popleft()
            self._poses.popleft()
            self._gyro.popleft()
        while len(self._holds) > 1 and self._holds[1][0] < self._t - self.horizon_ns:
            self._holds.popleft()  # the reading held at the horizon stays

    def dvl_age_s(self, stamp: int) -> float | None:
        """Seconds from the last valid DVL reading to ``stamp`` (None before any): how long its velocity has been held."""
        return (stamp - self._holds[-1][0]) * NS if self._holds else None

    def pose_at(self, stamp: int) -> np.ndarray | None:
        """T_DB at ``stamp``: the last stored pose before it, carried on at the current velocity;
        None before the first attitude or when ``stamp`` is older than the horizon."""
        if not self._stamps or stamp < self._stamps[0]:
            return None
        i = bisect.bisect_right(self._stamps, stamp) - 1
        T = self._poses[i].copy()
        T[:3, 3] += T[:3, :3] @ self._v_B * ((stamp - self._stamps[i]) * NS)
        return T

    def _gyro_at(self, stamp: int) -> np.ndarray | None:
        """R_GB at ``stamp`` (the rate carried on since the last reading), None without angular rates."""
        i = bisect.bisect_right(self._stamps, stamp) - 1
        if i < 0 or self._gyro[i] is None:
            return None
        R, w = self._gyro[i]
        return R @ so3_exp(w * ((stamp - self._stamps[i]) * NS))

    def motion(self, stamp_from: int, stamp_to: int) -> np.ndarray | None:
        """T_B(from),B(to) predicted by the navigation sensors, or None if either end is unknown; its
        rotation is the integrated angular rate where the readings carry one."""
        a, b = self.pose_at(stamp_from), self.pose_at(stamp_to)
        if a is None or b is None:
            return None
        T = np.linalg.inv(a) @ b
        ga, gb = self._gyro_at(stamp_from), self._gyro_at(stamp_to)
        if ga is not None and gb is not None:
            T[:3, :3] = ga.T @ gb
        return T

    def _rotation_variance(self, stamp_from: int, stamp_to: int) -> np.ndarray:
        """Per-axis variance (rad²) of :meth:`motion`'s rotation: the integrated rate's white noise
        σ²·dt·T, or two attitude readings' errors without rates."""
        if self._gyro_at(stamp_from) is not None and self._gyro_at(stamp_to) is not None:
            span = abs(stamp_to - stamp_from) * NS
            return np.full(3, self.gyro_variance() * max(self._gyro_dt, 1e-3) * span)
        return 2 * self._var_att

    def motion_covariance(self, stamp_from: int, stamp_to: int) -> np.ndarray | None:
        """6×6 covariance (rotation, translation; body frame) of :meth:`motion` between the stamps:
        two AHRS readings' attitude errors, the DVL's integrated velocity errors, the relative
        translation turned by the heading error of the first reading, and two depth readings' errors
        along the vertical (depth readings replace the integrated depth)."""
        motion = self.motion(stamp_from, stamp_to)
        if motion is None:
            return None
        i = bisect.bisect_right(self._stamps, stamp_from) - 1
        turned = self._var_att.max() * motion[:3, 3] @ motion[:3, 3]
        var_t = self._displacement_variance(stamp_from, stamp_to) + turned
        cov = np.diag(np.r_[self._rotation_variance(stamp_from, stamp_to), [var_t] * 3])
        down_B = self._poses[i][2, :3]  # {D}'s z axis in the body frame at stamp_from
        cov[3:, 3:] += 2 * self._var_depth * np.outer(down_B, down_B)
        return cov
