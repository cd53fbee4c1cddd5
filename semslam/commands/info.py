"""`semslam info MISSION`: what a mission holds."""

from __future__ import annotations

import sys
from pathlib import Path

import typer

from semslam.cli_support import ConfigOpt, MissionArg, user_errors


@user_errors
def info(mission: Path = MissionArg, config: Path | None = ConfigOpt):
    """Sensors, topics, message types, counts, rates, duration and gaps of a mission."""
    from semslam.config import load_config
    from semslam.mission.bag import read_mission
    from semslam.mission.summary import summarize

    cfg = load_config(config)
    m = read_mission(mission, cfg.reader)
    typer.echo(summarize(m, progress=sys.stderr.isatty()).format())
