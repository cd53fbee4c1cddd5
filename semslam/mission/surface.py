"""What the mission's surface periods say: the atmospheric pressure and the GPS datum.

``reader.atmospheric_pressure_pa: auto`` is resolved, in this order:

1. the mission's sidecar value (the writer records the pressure it converted depth with);
2. a sidecar without one was written by an earlier semslam, which always used the standard
   atmosphere (101325 Pa);
3. with a GPS bound: the median pressure over the readings taken within ``GPS_WINDOW_S`` of a fix
   with a position (the vehicle is at the surface while its GPS has a fix);
4. else the median pressure over the first seconds, until the pressure first rises
   ``DIVE_THRESHOLD_M`` of water above its first readings' (the dive starts), at most
   ``LEADING_WINDOW_S``, of the readings within the first readings' own spread (4 robust σ, at
   least 2 cm of water: the descent's first centimetres are left out): the recording is assumed
   to start at the surface;
5. a value outside ``PLAUSIBLE_PA`` (the recording started under water), or no readings at all:
   the standard atmosphere, with a warning.

The datum of the GPS fixes: ``reader.datum``, else the sidecar's, else the first fix with a position.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from semslam.errors import MissionError, one_line
from semslam.mission.config import STANDARD_ATMOSPHERE_PA, ReaderConfig
from semslam.mission.geodesy import Geodetic
from semslam.mission.gps_messages import fix_position

GPS_WINDOW_S = 1.0
DIVE_THRESHOLD_M = 0.5
FIRST_READINGS = 10
LEADING_WINDOW_S = 120.0
MIN_READINGS = 5
PLAUSIBLE_PA = (50_000.0, 110_000.0)


@dataclass(frozen=True)
class Resolved:
    """A constant resolved for the mission: its value, how it was found, and a warning if it is a guess."""

    value: object
    how: str
    warning: str | None = None


def _messages(reader, topic: str):
    conns = [c for c in reader.connections if c.topic == topic]
    messages = reader.messages(connections=conns)
    while True:
        try:
            item = next(messages, None)
        except Exception as exc:  # a damaged chunk / page: whatever rosbags or the storage raises
            path = (getattr(reader, "paths", None) or ["bag"])[0]
            raise MissionError(f"{path}: corrupt or truncated bag ({one_line(exc)})") from None
        if item is None:
            return
        conn, t, raw = item
        try:
            yield t, reader.deserialize(raw, conn.msgtype)
        except Exception:  # the read reports a malformed message, with file, topic and stamp
            continue


def resolve_atmosphere(
    reader,
    cfg: ReaderConfig,
    sidecar_pa: float | None,
    has_sidecar: bool,
    depth_topic: str | None,
    gps_topic: str | None,
) -> Resolved:
    p = cfg.atmospheric_pressure_pa
    if p != "auto":
        return Resolved(float(p), "configured")
    if sidecar_pa is not None:
        return Resolved(float(sidecar_pa), "auto: from the mission's sidecar")
    if has_sidecar:
        return Resolved(STANDARD_ATMOSPHERE_PA, "auto: the standard atmosphere, as semslam wrote this mission")
    if depth_topic is None:
        return Resolved(STANDARD_ATMOSPHERE_PA, "auto: no depth sensor")
    rho_g = cfg.water_density_kg_m3 * cfg.gravity_m_s2
    found = _while_gps_fix(reader, depth_topic, gps_topic) if gps_topic else None
    if found is None:
        found = _before_dive(reader, depth_topic, DIVE_THRESHOLD_M * rho_g)
    if found is None:
        return Resolved(STANDARD_ATMOSPHERE_PA, "auto: the standard atmosphere", "no pressure readings to find it from")
    value, how = found
    lo, hi = PLAUSIBLE_PA
    if not lo <= value <= hi:
        return Resolved(
            STANDARD_ATMOSPHERE_PA,
            "auto: the standard atmosphere",
            f"{how} gave {value:.0f} Pa, not an atmospheric pressure (did the recording start under water?); "
            "set reader.atmospheric_pressure_pa",
        )
    return Resolved(value, f"auto: {how}")


def _while_gps_fix(reader, depth_topic: str, gps_topic: str) -> tuple[float, str] | None:
    fixes = np.array([t for t, msg in _messages(reader, gps_topic) if fix_position(msg) is not None], np.int64)
    if fixes.size == 0:
        return None
    times, pressures = [], []
    for t, msg in _messages(reader, depth_topic):
        times.append(t)
        pressures.append(float(msg.fluid_pressure))
    if not times:
        return None
    t = np.asarray(times, np.int64)
    k = np.clip(np.searchsorted(fixes, t), 1, fixes.size) - 1
    near = np.minimum(np.abs(t - fixes[k]), np.abs(t - fixes[np.minimum(k + 1, fixes.size - 1)]))
    at_surface = np.asarray(pressures)[near <= GPS_WINDOW_S * 1e9]
    at_surface = at_surface[np.isfinite(at_surface)]
    if at_surface.size < MIN_READINGS:
        return None
    return float(np.median(at_surface)), f"median of {at_surface.size} pressure readings while the GPS had a fix"


def _before_dive(reader, depth_topic: str, threshold_pa: float) -> tuple[float, str] | None:
    times, values = [], []
    for t, msg in _messages(reader, depth_topic):
        p = float(msg.fluid_pressure)
        if not np.isfinite(p):
            continue
        if len(values) >= FIRST_READINGS:
            ref = float(np.median(values[:FIRST_READINGS]))
            if p > ref + threshold_pa or t - times[0] > LEADING_WINDOW_S * 1e9:
                break
        times.append(t)
        values.append(p)
    if len(values) < MIN_READINGS:
        return None
    # The readings of the descent's start, below the dive threshold, would pull the median down:
    # keep those within the surface's own spread (waves, noise) of its first readings.
    v = np.asarray(values)
    first = v[:FIRST_READINGS]
    ref = float(np.median(first))
    band = max(4.0 * 1.4826 * float(np.median(np.abs(first - ref))), 0.02 * threshold_pa / DIVE_THRESHOLD_M)
    surface = v[np.abs(v - ref) <= band]
    span = (times[-1] - times[0]) * 1e-9
    return float(np.median(surface)), (
        f"median of {surface.size} pressure readings of the first {span:.1f} s, before the depth rose"
    )


def resolve_datum(reader, cfg: ReaderConfig, sidecar_datum: Geodetic | None, gps_topic: str | None) -> Resolved:
    if cfg.datum is not None:
        d = cfg.datum
        return Resolved(Geodetic(d.latitude_deg, d.longitude_deg, d.altitude_m), "configured")
    if sidecar_datum is not None:
        return Resolved(sidecar_datum, "from the mission's sidecar")
    if gps_topic is None:
        return Resolved(None, "no GPS")
    for _, msg in _messages(reader, gps_topic):
        where = fix_position(msg)
        if where is not None:
            return Resolved(where, "the first fix with a position")
    return Resolved(None, "no GPS fix with a position", "the GPS never had a fix: no GPS measurements")
