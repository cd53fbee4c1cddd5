"""`semslam config dump`: the resolved configuration."""

from __future__ import annotations

from pathlib import Path

import typer

from semslam.cli_support import ConfigOpt, user_errors


@user_errors
def dump(config: Path | None = ConfigOpt):
    """Print the resolved configuration (defaults, overridden by --config)."""
    from semslam.config import dump_config, load_config

    typer.echo(dump_config(load_config(config)), nl=False)
