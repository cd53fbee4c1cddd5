"""`semslam info MISSION`: what a mission holds, and how it is read."""

from __future__ import annotations

import sys
from pathlib import Path

import typer

from semslam.cli_support import ConfigOpt, MissionArg, user_errors


@user_errors
def info(
    mission: Path = MissionArg,
    config: Path | None = ConfigOpt,
    write_config: Path | None = typer.Option(
        None,
        "--write-config",
        help="write the sensor binding used (every candidate topic listed, the unused ones commented out) "
        "as YAML, to edit and pass back with --config",
    ),
):
    """Sensors, topics, message types, counts, rates, duration and gaps of a mission; for a bag also
    the topic chosen per sensor, the stamps used, the surface pressure and GPS datum found, and why
    every other topic is left unread."""
    from semslam.config import load_config
    from semslam.errors import SemslamError
    from semslam.mission.bag import read_mission
    from semslam.mission.binding_yaml import binding_yaml
    from semslam.mission.summary import summarize

    cfg = load_config(config)
    m = read_mission(mission, cfg.reader)
    typer.echo(summarize(m, progress=sys.stderr.isatty()).format())
    if write_config is not None:
        try:
            write_config.write_text(binding_yaml(m))
        except OSError as exc:
            raise SemslamError(f"{write_config}: cannot write the configuration ({exc.strerror})") from None
        typer.echo(f"binding written to {write_config} (use it with --config {write_config})")
