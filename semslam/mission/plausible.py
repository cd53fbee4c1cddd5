"""Finite nonsense: a reading whose value no vehicle or sensor can have (a DVL velocity of 1e188 m/s
with a sane covariance), found against the generous bounds of ``reader.plausible``. The reader drops
and counts such a message like a non-finite one."""

from __future__ import annotations

import math

from semslam.mission.config import PlausibleBounds
from semslam.mission.measurements import Attitude, Depth, DvlVelocity, GpsFix, GroundTruthPose, Measurement, SonarSwath


def implausible(m: Measurement, bounds: PlausibleBounds) -> str | None:
    """Why ``m`` is beyond its sensor's physical bound (e.g. "velocity beyond 10 m/s"), else None.
    Checked on finite measurements; a DVL reading flagged invalid carries no velocity and passes."""
    if isinstance(m, DvlVelocity):
        if not m.valid:
            return None
        if math.hypot(*m.velocity.tolist()) > bounds.speed_m_s:
            return f"velocity beyond {bounds.speed_m_s:g} m/s"
        if m.altitude is not None and abs(m.altitude) > bounds.depth_m:
            return f"altitude beyond {bounds.depth_m:g} m"
    elif isinstance(m, Depth):
        if abs(m.depth) > bounds.depth_m:
            return f"depth beyond ±{bounds.depth_m:g} m"
    elif isinstance(m, Attitude):
        if m.angular_rate is not None and math.hypot(*m.angular_rate.tolist()) > bounds.angular_rate_rad_s:
            return f"angular_rate beyond {bounds.angular_rate_rad_s:g} rad/s"
    elif isinstance(m, (GpsFix, GroundTruthPose)):
        if math.hypot(*m.position.tolist()) > bounds.position_m:
            return f"position beyond {bounds.position_m:g} m"
    elif isinstance(m, SonarSwath):
        if len(m.ranges) and float(abs(m.ranges).max()) > bounds.range_m:
            return f"ranges beyond {bounds.range_m:g} m"
    return None
