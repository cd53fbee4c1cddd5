"""`semslam simulate`: a simulated mission with ground truth, written as a ROS bag."""

from __future__ import annotations

import sys
from pathlib import Path

import typer

from semslam.cli_support import user_errors
from semslam.errors import SemslamError


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
