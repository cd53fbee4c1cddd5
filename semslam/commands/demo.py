"""`semslam demo`: the default tank mission, simulated and compared."""

from __future__ import annotations

from pathlib import Path

import typer

from semslam.cli_support import user_errors
from semslam.commands.run import OverwriteOpt, RecordPointsOpt, record_option


@user_errors
def demo(
    out: Path | None = typer.Option(None, "--out", "-o", help="output directory (default: runs/demo-<time>)"),
    record: bool = record_option(True),
    record_points: int | None = RecordPointsOpt,
    overwrite: bool = OverwriteOpt,
):
    """Simulate the default tank mission and compare dr, ekf and graph on it."""
    from semslam.demo import run_demo
    from semslam.eval.report import metrics_table, recognition_table, text_table

    metrics, out = run_demo(out, progress=True, record=record, overwrite=overwrite, record_points=record_points)
    typer.echo(f"front-ends: {', '.join(metrics['frontends']) or 'none'} (by sensor kind)")
    typer.echo(text_table(metrics_table(metrics)))
    rec = recognition_table(metrics)
    if rec:
        typer.echo("")
        typer.echo(text_table(rec))
    size = sum(f.stat().st_size for f in out.rglob("*") if f.is_file())
    typer.echo(
        f"\nwhole comparison: {metrics['wall_time_s']:.0f} s for {metrics['mission']['duration_s']:.0f} s of mission"
    )
    typer.echo(f"outputs: {out.resolve()} ({size / 1e6:.1f} MB)")
    typer.echo(f"report: {(out / 'report.html').resolve()}")
    if record:
        from semslam.eval.replay import how_to_open

        typer.echo(how_to_open(out))
