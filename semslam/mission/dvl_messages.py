"""DVL messages → ``DvlVelocity``, each by its vendor's semantics.

* ``cola2_msgs/DVL`` and UUV Simulator's ``uuv_sensor_ros_plugins_msgs/DVL`` (the same layout):
  invalid when ``velocity_covariance`` is marked −1, or when it has beams and fewer than
  ``reader.dvl_min_valid_beams`` of them are valid (range ≥ 0, ``velocity_covariance`` ≥ 0,
  finite velocity). Altitude −1 (or NaN) is unknown.
* ``geometry_msgs/TwistWithCovarianceStamped``: no beams; invalid when ``covariance[0]`` is −1.
* Water Linked, ``dvl_msgs/DVL`` (ROS 2 driver) and ``waterlinked_a50_ros_driver/DVL`` (ROS 1):
  invalid when ``velocity_valid`` is false (no bottom lock), when fewer than
  ``dvl_min_valid_beams`` beams are ``valid``, or when the figure of merit exceeds
  ``reader.dvl_max_fom_m_s``. The covariance is the message's ``covariance`` (ROS 2, 9 values),
  else fom² on each axis (fom is the velocities' accuracy, m/s); altitude only with a lock.

An invalid reading's covariance carries no information and is read as NaN (so read → write →
read is exact). A valid reading whose covariance is unknown (all zeros; no covariance and no fom)
gets ``reader.unknown_covariance.dvl_m_s`` on each axis, noted for ``semslam info``.
"""

from __future__ import annotations

import math

import numpy as np

from semslam.mission.codec_base import DecodeContext, stamp_ns, unknown_covariance
from semslam.mission.measurements import DvlVelocity

_NAN33 = np.full((3, 3), np.nan)


def _assumed(cov: np.ndarray, sensor: str, ctx: DecodeContext) -> np.ndarray:
    if not unknown_covariance(cov):
        return cov
    sigma = ctx.cfg.unknown_covariance.dvl_m_s
    ctx.note(sensor, f"covariance unknown: σ {sigma:g} m/s assumed")
    return np.eye(3) * sigma**2


def _altitude(value: float) -> float | None:
    return float(value) if value >= 0 else None  # -1 (or NaN): unknown


def _marked(msg, v, cov: np.ndarray, valid: bool, sensor: str, ctx: DecodeContext, **beams) -> DvlVelocity:
    """A reading of the UUV Simulator convention: covariance -1 when invalid, zeros when unknown."""
    return DvlVelocity(
        stamp_ns(msg.header),
        sensor,
        velocity=(v.x, v.y, v.z),
        covariance=_assumed(cov, sensor, ctx) if valid else _NAN33,
        valid=valid,
        **beams,
    )


def decode_twist(msg, sensor: str, ctx: DecodeContext) -> DvlVelocity:
    cov = np.asarray(msg.twist.covariance, dtype=float).reshape(6, 6)[:3, :3]
    valid = not cov[0, 0] < 0  # -1 marks an invalid reading (same convention as cola2_msgs/DVL)
    return _marked(msg, msg.twist.twist.linear, cov, valid, sensor, ctx)


def decode_uuv_dvl(msg, sensor: str, ctx: DecodeContext) -> DvlVelocity:
    """cola2_msgs/DVL and uuv_sensor_ros_plugins_msgs/DVL."""
    cov = np.asarray(msg.velocity_covariance, dtype=float).reshape(3, 3)
    marked_invalid = cov[0, 0] < 0
    beam_valid = None
    if len(msg.beams):
        beam_valid = tuple(
            bool(b.range >= 0 and b.velocity_covariance >= 0 and np.isfinite(b.velocity)) for b in msg.beams
        )
    valid = not marked_invalid and (beam_valid is None or sum(beam_valid) >= ctx.cfg.dvl_min_valid_beams)
    return _marked(msg, msg.velocity, cov, valid, sensor, ctx, beam_valid=beam_valid, altitude=_altitude(msg.altitude))


def decode_waterlinked_dvl(msg, sensor: str, ctx: DecodeContext) -> DvlVelocity:
    """dvl_msgs/DVL (ROS 2) and waterlinked_a50_ros_driver/DVL (ROS 1): the same fields, the ROS 2
    one with a covariance (older firmware leaves it empty)."""
    beam_valid = tuple(bool(b.valid) for b in msg.beams) if len(msg.beams) else None
    fom = float(msg.fom)
    max_fom = ctx.cfg.dvl_max_fom_m_s
    valid = (
        bool(msg.velocity_valid)
        and (beam_valid is None or sum(beam_valid) >= ctx.cfg.dvl_min_valid_beams)
        and not (max_fom is not None and not fom <= max_fom)
    )
    cov = _NAN33
    if valid:
        given = np.asarray(getattr(msg, "covariance", ()), dtype=float).reshape(-1)
        if given.size == 9 and np.isfinite(given).all() and not unknown_covariance(given):
            cov = given.reshape(3, 3)
        elif math.isfinite(fom) and fom > 0:
            cov = np.eye(3) * fom**2
        else:
            cov = _assumed(np.zeros((3, 3)), sensor, ctx)
    v = msg.velocity
    return DvlVelocity(
        stamp_ns(msg.header),
        sensor,
        velocity=(v.x, v.y, v.z),
        covariance=cov,
        valid=valid,
        beam_valid=beam_valid,
        altitude=_altitude(msg.altitude) if valid else None,
    )
