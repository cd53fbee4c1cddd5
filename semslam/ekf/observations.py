"""Observations as the filter models them: each with its sensor's extrinsic and, for pipe segments, the
orthonormal line model of the paper (eqs. 2–16) and the segment's ends in {W} with the current pose."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from semslam.ekf import batch as bt
from semslam.ekf import models as mdl
from semslam.ekf.navigation import FilterNavigation
from semslam.observations import LineObservation, Observation, PointObservation


@dataclass
class Prepared:
    """An observation prepared for the filter: its sensor extrinsic and model."""

    obs: Observation
    R_BS: np.ndarray
    t_BS: np.ndarray
    line: mdl.LineObservationModel | None = None
    ends_W: np.ndarray | None = None  # the observed segment in {W} with the pose it was prepared at (pipes)

    @property
    def kind(self) -> str:
        return "pipe" if isinstance(self.obs, LineObservation) else "object"


def prepare(nav: FilterNavigation, observations: list[Observation], line_min_distance_m: float) -> list[Prepared]:
    """The objects and pipe segments of ``observations`` prepared with the current pose (pipe models in
    one batch). A segment whose line passes within ``line_min_distance_m`` of the sensor is left out:
    its orthonormal representation is singular there (ρ ≈ 0)."""
    out: list[Prepared | None] = []
    lines: list[tuple[int, LineObservation]] = []  # (slot in out, observation)
    for o in observations:
        R_BS, t_BS = nav.extrinsic(o.sensor)  # an undeclared sensor is a user error
        if isinstance(o, PointObservation):
            out.append(Prepared(o, R_BS, t_BS))
        elif isinstance(o, LineObservation):
            lines.append((len(out), o))
            out.append(None)
    if lines:
        ls = [o for _, o in lines]
        m, d, U, rho, cov = bt.line_observation_models(
            np.array([o.p for o in ls]), np.array([o.q for o in ls]), np.array([o.covariance for o in ls])
        )
        poses: dict[str, tuple] = {}
        for k, (slot, o) in enumerate(lines):
            if rho[k] < line_min_distance_m:
                nav.warn_once("rho", "pipe observations through the sensor origin ignored (ρ ≈ 0)")
                continue
            R_BS, t_BS = nav.extrinsic(o.sensor)
            if o.sensor not in poses:
                poses[o.sensor] = mdl.sensor_pose(nav.state.xv, R_BS, t_BS)[:2]
            R, t = poses[o.sensor]
            line = mdl.LineObservationModel(m[k], d[k], U[k], float(rho[k]), cov[k])
            out[slot] = Prepared(o, R_BS, t_BS, line, np.array([o.p, o.q]) @ R.T + t)
    return [o for o in out if o is not None]


def by_sensor(obs: list[Prepared], kind: str) -> list[tuple[str, list[int]]]:
    """(sensor, [indices]) of the prepared observations of one kind, grouped by sensor."""
    groups: dict[str, list[int]] = {}
    for i, o in enumerate(obs):
        if o.kind == kind:
            groups.setdefault(o.obs.sensor, []).append(i)
    return list(groups.items())
