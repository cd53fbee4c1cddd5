"""GPS fixes in the filter: for the EKF a position update of the antenna at every fix after the one
the filter started from (:class:`semslam.mission.gps_start.GpsStart`); dead reckoning takes only its
start from them.

A fix measures the antenna, at the lever arm t_BA of the GPS sensor: z = p + R(φ, θ, ψ) t_BA. A
perturbation δe of the Euler angles turns the body by ω_B = E(φ, θ) δe
(:func:`semslam.ekf.geometry.euler_rate_to_body`), so ∂z/∂e = −R [t_BA]× E.
"""

from __future__ import annotations

import numpy as np

from semslam.ekf import geometry as geo
from semslam.ekf.models import ATT, NX, POS, NavUpdate
from semslam.mission.gps_start import GpsStart
from semslam.mission.measurements import GpsFix
from semslam.mission.mission import MissionMetadata


def gps_update(x: np.ndarray, position: np.ndarray, covariance: np.ndarray, t_BA: np.ndarray) -> NavUpdate:
    """The antenna at lever arm ``t_BA`` measured at ``position`` (NED, m) with ``covariance``."""
    phi, theta, psi = (float(a) for a in x[ATT])
    R = geo.rot(phi, theta, psi)
    t = np.asarray(t_BA, float)
    H = np.zeros((3, NX))
    H[:, POS] = np.eye(3)
    skew = np.array([[0.0, -t[2], t[1]], [t[2], 0.0, -t[0]], [-t[1], t[0], 0.0]])
    H[:, ATT] = -R @ skew @ geo.euler_rate_to_body(phi, theta)
    return NavUpdate(np.asarray(position, float) - (x[POS] + R @ t), H, np.asarray(covariance, float))


class FilterGps:
    """The filter's GPS: its start and, when ``updates`` (the EKF; dead reckoning sets it False),
    the update of every later fix."""

    def __init__(self, metadata: MissionMetadata, initial_pose: str):
        self.start = GpsStart(metadata, initial_pose)
        self.updates = True

    def uses(self, fix: GpsFix) -> bool:
        """The filter updates with ``fix`` (not dead reckoning, not the start's fix)."""
        return self.updates and not self.start.is_start(fix)

    def update(self, x: np.ndarray, fix: GpsFix) -> NavUpdate:
        return gps_update(x, fix.position, fix.covariance, self.start.lever(fix.sensor))
