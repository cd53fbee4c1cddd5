"""The mission: sensor metadata (extrinsics, topics) and a time-ordered stream of measurements."""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field

import numpy as np

from semslam.errors import MissionError
from semslam.mission.geodesy import Geodetic
from semslam.mission.ground_truth import GroundTruthMap
from semslam.mission.measurements import DvlVelocity, Measurement

SENSOR_KINDS = ("dvl", "ahrs", "depth", "gps", "laser", "sonar", "ground_truth")


@dataclass
class SensorInfo:
    """One sensor of the vehicle: its kind, where it is recorded, and its extrinsic T_BS (4×4)."""

    name: str
    kind: str
    topic: str | None = None
    msgtype: str | None = None
    T_BS: np.ndarray = field(default_factory=lambda: np.eye(4))

    def __post_init__(self):
        if self.kind not in SENSOR_KINDS:
            raise ValueError(f"sensor {self.name!r}: unknown kind {self.kind!r} (expected one of {SENSOR_KINDS})")
        self.T_BS = np.asarray(self.T_BS, dtype=float).reshape(4, 4)


@dataclass
class MissionMetadata:
    """Everything about a mission that is not a measurement."""

    name: str = "mission"
    sensors: dict[str, SensorInfo] = field(default_factory=dict)
    ground_truth: GroundTruthMap | None = None  # None: the mission has none (a real recording)
    extras: dict = field(default_factory=dict)  # e.g. the simulator's declared noise and scene
    datum: Geodetic | None = None  # origin of the local NED frame of GPS fixes

    def sensors_of_kind(self, kind: str) -> list[SensorInfo]:
        return [s for s in self.sensors.values() if s.kind == kind]

    def extrinsic(self, sensor: str) -> np.ndarray:
        """T_BS (4×4) of ``sensor``; a sensor the mission does not declare is an error, never an
        identity silently assumed (an observation from it cannot be placed on the vehicle)."""
        info = self.sensors.get(sensor)
        if info is None:
            known = ", ".join(sorted(self.sensors)) or "none"
            raise MissionError(
                f"mission {self.name}: sensor {sensor!r} is not declared (sensors: {known}); its extrinsic T_BS is unknown"
            )
        return info.T_BS


@dataclass
class SensorStats:
    """Per-sensor statistics of a mission stream, as ``semslam info`` reports them."""

    count: int = 0
    first: int | None = None
    last: int | None = None
    dropped_nonfinite: int = 0
    invalid: int = 0  # e.g. DVL readings flagged invalid (dropouts)
    max_gap_s: float = 0.0
    gaps: list[tuple[float, float]] = field(default_factory=list)  # (start_s, duration_s) of dropouts/gaps

    @property
    def rate_hz(self) -> float | None:
        if self.count < 2 or self.first is None or self.last is None or self.last == self.first:
            return None
        return (self.count - 1) / ((self.last - self.first) * 1e-9)


class Mission:
    """A mission: metadata plus measurements iterated in stamp order.

    The measurements come from ``source``, a callable returning a fresh iterator each time, so a
    large bag can be streamed more than once without being held in memory.
    """

    def __init__(self, metadata: MissionMetadata, source: Callable[[], Iterable[Measurement]]):
        self.metadata = metadata
        self._source = source
        self.dropped: Counter[str] = Counter()  # sensor -> measurements dropped as non-finite (filled by readers)
        self.invalid: Counter[str] = Counter()  # sensor -> readings flagged invalid (DVL dropouts), last full pass
        self.rest = None  # the start at rest applied to it (semslam.mission.rest.RestAssumption), if any
        self.label: str | None = None  # what warnings call it, when its file's path would mislead (a study's stage)

    @classmethod
    def from_measurements(cls, metadata: MissionMetadata, measurements: Iterable[Measurement]) -> Mission:
        items = sorted(measurements, key=lambda m: m.stamp)  # stable: equal stamps keep their order
        return cls(metadata, lambda: iter(items))

    def __iter__(self) -> Iterator[Measurement]:
        invalid: Counter[str] = Counter()
        for m in self._source():
            if type(m) is DvlVelocity and not m.valid:
                invalid[m.sensor] += 1
            yield m
        self.invalid = invalid

    def of_type(self, cls: type[Measurement]) -> Iterator[Measurement]:
        return (m for m in self if isinstance(m, cls))

    def only(self, sensors: Iterable[str]) -> Mission:
        """The measurements of ``sensors`` alone, as a mission (a bag reads only their topics)."""
        keep = set(sensors)
        return Mission(self.metadata, lambda: (m for m in self._source() if m.sensor in keep))

    def without(self, leave_out: Callable[[Measurement], bool]) -> Mission:
        """The mission without the measurements ``leave_out`` picks (e.g. GPS fixes held out as the
        reference); a pass over it is a pass over this mission (its counts are this one's)."""
        return Mission(self.metadata, lambda: (m for m in self if not leave_out(m)))
