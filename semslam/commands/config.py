"""`semslam config dump`: the resolved configuration."""

from __future__ import annotations

from pathlib import Path

import typer

from semslam.cli_support import ConfigOpt, user_errors


@user_errors
def dump(config: Path | None = ConfigOpt):
    """Print the resolved configuration, every key with its description: the defaults, overridden by
    --config, and the section of every registered front-end."""
    from semslam.config import dump_config, load_config
    from semslam.registry import frontend_sections

    cfg = load_config(config)
    typer.echo(dump_config(cfg, frontend_sections(cfg.frontends)), nl=False)
