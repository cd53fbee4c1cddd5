"""`semslam compare`: dr, ekf and graph on identical inputs, with a report."""

from __future__ import annotations

import sys
from pathlib import Path

import typer

from semslam.cli_support import ConfigOpt, MissionArg, user_errors


@user_errors
def compare(
    mission: Path = MissionArg,
    out: Path = typer.Option(..., "--out", "-o", help="output directory"),
    frontends: str | None = typer.Option(None, "--frontends", help="comma-separated; default: by sensor kind"),
    config: Path | None = ConfigOpt,
):
    """dr, ekf and graph on identical inputs, with a report."""
    from semslam.compare import compare_to_dir
    from semslam.config import load_config
    from semslam.eval.report import metrics_table, text_table
    from semslam.mission.bag import read_mission

    cfg = load_config(config)
    m = read_mission(mission, cfg.reader)
    names = None if frontends is None else [n.strip() for n in frontends.split(",") if n.strip()]
    metrics, report = compare_to_dir(m, cfg, out, names, progress=sys.stderr.isatty())
    typer.echo(text_table(metrics_table(metrics)))
    typer.echo(f"report: {report}")
