"""The mission as `run` and `compare` take it: read, front-ends chosen, checked before any estimation
(:func:`semslam.mission.check.check_mission`, as `info` and `study` check it), and what its complete
pass found said after the run (the input line, the stream's warnings, metrics.json's ``input``)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import typer

if TYPE_CHECKING:
    from semslam.config import SemslamConfig
    from semslam.mission.mission import Mission
    from semslam.results import PipelineResult

AllowMissingOpt = typer.Option(
    "",
    "--allow-missing",
    help="accept a mission without these sources (comma-separated: dvl, ahrs): a warning instead of a refusal",
)


def warn(text: str) -> None:
    typer.echo(f"semslam: warning: {text}", err=True)


def choose_frontends(option: str | None, metadata, mission: object) -> list[str]:
    """The front-ends a command runs, said on stdout: those named by ``--frontends`` (comma-separated;
    "" for none) or, without the option, those of the mission's sensor kinds
    (:func:`semslam.compare.default_frontends`). A named front-end that consumes nothing the
    mission's sensors give is an error naming it, what it consumes and the sensors there are."""
    from semslam.compare import default_frontends
    from semslam.errors import ConfigError
    from semslam.mission.conversions import KIND_OF
    from semslam.registry import load_frontend_class

    kinds = sorted({s.kind for s in metadata.sensors.values()})
    if option is None:
        names = default_frontends(metadata)
        typer.echo(f"front-ends: {', '.join(names) or 'none'} (by sensor kind; --frontends chooses)")
        return names
    names = [n.strip() for n in option.split(",") if n.strip()]
    given = tuple(t for t, kind in KIND_OF.items() if kind in kinds)
    for name in names:
        consumes = tuple(load_frontend_class(name).consumes)
        if not any(issubclass(t, consumes) for t in given):
            raise ConfigError(
                f"--frontends {name}: it consumes {', '.join(t.__name__ for t in consumes)}, which no sensor of "
                f"{mission} gives (sensors: {', '.join(kinds) or 'none'})"
            )
    typer.echo(f"front-ends: {', '.join(names) or 'none'} (--frontends)")
    return names


def checked_mission(
    path: Path, config: SemslamConfig, frontends: str | None, allow_missing: str
) -> tuple[Mission, list[str], list[str]]:
    """The mission at ``path``, the front-ends to run (``--frontends``, else by sensor kind; said on
    stdout) and the check's warnings (said on stderr). A refusal (no velocity or attitude source
    unless ``allow_missing`` accepts it) is a MissionError, raised before any estimation."""
    from semslam.mission.bag import read_mission
    from semslam.mission.check import check_mission, parse_allow_missing

    parse_allow_missing(allow_missing)  # a typo is said before the bag is opened
    mission = read_mission(path, config.reader)
    names = choose_frontends(frontends, mission.metadata, path)
    check = check_mission(mission, names, allow_missing)
    check.raise_if_refused()
    for line in check.warnings:
        warn(line)
    return mission, names, check.warnings


def after_the_pass(mission: Mission, result: PipelineResult, metrics: dict, warnings: list[str]) -> None:
    """Once the pipeline has read the whole mission: the stream's warnings (messages dropped for
    their stamps, a part of a reset mission read) and an estimator that estimated no pose at all
    on stderr; metrics.json's ``input`` (dropped and invalid counts per sensor, and every warning
    of the check, the stream and the results, when there are any); the input line on stdout."""
    from semslam.compare import input_after_the_pass
    from semslam.mission.check import input_line

    metrics["input"], said = input_after_the_pass(mission, result, warnings)
    for line in said:
        warn(line)
    typer.echo(input_line(mission))
