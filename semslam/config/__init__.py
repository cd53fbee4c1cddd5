"""The typed configuration of semslam, the bottom layer: every default lives in a section model
(:mod:`semslam.config.estimation` for what every estimator shares, :mod:`semslam.config.graph`,
:mod:`semslam.config.ekf`; the bag reader's in :mod:`semslam.mission.config`; each front-end's in its
own ``config_model``), documented by its Field description. ``semslam config dump`` prints the
resolved configuration, every key with its description."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any, TypeVar

import yaml
from pydantic import BaseModel, ConfigDict, Field, model_validator

from semslam.config.ekf import EkfConfig
from semslam.config.estimation import (
    DEFAULT_BIAS_SIGMA0,
    MIN_BIAS_SIGMA0,
    AssociationConfig,
    InitialStateConfig,
    MotionNoiseConfig,
    SensorModelConfig,
)
from semslam.config.graph import GraphConfig
from semslam.errors import ConfigError, validated
from semslam.mission.config import ReaderConfig

__all__ = [
    "DEFAULT_BIAS_SIGMA0",
    "MIN_BIAS_SIGMA0",
    "AssociationConfig",
    "EkfConfig",
    "GraphConfig",
    "InitialStateConfig",
    "MotionNoiseConfig",
    "SemslamConfig",
    "SensorModelConfig",
    "dump_config",
    "load_config",
    "read_yaml_mapping",
]

M = TypeVar("M", bound=BaseModel)


class SemslamConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")
    reader: ReaderConfig = Field(default_factory=ReaderConfig, description="how a bag is read (semslam.mission)")
    initial: InitialStateConfig = Field(default_factory=InitialStateConfig, description="every estimator's start")
    motion: MotionNoiseConfig = Field(default_factory=MotionNoiseConfig, description="vehicle motion model noise")
    sensors: SensorModelConfig = Field(default_factory=SensorModelConfig, description="sensor error models")
    association: AssociationConfig = Field(
        default_factory=AssociationConfig, description="map building, the same for every estimator (semslam.mapping)"
    )
    graph: GraphConfig = Field(default_factory=GraphConfig, description="graph back-end (semslam.backend)")
    ekf: EkfConfig = Field(default_factory=EkfConfig, description="EKF-SLAM and dead reckoning (semslam.ekf)")
    frontends: dict[str, dict[str, Any]] = Field(
        default_factory=dict, description="front-end name → its own section, validated by the front-end's config_model"
    )

    @model_validator(mode="after")
    def _window_holds_tracks(self) -> SemslamConfig:
        # a tentative landmark's views must still be in the graph's window when it is promoted
        w, t = self.graph.window_s, self.association.track_timeout_s
        if w is not None and w <= 2 * t:
            raise ValueError(f"graph.window_s ({w} s) must exceed twice association.track_timeout_s ({t} s)")
        return self


def read_yaml_mapping(path: str | Path, what: str = "configuration") -> dict:
    """The mapping at the top of the YAML file ``path``; a missing file, invalid YAML or another
    top-level type is a one-line :class:`ConfigError` naming the file (``what``: what it is for)."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"{path}: {what} file not found")
    try:
        data = yaml.safe_load(path.read_text()) or {}
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML ({str(exc).splitlines()[0]})") from exc
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a mapping at the top level")
    return data


def load_config(path: str | Path | None = None) -> SemslamConfig:
    """The defaults, overridden by the YAML file at ``path`` if given."""
    if path is None:
        return SemslamConfig()
    data = read_yaml_mapping(path)
    try:
        return validated(SemslamConfig, data, "")
    except ConfigError as exc:  # "<file>: <key>: <problem>"
        raise ConfigError(f"{path}: {str(exc).lstrip('.: ')}") from None


def dump_config(config: SemslamConfig, frontends: Mapping[str, BaseModel] | None = None) -> str:
    """``config`` as YAML, every key preceded by its description as a comment. ``frontends``: each
    front-end's validated section (its ``config_model``), so that their keys are printed with their
    defaults too; a front-end section without a model is printed as given."""
    lines: list[str] = []
    for name, info in SemslamConfig.model_fields.items():
        if name == "frontends":
            continue
        _emit(lines, name, getattr(config, name), info.description, 0)
    sections = dict(config.frontends)
    sections.update(frontends or {})
    _comment(lines, SemslamConfig.model_fields["frontends"].description, 0)
    if not sections:
        lines.append("frontends: {}")
    else:
        lines.append("frontends:")
        for name in sorted(sections):
            _emit(lines, name, sections[name], None, 1)
    return "\n".join(lines) + "\n"


def _comment(lines: list[str], text: str | None, depth: int) -> None:
    if text:
        lines.append(f"{'  ' * depth}# {' '.join(text.split())}")


def _emit(lines: list[str], key: str, value: Any, description: str | None, depth: int) -> None:
    pad = "  " * depth
    _comment(lines, description, depth)
    if isinstance(value, BaseModel):
        lines.append(f"{pad}{key}:")
        for name, info in type(value).model_fields.items():
            _emit(lines, name, getattr(value, name), info.description, depth + 1)
        return
    if isinstance(value, Mapping) and value:
        lines.append(f"{pad}{key}:")
        for k, v in value.items():
            _emit(lines, str(k), v, None, depth + 1)
        return
    plain = value.model_dump(mode="json") if isinstance(value, BaseModel) else _jsonable(value)
    flow = yaml.safe_dump(plain, default_flow_style=True, allow_unicode=True, width=10_000).strip()
    lines.append(f"{pad}{key}: {flow.removesuffix('...').strip()}")


def _jsonable(value: Any) -> Any:
    """Tuples as lists, models as dicts: what YAML's safe dumper takes."""
    if isinstance(value, BaseModel):
        return value.model_dump(mode="json")
    if isinstance(value, (tuple, list)):
        return [_jsonable(v) for v in value]
    if isinstance(value, Mapping):
        return {str(k): _jsonable(v) for k, v in value.items()}
    return value
