"""GPS messages → ``GpsFix`` in the local NED frame about the mission's datum, and back.

* ``sensor_msgs/NavSatFix`` and ``gps_msgs/GPSFix`` (ROS 1: ``gps_common/GPSFix``): a fix whose
  status is NO_FIX (−1), or whose latitude, longitude or altitude is not finite, has no position
  and is dropped (counted under ``status NO_FIX`` / ``position not finite``). Fixes taken below
  ``reader.gps_max_depth_m`` are dropped by the reader, which knows the depth.
* Covariance: the message's ``position_covariance`` (ENU about the fix, turned into NED), its
  diagonal only when the type says DIAGONAL_KNOWN. When it is COVARIANCE_TYPE_UNKNOWN (or all
  zeros): a ``GPSFix``'s 95 % uncertainties ``err_horz`` / ``err_vert`` when given (σ = err_horz /
  2.45, the 95 % radius of a circular normal; err_vert / 1.96), else
  ``reader.unknown_covariance.gps_horizontal_m`` / ``gps_vertical_m``, noted for ``semslam info``.
* The datum is ``reader.datum``, else the sidecar's, else the first fix with a position.
"""

from __future__ import annotations

import math

import numpy as np

from semslam.mission.codec_base import DecodeContext, Unusable, stamp_ns, unknown_covariance
from semslam.mission.geodesy import Geodetic, enu_to_ned_covariance, ned_to_enu_covariance, to_geodetic, to_ned
from semslam.mission.measurements import GpsFix

STATUS_NO_FIX = -1
COVARIANCE_TYPE_UNKNOWN = 0
COVARIANCE_TYPE_DIAGONAL_KNOWN = 2
COVARIANCE_TYPE_KNOWN = 3
_CIRCULAR_95 = math.sqrt(-2.0 * math.log(0.05))  # 2.448: radius holding 95 % of a 2-D standard normal
_NORMAL_95 = 1.959964


def fix_position(msg) -> Geodetic | None:
    """The geodetic position of a NavSatFix / GPSFix, None when it has none (NO_FIX, NaN)."""
    if int(msg.status.status) <= STATUS_NO_FIX:
        return None
    lat, lon, alt = float(msg.latitude), float(msg.longitude), float(msg.altitude)
    if not (math.isfinite(lat) and math.isfinite(lon) and math.isfinite(alt)):
        return None
    return Geodetic(lat, lon, alt)


def _covariance_ned(msg, sensor: str, ctx: DecodeContext) -> np.ndarray:
    kind = int(msg.position_covariance_type)
    cov = np.asarray(msg.position_covariance, dtype=float).reshape(3, 3)
    if kind != COVARIANCE_TYPE_UNKNOWN and not unknown_covariance(cov) and np.isfinite(cov).all():
        if kind == COVARIANCE_TYPE_DIAGONAL_KNOWN:
            cov = np.diag(np.diag(cov))
        return enu_to_ned_covariance(cov)
    sig = ctx.cfg.unknown_covariance
    h, v = sig.gps_horizontal_m, sig.gps_vertical_m
    err_h, err_v = float(getattr(msg, "err_horz", 0.0)), float(getattr(msg, "err_vert", 0.0))
    if err_h > 0 and math.isfinite(err_h):
        h = err_h / _CIRCULAR_95
        v = err_v / _NORMAL_95 if err_v > 0 and math.isfinite(err_v) else v
        ctx.note(sensor, "covariance unknown: σ from err_horz/err_vert (95 %)")
    else:
        ctx.note(sensor, f"covariance unknown: σ {sig.gps_horizontal_m:g} m horizontal, {v:g} m vertical assumed")
    return np.diag([h * h, h * h, v * v])


def decode_gps_fix(msg, sensor: str, ctx: DecodeContext) -> GpsFix:
    """sensor_msgs/NavSatFix, gps_msgs/GPSFix, gps_common/GPSFix."""
    where = fix_position(msg)
    if where is None:
        if int(msg.status.status) <= STATUS_NO_FIX:
            raise Unusable("status NO_FIX", "the receiver has no fix")
        raise Unusable("position not finite", "latitude, longitude or altitude is NaN/inf")
    if ctx.datum is None:  # no configured or sidecar datum: the first fix with a position
        ctx.datum = where
    return GpsFix(
        stamp_ns(msg.header),
        sensor,
        position=to_ned(where.latitude_deg, where.longitude_deg, where.altitude_m, ctx.datum),
        covariance=_covariance_ned(msg, sensor, ctx),
    )


def encode_navsatfix(T: dict, header, m: GpsFix, datum: Geodetic):
    """A sensor_msgs/NavSatFix of type store ``T`` for ``m`` (status FIX by GPS, covariance KNOWN)."""
    lat, lon, alt = to_geodetic(m.position, datum)
    status = T["sensor_msgs/msg/NavSatStatus"](status=0, service=1)
    return T["sensor_msgs/msg/NavSatFix"](
        header=header,
        status=status,
        latitude=lat,
        longitude=lon,
        altitude=alt,
        position_covariance=ned_to_enu_covariance(m.covariance).reshape(9).copy(),
        position_covariance_type=COVARIANCE_TYPE_KNOWN,
    )
