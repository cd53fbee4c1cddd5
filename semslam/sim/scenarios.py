"""The simulated scenarios by name: what ``semslam simulate`` and ``semslam study --scenario`` run.

A scenario names its configuration model, its simulation function and the mission's one-line
description; :func:`resolve_config` builds a configuration the way both commands do it (defaults ←
what the seed draws for the varied aspects ← the user's YAML ← explicit options) and
:func:`simulate_to_bag` simulates it and writes the bag. Modules are imported when used, so that
naming a scenario stays cheap (no open3d).
"""

from __future__ import annotations

from collections.abc import Callable, Collection
from dataclasses import dataclass, field
from importlib import import_module
from pathlib import Path

from pydantic import BaseModel

from semslam.errors import ConfigError
from semslam.sim.config import build_sim_config, read_yaml_mapping
from semslam.sim.vary import ASPECTS, draws


def _load(ref: str):
    module, name = ref.split(":")
    return getattr(import_module(module), name)


def _describe_tank(mission) -> str:
    gt = mission.metadata.ground_truth
    return f"{len(gt.objects)} objects, {len(gt.pipes)} pipes"


def _describe_pipeline(mission) -> str:
    gt = mission.metadata.ground_truth
    return f"{len(gt.objects)} fittings, {len(gt.pipes)} pipe pieces, {len(mission.metadata.extras['scans'])} stereo clouds"


def _describe_field(mission) -> str:
    gt = mission.metadata.ground_truth
    swaths = mission.metadata.extras["sonar"]["swaths"]
    return f"{len(gt.structures)} structures, {len(gt.pipes)} pipelines, {swaths} sonar swaths"


@dataclass(frozen=True)
class Scenario:
    name: str
    summary: str
    config_model: str  # "module:Class" of its pydantic configuration
    simulate: str  # "module:function" (config, progress=...) -> Mission
    preview: str  # "module:function" (mission, png)
    describe: Callable = field(repr=False)  # mission -> one line for the user
    options: tuple[str, ...] = ()  # the simulate command's scenario-specific options it accepts
    varies_as: str | None = None  # the scenario whose seeded draws (semslam.sim.vary) it takes
    varied: bool = True  # its seeds draw world parameters (semslam.sim.vary); else the seed alone draws the world

    def model(self) -> type[BaseModel]:
        return _load(self.config_model)

    def simulator(self) -> Callable:
        return _load(self.simulate)


SCENARIOS: dict[str, Scenario] = {
    "tank": Scenario(
        "tank",
        "laser scans of a pipe rack",
        "semslam.sim.config:TankSimConfig",
        "semslam.sim.simulate:simulate_tank",
        "semslam.sim.preview:render_preview",
        _describe_tank,
        ("loops", "layout"),
    ),
    "field": Scenario(
        "field",
        "multibeam survey of 3 subsea structures",
        "semslam.sim.field_config:FieldSimConfig",
        "semslam.sim.field_mission:simulate_field",
        "semslam.sim.field_preview:render_field_preview",
        _describe_field,
    ),
    "dive": Scenario(
        "dive",
        "navigation dive from and back to the surface (GPS at the surface)",
        "semslam.sim.dive:DiveSimConfig",
        "semslam.sim.dive:simulate_dive",
        "semslam.sim.dive:render_preview",
        lambda mission: _load("semslam.sim.dive:describe")(mission),
        varies_as="field",
    ),
    "pipeline": Scenario(
        "pipeline",
        "stereo clouds of a pipeline on a natural seabed",
        "semslam.sim.pipeline_config:PipelineSimConfig",
        "semslam.sim.pipeline_mission:simulate_pipeline",
        "semslam.sim.pipeline_preview:render_pipeline_preview",
        _describe_pipeline,
        varied=False,
    ),
}


def scenario(name: str) -> Scenario:
    if name not in SCENARIOS:
        raise ConfigError(f"unknown scene {name!r} (choose {', '.join(SCENARIOS)})")
    return SCENARIOS[name]


#: options of ``semslam simulate`` → the configuration key they set
OPTION_KEYS = {
    "dvl_dropout_rate": "dvl__random_dropout_rate",
    "loops": "trajectory__loops",
    "layout": "structure__layout_yaml",
}


def option_overrides(name: str, **options) -> dict:
    """The configuration overrides of the options given (not None) to scenario ``name``: a
    :class:`ConfigError` for an option the scenario does not have."""
    given = {k: v for k, v in options.items() if v is not None}
    for k in given:
        if k not in ("dvl_dropout_rate", *scenario(name).options):
            owners = [s.name for s in SCENARIOS.values() if k in s.options]
            flag = "--" + k.replace("_", "-")
            raise ConfigError(f"{flag} is an option of the {' and '.join(owners)} scene, not of the {name}")
    return {OPTION_KEYS[k]: str(v) if isinstance(v, Path) else v for k, v in given.items()}


def resolve_config(
    name: str,
    seed: int,
    vary: Collection[str] = (),
    data: dict | None = None,
    source: str | None = None,
    **overrides,
) -> BaseModel:
    """The configuration of scenario ``name`` for ``seed``: defaults ← what the seed draws for the
    ``vary`` aspects (:mod:`semslam.sim.vary`; nothing for seed 0 or a scenario whose seed alone draws
    its world) ← ``data`` (the user's YAML
    mapping, named ``source`` in errors) ← ``overrides`` (dotted keys with ``__``)."""
    sc = scenario(name)
    base = draws(sc.varies_as or name, seed, vary) if sc.varied else {}
    return build_sim_config(sc.model(), data or {}, source=source, base=base, seed=seed, **overrides)


def simulate_to_bag(
    name: str,
    config: BaseModel,
    out: str | Path,
    *,
    preview: str | Path | None = None,
    overwrite: bool = False,
    progress: bool = False,
):
    """Simulate ``config`` (a configuration of scenario ``name``), write the bag (+ sidecar) at
    ``out`` and, if asked, the preview PNG. Returns the mission."""
    from semslam.mission.bag import write_mission

    sc = scenario(name)
    mission = sc.simulator()(config, progress=progress)
    write_mission(mission, out, overwrite=overwrite)
    if preview is not None:
        _load(sc.preview)(mission, preview)
    return mission


def simulate_with_options(
    name: str,
    out: str | Path,
    *,
    seed: int = 0,
    vary: Collection[str] = ASPECTS,
    config: str | Path | None = None,
    preview: str | Path | None = None,
    overwrite: bool = False,
    progress: bool = False,
    **options,
):
    """What ``semslam simulate NAME`` does: the configuration from ``seed``, ``vary``, the YAML file
    ``config`` and the command's ``options`` (:data:`OPTION_KEYS`), simulated and written to ``out``."""
    data = None if config is None else read_yaml_mapping(config, "simulation configuration")
    source = None if config is None else str(config)
    cfg = resolve_config(name, seed, vary, data, source, **option_overrides(name, **options))
    return simulate_to_bag(name, cfg, out, preview=preview, overwrite=overwrite, progress=progress)
