"""Keyframes of the graph back-end and the navigation factors at and between them.

Per keyframe k: X(k) = T_WB (Pose3), V(k) = body velocity and, when the AHRS heading bias is
modelled, B(k) and, with its drift rate modelled, D(k), and when the gyro's bias is modelled, G(k) (see
factors.navigation). Between consecutive keyframes: the preintegrated DVL/AHRS
displacement (with the velocity motion model across dropouts), over intervals with no DVL at
all, the velocity random walk, and the body rates integrated between the two attitudes (with G(k−1) to
first order, and G's random walk, when the gyro's bias is modelled). At each keyframe: the AHRS attitude, the latest DVL velocity and the
depth: every reading of the interval, each at the nearer of its two keyframes, brought there through
the DVL's vertical velocity and averaged (the newest reading alone when the interval has none).

The newest keyframe's factors are deferred (:meth:`IsamSession.defer`) until the next update that
goes to iSAM2 (a scan's landmark factors, the next keyframe, a GPS fix, a window slide, the end), so
that a scan's keyframe goes into iSAM2 in one update with the scan's landmark factors: its estimate and covariance
meanwhile are predicted locally (:meth:`Keyframes._predict`), one Gauss–Newton step of its factors
with the previous keyframe's joint marginal as a prior — what iSAM2's update of those factors alone
gives, up to the linearisation point, without re-eliminating the root clique (which on the tank
holds every landmark) at every keyframe.
"""

from __future__ import annotations

import bisect

import gtsam
import numpy as np
from scipy.spatial.transform import Rotation

from factors.heading_bias import RATE_UNIT_S
from factors.navigation import (
    GYRO_BIAS_UNIT_S,
    attitude_factor,
    biased_attitude_factor,
    depth_factor,
    displacement_factor,
    dvl_velocity_factor,
    gyro_rotation_factor,
    heading_bias_drift_factor,
    heading_bias_walk_factor,
    referred_depth,
    rotation_carry_factor,
    smoothed_displacement_factor,
    velocity_random_walk_factor,
)
from semslam.backend.navigation import NavigationBuffer
from semslam.backend.session import IsamSession, Owned
from semslam.backend.window import B, D, G, SlidingWindow, V, X
from semslam.config import SemslamConfig
from semslam.estimation import SpillLog
from semslam.mission.measurements import GroundTruthPose, Measurement
from semslam.mission.mission import MissionMetadata

ONLINE_ROW = np.dtype([("stamp", "i8"), ("R", "f8", (3, 3)), ("t", "f8", 3), ("position_cov", "f8", (3, 3))])


class OnlinePoses:
    """Each keyframe's pose as the online smoother gave it at its time (stamp, rotation, translation,
    position covariance in {W}), one :data:`ONLINE_ROW` a keyframe, on disk past a chunk
    (:class:`~semslam.estimation.SpillLog`); the newest stays in memory until the next, as it is
    renewed after its landmarks. :meth:`array` reads them back once, at the end."""

    __slots__ = ("_rows", "_newest")

    def __init__(self):
        self._rows = SpillLog(ONLINE_ROW)
        self._newest: tuple | None = None

    def __len__(self) -> int:
        return len(self._rows) + (self._newest is not None)

    def append(self, stamp: int, pose: gtsam.Pose3, position_cov: np.ndarray) -> None:
        if self._newest is not None:
            self._rows.append(*self._newest)
        self._newest = (stamp, pose.rotation().matrix(), pose.translation(), position_cov)

    def renew(self, pose: gtsam.Pose3, position_cov: np.ndarray) -> None:
        """The newest keyframe's pose and covariance, again."""
        self._newest = (self._newest[0], pose.rotation().matrix(), pose.translation(), position_cov)

    def array(self) -> np.ndarray:
        """Every keyframe's row, in order."""
        rows = self._rows.array()
        if self._newest is None:
            return rows
        return np.concatenate([rows, np.array([self._newest], ONLINE_ROW)])


class Keyframes:
    """The keyframes: their stamps, the newest one's estimate (pose, velocity, pose covariance, heading
    bias), each keyframe's pose as the online smoother gave it at its time, and the navigation
    buffer between keyframes."""

    def __init__(self, metadata: MissionMetadata, config: SemslamConfig, session: IsamSession, window: SlidingWindow):
        self.cfg = config.graph
        self.initial = config.initial
        self.accel_sigma = config.motion.accel_sigma_m_s2
        self.session = session
        self.window = window
        # an AHRS reading older than ahrs_max_age_s is not used, its rate neither (as the EKF's rate_max_age_s)
        self.nav = NavigationBuffer(
            metadata,
            config.motion.accel_sigma_m_s2,
            config.motion.angular_rate_density(metadata),
            config.graph.ahrs_max_age_s,
            dvl_by_gyro=config.motion.gyro_link,
        )
        self.wait_for_gt = self.initial.pose == "first_ground_truth" and bool(metadata.sensors_of_kind("ground_truth"))
        self.initial_gt: GroundTruthPose | None = None
        self.stamps: list[int] = []
        self.pose: gtsam.Pose3 | None = None  # the newest keyframe's estimate
        self.vel: np.ndarray | None = None
        self.pose_cov: np.ndarray | None = None
        # joint marginal covariance of the newest keyframe's (pose, velocity[, bias]), for the prediction
        self.state_cov: np.ndarray | None = None
        # AHRS heading bias as a random walk (0: not modelled, the AHRS heading taken as unbiased).
        self.bias_walk = config.sensors.heading_bias_walk(metadata)
        self.bias_sigma0 = config.sensors.heading_bias_sigma0(metadata)
        self.bias = 0.0  # the newest keyframe's bias estimate (rad)
        # the bias's drift rate D(k) (in rad per RATE_UNIT_S s) beside it, when modelled: a learned drift
        # carries the bias on where nothing observes it (0: the bias a random walk alone)
        self.rate_sigma0 = config.sensors.heading_bias_rate_sigma(metadata) * RATE_UNIT_S
        self.rate_walk = config.sensors.heading_bias_rate_walk(metadata)
        self.has_rate = self.bias_walk > 0 and self.rate_sigma0 > 0
        self.rate = 0.0  # the newest keyframe's rate estimate (rad per RATE_UNIT_S s)
        # the gyro's bias G(k) (in rad per GYRO_BIAS_UNIT_S s, body axes), a random walk, when modelled (0: the
        # rates taken as unbiased)
        self.gyro_link = config.motion.gyro_link  # off: no rotation link between keyframes with AHRS readings
        self.gyro_sigma0 = config.sensors.gyro_bias_sigma(metadata) * GYRO_BIAS_UNIT_S if self.gyro_link else 0.0
        self.gyro_walk = config.sensors.gyro_bias_walk(metadata) * GYRO_BIAS_UNIT_S
        self.has_gyro_bias = self.gyro_sigma0 > 0
        self.gyro_bias = np.zeros(3)  # the newest keyframe's gyro-bias estimate (G's units)
        self.online = OnlinePoses()  # each keyframe's online pose and position covariance in {W}
        # relative-pose factors' m-estimator, by measuring sensor (the config names sensor kinds)
        self.odometry_kernels = {
            s.name: gtsam.noiseModel.mEstimator.Cauchy.Create(config.graph.odometry_cauchy_k[s.kind])
            for s in metadata.sensors.values()
            if s.kind in config.graph.odometry_cauchy_k
        }

    def __len__(self) -> int:
        return len(self.stamps)

    @property
    def newest(self) -> int:
        return len(self.stamps) - 1

    def anchor(self) -> tuple[int, int]:
        """The newest keyframe's pose and velocity keys (a failed update re-anchors on them)."""
        return X(self.newest), V(self.newest)

    def add(self, measurement: Measurement) -> str | None:
        """Take a navigation or ground-truth measurement; returns "first" when the first keyframe is
        due, "next" when a keyframe is due (``keyframe_max_interval_s``), else None."""
        if isinstance(measurement, GroundTruthPose):
            if self.initial_gt is None:
                self.initial_gt = measurement
            return None
        self.nav.add(measurement)
        if self.nav.attitude is None:
            return None
        if not self.stamps:
            return "first" if not self.wait_for_gt or self.initial_gt is not None else None
        if (measurement.stamp - self.stamps[-1]) * 1e-9 >= self.cfg.keyframe_max_interval_s:
            return "next"
        return None

    def _nav_factors_at(self, k: int, t: float) -> tuple[list, np.ndarray, np.ndarray | None, bool]:
        """AHRS, depth and DVL factors of keyframe k at time t; returns (factors, R_WB, v_B prior mean,
        whether an AHRS factor is among them)."""
        factors = []
        R, _ = self.nav.attitude_at(t)
        fused = self.nav.take_fused_attitude(t)
        has_attitude = fused is not None and t - self.nav.attitude.t <= self.cfg.ahrs_max_age_s
        if has_attitude:
            R_f, cov_f, _ = fused
            factors.append(
                biased_attitude_factor(X(k), B(k), R_f, cov_f)
                if self.bias_walk > 0
                else attitude_factor(X(k), R_f, cov_f)
            )
        v_prior = None
        dvl = self.nav.dvl
        # The newest DVL sample is the velocity factor when it is fresh, and also when it is the last
        # knot of the interval that ends here (a dropout starting inside it): the displacement alone
        # cannot pin V(k), and the σ_a²·age inflation is the motion model's growth over the gap.
        in_interval = bool(self.stamps) and dvl is not None and dvl.t > self.stamps[-1] * 1e-9
        if dvl is not None and 0 <= t - dvl.t and (t - dvl.t <= self.cfg.dvl_max_age_s or in_interval):
            age = t - dvl.t
            factors.append(
                dvl_velocity_factor(V(k), dvl.v_S, dvl.cov_S, dvl.T_BS, dvl.omega_B, self.accel_sigma**2 * age)
            )
            v_prior = dvl.v_B
        readings = [r for r in self.nav.depths if r[0] <= t]
        dep = self.nav.depth
        if not readings and not self.stamps and dep is not None and 0 <= t - dep.t <= self.cfg.depth_max_age_s:
            # keyframe 0 with no reading since the AHRS's first: the newest one, at the keyframe's attitude
            readings = [(dep.t, dep.depth, dep.variance, R, dep.t_BS)]
        if readings:
            factors += self._interval_depth_factors(k, t, R, readings)
        return factors, R, v_prior, has_attitude

    def _interval_depth_factors(self, k: int, t: float, R: np.ndarray, readings: list) -> list:
        """Every depth reading of the interval (t_{k-1}, t] (keyframe 0: those before it): each to the
        nearer of X(k-1) and X(k), brought to its time through the DVL's vertical velocity and averaged
        there (:func:`~factors.navigation.referred_depth`), one factor per keyframe and pressure sensor.
        An interval without a reading adds none: the reading before it is already an earlier keyframe's."""
        t_prev = self.stamps[-1] * 1e-9 if self.stamps else -np.inf
        ends = ((k - 1, t_prev, self.nav.preint.R_i_T.T) if self.stamps else None, (k, t, R))
        groups: dict[tuple, list] = {}
        for r in readings:
            end = 0 if r[0] - t_prev < t - r[0] else 1
            groups.setdefault((end, tuple(r[4])), []).append(r)
        out = []
        for (end, t_BS), group in sorted(groups.items()):
            key, t_key, R_key = ends[end]
            t_BS = np.array(t_BS)
            z, var = referred_depth(group, t_key, R_key, t_BS, self.nav.vz, self.accel_sigma)
            out.append(depth_factor(X(key), z, var, t_BS))
        return out

    def first(self, stamp: int) -> None:
        """Keyframe 0: its navigation factors and the priors of the start state."""
        t = stamp * 1e-9
        factors, R, v_prior, _ = self._nav_factors_at(0, t)
        if self.initial_gt is not None and self.initial.pose == "first_ground_truth":
            pos = np.asarray(self.initial_gt.position, float)
            R0 = Rotation.from_quat(self.initial_gt.orientation).as_matrix()
        else:
            pos, R0 = np.zeros(3), self.unbiased(R)
        pose0 = gtsam.Pose3(gtsam.Rot3(R0), pos)
        sig = np.r_[[self.initial.attitude_sigma_rad] * 3, [self.initial.position_sigma_m] * 3]
        factors.append(gtsam.PriorFactorPose3(X(0), pose0, gtsam.noiseModel.Diagonal.Sigmas(sig)))
        v0 = v_prior if v_prior is not None else np.zeros(3)
        factors.append(
            gtsam.PriorFactorVector(V(0), v0, gtsam.noiseModel.Isotropic.Sigma(3, self.initial.velocity_sigma_m_s))
        )
        values = gtsam.Values()
        values.insert(X(0), pose0)
        values.insert(V(0), v0)
        # the sensor biases start at zero, each with its prior σ (when modelled)
        for modelled, key, dim, sigma in (
            (self.bias_walk > 0, B(0), 1, self.bias_sigma0),
            (self.has_rate, D(0), 1, self.rate_sigma0),
            (self.has_gyro_bias, G(0), 3, self.gyro_sigma0),
        ):
            if modelled:
                factors.append(
                    gtsam.PriorFactorVector(key, np.zeros(dim), gtsam.noiseModel.Isotropic.Sigma(dim, sigma))
                )
                values.insert(key, np.zeros(dim))
        self._commit(stamp, [(f, None) for f in factors], values)

    def next(self, stamp: int) -> int:
        """Keyframe k at ``stamp`` with its navigation factors; returns k."""
        # One keyframe waits at most: the one before is committed first, so that the prediction
        # starts from iSAM2's estimate and joint marginal. A chain of predictions, each linearised
        # once, drifts from the smoother where the position is loosely held (centimetres after a
        # 10 s DVL dropout, where iSAM2's one step over the chain stays with the sequential result).
        self.flush()
        k = len(self.stamps)
        t = stamp * 1e-9
        factors, R, v_prior, has_attitude = self._nav_factors_at(k, t)
        # A DVL sample used as V(k)'s prior is removed from the displacement's knots (no double use).
        if v_prior is not None and self.nav.preint.last_stamp == self.nav.dvl.t:
            self.nav.preint.drop_last()
        v_init = v_prior if v_prior is not None else self.vel
        if self.nav.preint.n_samples:  # the displacement and both velocity states jointly, every DVL
            # sample inside informing all three, with the velocity random walk between them
            s = self.nav.preint.smoothed(t, R, self.nav.dvl_turn(t))
            factors.append(smoothed_displacement_factor(X(k - 1), X(k), V(k - 1), V(k), s))
            dt, delta = s.dt, s.z0[:3]  # the displacement in {B(k-1)}: the interval's own mean
        else:  # no sample: the displacement of the two velocity states, linked by the process model
            d = self.nav.preint.integrate(t, R, self.nav.dvl_turn(t))
            factors.append(displacement_factor(X(k - 1), X(k), V(k - 1), V(k), d))
            factors.append(velocity_random_walk_factor(V(k - 1), V(k), d.dt, self.accel_sigma))
            dt, delta = d.dt, d.c + d.A @ self.vel + d.B @ v_init
        gyro = self.nav.gyro_rotation(t) if self.gyro_link else None
        # The rate's white noise integrated over the interval: σ density·√Δt, whether the rates were integrated
        # reading by reading or the last one held (no reading since X(k-1), keyframes 10–50 ms apart).
        rot_sigma = self.nav.rate_sigma * np.sqrt(max(t - self.stamps[-1] * 1e-9, 0.0))
        if gyro is not None:
            # The body rates integrated over the interval link the two attitudes, as the EKF's prediction does
            # between its AHRS updates: without it every keyframe's attitude stood on its own readings alone.
            factors.append(self._gyro_link(k, gyro, delta, rot_sigma))
        elif not has_attitude:
            # No AHRS reading since X(k-1) or a stale one, and no gyro's rate to integrate: nothing else fixes
            # X(k)'s rotation unless a landmark does, and iSAM2 fails on the indeterminate system.
            R_prev, _ = self.nav.attitude_at(self.stamps[-1] * 1e-9)
            factors.append(rotation_carry_factor(X(k - 1), X(k), R_prev.T @ R, delta, rot_sigma))
        p_init = self.pose.translation() + self.pose.rotation().matrix() @ delta
        values = gtsam.Values()
        values.insert(X(k), gtsam.Pose3(gtsam.Rot3(self.unbiased(R)), p_init))
        values.insert(V(k), np.asarray(v_init, float))
        if self.has_rate:
            factors.append(
                heading_bias_drift_factor(B(k - 1), D(k - 1), B(k), D(k), dt, self.bias_walk, self.rate_walk)
            )
            values.insert(B(k), np.array([self.bias + self.rate * dt / RATE_UNIT_S]))
            values.insert(D(k), np.array([self.rate]))
        elif self.bias_walk > 0:
            factors.append(heading_bias_walk_factor(B(k - 1), B(k), dt, self.bias_walk))
            values.insert(B(k), np.array([self.bias]))
        if self.has_gyro_bias:
            sigma = self.gyro_walk * np.sqrt(max(dt, 1e-6))
            factors.append(
                gtsam.BetweenFactorVector(G(k - 1), G(k), np.zeros(3), gtsam.noiseModel.Isotropic.Sigma(3, sigma))
            )
            values.insert(G(k), np.array(self.gyro_bias))
        if self.state_cov is None:  # no joint marginal to predict from
            self._commit(stamp, [(f, None) for f in factors], values)
            return k
        self._predict(k, factors, values)
        self.stamps.append(stamp)
        # iSAM2 starts the new variables where it would have (not at the prediction): it linearises
        # there, as it did with each keyframe its own update
        self.session.defer([(f, None) for f in factors], values, self.anchor())
        self._started(stamp)
        return k

    def _gyro_link(self, k: int, gyro: tuple, delta: np.ndarray, rot_sigma: float) -> gtsam.NonlinearFactor:
        """X(k−1) to X(k) by the rates integrated over the interval (``gyro``: ΔR, its length, ∂ΔR/∂b); with
        the gyro's bias modelled, through G(k−1), the rates integrated at its estimate then b̄ and corrected
        to first order."""
        R_ij, _, J_b = gyro
        if not self.has_gyro_bias:
            return rotation_carry_factor(X(k - 1), X(k), R_ij, delta, rot_sigma)
        b_bar = self.nav.gyro_bias * GYRO_BIAS_UNIT_S  # what the rates were integrated with (G's estimate then)
        return gyro_rotation_factor(X(k - 1), X(k), G(k - 1), R_ij, J_b, b_bar, rot_sigma)

    def _keys(self, k: int) -> list[int]:
        keys = [X(k), V(k)]
        if self.bias_walk > 0:
            keys.append(B(k))
        if self.has_rate:
            keys.append(D(k))
        if self.has_gyro_bias:
            keys.append(G(k))
        return keys

    def _predict(self, k: int, factors: list, values: gtsam.Values) -> None:
        """Keyframe k's estimate and joint covariance from its factors and keyframe k−1's estimate
        and joint marginal (a Gaussian prior): one Gauss–Newton step from ``values`` (the step iSAM2
        takes on new variables). Keyframe k−1's factors are linearised where iSAM2 linearises them,
        at its linearisation point θ, and the prior holds its estimate as the offset from θ (iSAM2's
        δ), so the step is iSAM2's own unless that update relinearises (at the estimate instead, a stiff
        factor on X(k−1) such as the averaged depth made it measurably off: experiments/estimators/README.md,
        stop 41)."""
        prev, new = self._keys(k - 1), self._keys(k)
        theta = self.session.theta
        at = gtsam.Values(values)
        at.insert(X(k - 1), theta.atPose3(X(k - 1)))
        at.insert(V(k - 1), theta.atVector(V(k - 1)))
        offset = [at.atPose3(X(k - 1)).localCoordinates(self.pose), np.asarray(self.vel) - at.atVector(V(k - 1))]
        if self.bias_walk > 0:
            at.insert(B(k - 1), theta.atVector(B(k - 1)))
            offset.append([self.bias - at.atVector(B(k - 1))[0]])
        if self.has_rate:
            at.insert(D(k - 1), theta.atVector(D(k - 1)))
            offset.append([self.rate - at.atVector(D(k - 1))[0]])
        if self.has_gyro_bias:
            at.insert(G(k - 1), theta.atVector(G(k - 1)))
            offset.append(self.gyro_bias - at.atVector(G(k - 1)))
        graph = gtsam.NonlinearFactorGraph()
        for f in factors:
            graph.add(f)
        ordering = gtsam.Ordering()
        for key in [*prev, *new]:
            ordering.push_back(key)
        H, eta = graph.linearize(at).hessian(ordering)
        n = len(self.state_cov)
        info = np.linalg.inv(self.state_cov)
        H[:n, :n] += info
        eta = np.ravel(eta).copy()
        eta[:n] += info @ np.concatenate(offset)
        cov = np.linalg.inv(H)
        step = cov @ eta
        cov = 0.5 * (cov[n:, n:] + cov[n:, n:].T)
        dx = step[n:]
        self.pose = values.atPose3(X(k)).retract(dx[:6])
        self.vel = values.atVector(V(k)) + dx[6:9]
        if self.bias_walk > 0:
            self.bias = float(values.atVector(B(k))[0] + dx[9])
        if self.has_rate:
            self.rate = float(values.atVector(D(k))[0] + dx[10])
        if self.has_gyro_bias:
            self.gyro_bias = values.atVector(G(k)) + dx[-3:]
        self.state_cov = cov
        self.pose_cov = cov[:6, :6]

    def flush(self) -> None:
        """The deferred keyframes into iSAM2 now (what needs iSAM2 itself: an older keyframe's
        marginal, a window slide, the result), and the newest keyframe's estimate from it."""
        if self.session.flush(self.stamps[-1] if self.stamps else 0):
            self.refresh()

    def _commit(self, stamp: int, factors: list[Owned], values: gtsam.Values) -> None:
        self.stamps.append(stamp)
        self.session.commit(factors, values, self.anchor(), stamp=stamp)
        self.refresh()
        self._started(stamp)

    def _started(self, stamp: int) -> None:
        """The navigation interval from the new keyframe at ``stamp``, and its online pose."""
        t = stamp * 1e-9
        R, _ = self.nav.attitude_at(t)
        att_sigma = float(np.sqrt(np.trace(self.nav.attitude.cov) / 3))
        self.nav.start_interval(t, R, att_sigma, self.gyro_bias / GYRO_BIAS_UNIT_S)
        self.online.append(stamp, self.pose, self._position_cov())

    def _position_cov(self) -> np.ndarray:
        R = self.pose.rotation().matrix()
        return R @ self.pose_cov[3:, 3:] @ R.T

    def refresh(self) -> None:
        """The newest keyframe's estimate from iSAM2."""
        k = self.newest
        self.pose = self.session.pose(X(k))
        self.vel = self.session.vector(V(k))
        if self.bias_walk > 0:
            self.bias = float(self.session.vector(B(k))[0])
        if self.has_rate:
            self.rate = float(self.session.vector(D(k))[0])
        if self.has_gyro_bias:
            self.gyro_bias = self.session.vector(G(k))
        try:  # from the root clique: it holds the newest keyframe
            self.state_cov = self.session.root_joint(self._keys(k))
            self.pose_cov = self.state_cov[:6, :6]
        except RuntimeError:
            self.state_cov = None
            self.pose_cov = np.eye(6) * 1e2

    def renew_online(self, k: int) -> None:
        """Keyframe k's online pose is the one after its landmarks (when k is the newest)."""
        if k == self.newest:
            self.online.renew(self.pose, self._position_cov())

    def unbiased(self, R_ahrs: np.ndarray) -> np.ndarray:
        """An AHRS attitude with the current heading-bias estimate taken out: Rz(−b) R."""
        if self.bias == 0.0:
            return R_ahrs
        c, s_ = np.cos(self.bias), np.sin(self.bias)
        return np.array([[c, s_, 0.0], [-s_, c, 0.0], [0.0, 0.0, 1.0]]) @ R_ahrs

    # ------------------------------------------------------------------ poses
    def pose_of(self, k: int) -> gtsam.Pose3:
        """Keyframe k's current estimate (frozen once it left the window)."""
        if k == self.newest and self.pose is not None:
            return self.pose
        if k < self.window.first_active:
            return self.window.frozen.atPose3(X(k))
        return self.session.pose(X(k))

    def pose_and_cov(self, k: int) -> tuple[gtsam.Pose3, np.ndarray]:
        """Keyframe k's pose estimate and marginal covariance (6×6, rotation then translation)."""
        if k == self.newest:
            return self.pose, self.pose_cov
        return self.session.pose(X(k)), self.session.root_marginal(X(k))

    def pose_at(self, stamp: int) -> gtsam.Pose3 | None:
        """T_WB at ``stamp``: interpolated between keyframe estimates, or predicted from the
        newest keyframe with the DVL and the gyro (the AHRS reading without its rates) integrated since."""
        if not self.stamps:
            return None
        if stamp >= self.stamps[-1]:
            if stamp == self.stamps[-1] or self.nav.preint is None:
                return self.pose
            t = stamp * 1e-9
            R, _ = self.nav.attitude_at(t)
            d = self.nav.preint.integrate(t, R, self.nav.dvl_turn(t))
            R_k = self.pose.rotation().matrix()
            p = self.pose.translation() + R_k @ (d.c + (d.A + d.B) @ self.vel)
            # the rotation: the keyframe's estimate turned by the gyro since it, where the interval has its rates (its
            # error the rate noise integrated since the keyframe), else the single AHRS reading at t
            dR = self.nav.gyro_rotation_at(t) if self.gyro_link else None
            return gtsam.Pose3(gtsam.Rot3(self.unbiased(R) if dR is None else R_k @ dR), p)
        i = bisect.bisect_right(self.stamps, stamp)
        if i == 0:
            return None
        a, b = self.pose_of(i - 1), self.pose_of(i)
        s = (stamp - self.stamps[i - 1]) / (self.stamps[i] - self.stamps[i - 1])
        return gtsam.Pose3(a.rotation().slerp(s, b.rotation()), (1 - s) * a.translation() + s * b.translation())

    def nearest(self, stamp: int) -> tuple[int | None, gtsam.Pose3]:
        """The keyframe nearest to ``stamp`` and T_B(keyframe),B(stamp) from the current estimate."""
        if not self.stamps:
            return None, gtsam.Pose3()
        i = bisect.bisect_left(self.stamps, stamp)
        i = min((c for c in (i - 1, i) if 0 <= c < len(self.stamps)), key=lambda c: abs(self.stamps[c] - stamp))
        if self.stamps[i] == stamp:
            return i, gtsam.Pose3()
        here = self.pose_at(stamp)
        if here is None:
            return None, gtsam.Pose3()
        return i, self.pose_of(i).between(here)

    def older(self, stamp: int, diagnostics: list[str]) -> int | None:
        """The keyframe that observations older than the newest keyframe attach to (None: it left the window)."""
        i = bisect.bisect_left(self.stamps, stamp)
        i = min(range(max(i - 1, 0), min(i + 1, len(self.stamps))), key=lambda j: abs(self.stamps[j] - stamp))
        if i < self.window.first_active:
            diagnostics.append(f"{stamp}: observations older than the smoothing window, dropped")
            return None
        diagnostics.append(f"{stamp}: observations older than the newest keyframe, attached to keyframe {i}")
        return i

    def odometry_factors(self, odom: list, diagnostics: list[str]) -> list:
        """Relative-pose constraints (e.g. swath registrations). An end that is not a keyframe is
        carried to the nearest keyframe with the estimated motion in between (short: at most half
        a keyframe interval of dead reckoning, whose error is far below the constraint's). A Cauchy
        m-estimator bounds the pull of one that converged wrong, for the sensor kinds the config names."""
        out = []
        for z in odom:
            i, T_i_from = self.nearest(z.stamp_from)
            j, T_j_to = self.nearest(z.stamp)
            if i is None or j is None or i == j or min(i, j) < self.window.first_active:
                diagnostics.append(
                    f"{z.stamp}: odometry from {z.stamp_from} has no distinct keyframes in the window to join, dropped"
                )
                continue
            meas = T_i_from.compose(gtsam.Pose3(z.relative_pose)).compose(T_j_to.inverse())
            noise = gtsam.noiseModel.Gaussian.Covariance(z.covariance)
            if z.sensor in self.odometry_kernels:
                noise = gtsam.noiseModel.Robust.Create(self.odometry_kernels[z.sensor], noise)
            out.append(gtsam.BetweenFactorPose3(X(i), X(j), meas, noise))
        return out
