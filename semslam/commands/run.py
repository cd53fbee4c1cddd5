"""`semslam run`: one estimator over a mission."""

from __future__ import annotations

import sys
from pathlib import Path

import typer

from semslam.cli_support import ConfigOpt, MissionArg, user_errors
from semslam.commands.mission_input import AllowMissingOpt

# Options that `compare` and `demo` share.
FrontendsOpt = typer.Option(
    None, "--frontends", help='comma-separated front-end names ("" for none); default: by sensor kind'
)
OverwriteOpt = typer.Option(False, "--overwrite", help="replace an existing output directory whole")
HoldOutGpsOpt = typer.Option(
    None, "--hold-out-gps", help="last | every:N: GPS fixes kept from the estimators, the reference of metrics.json"
)
RecordPointsOpt = typer.Option(
    None, "--record-points", min=0, help="replay: points kept of each scan (0: no scans; default 600)"
)


def record_option(default: bool):
    return typer.Option(
        default, "--record/--no-record", help="also write replay.mcap, a ROS 2 bag of the run for Foxglove and RViz"
    )


@user_errors
def run(
    mission: Path = MissionArg,
    out: Path = typer.Option(..., "--out", "-o", help="output directory"),
    estimator: str = typer.Option("graph", "--estimator", "-e", help="graph, ekf or dr"),
    batch: bool = typer.Option(False, "--batch", help="graph: re-optimise the whole mission at the end"),
    frontends: str | None = FrontendsOpt,
    config: Path | None = ConfigOpt,
    record: bool = record_option(False),
    record_points: int | None = RecordPointsOpt,
    hold_out_gps: str | None = HoldOutGpsOpt,
    overwrite: bool = OverwriteOpt,
    allow_missing: str = AllowMissingOpt,
):
    """Run one estimator over a mission and write its trajectory, map and metrics."""
    from semslam.commands.mission_input import after_the_pass, checked_mission
    from semslam.compare import estimators_input
    from semslam.config import load_config
    from semslam.estimators import create_estimator
    from semslam.eval.gps_reference import GpsReference, HoldOut, add_gps_reference
    from semslam.eval.outputs import build_metrics, staged_output, write_staged
    from semslam.eval.replay import make_recorder
    from semslam.pipeline import run_pipeline
    from semslam.registry import create_frontends

    # The output opened first: its path checked before any work, the run's spill files on its filesystem.
    with staged_output(out, overwrite) as stage:
        cfg = load_config(config)
        m, names, warnings = checked_mission(mission, cfg, frontends, allow_missing)
        # --batch turns it on; without the flag the config's graph.batch decides (it was ignored before)
        est = create_estimator(estimator, m.metadata, cfg, batch=True if batch else None)
        fes = create_frontends(names, m.metadata, cfg.frontends)
        recorder = make_recorder(record, m.metadata, record_points)
        observers = [recorder] if recorder is not None else []
        ref = GpsReference.hold_out(m, HoldOut.parse(hold_out_gps)) if hold_out_gps is not None else None
        seen = estimators_input(m, cfg, ref)
        # Only the labelled object observations (what the recognition tables read): a long survey's
        # records would otherwise keep every observation of the mission.
        result = run_pipeline(
            seen, [est], fes, progress=sys.stderr.isatty(), observers=observers, keep_observations="labelled"
        )
        metrics = add_gps_reference(build_metrics(result, m.metadata), ref, result, m.metadata)
        metrics["frontends"] = names
        after_the_pass(m, result, metrics, warnings)
        write_staged(stage, cfg, result, metrics, m.metadata, recorder=recorder)
    e = metrics["estimators"][est.name]
    ate = "n/a" if e["ate_rmse_m"] is None else f"{e['ate_rmse_m']:.3f} m"
    typer.echo(
        f"{est.name}: ATE RMSE {ate}, {e['n_objects']} objects, {e['n_pipes']} pipes, "
        f"{e['n_structures']} structures; outputs in {out}"
    )
    if recorder is not None:
        from semslam.eval.replay import how_to_open

        typer.echo(how_to_open(out))
