"""Front-ends for tests that feed estimators through the one driver (semslam.pipeline): observations
made in advance, observations computed from a measurement, and probes of an estimator's state."""

from __future__ import annotations

from collections.abc import Callable
from typing import ClassVar

from pydantic import BaseModel

from semslam.mission.measurements import Measurement, PointCloud
from semslam.observations import Observation
from semslam.registry import Frontend


class _NoConfig(BaseModel):
    pass


class Replay(Frontend):
    """Hands over, at each scan (PointCloud), the observations made for its stamp in advance."""

    name: ClassVar[str] = "replay"
    consumes: ClassVar[tuple] = (PointCloud,)
    config_model: ClassVar[type] = _NoConfig

    def __init__(self, observations: dict[int, list[Observation]]):
        self.observations = observations

    def process(self, measurement: Measurement, view=None) -> list[Observation]:
        return list(self.observations.get(measurement.stamp, []))


class Scanner(Frontend):
    """Observations computed from each measurement of the given types by ``scan(measurement)``."""

    name: ClassVar[str] = "scanner"
    consumes: ClassVar[tuple] = ()
    config_model: ClassVar[type] = _NoConfig

    def __init__(
        self, types: tuple[type, ...], scan: Callable[[Measurement], list[Observation]], name: str = "scanner"
    ):
        self.consumes = types  # per instance
        self.name = name
        self.scan = scan

    def process(self, measurement: Measurement, view=None) -> list[Observation]:
        return self.scan(measurement) or []


def probe(types: tuple[type, ...], look: Callable[[Measurement], None], name: str = "probe") -> Scanner:
    """A front-end that observes nothing and calls ``look(measurement)``: after the estimators took the
    measurement, and after the observations of the front-ends before it in the list."""

    def scan(m: Measurement) -> list[Observation]:
        look(m)
        return []

    return Scanner(types, scan, name)
