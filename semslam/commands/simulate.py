"""`semslam simulate`: a simulated mission with ground truth, written as a ROS bag."""

from __future__ import annotations

import sys
from pathlib import Path

import typer

from semslam.cli_support import user_errors
from semslam.errors import SemslamError

VARY_HELP = (
    "what the seed draws besides the noise realisations: all, none, or a comma-separated subset of "
    "layout, trajectory, noise, dropouts, start (ranges: semslam/sim/vary.py); seed 0 is always the default mission; the pipeline's seed draws its whole world"
)


@user_errors
def simulate(
    scene: str = typer.Argument(
        ...,
        help="tank (laser, DVL, AHRS, depth), field (multibeam sonar), pipeline (stereo camera over a natural seabed) or dive (navigation from and back to the surface, GPS)",
    ),
    out: Path = typer.Option(..., "--out", "-o", help="bag to write: .bag = ROS 1, .mcap, otherwise a ROS 2 directory"),
    seed: int = typer.Option(0, "--seed", help="random seed (seed 0 reproduces the default mission)"),
    vary: str = typer.Option("all", "--vary", help=VARY_HELP),
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
    from semslam.sim.scenarios import scenario, simulate_with_options
    from semslam.sim.vary import parse_aspects

    if out.exists() and not overwrite:  # say so before minutes of simulation, not after
        raise SemslamError(f"{out}: already exists (use --overwrite to replace it)")
    m = simulate_with_options(
        scene,
        out,
        seed=seed,
        vary=parse_aspects(vary),
        config=sim_config,
        preview=preview,
        overwrite=overwrite,
        progress=sys.stderr.isatty(),
        dvl_dropout_rate=dvl_dropout_rate,
        loops=loops,
        layout=layout,
    )
    typer.echo(f"wrote {out}: {scenario(scene).describe(m)}" + (f"; preview {preview}" if preview else ""))
