"""EKF-SLAM (``ekf``) and dead reckoning (``dr``): the estimators of Vallicrosa et al. 2021, Section 4.

The filter predicts with the constant-velocity model driven by the AHRS body rate, updates with the
depth, AHRS and DVL readings (invalid DVL readings are skipped, so the uncertainty grows during
dropouts), and — for ``ekf`` — with the objects (points) and pipes (lines) the front-ends extract:
JCBB association against the mapped features, one joint EKF update (Joseph form) for the paired
observations, and state augmentation with the cross-covariances for new features. Navigation steps
reach the map in compressed form (:mod:`semslam.ekf.filter`), so they cost the same whatever its size.

AHRS heading bias (an extension: the paper's filter has none). An AHRS heading drifts (magnetic
disturbances, gyro bias; the simulated tank's by ~2° over the mission) while its message declares only
white noise. The graph back-end models the drift as a random-walk state, so for a fair comparison the
filter models it the same way, from the same shared sensor model (``config.sensors``): whenever
``heading_bias_walk(metadata)`` > 0 the vehicle state is [x y z φ θ ψ u v w b] (10 entries, b at
:data:`semslam.ekf.models.BIAS`), b starts at 0 with σ ``heading_bias_sigma0(metadata)`` (the
mission's declared one), the prediction adds σ_b² Δt to its variance
(:func:`~semslam.ekf.models.predict_biased`), and the AHRS update measures (φ, θ, ψ + b), i.e.
R_meas = Rz(b) R_WB as the graph's ``biased_attitude_residual``
(:func:`~semslam.ekf.models.biased_attitude_update`). Nothing else sees b: landmark, DVL and depth
Jacobians have a zero column for it, and it rides in the vehicle block of the compressed steps. Only
the map (a heading relative to features seen earlier) makes b observable: dead reckoning carries it
with its uncertainty growing as the walk's, and so does its heading's. With no bias modelled (walk 0)
the filter is exactly the paper's 9-state one. ``finish()`` reports b and its σ over time in
``history["heading_bias"]`` (stamps, b, σ_b).

With b in the state the AHRS observes ψ + b only, so a rotation of vehicle and map about the vertical
(b turning back by as much) is unobservable — as a common translation already is. The textbook EKF
observes it spuriously (Huang, Mourikis & Roumeliotis 2008/2009): Jacobians at the updated estimates
let the heading, and the bias with it, wander with the map's linearisation errors (simulated tank, oracle
observations, the true bias taken out of the AHRS: the 9-state filter's ATE is 0.020 m; modelling a bias
anyway, 0.043 m with the textbook Jacobians, 0.031 m with these). So, with the bias modelled,
``ekf.heading_jacobians = "first_estimate"`` (the FEJ-EKF): the prediction's ∂p'/∂ψ = e_z × (p' − p) takes
p as propagated, not as updated, and every landmark Jacobian (association, update, new features) is
evaluated at the propagated position and the landmark's first estimate; then F N_k = N_k+1 and H N = 0
hold exactly for that null space N (tested). The innovations stay at the current estimate.

Association: every pair of a scan is linearised in one vectorised pass (:class:`_ScanPairs`), and
the shared JCBB (:func:`semslam.mapping.association.jcbb`) runs on their full joint covariance
(:class:`~semslam.mapping.association.DenseJoint`).

Pipe Jacobians are evaluated at each pipe's first estimate (FEJ, Huang, Mourikis & Roumeliotis
2008; ``ekf.line_jacobians``): a pipe's world-origin line parameters change under a common
translation of vehicle and map in a way that depends on their estimate, so Jacobians at the current
estimate let a sequence of updates observe that translation — spurious absolute-position
information that made the filter overconfident (on the tank stream, position σ 2.5 → 0.7 cm with
truth-exact observations). Objects (points) have no such dependence.

Feature initialisation (a choice, stated): the paper adds an unpaired feature at once; here an
unpaired observation first starts or extends a *tentative* feature (gated in {W} with the vehicle
uncertainty; objects against the weighted mean of the track's views), and enters the state once it
has been seen ``association.min_observations`` times (Himri et al. 2018: "landmarks created only
after consistent repeated observations"), initialised from its latest observation with the full
cross-covariances (eqs. 39–45). With ``min_observations = 1`` this is exactly the paper's flow. An
unpaired observation that is still compatible with a mapped feature at the track gate, or a pipe view
that lies on a mapped pipe by the paper's collinear-merge criterion (``association.merge_angle_rad`` /
``merge_distance_m``), is ambiguous, not new: it is dropped rather than started as a duplicate.

Pipes keep the endpoints of every view of them (in {W}); they are re-projected onto the current line
estimate whenever used, so they follow every update, and the pipe's ends are a noise-robust extreme of
them. A segment pairs with a pipe only if it comes within ``association.pipe_extent_gap_m`` of that
extent and no object (mapped or tentative) lies on the line between them, within
``association.inline_object_radius_m`` of it (both shared with the graph): collinear pipes on either
side of an in-line valve stay distinct, partial views of one pipe do not split it.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from semslam.config import EkfConfig, SemslamConfig
from semslam.ekf import batch as bt
from semslam.ekf import geometry as geo
from semslam.ekf import models as mdl
from semslam.ekf.filter import EkfState
from semslam.ekf.models import ATT, BIAS, NX, POS, VEL
from semslam.errors import MissionError
from semslam.estimation import EstimatorResult, LandmarkEstimate, Trajectory
from semslam.mapping.association import Candidates, DenseJoint, PairLinearization, chi2_gate, jcbb
from semslam.mapping.book import LandmarkBook
from semslam.mapping.extent import PipeExtent, along_sigma, off_axis
from semslam.mission.measurements import Attitude, Depth, DvlVelocity, GroundTruthPose, Measurement
from semslam.mission.mission import MissionMetadata
from semslam.observations import LineObservation, Observation, PointObservation

NS = 1e-9


# ------------------------------------------------------------------------------ features
@dataclass
class _Feature:
    """A mapped feature: its state block, and for pipes the saved endpoints in {W}."""

    id: int
    kind: str  # "object" | "pipe"
    index: int  # first state index
    size: int
    extent: PipeExtent | None = None  # pipes: what was seen of them
    vol_stamps: list[int] = field(default_factory=list)
    vol: list[float] = field(default_factory=list)
    l_first: np.ndarray | None = None  # the estimate it entered the state with (first-estimates Jacobians)

    @property
    def cols(self) -> np.ndarray:
        return np.arange(self.index, self.index + self.size)


@dataclass
class _Track:
    """A tentative feature: for objects the information-weighted mean of its observations in {W} and
    its covariance (as the graph's tracks), for pipes the latest observation (Plücker, covariance in
    line error coordinates) and the seen extent; how often it was seen."""

    kind: str
    mean: np.ndarray  # object: (3,) position; pipe: (6,) Plücker (m, d)
    cov: np.ndarray
    n: int
    last_stamp: int
    extent: PipeExtent | None = None
    key: int = 0  # its views and class evidence in the shared LandmarkBook
    info: np.ndarray | None = None  # objects: Σ C⁻¹ and Σ C⁻¹ w of the observations
    info_vec: np.ndarray | None = None

    def fuse(self, mean: np.ndarray, cov: np.ndarray) -> None:
        """Objects: add an observation to the weighted mean; pipes: keep the latest."""
        if self.kind != "object":
            self.mean, self.cov = mean, cov
            return
        Ci = np.linalg.inv(cov)
        if self.info is None:
            self.info, self.info_vec = np.zeros((3, 3)), np.zeros(3)
        self.info = self.info + Ci
        self.info_vec = self.info_vec + Ci @ mean
        self.cov = np.linalg.inv(self.info)
        self.mean = self.cov @ self.info_vec


# --------------------------------------------------------------------------- observations
@dataclass
class _Obs:
    """An observation prepared for the filter: its sensor extrinsic and model."""

    obs: Observation
    R_BS: np.ndarray
    t_BS: np.ndarray
    line: mdl.LineObservationModel | None = None
    ends_W: np.ndarray | None = None  # observed segment in {W} with the current pose (pipes)

    @property
    def kind(self) -> str:
        return "pipe" if isinstance(self.obs, LineObservation) else "object"


class _ScanPairs:
    """Every candidate pairing of one batch of observations with the mapped features, linearised at
    the current state in one vectorised pass (the same numbers as :meth:`EkfEstimator._pair`, pair by pair).

    A pair is a candidate when the observation and the feature are of one kind, the Euclidean
    pre-gate keeps it, its individual NIS passes the χ² gate at ``check_confidence`` (the loosest
    gate any use of the pairs applies: the others could never be paired or be "near") and (pipes)
    the segment is within the seen extent's gap with no object in between. For each candidate k:
    ``obs[k]``, ``feat[k]`` (feature index), innovation ``nu[k]``, ``H_x[k]``, ``H_l[k]``, ``R[k]`` and
    its individual NIS ``nis[k]``.
    """

    def __init__(self, est: EkfEstimator, obs: list[_Obs], check_confidence: float):
        self.est = est
        self.obs_list = obs
        self.n_obs = len(obs)
        feats = est._features
        obs_i, feat_j, nus, Hxs, Hls, Rs, niss = [], [], [], [], [], [], []
        if feats and obs:
            near = est._pre_gate(obs)
            x = est.state.x
            P = est.state.P
            Pvv = P[:NX, :NX]
            objects = None
            for kind in ("object", "pipe"):
                fidx = np.array([j for j, f in enumerate(feats) if f.kind == kind], int)
                if not len(fidx):
                    continue
                for _sensor, group in _by_sensor(obs, kind):
                    ii, jj = np.nonzero(near[np.ix_(group, fidx)])
                    if not len(ii):
                        continue
                    oi = np.asarray(group)[ii]
                    fj = fidx[jj]
                    o0 = obs[oi[0]]
                    starts = np.array([feats[j].index for j in fj])
                    size = 3 if kind == "object" else 4
                    cols = starts[:, None] + np.arange(size)
                    if kind == "object":
                        uj, inv = np.unique(fj, return_inverse=True)
                        L = x[np.array([feats[j].index for j in uj])[:, None] + np.arange(3)]
                        h, Hx_u, Hl = bt.point_measurements(x[:NX], L, o0.R_BS, o0.t_BS)
                        if est._fej_yaw:  # Jacobians at the first estimates (ν at the current ones)
                            L_f = np.array([feats[j].l_first for j in uj])
                            Hx_u = bt.point_measurements(est._x_lin(), L_f, o0.R_BS, o0.t_BS)[1]
                        z = np.array([obs[i].obs.position for i in oi])
                        nu = z - h[inv]
                        Hx = Hx_u[inv]
                        HlK = np.broadcast_to(Hl, (len(oi), 3, 3))
                        R = np.array([obs[i].obs.covariance for i in oi])
                    else:
                        L = x[cols]
                        lines = [obs[i].line for i in oi]
                        args = (
                            np.array([ln.U for ln in lines]),
                            np.array([ln.rho for ln in lines]),
                            np.array([ln.d for ln in lines]),
                            np.array([ln.cov for ln in lines]),
                            o0.R_BS,
                            o0.t_BS,
                        )
                        L_lin = np.array([feats[j].l_first for j in fj]) if est._fej or est._fej_yaw else None
                        nu, Hx, HlK, R = bt.line_innovations(
                            x[:NX], L, *args, L_lin=L_lin, x_lin=est._x_lin() if est._fej_yaw else None
                        )
                    # S = H_x P_vv H_xᵀ + H_x P_vl H_lᵀ + H_l P_lv H_xᵀ + H_l P_ll H_lᵀ + R
                    Pvl = P[:NX][:, cols].transpose(1, 0, 2)  # (K, 9, size)
                    Pll = P[cols[:, :, None], cols[:, None, :]]  # (K, size, size)
                    HxT, HlT = np.transpose(Hx, (0, 2, 1)), np.transpose(HlK, (0, 2, 1))
                    cross = Hx @ Pvl @ HlT
                    S = Hx @ Pvv @ HxT + cross + np.transpose(cross, (0, 2, 1)) + HlK @ Pll @ HlT + R
                    nis = np.einsum("ki,ki->k", nu, np.linalg.solve(S, nu[..., None])[..., 0])
                    keep = nis < chi2_gate(check_confidence, size)
                    if kind == "pipe":
                        if objects is None:
                            objects, mapped = est._object_positions(), est._mapped_object_positions()
                        for k in np.flatnonzero(keep):
                            f = feats[fj[k]]
                            m_W, d_W = geo.line_plucker(x[f.index : f.index + 4])
                            keep[k] = not est._pipe_apart(f.extent, obs[oi[k]].ends_W, m_W, d_W, objects, mapped)
                    obs_i.append(oi[keep])
                    feat_j.append(fj[keep])
                    nus += list(nu[keep])
                    Hxs += list(Hx[keep])
                    Hls += list(HlK[keep])
                    Rs += list(R[keep])
                    niss.append(nis[keep])
        self.obs = np.concatenate(obs_i) if obs_i else np.zeros(0, int)
        self.feat = np.concatenate(feat_j) if feat_j else np.zeros(0, int)
        self.nu, self.H_x, self.H_l, self.R = nus, Hxs, Hls, Rs
        self.nis = np.concatenate(niss) if niss else np.zeros(0)

    def _passing(self, confidence: float) -> np.ndarray:
        """Indices of the candidates individually compatible at ``confidence``."""
        dims = np.fromiter((len(v) for v in self.nu), int, len(self.nu))
        return np.flatnonzero(self.nis < np.where(dims == 3, chi2_gate(confidence, 3), chi2_gate(confidence, 4)))

    def near(self, confidence: float) -> np.ndarray:
        """Per observation: is some candidate feature individually compatible at ``confidence``?"""
        out = np.zeros(self.n_obs, bool)
        out[self.obs[self._passing(confidence)]] = True
        return out

    def associate(self, confidence: float) -> list[int | None]:
        """JCBB over the individually compatible candidates, with their full joint covariance, the
        observations searched most certain first (:func:`semslam.mapping.association.jcbb`)."""
        ks = self._passing(confidence)
        if not len(ks):
            return [None] * self.n_obs
        feats = self.est._features
        # J (stacked rows of the candidate pairs) over the vehicle and the candidate features' columns
        used = sorted({int(self.feat[k]) for k in ks})
        col0 = {}
        cols = [np.arange(NX)]
        c = NX
        for j in used:
            col0[j] = c
            cols.append(feats[j].cols)
            c += feats[j].size
        cols = np.concatenate(cols)
        D = sum(len(self.nu[k]) for k in ks)
        J = np.zeros((D, len(cols)))
        Rb = np.zeros((D, D))
        r = 0
        for k in ks:
            d = len(self.nu[k])
            j = int(self.feat[k])
            J[r : r + d, :NX] = self.H_x[k]
            J[r : r + d, col0[j] : col0[j] + feats[j].size] = self.H_l[k]
            Rb[r : r + d, r : r + d] = self.R[k]
            r += d
        P = self.est.state.P
        S_all = J @ P[np.ix_(cols, cols)] @ J.T + Rb
        found = Candidates(
            self.n_obs, self.obs[ks], self.feat[ks], [self.linearisation_at(k) for k in ks], self.nis[ks]
        )
        return jcbb(found, DenseJoint(found, S_all), confidence)

    def linearisation_at(self, k: int) -> PairLinearization:
        return PairLinearization(self.nu[k], self.H_x[k], self.H_l[k], self.R[k])

    def linearisation(self, i: int, j: int) -> PairLinearization:
        """The pair (observation i, feature j) as a PairLinearization (it must be a candidate)."""
        return self.linearisation_at(int(np.flatnonzero((self.obs == i) & (self.feat == j))[0]))


def _by_sensor(obs: list[_Obs], kind: str):
    """(sensor, [indices]) of the observations of one kind, grouped by sensor."""
    groups: dict[str, list[int]] = {}
    for i, o in enumerate(obs):
        if o.kind == kind:
            groups.setdefault(o.obs.sensor, []).append(i)
    return list(groups.items())


# ------------------------------------------------------------------------------- the filter
class EkfEstimator:
    """The paper's EKF-SLAM. ``EkfEstimator(metadata, config)`` with the full :class:`SemslamConfig`
    (sections ``motion``, ``sensors``, ``association`` and ``ekf``)."""

    name = "ekf"
    feature_updates = True

    def __init__(
        self,
        metadata: MissionMetadata,
        config: SemslamConfig | None = None,
    ):
        config = config or SemslamConfig()
        self.metadata = metadata
        self.cfg: EkfConfig = config.ekf
        self.initial = config.initial
        self.motion = config.motion
        self.assoc = config.association
        self._fej = self.cfg.line_jacobians == "first_estimate"
        # AHRS heading bias (the shared sensor model; 0 = not modelled): a 10th vehicle state
        self._bias_walk = config.sensors.heading_bias_walk(metadata)
        self._bias_sigma0 = config.sensors.heading_bias_sigma0(metadata)
        self.nv = NX + 1 if self._bias_walk > 0 else NX
        self._fej_yaw = self.nv > NX and self.cfg.heading_jacobians == "first_estimate"
        self._p_fe = np.zeros(3)  # the propagated (first) estimate of the position at the current time
        self.state: EkfState | None = None
        self.t: int | None = None  # stamp of the state (ns)
        self._omega = np.zeros(3)  # latest body rate (input)
        self._omega_stamp: int | None = None
        self._last_att: tuple[int, np.ndarray] | None = None  # for a rate by differences
        self._last_depth: float | None = None
        self._features: list[_Feature] = []
        self._tracks: list[_Track] = []
        self._next_id = 0
        self._next_track = 0
        self.book = LandmarkBook()  # views, class evidence and connectivity of the features
        has_gt = bool(metadata.sensors_of_kind("ground_truth"))
        self._wait_gt = self.initial.pose == "first_ground_truth" and has_gt
        # outputs
        self._traj: dict[str, list] = {k: [] for k in ("t", "x", "P")}  # vehicle state and covariance
        self._veh_hist: tuple[list, list] = ([], [])
        self._update_times: list[float] = []
        self._update_n: list[int] = []
        self._diag: list[str] = []
        self._warned: set[str] = set()
        self._dr_map: list[LandmarkEstimate] = []
        self._merged = 0  # duplicate objects and pipes fused

    # ------------------------------------------------------------------- sensor metadata
    def _extrinsic(self, sensor: str) -> tuple[np.ndarray, np.ndarray]:
        info = self.metadata.sensors.get(sensor)
        if info is None:
            raise MissionError(f"sensor {sensor!r} is not in the mission metadata (no extrinsic T_BS)")
        return info.T_BS[:3, :3], info.T_BS[:3, 3]

    def _warn_once(self, key: str, msg: str) -> None:
        if key not in self._warned:
            self._warned.add(key)
            self._diag.append(msg)

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
                [self._bias_sigma0**2] * (self.nv - NX),
            ]
        )
        self.state = EkfState(x0, P0)
        self._p_fe = x0[POS].copy()
        self.t = stamp
        self._record(stamp)

    # ---------------------------------------------------------------------- prediction
    def _predict_to(self, stamp: int) -> None:
        if stamp <= self.t:
            return
        omega = self._omega
        if self._omega_stamp is None or (stamp - self._omega_stamp) * NS > self.cfg.rate_max_age_s:
            omega = np.zeros(3)
        total = (stamp - self.t) * NS
        steps = max(1, int(math.ceil(total / self.cfg.max_prediction_step_s - 1e-9)))
        dt = total / steps
        sa, sw = self.motion.accel_sigma_m_s2, self.motion.angular_rate_sigma_rad_s
        for _ in range(steps):
            if self.nv > NX:
                xv, F, Q = mdl.predict_biased(self.state.xv, omega, dt, sa, sw, self._bias_walk)
            else:
                xv, F, Q = mdl.predict(self.state.xv.copy(), omega, dt, sa, sw)
            if self._fej_yaw:  # ∂p'/∂ψ = e_z × (p' − p) with p the propagated, not the updated, position
                F[0, 5] = -(xv[1] - self._p_fe[1])
                F[1, 5] = xv[0] - self._p_fe[0]
            self._p_fe = xv[:3].copy()
            self.state.predict_vehicle(xv, F, Q)
        self.t = stamp

    def _x_lin(self) -> np.ndarray:
        """The vehicle state where landmark Jacobians are evaluated: the current one with the position
        of the propagation (first-estimates Jacobians for the heading, see the module docstring)."""
        x = self.state.xv[:NX].copy()
        x[POS] = self._p_fe
        return x

    def _nav_update(self, u: mdl.NavUpdate) -> None:
        self.state.update_vehicle(u.innovation, u.H, u.R, nis=False)
        self._wrap_vehicle()

    def _wrap_vehicle(self) -> None:
        x = self.state.xv
        x[3] = geo.wrap_angle(x[3])
        x[5] = geo.wrap_angle(x[5])

    # ------------------------------------------------------------------ measurements
    def process_measurement(self, measurement: Measurement) -> None:
        m = measurement
        if self.state is None:
            self._try_initialise(m)
            return
        if isinstance(m, GroundTruthPose):
            return
        if m.stamp < self.t:
            self._warn_once("late", f"measurement older than the filter state dropped ({m.sensor})")
            return
        self._predict_to(m.stamp)
        if isinstance(m, Attitude):
            self._attitude(m)
        elif isinstance(m, DvlVelocity):
            if m.valid and np.isfinite(m.velocity).all():
                R_BS, t_BS = self._extrinsic(m.sensor)
                self._nav_update(mdl.dvl_update(self.state.xv, m.velocity, m.covariance, R_BS, t_BS, self._omega))
        elif isinstance(m, Depth):
            _, t_BS = self._extrinsic(m.sensor)
            self._nav_update(mdl.depth_update(self.state.xv, m.depth, m.variance, t_BS))
        self._record(m.stamp)

    def _try_initialise(self, m: Measurement) -> None:
        if isinstance(m, Depth):
            self._last_depth = m.depth
        if isinstance(m, GroundTruthPose) and self._wait_gt:
            R = Rotation.from_quat(m.orientation).as_matrix()
            self._initialise(m.stamp, np.asarray(m.position), R, np.full(3, self.initial.position_sigma_m))
        elif isinstance(m, Attitude) and not self._wait_gt:
            R_BS, _ = self._extrinsic(m.sensor)
            R_WB = Rotation.from_quat(m.orientation).as_matrix() @ R_BS.T
            z = self._last_depth if self._last_depth is not None else 0.0
            sig = np.array(
                [self.initial.position_sigma_m] * 2
                + [self.initial.position_sigma_m if self._last_depth is not None else 10.0]
            )
            self._initialise(m.stamp, np.array([0.0, 0.0, z]), R_WB, sig)
            self._attitude(m)

    def _attitude(self, m: Attitude) -> None:
        R_BS, _ = self._extrinsic(m.sensor)
        R_WS, omega, e_B, cov_B = _ahrs_reading(m, self.metadata, R_BS)
        if omega is not None:
            self._omega = omega
            self._omega_stamp = m.stamp
        elif self._last_att is not None and m.stamp > self._last_att[0]:
            # no rate in the message: the body rate from consecutive attitudes
            dt = (m.stamp - self._last_att[0]) * NS
            R_prev = self._last_att[1] @ R_BS.T
            self._omega = geo.so3_log(R_prev.T @ (R_WS @ R_BS.T)) / dt
            self._omega_stamp = m.stamp
        self._last_att = (m.stamp, R_WS)
        if self.nv > NX:
            self._nav_update(mdl.biased_attitude_update(self.state.xv, e_B, cov_B))
        else:
            self._nav_update(mdl.attitude_update(self.state.xv, e_B, cov_B))

    # --------------------------------------------------------------------------- records
    def _record(self, stamp: int) -> None:
        x, P = self.state.xv.copy(), self.state.Pvv.copy()
        tr = self._traj
        if tr["t"] and tr["t"][-1] == stamp:
            for k in tr:
                tr[k].pop()
        tr["t"].append(stamp)
        tr["x"].append(x)
        tr["P"].append(P)
        hs, hp = self._veh_hist
        if not hs or (stamp - hs[-1]) * NS >= self.cfg.history_period_s:
            hs.append(stamp)
            hp.append(P)

    # ---------------------------------------------------------------------- observations
    def _prepare(self, observations: Sequence[Observation]) -> list[_Obs]:
        out: list[_Obs | None] = []
        lines: list[tuple[int, LineObservation]] = []  # (slot in out, observation): modelled in one batch
        for o in observations:
            if isinstance(o, PointObservation):
                R_BS, t_BS = self._extrinsic(o.sensor)
                if np.isfinite(o.position).all():
                    out.append(_Obs(o, R_BS, t_BS))
            elif isinstance(o, LineObservation):
                self._extrinsic(o.sensor)  # an unknown sensor is a user error
                if not (np.isfinite(o.p).all() and np.isfinite(o.q).all()):
                    continue
                if np.linalg.norm(o.q - o.p) < self.cfg.line_min_length_m:
                    continue
                lines.append((len(out), o))
                out.append(None)
            else:
                self._warn_once(type(o).__name__, f"{type(o).__name__} is not used by the {self.name} filter")
        if lines:
            ls = [o for _, o in lines]
            m, d, U, rho, cov = bt.line_observation_models(
                np.array([o.p for o in ls]), np.array([o.q for o in ls]), np.array([o.covariance for o in ls])
            )
            poses: dict[str, tuple] = {}
            for k, (slot, o) in enumerate(lines):
                if rho[k] < self.cfg.line_min_distance_m:
                    self._warn_once("rho", "pipe observations through the sensor origin ignored (ρ ≈ 0)")
                    continue
                R_BS, t_BS = self._extrinsic(o.sensor)
                if o.sensor not in poses:
                    poses[o.sensor] = mdl.sensor_pose(self.state.xv, R_BS, t_BS)[:2]
                R, t = poses[o.sensor]
                line = mdl.LineObservationModel(m[k], d[k], U[k], float(rho[k]), cov[k])
                out[slot] = _Obs(o, R_BS, t_BS, line, np.array([o.p, o.q]) @ R.T + t)
        return [o for o in out if o is not None]

    def process_observations(self, stamp: int, observations: Sequence[Observation]) -> None:
        if self.state is None:
            return
        t0 = time.perf_counter()
        if stamp > self.t:
            self._predict_to(stamp)
        obs = self._prepare(observations)
        if obs:
            if self.feature_updates:
                self._slam_update(stamp, obs)
            else:
                self._place(stamp, obs)
            self._record(max(stamp, self.t))
            self._record_volumes(stamp)
        self._update_times.append(time.perf_counter() - t0)
        self._update_n.append(len(self._features) if self.feature_updates else len(self._dr_map))

    # ---------------------------------------------------------------- SLAM: association
    def _pair(self, o: _Obs, f: _Feature):
        """Linearisation of observation o against feature f, or None when they cannot pair."""
        if o.kind != f.kind:
            return None
        x = self.state.xv
        l = self.state.x[f.index : f.index + f.size]
        if f.kind == "object":
            h, H_x, H_l = mdl.point_measurement(x, l, o.R_BS, o.t_BS)
            if self._fej_yaw:
                H_x = mdl.point_measurement(self._x_lin(), f.l_first, o.R_BS, o.t_BS)[1]
            return PairLinearization(o.obs.position - h, H_x, H_l, np.asarray(o.obs.covariance))
        m_W, d_W = geo.line_plucker(l)
        if self._pipe_apart(f.extent, o.ends_W, m_W, d_W, self._object_positions()):
            return None
        nu, H_x, H_l, R = mdl.line_innovation(
            x,
            l,
            o.line,
            o.R_BS,
            o.t_BS,
            f.l_first if self._fej or self._fej_yaw else None,
            self._x_lin() if self._fej_yaw else None,
        )
        return PairLinearization(nu, H_x, H_l, R)

    def _pre_gate(self, obs: list[_Obs]) -> np.ndarray:
        """Euclidean pre-gate before the Mahalanobis tests, vectorised over the map: an observation
        (in {W} with the current pose) farther than ``pre_gate_m`` + 3 σ of the vehicle position from a
        feature (object: its position; pipe: its line) cannot pair with it. It only saves work: the
        χ² gates would reject such pairs anyway."""
        feats = self._features
        near = np.zeros((len(obs), len(feats)), bool)
        if not feats or not obs:
            return near
        x, P = self.state.x, self.state.P
        gate = self.assoc.pre_gate_m + 3.0 * math.sqrt(max(np.trace(P[POS, POS]), 0.0))
        kinds = np.array([f.kind for f in feats])
        starts = np.array([f.index for f in feats])
        obj, pip = np.flatnonzero(kinds == "object"), np.flatnonzero(kinds == "pipe")
        o_obj = [i for i, o in enumerate(obs) if o.kind == "object"]
        o_pip = [i for i, o in enumerate(obs) if o.kind == "pipe"]
        if len(obj) and o_obj:
            pos_obj = x[starts[obj, None] + np.arange(3)]
            poses = {}
            w = np.empty((len(o_obj), 3))
            for k, i in enumerate(o_obj):
                o = obs[i]
                key = o.obs.sensor
                if key not in poses:
                    poses[key] = mdl.sensor_pose(self.state.xv, o.R_BS, o.t_BS)[:2]
                R, t = poses[key]
                w[k] = t + R @ o.obs.position
            dist = np.linalg.norm(w[:, None, :] - pos_obj[None, :, :], axis=2)
            near[np.ix_(o_obj, obj)] = dist < gate
        if len(pip) and o_pip:
            lp = x[starts[pip, None] + np.arange(4)]
            U = geo.rot_batch(lp[:, :3])
            d_l = U[:, :, 1]
            c_l = np.cross(d_l, lp[:, 3:4] * U[:, :, 0])  # closest points d × m
            mid = np.array([obs[i].ends_W.mean(axis=0) for i in o_pip])
            r = mid[:, None, :] - c_l[None, :, :]  # (n_obs, n_pipes, 3)
            off = r - np.einsum("opk,pk->op", r, d_l)[:, :, None] * d_l[None, :, :]
            near[np.ix_(o_pip, pip)] = np.linalg.norm(off, axis=2) < gate
        return near

    def _object_positions(self) -> np.ndarray:
        """Mapped and tentative objects in {W} (N×3), the separators of collinear pipes."""
        x = self.state.x
        pts = [x[f.index : f.index + 3] for f in self._features if f.kind == "object"]
        pts += [t.mean for t in self._tracks if t.kind == "object"]
        return np.array(pts).reshape(-1, 3)

    def _pipe_apart(
        self,
        extent: PipeExtent,
        ends_W: np.ndarray,
        m: np.ndarray,
        d: np.ndarray,
        objects: np.ndarray,
        mapped: np.ndarray | None = None,
    ) -> bool:
        """A segment cannot be this pipe: beyond the gap from its seen extent, or across an object.
        The extent is cut at mapped in-line objects (as the graph's; ``mapped``: their positions
        when already known): a pipe seen through a socket or a tee must not keep the views of the
        pipe beyond it. (The cut extent is computed once, for both tests.)"""
        mapped = self._mapped_object_positions() if mapped is None else mapped
        a = self.assoc
        c = geo.closest_point(m, d)
        return extent.excludes(ends_W, c, d, objects, mapped, a.inline_object_radius_m, a.pipe_extent_gap_m)

    def _mapped_object_positions(self) -> np.ndarray:
        idx = [f.index for f in self._features if f.kind == "object"]
        if not idx:
            return np.zeros((0, 3))
        return self.state.x[np.array(idx)[:, None] + np.arange(3)]

    def _slam_update(self, stamp: int, obs: list[_Obs]) -> None:
        scan = _ScanPairs(self, obs, max(self.assoc.confidence, self.assoc.track_gate_confidence))
        pairs = scan.associate(self.assoc.confidence)
        paired = [(o, self._features[j]) for o, j in zip(obs, pairs) if j is not None]
        lins = [scan.linearisation(i, j) for i, j in enumerate(pairs) if j is not None]
        # ambiguous rather than new: compatible with a mapped feature at the looser track gate, on
        # the linearisation the pairings were decided on
        near = scan.near(self.assoc.track_gate_confidence)
        if paired:
            self._joint_update(paired, lins)
        for o, f in paired:
            self.book.observe(f.id, stamp, o.obs)
            if f.kind == "pipe":  # save the segment seen now (placed with the updated pose)
                R, t, _, _ = mdl.sensor_pose(self.state.xv, o.R_BS, o.t_BS)
                f.extent.add(np.array([o.obs.p, o.obs.q]) @ R.T + t, along_sigma(o.obs))
        unpaired = [i for i, j in enumerate(pairs) if j is None and not near[i]]
        on_pipe = self._on_mapped_pipe([obs[i] for i in unpaired])
        n_before = len(self._features)
        self._tentative(stamp, [obs[i] for i, on in zip(unpaired, on_pipe) if not on])
        touched = {f.id for _, f in paired} | {f.id for f in self._features[n_before:]}
        self._merge_duplicate_objects(touched)
        self._merge_duplicate_pipes(touched)

    def _merge_duplicate_objects(self, touched: set[int] | None = None) -> None:
        """Two mapped objects whose difference is compatible with zero (χ² at the association
        confidence, with their full joint covariance) are one object seen twice: fuse them with the
        constraint l_a = l_b and drop the younger block. Map management for the duplicates that
        outlying views can start (views that failed every gate against the object they were of).
        ``touched``: ids of the objects updated or added now (only pairs with one of them are tested)."""
        objs = [k for k, f in enumerate(self._features) if f.kind == "object"]
        if len(objs) < 2:
            return
        rows = (
            np.arange(len(objs))
            if touched is None
            else np.array([r for r, k in enumerate(objs) if self._features[k].id in touched], int)
        )
        if not len(rows):
            return
        x, P = self.state.x, self.state.P
        idx = np.array([self._features[k].index for k in objs])[:, None] + np.arange(3)
        pos = x[idx]
        close = np.linalg.norm(pos[rows][:, None] - pos[None], axis=2) < self.assoc.pre_gate_m
        close &= rows[:, None] != np.arange(len(objs))[None, :]
        ra, b = np.nonzero(close)
        a = rows[ra]
        keep_pair = (a < b) | ~np.isin(b, rows)  # each pair once
        a, b = a[keep_pair], b[keep_pair]
        if not len(a):
            return
        D = pos[a] - pos[b]
        S = P[idx[a][:, :, None], idx[a][:, None, :]] + P[idx[b][:, :, None], idx[b][:, None, :]]
        Pab = P[idx[a][:, :, None], idx[b][:, None, :]]
        S = S - Pab - np.transpose(Pab, (0, 2, 1))
        nis = np.einsum("ki,ki->k", D, np.linalg.solve(S, D[..., None])[..., 0])
        k = int(np.argmin(nis))
        if not nis[k] < chi2_gate(self.assoc.confidence, 3):
            return
        fa, fb = self._features[objs[a[k]]], self._features[objs[b[k]]]
        keep, drop = (fa, fb) if fa.id < fb.id else (fb, fa)
        self._fuse_duplicate(keep, drop, x[drop.cols] - x[keep.cols], -np.eye(3), np.eye(3))

    def _merge_duplicate_pipes(self, touched: set[int]) -> None:
        """Two mapped pipes that are one pipe seen twice (two tracks started on parts of it that did
        not overlap yet): the paper's collinearity criterion between them (angle, distance, extent
        gap, no object between), and either their line difference compatible with zero (χ² at the
        association confidence, full joint covariance: fused as objects are) or the two sharing a
        stretch of pipe (:meth:`_same_stretch`: the younger is dropped). The stretch rule catches
        what the χ² test leaves: two estimates of one short pipe can disagree by 5–8° with line
        covariances overconfident by then (NIS 100–450 on the tank), yet two pipes cannot share a
        stretch closer than a diameter. The younger's extent and views go to the older."""
        pipes = [f for f in self._features if f.kind == "pipe"]
        if len(pipes) < 2 or not any(f.id in touched for f in pipes):
            return
        x, P = self.state.x, self.state.P
        lp = x[np.array([f.index for f in pipes])[:, None] + np.arange(4)]
        U = geo.rot_batch(lp[:, :3])
        dirs, closest = U[:, :, 1], np.cross(U[:, :, 1], lp[:, 3:4] * U[:, :, 0])
        mids = np.array([f.extent.centre() for f in pipes])
        objects = None
        gate = chi2_gate(self.assoc.confidence, 4)
        best = None
        for a, fa in enumerate(pipes):
            if fa.id not in touched:
                continue
            m_a, d_a = lp[a, 3] * U[a, :, 0], dirs[a]
            # cheap screen over the map: near a's direction, b's seen middle near a's line
            r = mids - closest[a]
            off = np.linalg.norm(r - np.outer(r @ d_a, d_a), axis=1)
            screen = (np.abs(dirs @ d_a) >= math.cos(self.assoc.merge_angle_rad)) & (off <= self.assoc.merge_distance_m)
            for b in np.flatnonzero(screen):
                fb = pipes[b]
                if fb is fa or (fb.id in touched and fb.id < fa.id):  # each pair once
                    continue
                ends_b = fb.extent.ends(closest[b], dirs[b])
                objects = self._object_positions() if objects is None else objects
                if not self._on_pipe(ends_b, fa.extent, m_a, d_a, objects):
                    continue
                nu, H_a, H_b = geo.line_difference(lp[a], lp[b])
                cols = np.r_[fa.cols, fb.cols]
                H = np.hstack([H_a, H_b])
                nis = float(nu @ np.linalg.solve(H @ P[np.ix_(cols, cols)] @ H.T, nu))
                if nis >= gate and not self._same_stretch(fa.extent, ends_b, m_a, d_a):
                    continue
                if best is None or nis < best[0]:
                    best = (nis, fa, fb, nu, H_a, H_b)
        if best is None:
            return
        nis, fa, fb, nu, H_a, H_b = best
        keep, drop, H_keep, H_drop = (fa, fb, H_a, H_b) if fa.id < fb.id else (fb, fa, H_b, H_a)
        # two estimates that fail the χ² test are not fused: the constraint would pull the state (the
        # vehicle too) across a disagreement their covariances call impossible; the younger is dropped
        self._fuse_duplicate(keep, drop, nu, H_keep, H_drop, constrain=nis < gate)
        keep.extent.merge(drop.extent)
        x = self.state.x
        x[keep.index : keep.index + 3] = geo.wrap(x[keep.index : keep.index + 3])

    def _same_stretch(self, extent: PipeExtent, ends_b: np.ndarray, m: np.ndarray, d: np.ndarray) -> bool:
        """Segment ends_b shares over half of the shorter stretch with the seen extent of the pipe (m, d),
        its ends within ``association.duplicate_pipe_distance_m`` of that pipe's axis."""
        c = geo.closest_point(m, d)
        return (
            off_axis(ends_b, c, d) <= self.assoc.duplicate_pipe_distance_m
            and extent.overlap_fraction(ends_b, c, d) >= 0.5
        )

    def _fuse_duplicate(
        self,
        keep: _Feature,
        drop: _Feature,
        diff: np.ndarray,
        H_keep: np.ndarray,
        H_drop: np.ndarray,
        constrain: bool = True,
    ) -> None:
        """Impose keep = drop (their difference ``diff`` with Jacobians H_keep, H_drop, as a perfect
        measurement of zero) unless not ``constrain``, then drop the younger block (marginalise it
        out); its views and class evidence go to keep."""
        if constrain:
            cols = np.r_[keep.cols, drop.cols]
            self.state.update(-diff, cols, np.hstack([H_keep, H_drop]), np.eye(len(diff)) * 1e-12)
            self._wrap_vehicle()
        self.state.remove(drop.index, drop.size)
        self._features.remove(drop)
        for f in self._features:
            if f.index > drop.index:
                f.index -= drop.size
        self.book.merge(keep.id, drop.id)
        self._merged += 1

    def _on_mapped_pipe(self, obs: list[_Obs]) -> np.ndarray:
        """Per observation: a pipe view on a mapped pipe by :meth:`_on_pipe`."""
        out = np.zeros(len(obs), bool)
        pipes = [f for f in self._features if f.kind == "pipe"]
        todo = [i for i, o in enumerate(obs) if o.kind == "pipe"]
        if pipes and todo:
            x = self.state.x
            lines = [geo.line_plucker(x[f.index : f.index + 4]) for f in pipes]
            objects = self._object_positions()
            for i in todo:
                out[i] = any(self._on_pipe(obs[i].ends_W, f.extent, m, d, objects) for f, (m, d) in zip(pipes, lines))
        return out

    def _on_pipe(
        self, ends_W: np.ndarray, extent: PipeExtent, m: np.ndarray, d: np.ndarray, objects: np.ndarray
    ) -> bool:
        """The paper's collinear merge (shared ``association.merge_angle_rad`` / ``merge_distance_m``): the
        segment is within that angle of the pipe's axis, both its ends within that distance of it, within
        the extent gap and not across an object."""
        u = ends_W[1] - ends_W[0]
        u = u / np.linalg.norm(u)
        if abs(float(u @ d)) < math.cos(self.assoc.merge_angle_rad):
            return False
        if off_axis(ends_W, geo.closest_point(m, d), d) > self.assoc.merge_distance_m:
            return False
        return not self._pipe_apart(extent, ends_W, m, d, objects)

    def _joint_update(self, paired: list[tuple[_Obs, _Feature]], lins: list | None = None) -> None:
        """One EKF update with every paired observation stacked (H sparse: vehicle + those features)."""
        if lins is None:
            lins = [self._pair(o, f) for o, f in paired]
        cols = np.concatenate([np.arange(NX)] + [f.cols for _, f in paired])
        D = sum(len(p.innovation) for p in lins)
        H = np.zeros((D, len(cols)))
        R = np.zeros((D, D))
        nu = np.zeros(D)
        r, c = 0, NX
        for p, (_, f) in zip(lins, paired):
            d = len(p.innovation)
            H[r : r + d, :NX] = p.H_x
            H[r : r + d, c : c + f.size] = p.H_l
            R[r : r + d, r : r + d] = p.R
            nu[r : r + d] = p.innovation
            r, c = r + d, c + f.size
        self.state.update(nu, cols, H, R)
        self._wrap_vehicle()
        x = self.state.x
        for _, f in paired:
            if f.kind == "pipe":  # keep the Euler angles of the line in range
                x[f.index : f.index + 3] = geo.wrap(x[f.index : f.index + 3])

    # ------------------------------------------------------------ SLAM: new features
    def _world(self, o: _Obs):
        """The observation in {W} with the current pose: (mean, covariance, Jacobians for augmentation)."""
        x, Pvv = self.state.xv, self.state.P[:NX, :NX]
        if o.kind == "object":
            l, G_x, G_z = mdl.point_initialise(x, o.obs.position, o.R_BS, o.t_BS)
            cov = G_x @ Pvv @ G_x.T + G_z @ o.obs.covariance @ G_z.T
            return l, cov
        m_W, d_W, Jx, Jpq = mdl.line_world(x, o.obs.p, o.obs.q, o.R_BS, o.t_BS)
        U, rho = geo.orthonormal_from_plucker(m_W, d_W)
        A = geo.line_error_map(U, rho)
        Gx, Gz = A @ Jx, A @ Jpq
        return np.r_[m_W, d_W], Gx @ Pvv @ Gx.T + Gz @ o.obs.covariance @ Gz.T

    def _track_nis(
        self, tr: _Track, o: _Obs, mean: np.ndarray, cov: np.ndarray, objects=None, below: float = math.inf
    ) -> float:
        """NIS of observation o (in {W}: mean, cov) against tentative feature tr; inf when they cannot
        be one (other kind; pipes: beyond the seen extent or across an object). ``objects`` (the
        separators, or a callable giving them) is only needed for a pipe whose NIS is below ``below``."""
        if tr.kind != o.kind:
            return math.inf
        if tr.kind == "object":
            nu = mean - tr.mean
        else:
            m_t, d_t = tr.mean[:3], tr.mean[3:]
            m_o, d_o = mean[:3], mean[3:]
            if d_o @ d_t < 0:
                m_o, d_o = -m_o, -d_o
                D = np.array([-1.0, -1.0, 1.0, 1.0])
                cov = cov * np.outer(D, D)
            U_t, rho_t = geo.orthonormal_from_plucker(m_t, d_t)
            U_o, rho_o = geo.orthonormal_from_plucker(m_o, d_o)
            nu = np.append(geo.so3_log(U_t.T @ U_o), rho_o - rho_t)
        S = tr.cov + cov
        try:
            nis = float(nu @ np.linalg.solve(S, nu))
        except np.linalg.LinAlgError:
            return math.inf
        if tr.kind == "pipe" and nis < below:
            if objects is None:
                objects = self._object_positions()
            elif callable(objects):
                objects = objects()
            if self._pipe_apart(tr.extent, o.ends_W, m_t, d_t, objects):
                return math.inf
        return nis

    def _tentative(self, stamp: int, new: list[_Obs]) -> None:
        """Unpaired observations extend or start tentative features; confirmed ones join the state."""
        horizon = self.assoc.track_timeout_s / NS
        for t in self._tracks:
            if stamp - t.last_stamp > horizon:
                self.book.forget(("track", t.key))
        self._tracks = [t for t in self._tracks if stamp - t.last_stamp <= horizon]
        used: set[int] = set()
        memo: list = [None]  # the separators, recomputed only after an object changed

        def objects() -> np.ndarray:
            if memo[0] is None:
                memo[0] = self._object_positions()
            return memo[0]

        for o in new:
            mean, cov = self._world(o)
            best, best_nis = None, chi2_gate(self.assoc.track_gate_confidence, 3 if o.kind == "object" else 4)
            for k, tr in enumerate(self._tracks):
                if k in used or tr.kind != o.kind:
                    continue
                nis = self._track_nis(tr, o, mean, cov, objects, below=best_nis)
                if nis < best_nis:
                    best, best_nis = k, nis
            if best is None:
                tr = _Track(
                    o.kind, mean, cov, 1, stamp, PipeExtent() if o.kind == "pipe" else None, key=self._next_track
                )
                self._next_track += 1
                tr.fuse(mean, cov)
                self._tracks.append(tr)
                used.add(len(self._tracks) - 1)
            else:
                tr = self._tracks[best]
                used.add(best)
                tr.fuse(mean, cov)
                tr.n, tr.last_stamp = tr.n + 1, stamp
            self.book.observe(("track", tr.key), stamp, o.obs)
            if tr.kind == "pipe":
                tr.extent.add(o.ends_W, along_sigma(o.obs))
            if tr.n >= self.assoc.min_observations:
                self._add_feature(o, tr)
                tr.n = -1  # consumed
            if o.kind == "object":
                memo[0] = None
        self._tracks = [t for t in self._tracks if t.n >= 0]

    def _add_feature(self, o: _Obs, tr: _Track) -> None:
        x = self.state.xv
        init = mdl.point_initialise if o.kind == "object" else mdl.line_initialise
        z = (o.obs.position,) if o.kind == "object" else (o.obs.p, o.obs.q)
        l, G_x, G_z = init(x, *z, o.R_BS, o.t_BS)
        l_first = l
        if self._fej_yaw:  # Jacobians at the propagated pose, the first estimate as it places the feature
            l_first, G_x, G_z = init(self._x_lin(), *z, o.R_BS, o.t_BS)
        idx = self.state.augment(l, G_x, G_z, np.asarray(o.obs.covariance))
        self._features.append(
            _Feature(
                self._next_id,
                o.kind,
                idx,
                len(l),
                extent=tr.extent,
                l_first=np.array(l_first, float),
            )
        )
        self.book.merge(self._next_id, ("track", tr.key))
        self._next_id += 1

    # --------------------------------------------------------------------- dead reckoning
    def _place(self, stamp: int, obs: list[_Obs]) -> None:
        """Dead reckoning: every observation becomes its own map entry, placed with the DR pose."""
        x, Pvv = self.state.xv, self.state.Pvv[:NX, :NX]  # the Jacobians' bias column is zero
        entries: list[tuple] = []  # (index, kind, l or (p, q), cov, observation)
        for _sensor, group in _by_sensor(obs, "object"):  # objects: one batch per sensor
            o0 = obs[group[0]]
            Z = np.array([obs[i].obs.position for i in group])
            R, t, R_WB, E = bt.sensor_pose(x, o0.R_BS, o0.t_BS)
            L = Z @ R.T + t
            G_x = np.empty((len(group), 3, NX))
            G_x[:] = bt._dt_dx(R_WB, E, o0.t_BS)
            G_x[:, :, ATT] -= R @ bt.skew_batch(Z) @ (o0.R_BS.T @ E)
            C = np.array([obs[i].obs.covariance for i in group])
            cov = G_x @ Pvv @ np.transpose(G_x, (0, 2, 1)) + R @ C @ R.T
            entries += [(i, "object", l, c, obs[i]) for i, l, c in zip(group, L, cov)]
        for i, o in enumerate(obs):
            if o.kind == "pipe":
                l, G_x, G_pq = mdl.line_initialise(x, o.obs.p, o.obs.q, o.R_BS, o.t_BS)
                cov = G_x @ Pvv @ G_x.T + G_pq @ o.obs.covariance @ G_pq.T
                m_W, d_W = geo.line_plucker(l)
                entries.append((i, "pipe", geo.project_on_line(o.ends_W, m_W, d_W), cov, o))
        entries.sort(key=lambda e: e[0])  # ids in observation order
        vols = {3: None, 4: None}
        for size in (3, 4):
            covs = [e[3] for e in entries if len(e[3]) == size]
            if covs:
                vols[size] = iter(np.linalg.slogdet(np.array(covs))[1])
        stamps = np.array([stamp], np.int64)
        for _, kind, val, cov, o in entries:
            self.book.observe(self._next_id, stamp, o.obs)
            if kind == "object":
                lm = LandmarkEstimate(
                    self._next_id,
                    "object",
                    position=val,
                    covariance=cov,
                    class_posterior=self.book.class_posterior(self._next_id),
                    n_observations=1,
                )
            else:
                lm = LandmarkEstimate(self._next_id, "pipe", p=val[0], q=val[1], covariance=cov, n_observations=1)
            self._dr_map.append(lm)
            self._dr_vol[self._next_id] = (stamps, np.array([next(vols[len(cov)])]))
            self._next_id += 1

    # ------------------------------------------------------------------------- history
    def _record_volumes(self, stamp: int) -> None:
        """Uncertainty volume (Σ log eigenvalues = log det) of every feature block (Figs. 11–12)."""
        if not self._features:
            return
        P = self.state.P
        for size in (3, 4):
            fs = [f for f in self._features if f.size == size]
            if not fs:
                continue
            idx = np.array([f.cols for f in fs])
            blocks = P[idx[:, :, None], idx[:, None, :]]
            vols = np.log(np.clip(np.linalg.eigvalsh(blocks), 1e-300, None)).sum(axis=1)
            for f, v in zip(fs, vols):
                f.vol_stamps.append(stamp)
                f.vol.append(float(v))

    # ------------------------------------------------------------------------- outputs
    def _landmark(self, f: _Feature) -> LandmarkEstimate:
        x, P = self.state.x, self.state.P
        l = x[f.index : f.index + f.size].copy()
        cov = P[np.ix_(f.cols, f.cols)].copy()
        if f.kind == "object":
            return LandmarkEstimate(
                f.id,
                "object",
                position=l,
                covariance=cov,
                class_posterior=self.book.class_posterior(f.id),
                n_observations=self.book.n_views(f.id),
            )
        m, d = geo.line_plucker(l)
        p, q = f.extent.ends(
            geo.closest_point(m, d), d, self._mapped_object_positions(), self.assoc.inline_object_radius_m
        )
        return LandmarkEstimate(f.id, "pipe", p=p, q=q, covariance=cov, n_observations=self.book.n_views(f.id))

    def landmarks(self) -> list[LandmarkEstimate]:
        if not self.feature_updates:
            return list(self._dr_map)
        return [self._landmark(f) for f in self._features]

    def pose_at(self, stamp: int) -> np.ndarray | None:
        """T_WB at ``stamp``: predicted forward from the current state, or the recorded estimate nearest
        in time for a past stamp."""
        if self.state is None:
            return None
        if stamp >= self.t:
            x = self.state.xv[:NX].copy()
            dt = (stamp - self.t) * NS
            if dt > 0:
                x = mdl.predict(x, self._omega, dt, self.motion.accel_sigma_m_s2, self.motion.angular_rate_sigma_rad_s)[
                    0
                ]
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

    def view(self) -> EkfEstimator:
        return self  # pose_at / landmarks: the EstimateView protocol

    def finish(self) -> EstimatorResult:
        tr = self._traj
        if not tr["t"]:
            empty = Trajectory(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 4)))
            return EstimatorResult(self.name, empty, diagnostics=self._diag + ["the filter was never initialised"])
        X, P = np.array(tr["x"]), np.array(tr["P"])
        quats = Rotation.from_euler("ZYX", X[:, ATT][:, ::-1]).as_quat()
        traj = Trajectory(
            stamps=np.array(tr["t"], np.int64),
            positions=X[:, POS].copy(),
            orientations=quats,
            position_cov=P[:, POS, POS].copy(),
            velocities=X[:, VEL].copy(),
            velocity_cov=P[:, VEL, VEL].copy(),
        )
        if self.feature_updates:
            volumes = {f.id: (np.array(f.vol_stamps, np.int64), np.array(f.vol)) for f in self._features}
            kinds = {f.id: f.kind for f in self._features}
        else:
            volumes = dict(self._dr_vol)
            kinds = {lm.id: lm.kind for lm in self._dr_map}
        history = {
            "landmark_volume": volumes,
            "landmark_kind": kinds,
            "vehicle_cov": (np.array(self._veh_hist[0], np.int64), np.array(self._veh_hist[1])),
            **self.book.history(kinds),
        }
        landmarks = self.landmarks()
        if self.feature_updates:  # dead reckoning's map is every observation on its own: nothing to connect
            self.book.connect(landmarks, self.assoc.merge_distance_m)
        if self.nv > NX:  # the AHRS heading bias estimate and its σ (rad) over time
            history["heading_bias"] = (traj.stamps, X[:, BIAS].copy(), np.sqrt(P[:, BIAS, BIAS]))
        return EstimatorResult(
            name=self.name,
            trajectory=traj,
            landmarks=landmarks,
            online_trajectory=traj,  # a filter's estimate at each time is its online estimate
            update_times_s=np.array(self._update_times),
            update_n_landmarks=np.array(self._update_n, int),
            history=history,
            diagnostics=list(self._diag),
        )


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


class DeadReckoning(EkfEstimator):
    """The same filter with the feature updates disabled; its map is every observation placed with the
    dead-reckoning pose (the paper's Figure 10a)."""

    name = "dr"
    feature_updates = False

    def __init__(self, metadata: MissionMetadata, config: SemslamConfig | None = None):
        super().__init__(metadata, config)
        self._dr_vol: dict[int, tuple[np.ndarray, np.ndarray]] = {}
