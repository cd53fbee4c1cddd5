"""The front-end protocol and registry.

Front-ends are found through the entry-point group ``semslam.frontends``: a third-party package
plugs one in by declaring, in its own pyproject.toml::

    [project.entry-points."semslam.frontends"]
    mysonar = "mypkg.sonar:MySonarFrontend"

The built-in front-ends are registered the same way. Nothing in ``semslam`` imports a concrete
front-end.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from importlib.metadata import entry_points
from pathlib import Path
from typing import Any, ClassVar, Protocol, runtime_checkable

from semslam.errors import ConfigError
from semslam.estimation import EstimateView
from semslam.mission.measurements import Measurement
from semslam.mission.mission import MissionMetadata
from semslam.observations import Observation

ENTRY_POINT_GROUP = "semslam.frontends"


@runtime_checkable
class Frontend(Protocol):
    """A sensor front-end.

    Constructed as ``cls(metadata, config)`` where ``config`` is the front-end's own section of the
    configuration (``frontends.<name>``), which the front-end validates itself.
    """

    name: ClassVar[str]
    consumes: ClassVar[tuple[type[Measurement], ...]]

    def process(self, measurement: Measurement, view: EstimateView) -> list[Observation]: ...

    # Optional: ``finish(view) -> FrontendSummary`` at the end of the mission (see FrontendSummary).
    # Optional: ``uses_view: ClassVar[bool] = False`` for a front-end that never reads the view: it
    # then runs in a process of its own, ahead of the estimators (semslam.frontend_process); it, its
    # observations and its summary must pickle, and it gets ``view=None``.
    # Optional with it: ``parallel_consumes: ClassVar[tuple[type, ...]]``, the consumed types whose
    # result depends only on the measurement and on what the front-end kept from its other types;
    # replicas in several worker processes then share them (semslam.frontend_process), and
    # ``finish()`` must not depend on them.


@dataclass
class FrontendSummary:
    """What a front-end hands over at the end of a mission (all optional).

    ``observations``: last observations, fed to every estimator at the mission's last stamp (e.g. a
    final recognition pass). ``metrics``: a block of metrics.json, under the key ``section``
    (e.g. ``"sonar"``). ``files``: extra outputs, file name → writer(path) called inside the output
    directory's staging folder (e.g. a world model mesh), so a failure leaves nothing half-written.
    """

    section: str | None = None
    metrics: dict[str, Any] = field(default_factory=dict)
    observations: list[Observation] = field(default_factory=list)
    files: dict[str, Callable[[Path], None]] = field(default_factory=dict)


def available_frontends() -> dict[str, Any]:
    """Entry points of every registered front-end, by name."""
    return {ep.name: ep for ep in entry_points(group=ENTRY_POINT_GROUP)}


def load_frontend_class(name: str) -> type:
    eps = available_frontends()
    if name not in eps:
        known = ", ".join(sorted(eps)) or "none"
        raise ConfigError(f"unknown front-end {name!r} (registered: {known})")
    try:
        cls = eps[name].load()
    except Exception as exc:  # a broken plug-in must not take the whole command down with a traceback
        raise ConfigError(f"front-end {name!r} ({eps[name].value}) failed to load: {exc}") from exc
    missing = [attr for attr in ("name", "consumes", "process") if not hasattr(cls, attr)]
    if missing:
        raise ConfigError(f"front-end {name!r} ({eps[name].value}) lacks {', '.join(missing)}")
    return cls


def create_frontends(
    names: Sequence[str], metadata: MissionMetadata, configs: Mapping[str, Mapping[str, Any]] | None = None
) -> list[Frontend]:
    configs = configs or {}
    return [load_frontend_class(n)(metadata, dict(configs.get(n, {}))) for n in names]
