"""Navigation measurement buffer of the graph back-end: the latest AHRS, depth and DVL readings,
brought to a keyframe's time, the AHRS readings since the last keyframe fused into one attitude,
and the DVL preintegrator running since the last keyframe."""

from __future__ import annotations

import bisect
from dataclasses import dataclass

import numpy as np

from factors.geometry import quat_to_rot, so3_exp, so3_log, so3_right_jacobian
from factors.navigation import DvlPreintegrator, ahrs_body_rotation, dvl_to_body
from semslam.mission.measurements import Attitude, Depth, DvlVelocity
from semslam.mission.mission import MissionMetadata

_I3 = np.eye(3)
_I3.flags.writeable = False  # per AHRS reading: made once


@dataclass
class AttitudeSample:
    t: float  # s
    R_WB: np.ndarray
    cov: np.ndarray  # right-tangent covariance of R_WB (3×3)
    omega_B: np.ndarray | None  # body angular rate (rad/s), when known
    from_gyro: bool = True  # omega_B is the AHRS's measured rate (False: attitudes differenced, or none)

    def rate(self, gyro_bias: np.ndarray | None = None) -> np.ndarray | None:
        """The body rate to carry with: the gyro's less its bias ``gyro_bias`` (body axes, rad/s); a rate
        differenced from attitudes is no gyro's and takes no bias."""
        if self.omega_B is None or gyro_bias is None or not self.from_gyro:
            return self.omega_B
        return self.omega_B - gyro_bias

    def carried_to(
        self, t: float, rate_sigma: float, gyro_bias: np.ndarray | None = None, max_age: float = np.inf
    ) -> tuple[np.ndarray, np.ndarray]:
        """R_WB at t, rotated on by the angular rate (less ``gyro_bias``) while the reading is younger than
        ``max_age``, held still after; the covariance grows with the age by the white rate noise integrated
        over it: rate_sigma²·|Δt| per axis, ``rate_sigma`` the gyro's density (rad/s/√Hz)."""
        dt = t - self.t
        w = self.rate(gyro_bias)
        held = float(min(max(dt, -max_age), max_age))  # np.clip's result, without its ~10 µs a call
        R = self.R_WB if w is None or held == 0 else self.R_WB @ so3_exp(w * held)
        return R, self.cov + _I3 * (rate_sigma**2 * abs(dt))


@dataclass
class FusedAttitude(AttitudeSample):
    """Every AHRS reading since the last keyframe in one attitude: a Kalman filter on SO(3) that
    carries its estimate from reading to reading with the measured rate (its covariance growing by
    the rate noise) and updates it with each reading. At 20 Hz and a keyframe a second, one factor
    then holds the information of ~20 readings (the heading σ of one reading, 0.5° in the tank,
    becomes ~0.15°) instead of the newest reading's alone, as the EKF uses them all."""

    n: int = 1  # readings fused

    def update(
        self, s: AttitudeSample, rate_sigma: float, gyro_bias: np.ndarray | None = None, max_age: float = np.inf
    ) -> None:
        R, P = self.carried_to(s.t, rate_sigma, gyro_bias, max_age)
        K = P @ np.linalg.inv(P + s.cov)
        self.R_WB = R @ so3_exp(K @ so3_log(R.T @ s.R_WB))
        self.cov = (_I3 - K) @ P
        self.cov = 0.5 * (self.cov + self.cov.T)
        self.t, self.omega_B, self.from_gyro, self.n = s.t, s.omega_B, s.from_gyro, self.n + 1


@dataclass
class DvlSample:
    t: float
    v_S: np.ndarray
    cov_S: np.ndarray
    T_BS: np.ndarray
    omega_B: np.ndarray
    v_B: np.ndarray
    cov_B: np.ndarray


@dataclass
class DepthSample:
    t: float
    depth: float
    variance: float
    t_BS: np.ndarray


class NavigationBuffer:
    """Keeps what the keyframes need from the navigation stream, in the body frame."""

    def __init__(
        self,
        metadata: MissionMetadata,
        accel_sigma: float,
        rate_sigma: float,
        rate_max_age: float = np.inf,
        dvl_by_gyro: bool = False,
    ):
        self.metadata = metadata
        self.accel_sigma = accel_sigma
        self.rate_sigma = rate_sigma  # the gyro's white-noise density (rad/s/√Hz)
        self.rate_max_age = rate_max_age  # an AHRS rate older than this (s) carries nothing: held still after
        # the DVL samples turned into the keyframe's frame by the gyro's rotation since it (:meth:`gyro_rotation`)
        # where the interval has one, not by two single AHRS readings
        self.dvl_by_gyro = dvl_by_gyro
        self.attitude: AttitudeSample | None = None
        self.fused: FusedAttitude | None = None  # the readings since the last keyframe
        self.dvl: DvlSample | None = None
        self.depth: DepthSample | None = None
        # the interval's depth readings (t, depth, variance, R_WB at t, the sensor's lever arm), and the world vertical velocity
        # of its DVL samples (t, v_z, variance; the previous interval's last one kept, to hold before the first)
        self.depths: list[tuple[float, float, float, np.ndarray, np.ndarray]] = []  # + t_BS
        self.vz: list[tuple[float, float, float]] = []
        self.preint: DvlPreintegrator | None = None
        # (interval start, integrated to, R_{k-1}ᵀ R, its Jacobian wrt the gyro bias: ΔR(b̄ + δ) ≈ ΔR Exp(J δ))
        self.gyro: tuple[float, float, np.ndarray, np.ndarray] | None = None
        self.gyro_measured = True  # every AHRS reading of the interval so far carried a measured rate
        self.gyro_bias = np.zeros(3)  # b̄: the gyro bias the interval's rates are integrated with (body axes)
        # :attr:`gyro` at the interval's start and at each reading since, with the reading then latest (its rate held
        # on from there): the gyro's rotation at a time before the newest reading (:meth:`gyro_rotation_at`)
        self.gyro_knots: list[tuple[tuple, AttitudeSample | None]] = []

    def _T_BS(self, sensor: str) -> np.ndarray:
        return self.metadata.extrinsic(sensor)

    def add(self, m) -> None:
        t = m.stamp * 1e-9
        if isinstance(m, Attitude):
            R_BS = self._T_BS(m.sensor)[:3, :3]
            R_WS = quat_to_rot(m.orientation)
            R_WB, cov = ahrs_body_rotation(R_WS, np.asarray(m.covariance), R_BS)
            omega = None if m.angular_rate is None else R_BS @ np.asarray(m.angular_rate)
            if self.gyro is not None and omega is not None:
                self.gyro = self._gyro_to(t)
            from_gyro = omega is not None
            if not from_gyro:
                self.gyro_measured = False  # this interval's rotation is no gyro's: no gyro link for it
            if omega is None and self.attitude is not None and t > self.attitude.t:
                # Finite difference of consecutive attitudes when the AHRS gives no rate.
                omega = so3_log(self.attitude.R_WB.T @ R_WB) / (t - self.attitude.t)
            self.attitude = AttitudeSample(t, R_WB, cov, omega, from_gyro)
            if self.gyro is not None and omega is not None and from_gyro:
                self.gyro_knots.append((self.gyro, self.attitude))
            if self.fused is None:
                self.fused = FusedAttitude(t, R_WB, cov, omega, from_gyro)
            else:
                self.fused.update(self.attitude, self.rate_sigma, self.gyro_bias, self.rate_max_age)
        elif isinstance(m, Depth):
            self.depth = DepthSample(t, m.depth, m.variance, self._T_BS(m.sensor)[:3, 3])
            if self.attitude is not None:
                self.depths.append((t, float(m.depth), float(m.variance), self.attitude_at(t)[0], self.depth.t_BS))
        elif isinstance(m, DvlVelocity):
            if not m.valid or not np.all(np.isfinite(m.velocity)):
                return
            T_BS = self._T_BS(m.sensor)
            omega = self.omega(t)
            v_B, cov_B = dvl_to_body(np.asarray(m.velocity), np.asarray(m.covariance), T_BS, omega)
            self.dvl = DvlSample(t, np.asarray(m.velocity), np.asarray(m.covariance), T_BS, omega, v_B, cov_B)
            if self.attitude is not None:
                R, _ = self.attitude_at(t)
                if not self.vz or t > self.vz[-1][0]:
                    self.vz.append((t, float(R[2] @ v_B), float(R[2] @ cov_B @ R[2])))
                if self.preint is not None:
                    self.preint.add(t, R, v_B, cov_B, self.dvl_turn(t))

    def omega(self, t: float) -> np.ndarray:
        """The body rate at t: the latest AHRS reading's less the gyro bias b̄ (:attr:`gyro_bias`); zero when
        there is none or it is older than :attr:`rate_max_age`."""
        a = self.attitude
        if a is None or a.omega_B is None or t - a.t > self.rate_max_age:
            return np.zeros(3)
        return a.rate(self.gyro_bias)

    def attitude_at(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """R_WB at t from the latest AHRS reading, rotated on by its rate less b̄ over its age (at most
        :attr:`rate_max_age`); the covariance grows with the age (rate noise)."""
        return self.attitude.carried_to(t, self.rate_sigma, self.gyro_bias, self.rate_max_age)

    def take_fused_attitude(self, t: float) -> tuple[np.ndarray, np.ndarray, int] | None:
        """The AHRS readings since the last call fused and carried to t: (R_WB, covariance, how
        many readings); the next call starts afresh, so that no reading is used twice."""
        if self.fused is None:
            return None
        R, cov = self.fused.carried_to(t, self.rate_sigma, self.gyro_bias, self.rate_max_age)
        n, self.fused = self.fused.n, None
        return R, cov, n

    def _gyro_to(self, t: float) -> tuple[float, float, np.ndarray, np.ndarray]:
        return self._gyro_from(self.gyro, self.attitude, t)

    def _gyro_from(
        self, gyro: tuple[float, float, np.ndarray, np.ndarray], a: AttitudeSample | None, t: float
    ) -> tuple[float, float, np.ndarray, np.ndarray]:
        """``gyro`` (integrated to t1) carried on to t by ``a``'s rate less b̄, held from t1."""
        t0, t1, dR, J = gyro
        # the latest rate held from t1 to t, as long as it is younger than rate_max_age (held still after)
        h = 0.0 if a is None or a.omega_B is None else max(min(t, a.t + self.rate_max_age) - t1, 0.0)
        if h == 0.0:
            return t0, max(t, t1), dR, J
        phi = a.rate(self.gyro_bias) * h
        step = so3_exp(phi)
        # ΔR Exp(J δ) Exp(φ − h δ) ≈ ΔR Exp(φ) Exp((Exp(φ)ᵀ J − J_r(φ) h) δ)
        return t0, t, dR @ step, step.T @ J - so3_right_jacobian(phi) * h

    def gyro_rotation(self, t: float) -> tuple[np.ndarray, float, np.ndarray] | None:
        """The body rates less the bias b̄ (:attr:`gyro_bias`) integrated since the interval's start to t:
        (R_{k-1}ᵀ R(t), the interval's length, ∂ΔR/∂b: ΔR(b̄ + δ) ≈ ΔR Exp(J δ)). None unless every rate over the
        interval was measured by the gyro: rates differenced from the AHRS's attitudes would count its readings
        twice (they already enter as attitude factors) and fit the gyro's bias to what is no gyro's."""
        a = self.attitude
        if self.gyro is None or a is None or a.omega_B is None or not (a.from_gyro and self.gyro_measured):
            return None
        t0, _, dR, J = self._gyro_to(t)
        return dR, t - t0, J

    def gyro_rotation_at(self, t: float) -> np.ndarray | None:
        """R_{k-1}ᵀ R(t) by the gyro (:meth:`gyro_rotation`'s ΔR) at any t since the interval's start, also before its
        newest reading: from the last reading at or before t, by that reading's rate. None where
        :meth:`gyro_rotation` is."""
        g = self.gyro_rotation(t)
        if g is None or t >= self.gyro[1]:
            return None if g is None else g[0]
        i = bisect.bisect_right(self.gyro_knots, t, key=lambda knot: knot[0][1]) - 1  # by the time integrated to
        if i < 0:
            return None
        gyro, a = self.gyro_knots[i]
        return self._gyro_from(gyro, a, t)[2]

    def dvl_turn(self, t: float) -> np.ndarray | None:
        """R_{k-1}ᵀ R(t) by the gyro (:meth:`gyro_rotation`) to turn the DVL's samples and the end keyframe's velocity
        into the interval's start frame with: its error is the rate noise integrated since the keyframe, where
        R_{k-1}ᵀ R(t) from two single AHRS readings has both readings' (the first common to every sample). None
        without :attr:`dvl_by_gyro` or without the gyro's rotation (the readings then)."""
        g = self.gyro_rotation(t) if self.dvl_by_gyro else None
        return None if g is None else g[0]

    def start_interval(self, t: float, R_WB: np.ndarray, attitude_sigma: float, gyro_bias=None) -> None:
        """The next interval from a keyframe at t; ``gyro_bias``: the keyframe's gyro-bias estimate, which
        the interval's rates are integrated with (None: 0)."""
        self.gyro = (t, t, np.eye(3), np.zeros((3, 3)))
        self.gyro_measured = True
        self.gyro_knots = [(self.gyro, self.attitude)]
        self.gyro_bias = np.zeros(3) if gyro_bias is None else np.asarray(gyro_bias, float)
        self.preint = DvlPreintegrator(t, R_WB, self.accel_sigma, attitude_sigma, self.rate_sigma)
        self.depths = [d for d in self.depths if d[0] > t]
        self.vz = self.vz[-1:]
