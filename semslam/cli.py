"""The ``semslam`` command: the app, assembled from one module per sub-command (``semslam.commands``)
and from the command groups that plug-ins contribute."""

from __future__ import annotations

import typer

from semslam import __version__
from semslam.commands import compare, config, demo, info, run, simulate, study

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


app.command("info")(info.info)
app.command("simulate")(simulate.simulate)
app.command("run")(run.run)
app.command("compare")(compare.compare)
app.command("demo")(demo.demo)
app.command("study")(study.study)
config_app.command("dump")(config.dump)


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
