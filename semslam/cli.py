"""The ``semslam`` command."""

from __future__ import annotations

import sys
from pathlib import Path

import typer

from semslam import __version__
from semslam.cli_support import user_errors
from semslam.errors import SemslamError

app = typer.Typer(
    name="semslam",
    help="Factor-graph back-end for underwater semantic SLAM.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
)
config_app = typer.Typer(help="Inspect the configuration.", no_args_is_help=True)
app.add_typer(config_app, name="config")


def _version(value: bool):
    if value:
        typer.echo(f"semslam {__version__}")
        raise typer.Exit()


@app.callback()
def main(
    version: bool = typer.Option(False, "--version", callback=_version, is_eager=True, help="Print the version."),
):
    """Factor-graph back-end for underwater semantic SLAM."""


MissionArg = typer.Argument(..., help="ROS 1 .bag, ROS 2 bag directory or .mcap")
ConfigOpt = typer.Option(None, "--config", "-c", help="YAML configuration (see `semslam config dump`)")


@app.command()
@user_errors
def info(mission: Path = MissionArg, config: Path | None = ConfigOpt):
    """Sensors, topics, message types, counts, rates, duration and gaps of a mission."""
    from semslam.config import load_config
    from semslam.mission.bag import read_mission
    from semslam.mission.summary import summarize

    cfg = load_config(config)
    m = read_mission(mission, cfg.reader)
    typer.echo(summarize(m, progress=sys.stderr.isatty()).format())


@config_app.command("dump")
@user_errors
def config_dump(config: Path | None = ConfigOpt):
    """Print the resolved configuration (defaults, overridden by --config)."""
    from semslam.config import dump_config, load_config

    typer.echo(dump_config(load_config(config)), nl=False)


@app.command()
@user_errors
def simulate(
    scene: str = typer.Argument(..., help="tank (laser, DVL, AHRS, depth) or field (multibeam sonar)"),
    out: Path = typer.Option(..., "--out", "-o", help="bag to write: .bag = ROS 1, .mcap, otherwise a ROS 2 directory"),
    seed: int = typer.Option(0, "--seed", help="random seed (seed 0 reproduces the default layout)"),
    loops: float | None = typer.Option(None, "--loops", help="tank: loops around the structure (default 3)"),
    dvl_dropout_rate: float | None = typer.Option(
        None, "--dvl-dropout-rate", help="fraction of the mission lost to random DVL dropout bursts"
    ),
    layout: Path | None = typer.Option(None, "--layout", help="tank: structure layout YAML instead of a seeded one"),
    preview: Path | None = typer.Option(None, "--preview", help="also render the scene and trajectory to this PNG"),
    sim_config: Path | None = typer.Option(None, "--sim-config", help="YAML overriding the simulator defaults"),
    overwrite: bool = typer.Option(False, "--overwrite", help="replace an existing bag"),
):
    """Simulate a mission with ground truth and write it as an ordinary ROS bag."""
    if out.exists() and not overwrite:  # say so before minutes of simulation, not after
        raise SemslamError(f"{out}: already exists (use --overwrite to replace it)")
    if scene == "tank":
        from semslam.sim.simulate import simulate_tank_to_bag

        m = simulate_tank_to_bag(
            out,
            seed=seed,
            dvl_dropout_rate=dvl_dropout_rate,
            loops=loops,
            preview=preview,
            config=sim_config,
            layout=layout,
            overwrite=overwrite,
            progress=sys.stderr.isatty(),
        )
    elif scene == "field":
        if loops is not None or layout is not None:
            raise SemslamError("--loops and --layout are options of the tank scene, not of the field")
        from semslam.sim.field_mission import simulate_field_to_bag

        m = simulate_field_to_bag(
            out,
            seed=seed,
            dvl_dropout_rate=dvl_dropout_rate,
            preview=preview,
            config=sim_config,
            overwrite=overwrite,
            progress=sys.stderr.isatty(),
        )
    else:
        raise SemslamError(f"unknown scene {scene!r} (choose tank or field)")
    gt = m.metadata.ground_truth
    if scene == "field":
        what = f"{len(gt.structures)} structures, {len(gt.pipes)} pipelines, {m.metadata.extras['sonar']['swaths']} sonar swaths"
    else:
        what = f"{len(gt.objects)} objects, {len(gt.pipes)} pipes"
    typer.echo(f"wrote {out}: {what}" + (f"; preview {preview}" if preview else ""))


@app.command()
@user_errors
def run(
    mission: Path = MissionArg,
    out: Path = typer.Option(..., "--out", "-o", help="output directory"),
    estimator: str = typer.Option("graph", "--estimator", "-e", help="graph, ekf or dr"),
    batch: bool = typer.Option(False, "--batch", help="graph: re-optimise the whole mission at the end"),
    frontends: str = typer.Option("", "--frontends", help="comma-separated front-end names"),
    config: Path | None = ConfigOpt,
):
    """Run one estimator over a mission and write its trajectory, map and metrics."""
    from semslam.config import load_config
    from semslam.estimators import create_estimator
    from semslam.eval.outputs import build_metrics, write_outputs
    from semslam.mission.bag import read_mission
    from semslam.pipeline import run_pipeline
    from semslam.registry import create_frontends

    cfg = load_config(config)
    m = read_mission(mission, cfg.reader)
    est = create_estimator(estimator, m.metadata, cfg, batch=batch)
    names = [n.strip() for n in frontends.split(",") if n.strip()]
    fes = create_frontends(names, m.metadata, cfg.frontends)
    result = run_pipeline(m, [est], fes, progress=sys.stderr.isatty())
    metrics = build_metrics(result, m.metadata)
    write_outputs(out, cfg, result, metrics)
    e = metrics["estimators"][est.name]
    ate = "n/a" if e["ate_rmse_m"] is None else f"{e['ate_rmse_m']:.3f} m"
    typer.echo(
        f"{est.name}: ATE RMSE {ate}, {e['n_objects']} objects, {e['n_pipes']} pipes, "
        f"{e['n_structures']} structures; outputs in {out}"
    )


@app.command()
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


@app.command()
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


def _plugin_commands() -> None:
    """Command groups that packages contribute through the ``semslam.commands`` entry-point group
    (e.g. ``models`` from the laser front-end's recognition), so the core imports no front-end."""
    from importlib.metadata import entry_points

    for ep in entry_points(group="semslam.commands"):
        try:
            sub = ep.load()
        except Exception as exc:  # a broken plug-in must not break the whole command
            typer.echo(f"semslam: warning: command group {ep.name!r} failed to load: {exc}", err=True)
            continue
        app.add_typer(sub, name=ep.name)


_plugin_commands()

if __name__ == "__main__":  # pragma: no cover
    app()
