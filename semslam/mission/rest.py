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

If the mission has a depth sensor, while it says the vehicle still waits (the mean of its readings over the last
``DEPTH_WINDOW_S`` within ``DEPTH_CHI2`` of the mean of every earlier reading, with their declared
variances), the readings' σ is ``initial.at_rest_waiting_sigma_m_s`` (a vehicle holding station,
about as sure as the DVL's zero-velocity test below); from its first change (the dive) to the first
valid reading, ``initial.at_rest_until_velocity_sigma_m_s``: a vehicle that dives may start to move
and the zero readings then only bound its speed. Why not end the claim at the dive: nothing would then
bound the horizontal velocity until the lock, and a wrong association in that stretch can split the map
(both measured: experiments/estimators/README.md, stop 41). Until the depth has a window's worth of
earlier readings to compare with, it says nothing, and the looser σ holds.

Then, while the vehicle is still (``initial.still_test_readings``, a zero-velocity test): as long as
the DVL's newest valid reading and the mean of its last N are consistent with zero velocity (χ²(3) ≤
``STILL_CHI2`` with their declared covariance), each reading's horizontal body velocity is read as
exactly zero (its vertical and covariance kept) and a dropout is bridged with zero readings; from the
first reading that fails, the DVL passes unchanged for the rest of the mission. Why: a vehicle whose
DVL locks while it still waits (on deck, in a tank, on the seabed) otherwise integrates the readings'
white noise, ~1 cm per axis over 8 s, and nothing later in a mission without a position fix can take
that offset out: it was the graph's whole error on half of 33 tank worlds (experiments/estimators/
README.md, stop 39). The dive's vertical speed fails the test, so does any horizontal motion above
~1 cm/s over the window.
"""

from __future__ import annotations

from collections import deque

import numpy as np

from semslam.mission.measurements import Depth, DvlVelocity, GpsFix
from semslam.mission.mission import Mission

PERIOD_S = 0.2  # a DVL's rate; the readings stand in for the ones it could not give
SAID_AFTER_S = 1.0  # a hold shorter than this (a GPS fix or the lock a moment later) changes nothing worth a word
VERTICAL_SIGMA_M_S = 1.0  # no information along z: a dive's 0.1–0.5 m/s is not held
STILL_CHI2 = 16.27  # χ²(3) at 0.999: a reading (or a window's mean) this close to zero says "still"
DEPTH_WINDOW_S = 1.0  # the depth sensor's newest readings, compared with every earlier one
DEPTH_CHI2 = 25.0  # 5σ: tested at every reading while the vehicle waits, a rarer false alarm than χ²(1) 0.999


class RestAssumption:
    """What the start at rest did over the last pass: ``readings`` added, and the stamps of the first
    and the last (``None``: the mission's velocity or a GPS fix came before any estimator needed one)."""

    def __init__(self, sigma_m_s: float | None, sensor: str, waiting_sigma_m_s: float | None = None):
        self.sigma_m_s = sigma_m_s
        self.waiting_sigma_m_s = waiting_sigma_m_s
        self.sensor = sensor
        self.readings = 0
        self.first: int | None = None
        self.last: int | None = None
        self.still_first: int | None = None  # the zero-velocity test's first and last zeroed reading
        self.still_last: int | None = None
        self.start: int | None = None  # the mission's first stamp
        self.moved: int | None = None  # the stamp at which the depth sensor said the vehicle dives

    @property
    def held_s(self) -> float:
        """How long the assumption held (s): from its first reading to its last."""
        return 0.0 if not self.readings else (self.last - self.first) * 1e-9

    @property
    def still_s(self) -> float:
        """How long the zero-velocity test held the vehicle still (s), from its first zeroed reading."""
        return 0.0 if self.still_first is None else (self.still_last - self.still_first) * 1e-9

    @property
    def held_said(self) -> bool:
        """The start at rest held for ``SAID_AFTER_S`` or more (shorter changes nothing worth a word)."""
        return self.readings > 0 and self.held_s >= SAID_AFTER_S

    @property
    def still_said(self) -> bool:
        """The zero-velocity test held for ``SAID_AFTER_S`` or more."""
        return self.still_s >= SAID_AFTER_S

    @property
    def said(self) -> bool:
        """Whether the run says what it assumed at the start (either part)."""
        return self.held_said or self.still_said

    def describe(self) -> str | None:
        """The warning a run gives, or None if the assumption held too briefly to matter."""
        if not self.said:
            return None
        parts = []
        if self.held_said:
            sure = f"σ {self.sigma_m_s:g} m/s, initial.at_rest_until_velocity_sigma_m_s; null turns it off"
            if self.waiting_sigma_m_s is not None:
                waiting = f"σ {self.waiting_sigma_m_s:g} m/s (initial.at_rest_waiting_sigma_m_s)"
                sure = (
                    f"{waiting} while its depth held, {sure}"
                    if self.moved is None
                    else f"{waiting} until its depth changed at {(self.moved - self.start) * 1e-9:.1f} s, then {sure}"
                )
            parts.append(
                f"no valid velocity reading for the first {self.held_s:.1f} s ({self.sensor} without bottom lock): the "
                f"vehicle was taken at rest horizontally until then ({sure})"
            )
        if self.still_said:
            parts.append(
                f"the {self.sensor}'s readings were consistent with zero velocity for {self.still_s:.1f} s from "
                f"{(self.still_first - self.start) * 1e-9:.1f} s into the mission: read as exactly zero horizontally "
                "until then (initial.still_test_readings; null turns it off)"
            )
        return "; ".join(parts)


def _zero_horizontal(R_BS: np.ndarray, v_S: np.ndarray) -> np.ndarray:
    v_B = R_BS @ v_S
    v_B[:2] = 0.0
    return R_BS.T @ v_B


def _without_vertical(R_BS: np.ndarray, cov_S: np.ndarray) -> np.ndarray:
    """``cov_S`` with nothing known along the body's z (a dropout's stand-in does not hold a dive)."""
    cov_B = R_BS @ cov_S @ R_BS.T
    cov_B[2, :] = cov_B[:, 2] = 0.0
    cov_B[2, 2] = VERTICAL_SIGMA_M_S**2
    return R_BS.T @ cov_B @ R_BS


class _DepthChange:
    """Whether the depth sensor says the vehicle no longer waits: it dives (see the module docstring)."""

    def __init__(self):
        self.window: deque = deque()  # (stamp, depth, variance) of the last DEPTH_WINDOW_S
        self.before = np.zeros(3)  # count, sum of depths, sum of variances of every earlier reading
        self.judged = False  # a window's worth of earlier readings compared once: until then it says nothing

    def moved(self, stamp: int, depth: float, variance: float) -> bool:
        self.window.append((stamp, depth, variance))
        while self.window[0][0] < stamp - int(DEPTH_WINDOW_S * 1e9):
            _, z, var = self.window.popleft()
            self.before += (1.0, z, var)
        n0, n1 = self.before[0], len(self.window)
        if n0 < n1:  # not yet a window's worth of readings to compare with
            return False
        self.judged = True
        z = np.array([w[1] for w in self.window])
        var = self.before[2] / n0**2 + sum(w[2] for w in self.window) / n1**2
        return (z.mean() - self.before[1] / n0) ** 2 > DEPTH_CHI2 * var


class _StillTest:
    """The zero-velocity test over the last ``n`` valid readings (see the module docstring)."""

    def __init__(self, n: int):
        self.recent: deque = deque(maxlen=n)

    def still(self, v: np.ndarray, cov: np.ndarray) -> bool:
        self.recent.append((v, cov))
        mean = np.mean([r[0] for r in self.recent], axis=0)
        mean_cov = np.sum([r[1] for r in self.recent], axis=0) / len(self.recent) ** 2
        one = v @ np.linalg.solve(cov, v)
        joint = mean @ np.linalg.solve(mean_cov, mean)
        return max(one, joint) <= STILL_CHI2


def at_rest_until_velocity(
    mission: Mission, sigma_m_s: float | None, still_readings: int | None = None, waiting_sigma_m_s: float | None = None
) -> tuple[Mission, RestAssumption | None]:
    """``mission`` with the start at rest and the zero-velocity test after it (see the module
    docstring), and the record of what they did (filled by each pass); unchanged (and None) when both
    are off (``sigma_m_s``, ``still_readings`` None) or the mission has no DVL."""
    dvls = mission.metadata.sensors_of_kind("dvl")
    if (sigma_m_s is None and still_readings is None) or not dvls:
        return mission, None
    dvl = dvls[0].name
    R_BS = mission.metadata.extrinsic(dvl)[:3, :3]
    if sigma_m_s is not None:
        cov_S = R_BS.T @ np.diag([sigma_m_s**2, sigma_m_s**2, VERTICAL_SIGMA_M_S**2]) @ R_BS
        w = sigma_m_s if waiting_sigma_m_s is None else waiting_sigma_m_s
        cov_waiting = R_BS.T @ np.diag([w**2, w**2, VERTICAL_SIGMA_M_S**2]) @ R_BS
    period = int(PERIOD_S * 1e9)
    depth_sensor = next(iter(mission.metadata.sensors_of_kind("depth")), None)
    if depth_sensor is None:  # nothing tells a waiting vehicle from a moving one: the looser σ throughout
        waiting_sigma_m_s = None
    record = RestAssumption(sigma_m_s, dvl, waiting_sigma_m_s)

    def stream():
        record.readings, record.first, record.last = 0, None, None
        record.still_first = record.still_last = record.moved = None
        holding, due = sigma_m_s is not None, None
        depth = _DepthChange() if waiting_sigma_m_s is not None else None
        test = _StillTest(still_readings) if still_readings is not None else None  # None: not (or no longer) testing
        bridge = None
        for m in mission:
            valid = isinstance(m, DvlVelocity) and m.valid and m.is_finite()
            if isinstance(m, GpsFix):  # a fix says where the vehicle is: nothing is assumed from here on
                holding, test = False, None
            if holding and valid:  # any DVL's valid reading ends the start at rest
                holding = False
            if holding and depth is not None and isinstance(m, Depth) and m.sensor == depth_sensor.name:
                if depth.moved(m.stamp, m.depth, m.variance):  # the vehicle dives: no longer waiting
                    record.moved, depth = m.stamp, None
            if due is None:  # the first reading stands in for a DVL one PERIOD_S late, not at once
                due, record.start = m.stamp + period, m.stamp
            if holding and m.stamp >= due:
                yield DvlVelocity(
                    m.stamp,
                    dvl,
                    velocity=np.zeros(3),
                    covariance=cov_waiting if depth is not None and depth.judged else cov_S,
                )
                record.readings += 1
                record.first = m.stamp if record.first is None else record.first
                record.last, due = m.stamp, m.stamp + period
            if test is not None and not holding:
                if valid and m.sensor == dvl:  # the test reads the DVL whose readings it stands in for
                    v, cov = np.asarray(m.velocity, float), np.asarray(m.covariance, float)
                    if test.still(v, cov):
                        record.still_first = m.stamp if record.still_first is None else record.still_first
                        record.still_last = m.stamp
                        bridge = (m.stamp + period, _without_vertical(R_BS, cov))
                        yield DvlVelocity(m.stamp, m.sensor, velocity=_zero_horizontal(R_BS, v), covariance=cov)
                        continue
                    test = None
                elif not valid and bridge is not None and m.stamp >= bridge[0]:  # a dropout while still
                    yield DvlVelocity(m.stamp, dvl, velocity=np.zeros(3), covariance=bridge[1])
                    record.still_last = m.stamp
                    bridge = (m.stamp + period, bridge[1])
            yield m

    return Mission(mission.metadata, stream), record
