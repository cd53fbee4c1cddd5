"""What every message codec shares: the errors a decoder raises, message type names, header stamps."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from semslam.mission.config import STANDARD_ATMOSPHERE_PA, ReaderConfig
from semslam.mission.geodesy import Geodetic


class MalformedMessage(ValueError):
    """A message that cannot be converted; ``field`` names the offending message field."""

    def __init__(self, field: str, what: str):
        super().__init__(f"field {field}: {what}")
        self.field = field
        self.what = what


class Unusable(ValueError):
    """A well-formed message that carries no measurement of its kind (dropped and counted under
    ``field``, a field name or a short reason such as ``status NO_FIX``)."""

    def __init__(self, field: str, what: str):
        super().__init__(f"field {field}: {what}")
        self.field = field


class Unencodable(ValueError):
    """A measurement that the chosen message type cannot carry."""


def normalize_msgtype(msgtype: str) -> str:
    """'sensor_msgs/PointCloud2' (ROS 1 spelling) → 'sensor_msgs/msg/PointCloud2'."""
    parts = msgtype.split("/")
    return f"{parts[0]}/msg/{parts[1]}" if len(parts) == 2 else msgtype


def short_msgtype(msgtype: str) -> str:
    """'sensor_msgs/msg/PointCloud2' → 'sensor_msgs/PointCloud2' (how people write it)."""
    return normalize_msgtype(msgtype).replace("/msg/", "/")


def stamp_ns(header) -> int:
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


def unknown_covariance(cov: np.ndarray) -> bool:
    """A covariance of all zeros: 'unknown' by the convention of sensor_msgs (Imu, NavSatFix) and of
    the DVL messages derived from UUV Simulator's (never a perfect sensor)."""
    return not any(np.asarray(cov).ravel().tolist())  # 9 values: faster in Python than np.any


@dataclass
class DecodeContext:
    """What decoders need beyond the message: the reader's configuration, the constants resolved
    for this mission (``auto`` replaced by what was found), and where they note an assumption (a
    covariance the message left unknown) so that ``semslam info`` can say what was assumed."""

    cfg: ReaderConfig
    atmospheric_pressure_pa: float = STANDARD_ATMOSPHERE_PA
    datum: Geodetic | None = None
    notes: dict[str, Counter[str]] = field(default_factory=dict)  # sensor → note → count
    pending: list[tuple[str, str]] = field(default_factory=list)  # the notes of the message being decoded

    def note(self, sensor: str, what: str) -> None:
        """Note an assumption made for the message being decoded; it counts once the reader keeps
        the measurement (``commit``), not if the message is dropped."""
        self.pending.append((sensor, what))

    def commit(self) -> None:
        for sensor, what in self.pending:
            self.notes.setdefault(sensor, Counter())[what] += 1
        self.pending.clear()
