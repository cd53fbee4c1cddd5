"""`semslam models ...`: the CAD models that object recognition knows (plugged into the CLI
through the ``semslam.commands`` entry point)."""

from __future__ import annotations

from pathlib import Path

import typer

from semslam.cli_support import user_errors
from semslam.errors import SemslamError

app = typer.Typer(help="CAD models that object recognition knows.", no_args_is_help=True)


@app.command("add")
@user_errors
def models_add(
    file: Path = typer.Argument(..., help="the model's mesh: STL, OBJ or PLY"),
    cls: str = typer.Option(..., "--class", help="the object class it belongs to"),
    name: str | None = typer.Option(None, "--name", help="model name (default: the file's stem)"),
    scale: float = typer.Option(1.0, "--scale", help="factor to metres (e.g. 0.001 for a mesh in mm)"),
):
    """Make a user's CAD model recognisable: render its views and cache their descriptors."""
    from frontends.laser.recognition.views import add_model

    mv = add_model(file, cls, name=name, scale=scale)
    typer.echo(f"model {mv.name!r} ({mv.cls}): {len(mv.T_CM)} views described and cached")


@app.command("list")
@user_errors
def models_list():
    """The user models registered for recognition (the built-in library is always included)."""
    from frontends.laser.recognition.views import registered_models

    models = registered_models()
    if not models:
        typer.echo("no user models (the six built-in classes are always known)")
    for model_name, entry in sorted(models.items()):
        typer.echo(f"{model_name}: {entry}")


@app.command("remove")
@user_errors
def models_remove(name: str = typer.Argument(..., help="model name")):
    """Forget a user model."""
    from frontends.laser.recognition.views import remove_model

    if not remove_model(name):
        raise SemslamError(f"no user model named {name!r}")
    typer.echo(f"removed {name!r}")
