"""`semslam demo`: the default tank mission, simulated and compared."""

from __future__ import annotations

from pathlib import Path

import typer

from semslam.cli_support import user_errors


@user_errors
def demo(out: Path | None = typer.Option(None, "--out", "-o", help="output directory")):
    """Simulate the default tank mission and compare dr, ekf and graph on it."""
    from semslam.demo import run_demo
    from semslam.eval.report import metrics_table, recognition_table, text_table

    metrics, report = run_demo(out, progress=True)
    typer.echo(text_table(metrics_table(metrics)))
    rec = recognition_table(metrics)
    if rec:
        typer.echo("")
        typer.echo(text_table(rec))
    typer.echo(
        f"\nwhole comparison: {metrics['wall_time_s']:.0f} s for {metrics['mission']['duration_s']:.0f} s of mission"
    )
    typer.echo(f"report: {report.resolve()}")
