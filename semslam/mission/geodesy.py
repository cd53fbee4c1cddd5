"""Geodetic (WGS84) ↔ the mission's local NED frame about its datum, with pymap3d.

GPS messages give covariances in ENU about the fix (sensor_msgs/NavSatFix, gps_msgs/GPSFix); the
mission's world frame is NED, so those are permuted (E, N, U) → (N, E, −D).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# (E, N, U) → (N, E, D): x_NED = P x_ENU
_ENU_TO_NED = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])


@dataclass(frozen=True)
class Geodetic:
    """A WGS84 position: latitude and longitude in degrees, ellipsoidal height in metres."""

    latitude_deg: float
    longitude_deg: float
    altitude_m: float = 0.0

    def to_dict(self) -> dict:
        return {"latitude_deg": self.latitude_deg, "longitude_deg": self.longitude_deg, "altitude_m": self.altitude_m}

    @classmethod
    def from_dict(cls, d: dict) -> Geodetic:
        return cls(float(d["latitude_deg"]), float(d["longitude_deg"]), float(d.get("altitude_m", 0.0)))

    def format(self) -> str:
        ns = "N" if self.latitude_deg >= 0 else "S"
        ew = "E" if self.longitude_deg >= 0 else "W"
        return f"{abs(self.latitude_deg):.7f}°{ns} {abs(self.longitude_deg):.7f}°{ew} {self.altitude_m:.2f} m (WGS84)"


def to_ned(latitude_deg: float, longitude_deg: float, altitude_m: float, datum: Geodetic) -> np.ndarray:
    """The position (N, E, D) in metres about ``datum``."""
    import pymap3d

    n, e, d = pymap3d.geodetic2ned(
        latitude_deg, longitude_deg, altitude_m, datum.latitude_deg, datum.longitude_deg, datum.altitude_m
    )
    return np.array([float(n), float(e), float(d)])


def to_geodetic(ned: np.ndarray, datum: Geodetic) -> tuple[float, float, float]:
    """(latitude °, longitude °, height m) of the NED position ``ned`` about ``datum``."""
    import pymap3d

    lat, lon, alt = pymap3d.ned2geodetic(
        float(ned[0]), float(ned[1]), float(ned[2]), datum.latitude_deg, datum.longitude_deg, datum.altitude_m
    )
    return float(lat), float(lon), float(alt)


def enu_to_ned_covariance(cov_enu: np.ndarray) -> np.ndarray:
    return _ENU_TO_NED @ np.asarray(cov_enu, dtype=float).reshape(3, 3) @ _ENU_TO_NED.T


def ned_to_enu_covariance(cov_ned: np.ndarray) -> np.ndarray:
    return _ENU_TO_NED.T @ np.asarray(cov_ned, dtype=float).reshape(3, 3) @ _ENU_TO_NED
