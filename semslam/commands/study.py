"""`semslam study`: many missions as Dask tasks, with distributions and confidence intervals."""

from __future__ import annotations

from pathlib import Path

import typer

from semslam.cli_support import ConfigOpt, user_errors
from semslam.commands.simulate import VARY_HELP
from semslam.errors import SemslamError


@user_errors
def study(
    bags: list[Path] = typer.Argument(None, help="missions (ROS 1 .bag, ROS 2 bag directory or .mcap); or --scenario"),
    out: Path = typer.Option(..., "--out", "-o", help="study folder (re-running the same study resumes it)"),
    scenario: str | None = typer.Option(
        None, "--scenario", help="simulate the missions: tank, field, pipeline or dive"
    ),
    seeds: str = typer.Option("0-19", "--seeds", help="with --scenario: seeds, e.g. 0-49 or 0,3,7-9"),
    vary: str = typer.Option("all", "--vary", help=VARY_HELP),
    sim_config: Path | None = typer.Option(
        None, "--sim-config", help="with --scenario: YAML over the simulator's defaults"
    ),
    config: Path | None = ConfigOpt,
    frontends: str | None = typer.Option(None, "--frontends", help="comma-separated; default: by sensor kind"),
    hold_out_gps: str | None = typer.Option(
        None,
        "--hold-out-gps",
        help="last | every:N: each mission's GPS fixes kept from the estimators as its reference (as compare's); "
        "the study's GPS errors and ratios are at those fixes",
    ),
    scheduler: str | None = typer.Option(
        None, "--scheduler", help="address of a Dask scheduler (default: a LocalCluster)"
    ),
    workers: int | None = typer.Option(
        None,
        "--workers",
        help="LocalCluster workers, one mission each (default: one per two cores; at most one per core); "
        "a mission runs its front-ends in the cores left to it (as compare does when it has two or more)",
    ),
    timeout: float | None = typer.Option(None, "--timeout", help="seconds a mission may take before it is killed"),
    keep_bags: bool = typer.Option(
        False, "--keep-bags", help="with --scenario: keep each simulated bag in its mission folder"
    ),
):
    """Run many missions (simulated over seeds, or bags) as Dask tasks: each compared with dr, ekf and
    graph as `semslam compare` does, then distributions and paired ratios with bootstrap CIs."""
    from semslam.eval.gps_reference import HoldOut
    from semslam.sim.vary import parse_aspects
    from semslam.study.plan import bag_tasks, parse_seeds, scenario_tasks, semslam_config
    from semslam.study.run import run_study

    if bool(bags) == bool(scenario):
        raise SemslamError("give either bags or --scenario (not both, not neither)")
    if timeout is not None and timeout <= 0:
        raise SemslamError(f"--timeout: must be positive (got {timeout:g})")
    names = None if frontends is None else [n.strip() for n in frontends.split(",") if n.strip()]
    held = None if hold_out_gps is None else str(HoldOut.parse(hold_out_gps))  # a bad value: one line, now
    common = {"frontends": names, "hold_out_gps": held, "timeout_s": timeout, "keep_bag": keep_bags}
    out = out.resolve()
    cfg = semslam_config(config, scenario)
    description = {"config": str(config) if config else None, "frontends": names, "timeout_s": timeout}
    description["hold_out_gps"] = held
    if scenario:
        aspects = parse_aspects(vary)
        seed_list = parse_seeds(seeds)
        tasks = scenario_tasks(out, scenario, seed_list, aspects, cfg, sim_config, **common)
        description |= {"kind": "scenario", "scenario": scenario, "seeds": seed_list, "vary": list(aspects)}
        description["sim_config"] = str(sim_config) if sim_config else None
    else:
        if keep_bags or sim_config is not None:
            raise SemslamError("--keep-bags and --sim-config are options of a --scenario study")
        tasks = bag_tasks(out, bags, cfg, **common)
        description |= {"kind": "bags", "bags": [str(b) for b in bags]}
    result = run_study(tasks, out, description=description, scheduler=scheduler, workers=workers, log=typer.echo)
    c = result["counts"]
    typer.echo(f"{c['ok']}/{c['planned']} missions finished ({c['failed']} failed, {c['timeout']} timed out)")
    for pair, block in result["ratios"].items():
        r = block["ate_rmse_m"]
        if r["n"]:
            ci = r["median_ci95"]
            ci_text = f" [{ci[0]:.3f}, {ci[1]:.3f}]" if ci else ""
            typer.echo(f"ATE {pair}: median ratio {r['median']:.3f}{ci_text} over {r['n']} missions")
    typer.echo(f"report: {out / 'report.html'}")
    if c["ok"] < c["planned"]:
        raise typer.Exit(1)
