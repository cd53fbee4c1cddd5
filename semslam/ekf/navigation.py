"""The filter's vehicle: initialisation, the constant-velocity prediction driven by the AHRS body rate,
the depth, AHRS and DVL updates (Vallicrosa et al. 2021, eqs. 20–29), and the vehicle's estimate over
time. Invalid DVL readings are skipped, so the uncertainty grows during dropouts.

AHRS heading bias (an extension: the paper's filter has none). With ``heading_bias_walk(metadata)``
> 0 (the shared sensor model, as the graph's) the vehicle state is [x y z φ θ ψ u v w b] (b at
:data:`semslam.ekf.models.BIAS`): b starts at 0 with σ ``heading_bias_sigma0(metadata)``, the
prediction adds σ_b² Δt to its variance (:func:`~semslam.ekf.models.predict_biased`) and the AHRS
update measures (φ, θ, ψ + b), R_meas = Rz(b) R_WB as the graph's ``biased_attitude_residual``.
With ``heading_bias_rate_sigma(metadata)`` > 0 as well, an 11th entry ρ, the bias's drift rate in
rad per ``factors.heading_bias.RATE_UNIT_S`` s (prior σ from the declared drift), carries b on:
b' = b + ρ Δt/τ, ρ a random walk (the graph's ``heading_bias_drift_factor``). Nothing else sees b: only the map (a heading relative to features seen earlier) makes it observable.

The gyro's bias (stop 43; the shared model ``sensors.gyro_bias_sigma(metadata)`` > 0): three more
entries b_g, body axes as the rates the prediction takes (ω_B = R_BS ω_S), last in the vehicle block
(after b and ρ): prior σ ``gyro_bias_sigma``, a random walk of ``gyro_bias_walk``; the prediction
integrates ω_B − b_g (:func:`~semslam.ekf.models.predict`) and the DVL's lever arm turns at it. A rate
taken from attitude differences (an AHRS without one) is no gyro's: there b_g is not subtracted (its
entries only walk). σ 0 = no entries, the filter as before. Dead reckoning runs this filter too.

With b in the state a rotation of vehicle and map about the vertical is unobservable; the textbook
EKF's Jacobians at the updated estimates observe it spuriously (Huang, Mourikis & Roumeliotis
2008/2009). With ``ekf.heading_jacobians = "first_estimate"`` (the FEJ-EKF) the prediction's
∂p'/∂ψ = e_z × (p' − p) takes p as propagated (:attr:`FilterNavigation.p_fe`), and every landmark
Jacobian is evaluated at the propagated position (:meth:`FilterNavigation.x_lin`) and the landmark's
first estimate; then F N_k = N_k+1 and H N = 0 hold exactly for that null space N.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from factors.heading_bias import RATE_UNIT_S
from semslam.config import SemslamConfig
from semslam.ekf import geometry as geo
from semslam.ekf import models as mdl
from semslam.ekf.filter import EkfState
from semslam.ekf.gps import FilterGps
from semslam.ekf.models import ATT, BIAS, GYRO_BIAS_SIZE, NX, POS, VEL
from semslam.estimation import Trajectory
from semslam.mission.measurements import Attitude, Depth, DvlVelocity, GpsFix, GroundTruthPose, Measurement
from semslam.mission.mission import MissionMetadata
from semslam.observations import OdometryObservation

NS = 1e-9


class FilterNavigation:
    """The vehicle block of the filter's state and everything that moves it: ``state`` is the whole
    filter (vehicle first, then the map's blocks), ``t`` its stamp."""

    def __init__(self, metadata: MissionMetadata, config: SemslamConfig, diagnostics: list[str]):
        self.metadata = metadata
        self.cfg = config.ekf
        self.initial = config.initial
        self.motion = config.motion
        self.rate_density = config.motion.angular_rate_density(metadata)
        self.diagnostics = diagnostics
        self._warned: set[str] = set()
        # AHRS heading bias (the shared sensor model; 0 = not modelled): a 10th vehicle state
        self.bias_walk = config.sensors.heading_bias_walk(metadata)
        self.bias_sigma0 = config.sensors.heading_bias_sigma0(metadata)
        # and its drift rate ρ (rad per RATE_UNIT_S s, factors.heading_bias) an 11th, when modelled
        rate_sigma = config.sensors.heading_bias_rate_sigma(metadata)
        self.bias_rate_walk = config.sensors.heading_bias_rate_walk(metadata) if rate_sigma > 0 else None
        self.rate_sigma0 = rate_sigma * RATE_UNIT_S
        self.n_heading = (self.bias_walk > 0) + (self.bias_rate_walk is not None)  # heading-bias entries (0–2)
        # the gyro's bias (body axes, 3 entries after those; the shared model, 0 = not modelled)
        self.gyro_sigma0 = config.sensors.gyro_bias_sigma(metadata)
        self.gyro_walk = config.sensors.gyro_bias_walk(metadata) if self.gyro_sigma0 > 0 else None
        self.nv = NX + self.n_heading + GYRO_BIAS_SIZE * (self.gyro_walk is not None)
        self.fej_yaw = self.n_heading > 0 and self.cfg.heading_jacobians == "first_estimate"
        self.p_fe = np.zeros(3)  # the propagated (first) estimate of the position at the current time
        self.state: EkfState | None = None
        self.t: int | None = None  # stamp of the state (ns)
        self.omega = np.zeros(3)  # latest body rate (input)
        self._omega_stamp: int | None = None
        self._omega_gyro = False  # the latest body rate is the gyro's reading (its bias applies), not differences
        self._last_att: tuple[int, np.ndarray] | None = None  # for a rate by differences
        self._last_depth: float | None = None
        self._wait_gt = self.initial.pose == "first_ground_truth" and bool(metadata.sensors_of_kind("ground_truth"))
        self.gps = FilterGps(metadata, self.initial.pose)  # the start from the first fix; the EKF's updates
        self._traj: dict[str, list] = {k: [] for k in ("t", "x", "P")}  # vehicle state and covariance
        self._history: tuple[list, list] = ([], [])  # (stamps, vehicle covariance) every history_period_s
        gate = self.cfg.odometry_gate_probability
        self._odometry_gate = None if gate is None else float(chi2.ppf(gate, 3))  # NIS bound of a velocity (3-D)
        self._odometry_counts = {"taken": 0, "rejected": 0}
        self._odometry_note: int | None = None  # where in ``diagnostics`` the gate's count stands

    def extrinsic(self, sensor: str) -> tuple[np.ndarray, np.ndarray]:
        """R_BS, t_BS of ``sensor`` (an undeclared sensor is a MissionError)."""
        T = self.metadata.extrinsic(sensor)
        return T[:3, :3], T[:3, 3]

    def warn_once(self, key: str, msg: str) -> None:
        if key not in self._warned:
            self._warned.add(key)
            self.diagnostics.append(msg)

    # ------------------------------------------------------------------- initialisation
    def _initialise(self, stamp: int, position: np.ndarray, R_WB: np.ndarray, pos_sigma: np.ndarray) -> None:
        x0 = np.zeros(self.nv)  # the heading bias (if modelled) starts at 0
        x0[POS] = position
        x0[ATT] = geo.euler(R_WB)
        c = self.initial
        P0 = np.diag(
            np.r_[
                pos_sigma**2,
                [c.attitude_sigma_rad**2] * 3,
                [c.velocity_sigma_m_s**2] * 3,
                [self.bias_sigma0**2] * (self.n_heading > 0),
                [self.rate_sigma0**2] * (self.n_heading > 1),
                [self.gyro_sigma0**2] * (GYRO_BIAS_SIZE * (self.gyro_walk is not None)),
            ]
        )
        self.state = EkfState(x0, P0)
        self.p_fe = x0[POS].copy()
        self.t = stamp
        self.record(stamp)

    def _try_initialise(self, m: Measurement) -> None:
        if isinstance(m, Depth):
            self._last_depth = m.depth
        waits_for_fix = self.gps.start.holds(m)
        if isinstance(m, GroundTruthPose) and self._wait_gt:
            R = Rotation.from_quat(m.orientation).as_matrix()
            self._initialise(m.stamp, np.asarray(m.position), R, np.full(3, self.initial.position_sigma_m))
        elif isinstance(m, Attitude) and not self._wait_gt and not waits_for_fix:
            R_BS, _ = self.extrinsic(m.sensor)
            R_WB = Rotation.from_quat(m.orientation).as_matrix() @ R_BS.T
            z = self._last_depth if self._last_depth is not None else 0.0
            sig = np.array(
                [self.initial.position_sigma_m] * 2
                + [self.initial.position_sigma_m if self._last_depth is not None else 10.0]
            )
            pos, sig = self.gps.start.pose(R_WB) or (np.array([0.0, 0.0, z]), sig)
            self._initialise(m.stamp, pos, R_WB, sig)
            self._attitude(m)

    # ---------------------------------------------------------------------- prediction
    def predict_to(self, stamp: int) -> None:
        if stamp <= self.t:
            return
        omega, gyro = self.omega, self._omega_gyro
        if self._omega_stamp is None or (stamp - self._omega_stamp) * NS > self.cfg.rate_max_age_s:
            omega, gyro = np.zeros(3), False
        total = (stamp - self.t) * NS
        steps = max(1, int(math.ceil(total / self.cfg.max_prediction_step_s - 1e-9)))
        dt = total / steps
        sa, sw = self.motion.accel_sigma_m_s2, self.rate_density
        hb = (self.bias_walk, self.bias_rate_walk) if self.n_heading else (None, None)
        for _ in range(steps):
            if self.nv > NX:
                w = omega
                if self.gyro_walk is not None and not gyro:  # a rate not the gyro's: its bias does not apply
                    w = omega + self.state.xv[-GYRO_BIAS_SIZE:]
                xv, F, Q = mdl.predict_biased(self.state.xv, w, dt, sa, sw, *hb, self.gyro_walk)
                if self.gyro_walk is not None and not gyro:
                    F[ATT, -GYRO_BIAS_SIZE:] = 0.0
            else:
                xv, F, Q = mdl.predict(self.state.xv.copy(), omega, dt, sa, sw)
            if self.fej_yaw:  # ∂p'/∂ψ = e_z × (p' − p) with p the propagated, not the updated, position
                F[0, 5] = -(xv[1] - self.p_fe[1])
                F[1, 5] = xv[0] - self.p_fe[0]
            self.p_fe = xv[:3].copy()
            self.state.predict_vehicle(xv, F, Q)
        self.t = stamp

    def rate(self) -> np.ndarray:
        """The body rate the prediction integrates now: the gyro's reading less its estimated bias."""
        if self.gyro_walk is not None and self._omega_gyro:
            return self.omega - self.state.xv[-GYRO_BIAS_SIZE:]
        return self.omega

    def x_lin(self) -> np.ndarray:
        """The vehicle state where landmark Jacobians are evaluated: the current one with the position
        of the propagation (first-estimates Jacobians for the heading, see the module docstring)."""
        x = self.state.xv[:NX].copy()
        x[POS] = self.p_fe
        return x

    def _nav_update(self, u: mdl.NavUpdate) -> None:
        self.state.update_vehicle(u.innovation, u.H, u.R, nis=False)
        self.wrap_vehicle()

    def wrap_vehicle(self) -> None:
        x = self.state.xv
        x[3] = geo.wrap_angle(x[3])
        x[5] = geo.wrap_angle(x[5])

    # ------------------------------------------------------------------ measurements
    def process(self, m: Measurement) -> None:
        """A navigation (or ground-truth) measurement, in stamp order."""
        if self.state is None:
            self._try_initialise(m)
            return
        if isinstance(m, GroundTruthPose) or (isinstance(m, GpsFix) and not self.gps.uses(m)):
            return  # dead reckoning takes no fix; nor does the EKF take the one it started from again
        if m.stamp < self.t:
            self.warn_once("late", f"measurement older than the filter state dropped ({m.sensor})")
            return
        self.predict_to(m.stamp)
        if isinstance(m, Attitude):
            self._attitude(m)
        elif isinstance(m, DvlVelocity):
            if m.valid and np.isfinite(m.velocity).all():
                R_BS, t_BS = self.extrinsic(m.sensor)
                gyro = self.gyro_walk is not None and self._omega_gyro
                u = mdl.dvl_update(self.state.xv, m.velocity, m.covariance, R_BS, t_BS, self.omega, gyro)
                self._nav_update(u)
        elif isinstance(m, Depth):
            _, t_BS = self.extrinsic(m.sensor)
            self._nav_update(mdl.depth_update(self.state.xv, m.depth, m.variance, t_BS))
        elif isinstance(m, GpsFix):
            self._nav_update(self.gps.update(self.state.xv, m))
        self.record(m.stamp)

    def odometry(self, z: OdometryObservation) -> None:
        """Laser odometry as the filter can take it: a pseudo-measurement of the body velocity, the
        mean over the registration's interval (the state holds no past pose to relate the relative
        pose to). Under the constant-velocity model a body turning at a steady rate moves by
        Δt·R_half·v_B, R_half the rotation halfway; the covariance is the relative translation's over
        Δt², plus how far the velocity may wander from its mean in Δt (σ_a²·Δt/3). The rotation it
        measures is not used: the AHRS observes the attitude directly.

        Gated as the graph's robust factor discounts it: a pseudo-measurement whose NIS νᵀS⁻¹ν exceeds
        χ²₃ at ``ekf.odometry_gate_probability`` is rejected (a registration that converged wrong, where
        the filter knows its velocity; deep in a DVL dropout S is wide and the gate lets it through)."""
        dt = (z.stamp - z.stamp_from) * NS
        if dt <= 0 or z.stamp < self.t:
            return
        self.predict_to(z.stamp)
        R_half = Rotation.from_rotvec(0.5 * Rotation.from_matrix(z.relative_pose[:3, :3]).as_rotvec()).as_matrix()
        v = R_half.T @ z.relative_pose[:3, 3] / dt
        cov = R_half.T @ z.covariance[3:, 3:] @ R_half / dt**2 + np.eye(3) * self.motion.accel_sigma_m_s2**2 * dt / 3
        innovation = v - self.state.xv[VEL]
        if self._odometry_gate is not None:
            S = self.state.Pvv[VEL, VEL] + cov
            if innovation @ np.linalg.solve(S, innovation) > self._odometry_gate:
                self._count_odometry("rejected")
                return
        self._count_odometry("taken")
        H = np.zeros((3, NX))
        H[:, VEL] = np.eye(3)
        self._nav_update(mdl.NavUpdate(innovation, H, cov))
        self.record(z.stamp)

    def _count_odometry(self, outcome: str) -> None:
        """Counts the odometry pseudo-measurements; once one was rejected, one diagnostic line says how many."""
        c = self._odometry_counts
        c[outcome] += 1
        if not c["rejected"]:
            return
        note = (
            f"odometry: {c['rejected']} of {c['taken'] + c['rejected']} registrations rejected by the NIS gate "
            f"(χ²₃, p = {self.cfg.odometry_gate_probability})"
        )
        if self._odometry_note is None:
            self._odometry_note = len(self.diagnostics)
            self.diagnostics.append(note)
        else:
            self.diagnostics[self._odometry_note] = note

    def _attitude(self, m: Attitude) -> None:
        R_BS, _ = self.extrinsic(m.sensor)
        R_WS, omega, e_B, cov_B = _ahrs_reading(m, self.metadata, R_BS)
        if omega is not None:
            self.omega = omega
            self._omega_stamp = m.stamp
            self._omega_gyro = True
        elif self._last_att is not None and m.stamp > self._last_att[0]:
            # no rate in the message: the body rate from consecutive attitudes
            dt = (m.stamp - self._last_att[0]) * NS
            R_prev = self._last_att[1] @ R_BS.T
            self.omega = geo.so3_log(R_prev.T @ (R_WS @ R_BS.T)) / dt
            self._omega_stamp = m.stamp
            self._omega_gyro = False
        self._last_att = (m.stamp, R_WS)
        if self.n_heading:
            self._nav_update(mdl.biased_attitude_update(self.state.xv, e_B, cov_B))
        else:
            self._nav_update(mdl.attitude_update(self.state.xv, e_B, cov_B))

    # --------------------------------------------------------------------------- records
    def record(self, stamp: int) -> None:
        """The vehicle's estimate at ``stamp`` (replacing one recorded at the same stamp)."""
        x, P = self.state.xv.copy(), self.state.Pvv.copy()
        tr = self._traj
        if tr["t"] and tr["t"][-1] == stamp:
            for k in tr:
                tr[k].pop()
        tr["t"].append(stamp)
        tr["x"].append(x)
        tr["P"].append(P)
        hs, hp = self._history
        if not hs or (stamp - hs[-1]) * NS >= self.cfg.history_period_s:
            hs.append(stamp)
            hp.append(P)

    def pose_at(self, stamp: int) -> np.ndarray | None:
        """T_WB at ``stamp``: predicted forward from the current state, or the recorded estimate nearest
        in time for a past stamp."""
        if self.state is None:
            return None
        if stamp >= self.t:
            x = self.state.xv[:NX].copy()
            dt = (stamp - self.t) * NS
            if dt > 0:
                x = mdl.predict(x, self.rate(), dt, self.motion.accel_sigma_m_s2, self.rate_density)[0]
        else:
            ts = np.asarray(self._traj["t"])
            k = int(np.clip(np.searchsorted(ts, stamp), 0, len(ts) - 1))
            if k > 0 and abs(ts[k - 1] - stamp) < abs(ts[k] - stamp):
                k -= 1
            x = self._traj["x"][k]
        T = np.eye(4)
        T[:3, :3] = geo.rot(*x[ATT])
        T[:3, 3] = x[POS]
        return T

    def trajectory(self) -> tuple[Trajectory, dict] | None:
        """The vehicle's estimate at every recorded stamp, and its history (vehicle covariance over
        time; with the heading bias modelled, b and its σ, and with its rate, the rate and its σ); None if the filter never started."""
        tr = self._traj
        if not tr["t"]:
            return None
        X, P = np.array(tr["x"]), np.array(tr["P"])
        traj = Trajectory(
            stamps=np.array(tr["t"], np.int64),
            positions=X[:, POS].copy(),
            orientations=Rotation.from_euler("ZYX", X[:, ATT][:, ::-1]).as_quat(),
            position_cov=P[:, POS, POS].copy(),
            velocities=X[:, VEL].copy(),
            velocity_cov=P[:, VEL, VEL].copy(),
        )
        history = {"vehicle_cov": (np.array(self._history[0], np.int64), np.array(self._history[1]))}
        if self.n_heading:  # the AHRS heading bias estimate and its σ (rad) over time
            history["heading_bias"] = (traj.stamps, X[:, BIAS].copy(), np.sqrt(P[:, BIAS, BIAS]))
        if self.n_heading > 1:  # and its drift rate (rad/s) and σ
            r = BIAS + 1
            history["heading_bias_rate"] = (traj.stamps, X[:, r] / RATE_UNIT_S, np.sqrt(P[:, r, r]) / RATE_UNIT_S)
        if self.gyro_walk is not None:  # the gyro's bias (rad/s, body axes) and its σ, (K, 3) each
            g = slice(self.nv - GYRO_BIAS_SIZE, self.nv)
            sg = np.sqrt(np.diagonal(P[:, g, g], axis1=1, axis2=2))
            history["gyro_bias"] = (traj.stamps, X[:, g].copy(), sg)
        return traj, history


# The last AHRS reading in {B}: DR and the EKF are fed the same measurement object one after the
# other (semslam.pipeline), and what it says does not depend on the filter's state.
_last_ahrs: tuple = (None, None, None)  # (measurement, metadata, reading)


def _ahrs_reading(m: Attitude, metadata: MissionMetadata, R_BS: np.ndarray) -> tuple:
    """(R_WS, body rate ω_B or None, Euler angles of R_WB, their covariance) of an AHRS reading."""
    global _last_ahrs
    if _last_ahrs[0] is m and _last_ahrs[1] is metadata:
        return _last_ahrs[2]
    R_WS = geo.quat_to_rot(m.orientation)
    omega = R_BS @ m.angular_rate if m.angular_rate is not None and np.isfinite(m.angular_rate).all() else None
    reading = (R_WS, omega, *mdl.attitude_in_body(R_WS, m.covariance, R_BS))
    for a in reading:  # shared: nobody may change it
        if a is not None:
            a.flags.writeable = False
    _last_ahrs = (m, metadata, reading)
    return reading
