"""Dead reckoning's map: every observation on its own, placed with the dead-reckoning pose and its
uncertainty (the paper's Figure 10a)."""

from __future__ import annotations

import numpy as np

from semslam.config import SemslamConfig
from semslam.ekf import batch as bt
from semslam.ekf import geometry as geo
from semslam.ekf import models as mdl
from semslam.ekf.models import ATT, NX
from semslam.ekf.navigation import FilterNavigation
from semslam.ekf.observations import by_sensor, prepare
from semslam.estimation import LandmarkEstimate
from semslam.mapping.book import LandmarkBook
from semslam.mapping.builder import well_formed
from semslam.observations import LineObservation, Observation, PointObservation


class PlacedMap:
    """Every object and pipe observation as its own map entry."""

    def __init__(self, nav: FilterNavigation, config: SemslamConfig, book: LandmarkBook):
        self.nav = nav
        self.cfg = config.ekf
        self.assoc = config.association
        self.book = book
        self.entries: list[LandmarkEstimate] = []
        self.volume: dict[int, tuple[np.ndarray, np.ndarray]] = {}

    def __len__(self) -> int:
        return len(self.entries)

    def observe(self, stamp: int, observations: list[Observation]) -> bool:
        """Place the batch's objects and pipe segments; True if any was placed."""
        mapped = [z for z in observations if isinstance(z, (PointObservation, LineObservation))]
        for z in observations:
            if not isinstance(z, (PointObservation, LineObservation)):
                self.nav.warn_once(type(z).__name__, f"{type(z).__name__} is not used by the filters")
        obs = prepare(
            self.nav, well_formed(mapped, self.assoc, self.nav.diagnostics, stamp), self.cfg.line_min_distance_m
        )
        if not obs:
            return False
        x, Pvv = self.nav.state.xv, self.nav.state.Pvv[:NX, :NX]  # the Jacobians' bias column is zero
        entries: list[tuple] = []  # (index, kind, l or (p, q), cov, observation)
        for _sensor, group in by_sensor(obs, "object"):  # objects: one batch per sensor
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
        vols = {}
        for size in (3, 4):
            covs = [e[3] for e in entries if len(e[3]) == size]
            if covs:
                vols[size] = iter(np.linalg.slogdet(np.array(covs))[1])
        stamps = np.array([stamp], np.int64)
        for _, kind, val, cov, o in entries:
            lid = len(self.entries)
            self.book.observe(lid, stamp, o.obs)
            if kind == "object":
                lm = LandmarkEstimate(
                    lid, "object", position=val, covariance=cov, class_posterior=self.book.class_posterior(lid)
                )
            else:
                lm = LandmarkEstimate(lid, "pipe", p=val[0], q=val[1], covariance=cov)
            lm.n_observations = 1
            self.entries.append(lm)
            self.volume[lid] = (stamps, np.array([next(vols[len(cov)])]))
        return True

    def estimates(self) -> list[LandmarkEstimate]:
        return list(self.entries)
