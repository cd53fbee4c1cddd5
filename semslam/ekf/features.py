"""The filter's map: object points and pipe lines (Vallicrosa et al. 2021, eqs. 2–16) as blocks of the
state, and what the shared map building (:mod:`semslam.mapping.builder`) asks of them.

Association: every pair of a batch is linearised in one vectorised pass (:class:`ScanPairs`), and the
shared JCBB runs on their full joint covariance (:class:`~semslam.mapping.association.DenseJoint`). The
paired observations are one joint EKF update (Joseph form). A tentative feature enters the state from
its latest view with the full cross-covariances (eqs. 39–45); with ``association.min_observations = 1``
this is the paper's flow.

Pipe Jacobians are evaluated at each pipe's first estimate (FEJ, Huang, Mourikis & Roumeliotis 2008;
``ekf.line_jacobians``): a pipe's world-origin line parameters change under a common translation of
vehicle and map in a way that depends on their estimate, so Jacobians at the current estimate let a
sequence of updates observe that translation, spurious absolute-position information that makes the
filter overconfident. Objects (points) have no such dependence. For the same reason two features of
one pipe are merged by their difference as seen from the vehicle, not by the difference of their
world-origin parameters (:meth:`FeatureMap.merge`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from semslam.config import SemslamConfig
from semslam.ekf import batch as bt
from semslam.ekf import geometry as geo
from semslam.ekf import models as mdl
from semslam.ekf.models import NX, POS
from semslam.ekf.navigation import FilterNavigation
from semslam.ekf.observations import Prepared, by_sensor, prepare
from semslam.estimation import LandmarkEstimate
from semslam.mapping.association import Candidates, DenseJoint, PairLinearization, chi2_gate
from semslam.mapping.book import LandmarkBook
from semslam.mapping.builder import Scan
from semslam.mapping.fittings import port_depths
from semslam.mapping.tracks import Track
from semslam.observations import Observation, StructureObservation

_I3, _Z3 = np.eye(3), np.zeros(3)  # {B} itself as the "sensor" (a pipe seen from the vehicle)
# A pipe's moment is about a point this far from its first view, square to it (geometry.line_anchor): the
# distance at which the tank's level pipes lie below the world origin, where the origin's chart works.
LINE_ANCHOR_DISTANCE_M = 4.0


@dataclass
class Feature:
    """A mapped feature: its block of the state."""

    id: int
    kind: str  # "object" | "pipe"
    index: int  # first state index
    size: int
    l_first: np.ndarray  # the estimate it entered the state with (first-estimates Jacobians)
    anchor: np.ndarray = field(default_factory=lambda: np.zeros(3))  # pipes: the point their moment is about
    vol_stamps: list[int] = field(default_factory=list)
    vol: list[float] = field(default_factory=list)

    @property
    def cols(self) -> np.ndarray:
        return np.arange(self.index, self.index + self.size)

    def world_line(self, l: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """A pipe's line in {W} from its parameters ``l`` (moment about its anchor): (the point
        nearest the origin, the unit direction)."""
        m, d = geo.anchored_plucker(l, self.anchor)
        return geo.closest_point(m, d), d


class FeatureMap:
    """The features of the filter (:class:`semslam.mapping.builder.LandmarkState`)."""

    def __init__(self, nav: FilterNavigation, config: SemslamConfig, book: LandmarkBook):
        self.nav = nav
        self.cfg = config.ekf
        self.assoc = config.association
        self.book = book
        self.fej_lines = self.cfg.line_jacobians == "first_estimate"
        self.features: list[Feature] = []
        self._next_id = 0
        self._prepared: dict[int, Prepared] = {}  # the batch's observations, by object identity

    def __len__(self) -> int:
        return len(self.features)

    def feature(self, lid: int) -> Feature:
        return next(f for f in self.features if f.id == lid)

    # ------------------------------------------------------------------ for the map building
    def prepared(self, observations: list[Observation]) -> list[Prepared]:
        """The batch's observations prepared with the current pose (once each; see :func:`prepare`)."""
        todo = [z for z in observations if id(z) not in self._prepared]
        for p in prepare(self.nav, todo, self.cfg.line_min_distance_m):
            self._prepared[id(p.obs)] = p
        return [self._prepared[id(z)] for z in observations if id(z) in self._prepared]

    def begin(self) -> None:
        self._prepared = {}

    def usable(self, z: Observation) -> bool:
        if isinstance(z, StructureObservation):
            self.nav.warn_once("structure", "StructureObservation is not used by the filters")
            return False
        return bool(self.prepared([z]))

    def sensor_pose(self, sensor: str) -> np.ndarray:
        R_BS, t_BS = self.nav.extrinsic(sensor)
        R, t, _, _ = mdl.sensor_pose(self.nav.state.xv, R_BS, t_BS)
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R, t
        return T

    def place(self, z: Observation) -> tuple:
        """The observation in {W} with the current pose: an object's position and its covariance (the
        vehicle's included, all of it independent from view to view: no drifting part, see
        :class:`~semslam.mapping.tracks.TrackView`), a pipe segment's ends; and the prepared
        observation. The filter's pose is corrected, not smoothed, and a track's views of one object
        wander more between scans than the growth of its covariance: split as the graph's, tank world
        79's EKF ATE went 0.069 → 0.179 m (experiments/estimators/README.md, stop 37). A mixed track
        does not bend its trajectory: a feature starts from the track's latest view only."""
        (o,) = self.prepared([z])
        x = self.nav.state.xv
        if o.kind == "object":
            l, G_x, G_z = mdl.point_initialise(x, o.obs.position, o.R_BS, o.t_BS)
            Pvv = self.nav.state.P[:NX, :NX]
            return l, G_x @ Pvv @ G_x.T + G_z @ o.obs.covariance @ G_z.T, o, None, None
        R, t, _, _ = mdl.sensor_pose(x, o.R_BS, o.t_BS)
        return np.array([o.obs.p, o.obs.q]) @ R.T + t, None, o, None, None

    def objects(self) -> tuple[list[int], np.ndarray]:
        fs = [f for f in self.features if f.kind == "object"]
        if not fs:
            return [], np.zeros((0, 3))
        return [f.id for f in fs], self.nav.state.x[np.array([f.index for f in fs])[:, None] + np.arange(3)]

    def pipes(self) -> list[tuple[int, np.ndarray, np.ndarray]]:
        x = self.nav.state.x
        out = []
        for f in self.features:
            if f.kind == "pipe":
                out.append((f.id, *f.world_line(x[f.cols])))
        return out

    def candidates(
        self, observations: list[Observation], confidence: float, scan: Scan
    ) -> tuple[Candidates, list[int]]:
        obs = self.prepared(observations)
        index = {id(z): i for i, z in enumerate(observations)}
        pairs = ScanPairs(self, obs, confidence, scan)
        found = Candidates(
            len(observations),
            np.array([index[id(obs[i].obs)] for i in pairs.obs], int),
            pairs.feat,
            [PairLinearization(*v) for v in zip(pairs.nu, pairs.H_x, pairs.H_l, pairs.R)],
            pairs.nis,
        )
        return found, [f.id for f in self.features]

    def joint(self, found: Candidates) -> DenseJoint:
        """The joint covariance of every candidate's innovation: J P Jᵀ + R, J the stacked rows of the
        pairs over the vehicle and the candidate features' columns."""
        used = sorted({int(j) for j in found.lm})
        col0, cols, c = {}, [np.arange(NX)], NX
        for j in used:
            col0[j] = c
            cols.append(self.features[j].cols)
            c += self.features[j].size
        cols = np.concatenate(cols)
        D = sum(len(p.innovation) for p in found.lin)
        J = np.zeros((D, len(cols)))
        Rb = np.zeros((D, D))
        r = 0
        for j, p in zip(found.lm, found.lin):
            d, f = len(p.innovation), self.features[int(j)]
            J[r : r + d, :NX] = p.H_x
            J[r : r + d, col0[int(j)] : col0[int(j)] + f.size] = p.H_l
            Rb[r : r + d, r : r + d] = p.R
            r += d
        P = self.nav.state.P
        return DenseJoint(found, J @ P[np.ix_(cols, cols)] @ J.T + Rb)

    def update(self, paired: list[tuple[Observation, int, PairLinearization]]) -> None:
        """One EKF update with every paired observation stacked (H sparse: the vehicle and those
        features; two segments of one pipe share its columns)."""
        feats = {f.id: f for f in self.features}
        blocks: dict[int, int] = {}  # feature id → its first column in H
        c = NX
        for _, lid, _ in paired:
            if lid not in blocks:
                blocks[lid] = c
                c += feats[lid].size
        cols = np.concatenate([np.arange(NX)] + [feats[lid].cols for lid in blocks])
        D = sum(len(p.innovation) for _, _, p in paired)
        H = np.zeros((D, len(cols)))
        R = np.zeros((D, D))
        nu = np.zeros(D)
        r = 0
        for _, lid, p in paired:
            d, c0 = len(p.innovation), blocks[lid]
            H[r : r + d, :NX] = p.H_x
            H[r : r + d, c0 : c0 + feats[lid].size] = p.H_l
            R[r : r + d, r : r + d] = p.R
            nu[r : r + d] = p.innovation
            r += d
        state = self.nav.state
        state.update(nu, cols, H, R)
        self.nav.wrap_vehicle()
        for lid in blocks:
            f = feats[lid]
            if f.kind == "pipe":  # keep the Euler angles of the line in range
                state.x[f.index : f.index + 3] = geo.wrap(state.x[f.index : f.index + 3])

    def promote(self, track: Track) -> int:
        """A tentative feature joins the state, initialised from its latest view with the full
        cross-covariances (first-estimates Jacobians at the propagated pose when the heading bias is
        modelled)."""
        o: Prepared = track.views[-1].payload
        xv = self.nav.state.xv
        if o.kind == "object":
            init, z, extra = mdl.point_initialise, (o.obs.position,), ()
        else:
            ends = track.views[-1].world  # the segment in {W}, placed with the current pose
            d = ends[1] - ends[0]
            anchor = geo.line_anchor(ends.mean(axis=0), d / np.linalg.norm(d), LINE_ANCHOR_DISTANCE_M)
            init, z, extra = mdl.line_initialise, (o.obs.p, o.obs.q), (anchor,)
        l, G_x, G_z = init(xv, *z, o.R_BS, o.t_BS, *extra)
        l_first = l
        if self.nav.fej_yaw:
            l_first, G_x, G_z = init(self.nav.x_lin(), *z, o.R_BS, o.t_BS, *extra)
        idx = self.nav.state.augment(l, G_x, G_z, np.asarray(o.obs.covariance))
        lid = self._next_id
        self._next_id += 1
        self.features.append(Feature(lid, o.kind, idx, len(l), np.array(l_first, float), *extra))
        return lid

    def settle(self) -> None:
        """Every update of the filter is applied at once: nothing is pending."""

    def _difference(self, a: Feature, b: Feature) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """ν, the state columns it depends on and H = ∂ν/∂x on them: the difference of two features,
        zero when they are one.

        Objects: b − a in {W}. Pipes: the line error that takes a to b as seen from the vehicle ({B}),
        not between their world-origin parameters. A common translation (or, with the heading bias
        modelled, rotation about the vertical) of vehicle and map changes nothing seen from the
        vehicle, so with the Jacobians at the points where the filter linearises each pipe's views
        (its first estimate, the propagated position: :class:`ScanPairs`) the difference observes
        none of it, whatever the two estimates: H N = 0 for that null space N. The world-origin
        parameters of two lines that differ change differently under a translation, and a merge, a
        perfect measurement, read that as absolute position: a twin 2-3° off moved vehicle and map
        by 0.26-0.62 m (experiments/estimators/EKF.md)."""
        x = self.nav.state.x
        if a.kind == "object":
            return x[b.cols] - x[a.cols], np.r_[a.cols, b.cols], np.hstack([-np.eye(3), np.eye(3)])
        nav = self.nav
        xv = x[:NX]
        x_lin = nav.x_lin() if nav.fej_yaw else xv
        first = self.fej_lines or nav.fej_yaw
        seen = []
        for f in (a, b):
            m, d, _, _ = mdl.line_to_sensor(xv, x[f.cols], _I3, _Z3, f.anchor)  # the pipe in {B}, now
            U, rho = geo.orthonormal_from_plucker(m, d)
            m_l, d_l, J_x, J_l = mdl.line_to_sensor(x_lin, f.l_first if first else x[f.cols], _I3, _Z3, f.anchor)
            A = geo.line_error_map(*geo.orthonormal_from_plucker(m_l, d_l))
            seen.append((U, rho, A @ J_x, A @ J_l))
        (Ua, ra, Ax, Al), (Ub, rb, Bx, Bl) = seen
        nu, G_a, G_b = geo.orthonormal_difference(Ua, ra, Ub, rb)
        return nu, np.r_[np.arange(NX), a.cols, b.cols], np.hstack([G_a @ Ax + G_b @ Bx, G_a @ Al, G_b @ Bl])

    def difference_nis(self, a: int, b: int) -> float | None:
        """χ² of the two features' difference against zero, with their full joint covariance."""
        nu, cols, H = self._difference(self.feature(a), self.feature(b))
        try:
            return float(nu @ np.linalg.solve(H @ self.nav.state.P[np.ix_(cols, cols)] @ H.T, nu))
        except np.linalg.LinAlgError:
            return None

    def gating_spread(self, ids: list[int]) -> np.ndarray:
        """√trace of each object's block of the state covariance (|tr P_ab| ≤ √(tr P_aa tr P_bb) bounds
        the correlation :meth:`difference_nis` counts)."""
        var = np.diag(self.nav.state.P)
        index = {f.id: f.index for f in self.features}
        return np.sqrt(var[np.array([index[lid] for lid in ids], int)[:, None] + np.arange(3)].sum(axis=1))

    def merge(self, keep: int, drop: int, constrain: bool) -> None:
        """Impose keep = drop (their difference, :meth:`_difference`, as a perfect measurement of zero)
        unless not ``constrain`` (the constraint would pull the state, the vehicle too, across a
        disagreement their covariances call impossible), then drop the younger block (marginalise it
        out)."""
        fk, fd = self.feature(keep), self.feature(drop)
        state = self.nav.state
        if constrain:
            nu, cols, H = self._difference(fk, fd)
            state.update(-nu, cols, H, np.eye(len(nu)) * 1e-12)
            self.nav.wrap_vehicle()
        state.remove(fd.index, fd.size)
        self.features.remove(fd)
        for f in self.features:
            if f.index > fd.index:
                f.index -= fd.size
        if fk.kind == "pipe":
            state.x[fk.index : fk.index + 3] = geo.wrap(state.x[fk.index : fk.index + 3])

    # ------------------------------------------------------------------ outputs
    def record_volumes(self, stamp: int) -> None:
        """Uncertainty volume (Σ log eigenvalues = log det) of every feature block (Figs. 11–12)."""
        P = self.nav.state.P
        for size in (3, 4):
            fs = [f for f in self.features if f.size == size]
            if not fs:
                continue
            idx = np.array([f.cols for f in fs])
            vols = np.log(np.clip(np.linalg.eigvalsh(P[idx[:, :, None], idx[:, None, :]]), 1e-300, None)).sum(axis=1)
            for f, v in zip(fs, vols):
                f.vol_stamps.append(stamp)
                f.vol.append(float(v))

    def estimates(self) -> list[LandmarkEstimate]:
        """The map with global ids and the filter's covariances."""
        x, P = self.nav.state.x, self.nav.state.P
        ids, mapped = self.objects()
        depths = port_depths([self.book.class_posterior(i) for i in ids])
        out = []
        for f in self.features:
            l, cov = x[f.index : f.index + f.size].copy(), P[np.ix_(f.cols, f.cols)].copy()
            le = LandmarkEstimate(f.id, f.kind, covariance=cov, n_observations=self.book.n_views(f.id))
            if f.kind == "object":
                le.position, le.class_posterior = l, self.book.class_posterior(f.id)
            else:
                radius = self.assoc.inline_object_radius_m
                le.p, le.q = self.book.extent(f.id).ends(*f.world_line(l), mapped, radius, depths)
            out.append(le)
        return out


class ScanPairs:
    """Every candidate pairing of a batch's observations with the mapped features, linearised at the
    current state in one vectorised pass.

    A pair is a candidate when the observation and the feature are of one kind, the Euclidean pre-gate
    keeps it (``association.pre_gate_m`` plus 3σ of the vehicle position), its individual NIS passes
    the χ² gate at ``confidence`` and (pipes) ``scan.excludes`` does not rule it out. For each
    candidate k: ``obs[k]`` (index into the prepared observations), ``feat[k]`` (feature index),
    innovation ``nu[k]``, ``H_x[k]``, ``H_l[k]``, ``R[k]`` and its individual NIS ``nis[k]``.
    """

    def __init__(self, fmap: FeatureMap, obs: list[Prepared], confidence: float, scan: Scan):
        nav, feats = fmap.nav, fmap.features
        obs_i, feat_j, nus, Hxs, Hls, Rs, niss = [], [], [], [], [], [], []
        if feats and obs:
            near = pre_gate(fmap, obs)
            x, P = nav.state.x, nav.state.P
            Pvv = P[:NX, :NX]
            for kind in ("object", "pipe"):
                fidx = np.array([j for j, f in enumerate(feats) if f.kind == kind], int)
                if not len(fidx):
                    continue
                for _sensor, group in by_sensor(obs, kind):
                    ii, jj = np.nonzero(near[np.ix_(group, fidx)])
                    if not len(ii):
                        continue
                    oi = np.asarray(group)[ii]
                    fj = fidx[jj]
                    o0 = obs[oi[0]]
                    size = 3 if kind == "object" else 4
                    cols = np.array([feats[j].index for j in fj])[:, None] + np.arange(size)
                    if kind == "object":
                        uj, inv = np.unique(fj, return_inverse=True)
                        L = x[np.array([feats[j].index for j in uj])[:, None] + np.arange(3)]
                        h, Hx_u, Hl = bt.point_measurements(x[:NX], L, o0.R_BS, o0.t_BS)
                        if nav.fej_yaw:  # Jacobians at the first estimates (ν at the current ones)
                            L_f = np.array([feats[j].l_first for j in uj])
                            Hx_u = bt.point_measurements(nav.x_lin(), L_f, o0.R_BS, o0.t_BS)[1]
                        nu = np.array([obs[i].obs.position for i in oi]) - h[inv]
                        Hx = Hx_u[inv]
                        HlK = np.broadcast_to(Hl, (len(oi), 3, 3))
                        R = np.array([obs[i].obs.covariance for i in oi])
                    else:
                        lines = [obs[i].line for i in oi]
                        args = (
                            np.array([ln.U for ln in lines]),
                            np.array([ln.rho for ln in lines]),
                            np.array([ln.d for ln in lines]),
                            np.array([ln.cov for ln in lines]),
                            o0.R_BS,
                            o0.t_BS,
                        )
                        L_lin = np.array([feats[j].l_first for j in fj]) if fmap.fej_lines or nav.fej_yaw else None
                        nu, Hx, HlK, R = bt.line_innovations(
                            x[:NX],
                            x[cols],
                            *args,
                            L_lin=L_lin,
                            x_lin=nav.x_lin() if nav.fej_yaw else None,
                            anchors=np.array([feats[j].anchor for j in fj]),
                        )
                    # S = H_x P_vv H_xᵀ + H_x P_vl H_lᵀ + H_l P_lv H_xᵀ + H_l P_ll H_lᵀ + R
                    Pvl = P[:NX][:, cols].transpose(1, 0, 2)  # (K, 9, size)
                    Pll = P[cols[:, :, None], cols[:, None, :]]  # (K, size, size)
                    HxT, HlT = np.transpose(Hx, (0, 2, 1)), np.transpose(HlK, (0, 2, 1))
                    cross = Hx @ Pvl @ HlT
                    S = Hx @ Pvv @ HxT + cross + np.transpose(cross, (0, 2, 1)) + HlK @ Pll @ HlT + R
                    nis = np.einsum("ki,ki->k", nu, np.linalg.solve(S, nu[..., None])[..., 0])
                    keep = nis < chi2_gate(confidence, size)
                    if kind == "pipe" and keep.any():
                        ks = np.flatnonzero(keep)
                        fs = [feats[fj[k]] for k in ks]
                        lines = [f.world_line(x[f.cols]) for f in fs]
                        keep[ks] = ~scan.excludes_all(
                            [f.id for f in fs],
                            np.array([obs[oi[k]].ends_W for k in ks]),
                            np.array([c for c, _ in lines]),
                            np.array([d for _, d in lines]),
                        )
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


def pre_gate(fmap: FeatureMap, obs: list[Prepared]) -> np.ndarray:
    """Euclidean pre-gate before the χ² tests, vectorised over the map: an observation (in {W} with
    the current pose) farther than ``pre_gate_m`` + 3σ of the vehicle position from a feature (object:
    its position; pipe: its line) cannot pair with it. It only saves work: the χ² gates would reject
    such pairs anyway."""
    feats, state = fmap.features, fmap.nav.state
    near = np.zeros((len(obs), len(feats)), bool)
    x, P = state.x, state.P
    gate = fmap.assoc.pre_gate_m + 3.0 * math.sqrt(max(np.trace(P[POS, POS]), 0.0))
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
            if o.obs.sensor not in poses:
                poses[o.obs.sensor] = mdl.sensor_pose(state.xv, o.R_BS, o.t_BS)[:2]
            R, t = poses[o.obs.sensor]
            w[k] = t + R @ o.obs.position
        near[np.ix_(o_obj, obj)] = np.linalg.norm(w[:, None, :] - pos_obj[None, :, :], axis=2) < gate
    if len(pip) and o_pip:
        lp = x[starts[pip, None] + np.arange(4)]
        U = geo.rot_batch(lp[:, :3])
        d_l = U[:, :, 1]
        anchors = np.array([feats[j].anchor for j in pip])
        m_l = lp[:, 3:4] * U[:, :, 0] + np.cross(anchors, d_l)  # moments about the origin
        c_l = np.cross(d_l, m_l)  # closest points d × m
        mid = np.array([obs[i].ends_W.mean(axis=0) for i in o_pip])
        r = mid[:, None, :] - c_l[None, :, :]  # (n_obs, n_pipes, 3)
        off = r - np.einsum("opk,pk->op", r, d_l)[:, :, None] * d_l[None, :, :]
        near[np.ix_(o_pip, pip)] = np.linalg.norm(off, axis=2) < gate
    return near
