"""The front-end protocol and registry.

Front-ends are found through the entry-point group ``semslam.frontends``: a third-party package
plugs one in by declaring, in its own pyproject.toml::

    [project.entry-points."semslam.frontends"]
    mysonar = "mypkg.sonar:MySonarFrontend"

The built-in front-ends are registered the same way. Nothing in ``semslam`` imports a concrete
front-end.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from importlib.metadata import entry_points
from pathlib import Path
from typing import Any, ClassVar

from pydantic import BaseModel

from semslam.errors import ConfigError, validated
from semslam.estimation import EstimateView
from semslam.mission.measurements import Measurement
from semslam.mission.mission import MissionMetadata
from semslam.observations import Observation

ENTRY_POINT_GROUP = "semslam.frontends"


class Frontend(ABC):
    """A sensor front-end: the base class of every front-end, built-in or plugged in.

    Constructed as ``cls(metadata, config)`` where ``config`` is the front-end's own section of the
    configuration (``frontends.<name>``, a mapping), which it validates with its ``config_model``
    (e.g. through :func:`semslam.errors.validated`) and keeps as ``self.config``.

    Required: ``name``, ``consumes`` (the measurement types it takes), ``config_model`` (the pydantic
    model of its section: ``semslam config dump`` prints its keys) and :meth:`process`. The optional
    hooks below have their defaults here.
    """

    name: ClassVar[str]
    consumes: ClassVar[tuple[type[Measurement], ...]]
    config_model: ClassVar[type[BaseModel]]
    #: False for a front-end that never reads the view: it then runs in a process of its own, ahead of
    #: the estimators (semslam.frontend_process); it, its observations and its summary must pickle,
    #: and it gets ``view=None``.
    uses_view: ClassVar[bool] = True
    #: With ``uses_view = False``: the consumed types whose result depends only on the measurement and
    #: on what the front-end kept from its other types; replicas in several worker processes then
    #: share them, and :meth:`finish` must not depend on them.
    parallel_consumes: ClassVar[tuple[type[Measurement], ...]] = ()
    config: BaseModel

    @abstractmethod
    def process(self, measurement: Measurement, view: EstimateView | None) -> list[Observation]:
        """The observations drawn from one measurement (in the sensor's frame, see semslam.observations)."""

    def finish(self, view: EstimateView | None) -> FrontendSummary | None:
        """What the front-end hands over at the end of the mission (see :class:`FrontendSummary`)."""
        return None

    @classmethod
    def __subclasshook__(cls, other: type):
        # A class that declares every member, required and optional, is a front-end without deriving
        # from this one (structurally); one that lacks hooks is adopted by the registry (_adopt).
        if cls is Frontend and all(any(a in b.__dict__ for b in other.__mro__) for a in (*REQUIRED, *HOOKS)):
            return True
        return NotImplemented


REQUIRED = ("name", "consumes", "config_model", "process")
HOOKS = ("uses_view", "parallel_consumes", "finish")


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
    if not isinstance(cls, type):
        raise ConfigError(f"front-end {name!r} ({eps[name].value}) is not a class")
    missing = [attr for attr in REQUIRED if not hasattr(cls, attr)]
    if missing:
        raise ConfigError(f"front-end {name!r} ({eps[name].value}) lacks {', '.join(missing)}")
    if not issubclass(cls, Frontend):
        _adopt(cls)
    return cls


def _adopt(cls: type) -> None:
    """A front-end written before the base class (it has the required members but does not derive from
    :class:`Frontend`) gets the base class's defaults for the optional hooks it does not declare, and
    counts as a Frontend: the driver then calls every hook without asking whether it exists."""
    for hook in HOOKS:
        if not hasattr(cls, hook):
            setattr(cls, hook, getattr(Frontend, hook))
    Frontend.register(cls)


def frontend_sections(sections: Mapping[str, Mapping[str, Any]] | None = None) -> dict[str, BaseModel]:
    """Every registered front-end's configuration section, validated by its ``config_model``: its
    defaults overridden by ``sections[name]`` (the ``frontends`` section of the configuration). A
    section for a front-end that is not registered is a ConfigError."""
    sections = dict(sections or {})
    registered = available_frontends()
    unknown = sorted(set(sections) - set(registered))
    if unknown:
        known = ", ".join(sorted(registered)) or "none"
        raise ConfigError(f"frontends.{unknown[0]}: no such front-end (registered: {known})")
    out = {}
    for name in sorted(registered):
        cls = load_frontend_class(name)
        out[name] = validated(cls.config_model, sections.get(name), f"frontends.{name}")
    return out


def create_frontends(
    names: Sequence[str], metadata: MissionMetadata, configs: Mapping[str, Mapping[str, Any]] | None = None
) -> list[Frontend]:
    configs = configs or {}
    return [load_frontend_class(n)(metadata, dict(configs.get(n, {}))) for n in names]
