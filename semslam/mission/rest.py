"""The start at rest: until the vehicle's first valid velocity reading (and while no GPS fix says
where it is), it is taken as holding its horizontal position.

Why: a recording often starts with the vehicle at the surface, its DVL without bottom lock until it
has dived (15–20 s in the simulated tank worlds). With nothing measuring the horizontal velocity, the
constant-velocity motion model lets the start's velocity uncertainty grow the position's to metres,
fully correlated with the velocity: the first valid reading is then read as that velocity held since
the start, and the position jumps by it times the wait (measured: experiments/estimators/README.md).
A vehicle waiting for bottom lock dives or holds station; the first velocity reading says nothing
about how it got there.

So, until then, every ``PERIOD_S`` the estimators get a zero body velocity reading of the DVL with
σ ``initial.at_rest_until_velocity_sigma_m_s`` along the body's x and y and none along z (the dive's
vertical speed is the depth sensor's to observe). The readings go into the stream every estimator
reads, so the EKF, the graph and dead reckoning take the same assumption; it is said after the run
with how long it held (a mission whose DVL has lock from its first second never meets it).
"""

from __future__ import annotations

import numpy as np

from semslam.mission.measurements import DvlVelocity, GpsFix
from semslam.mission.mission import Mission

PERIOD_S = 0.2  # a DVL's rate; the readings stand in for the ones it could not give
SAID_AFTER_S = 1.0  # a hold shorter than this (a GPS fix or the lock a moment later) changes nothing worth a word
VERTICAL_SIGMA_M_S = 1.0  # no information along z: a dive's 0.1–0.5 m/s is not held


class RestAssumption:
    """What the start at rest did over the last pass: ``readings`` added, and the stamps of the first
    and the last (``None``: the mission's velocity or a GPS fix came before any estimator needed one)."""

    def __init__(self, sigma_m_s: float, sensor: str):
        self.sigma_m_s = sigma_m_s
        self.sensor = sensor
        self.readings = 0
        self.first: int | None = None
        self.last: int | None = None

    @property
    def held_s(self) -> float:
        """How long the assumption held (s): from its first reading to its last."""
        return 0.0 if not self.readings else (self.last - self.first) * 1e-9

    @property
    def said(self) -> bool:
        """Whether the run says it assumed a start at rest (it held for ``SAID_AFTER_S`` or more)."""
        return self.readings > 0 and self.held_s >= SAID_AFTER_S

    def describe(self) -> str | None:
        """The warning a run gives, or None if the assumption held too briefly to matter."""
        if not self.said:
            return None
        return (
            f"no valid velocity reading for the first {self.held_s:.1f} s ({self.sensor} without bottom lock): the vehicle "
            f"was taken at rest horizontally until then (σ {self.sigma_m_s:g} m/s, "
            "initial.at_rest_until_velocity_sigma_m_s; null turns it off)"
        )


def at_rest_until_velocity(mission: Mission, sigma_m_s: float | None) -> tuple[Mission, RestAssumption | None]:
    """``mission`` with the start at rest (see the module docstring), and the record of what it did
    (filled by each pass); unchanged (and None) when ``sigma_m_s`` is None or the mission has no DVL."""
    dvls = mission.metadata.sensors_of_kind("dvl")
    if sigma_m_s is None or not dvls:
        return mission, None
    dvl = dvls[0].name
    R_BS = mission.metadata.extrinsic(dvl)[:3, :3]
    cov_S = R_BS.T @ np.diag([sigma_m_s**2, sigma_m_s**2, VERTICAL_SIGMA_M_S**2]) @ R_BS
    period = int(PERIOD_S * 1e9)
    record = RestAssumption(sigma_m_s, dvl)

    def stream():
        record.readings, record.first, record.last = 0, None, None
        holding, due = True, None
        for m in mission:
            if holding and (isinstance(m, GpsFix) or (isinstance(m, DvlVelocity) and m.valid and m.is_finite())):
                holding = False
            if due is None:  # the first reading stands in for a DVL one PERIOD_S late, not at once
                due = m.stamp + period
            if holding and m.stamp >= due:
                yield DvlVelocity(m.stamp, dvl, velocity=np.zeros(3), covariance=cov_S)
                record.readings += 1
                record.first = m.stamp if record.first is None else record.first
                record.last, due = m.stamp, m.stamp + period
            yield m

    return Mission(mission.metadata, stream), record
