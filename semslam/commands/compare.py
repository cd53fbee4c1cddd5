"""`semslam compare`: dr, ekf and graph on identical inputs, with a report."""

from __future__ import annotations

import sys
from pathlib import Path

import typer

from semslam.cli_support import ConfigOpt, MissionArg, user_errors
from semslam.commands.mission_input import AllowMissingOpt
from semslam.commands.run import FrontendsOpt, HoldOutGpsOpt, OverwriteOpt, RecordPointsOpt, record_option


@user_errors
def compare(
    mission: Path = MissionArg,
    out: Path = typer.Option(..., "--out", "-o", help="output directory"),
    frontends: str | None = FrontendsOpt,
    config: Path | None = ConfigOpt,
    record: bool = record_option(False),
    record_points: int | None = RecordPointsOpt,
    hold_out_gps: str | None = HoldOutGpsOpt,
    overwrite: bool = OverwriteOpt,
    allow_missing: str = AllowMissingOpt,
):
    """dr, ekf and graph on identical inputs, with a report."""
    from semslam.commands.mission_input import after_the_pass, checked_mission
    from semslam.compare import run_comparison
    from semslam.config import load_config
    from semslam.eval.gps_reference import HoldOut
    from semslam.eval.outputs import staged_output, write_staged
    from semslam.eval.replay import make_recorder
    from semslam.eval.report import metrics_table, text_table
    from semslam.pipeline import observed_by

    # The output opened first: its path checked before any work, the run's spill files on its filesystem.
    with staged_output(out, overwrite) as stage:
        cfg = load_config(config)
        hold_out = HoldOut.parse(hold_out_gps) if hold_out_gps is not None else None
        m, names, warnings = checked_mission(mission, cfg, frontends, allow_missing)
        recorder = make_recorder(record, m.metadata, record_points)
        with observed_by(*([recorder] if recorder is not None else [])):
            result, metrics = run_comparison(m, cfg, names, progress=sys.stderr.isatty(), hold_out_gps=hold_out)
        after_the_pass(m, result, metrics, warnings)
        write_staged(stage, cfg, result, metrics, m.metadata, report=True, recorder=recorder)
    typer.echo(text_table(metrics_table(metrics)))
    typer.echo(f"report: {Path(out) / 'report.html'}")
    if recorder is not None:
        from semslam.eval.replay import how_to_open

        typer.echo(how_to_open(out))
