"""`semslam info MISSION`: what a mission holds, how it is read, and what the mission check finds."""

from __future__ import annotations

import sys
from pathlib import Path

import typer

from semslam.cli_support import ConfigOpt, MissionArg, user_errors
from semslam.commands.mission_input import AllowMissingOpt


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
    allow_missing: str = AllowMissingOpt,
    frontends: str = typer.Option(
        "", "--frontends", help="the front-ends a run would use (comma-separated; odometry is a velocity source)"
    ),
):
    """Sensors, topics, message types, counts, rates, duration and gaps of a mission; for a bag also
    the topic chosen per sensor, the stamps used, the surface pressure and GPS datum found, and why
    every other topic is left unread. Then the mission check that run, compare and study apply:
    exit status 1 when it refuses the mission (the report is printed all the same)."""
    from semslam.config import load_config
    from semslam.errors import SemslamError
    from semslam.mission.bag import read_mission
    from semslam.mission.binding_yaml import binding_yaml
    from semslam.mission.check import check_mission, stream_findings
    from semslam.mission.summary import summarize

    cfg = load_config(config)
    m = read_mission(mission, cfg.reader, survey=True)
    check = check_mission(m, [n.strip() for n in frontends.split(",") if n.strip()], allow_missing)
    summary = summarize(m, progress=sys.stderr.isatty())
    check.findings += stream_findings(m)
    typer.echo(summary.format() + "\n" + "\n".join(check.lines()))
    if write_config is not None:
        try:
            write_config.write_text(binding_yaml(m))
        except OSError as exc:
            raise SemslamError(f"{write_config}: cannot write the configuration ({exc.strerror})") from None
        typer.echo(f"binding written to {write_config} (use it with --config {write_config})")
    check.raise_if_refused()
