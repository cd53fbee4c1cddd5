"""What every `semslam` command shares, including command groups that plug-ins contribute."""

from __future__ import annotations

import functools

import typer

from semslam.errors import SemslamError


def user_errors(fn):
    """A user error becomes one line on stderr and exit code 1, never a traceback."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        try:
            return fn(*args, **kwargs)
        except SemslamError as exc:
            typer.echo(f"semslam: error: {exc}", err=True)
            raise typer.Exit(1) from None
        except KeyboardInterrupt:
            typer.echo("semslam: interrupted", err=True)
            raise typer.Exit(130) from None

    return wrapper


MissionArg = typer.Argument(..., help="ROS 1 .bag, ROS 2 bag directory or .mcap")
ConfigOpt = typer.Option(None, "--config", "-c", help="YAML configuration (see `semslam config dump`)")
