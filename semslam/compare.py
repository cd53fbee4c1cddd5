"""Compare dr, ekf and graph on one mission: one pipeline run, identical inputs, one report."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from semslam.config import SemslamConfig
from semslam.estimation import EstimatorResult
from semslam.estimators import create_estimator
from semslam.eval.gps_reference import GpsReference, HoldOut, add_gps_reference
from semslam.eval.metrics import recovered_failures
from semslam.eval.outputs import build_metrics, staged_output, write_staged
from semslam.mission.check import input_block, stream_findings, where
from semslam.mission.mission import Mission, MissionMetadata
from semslam.mission.rest import at_rest_until_velocity
from semslam.pipeline import run_pipeline
from semslam.registry import available_frontends, create_frontends
from semslam.results import PipelineResult

DEFAULT_ESTIMATORS = ("dr", "ekf", "graph")
# Which registered front-end handles which sensor kind when the user names none.
FRONTEND_FOR_KIND = {"laser": "laser", "sonar": "sonar"}


def default_frontends(metadata: MissionMetadata) -> list[str]:
    registered = available_frontends()
    kinds = {s.kind for s in metadata.sensors.values()}
    return [fe for kind, fe in FRONTEND_FOR_KIND.items() if kind in kinds and fe in registered]


def estimators_input(mission: Mission, config: SemslamConfig, reference: GpsReference | None = None) -> Mission:
    """The stream every estimator reads: ``mission`` with the start at rest (:mod:`semslam.mission.rest`,
    recorded as ``mission.rest`` for the run's warnings and metrics.json's ``input``), without the GPS
    fixes held out as the ``reference``."""
    initial = config.initial
    seen, mission.rest = at_rest_until_velocity(
        mission,
        initial.at_rest_until_velocity_sigma_m_s,
        initial.still_test_readings,
        initial.at_rest_waiting_sigma_m_s,
    )
    return reference.estimators_see(seen) if reference is not None else seen


def run_comparison(
    mission: Mission,
    config: SemslamConfig,
    frontends: Sequence[str] | None = None,
    estimators: Sequence[str] = DEFAULT_ESTIMATORS,
    progress: bool = False,
    frontend_workers: int | None = None,
    hold_out_gps: HoldOut | None = None,
    check_warnings: Sequence[str] = (),
) -> tuple[PipelineResult, dict]:
    """Run every estimator on the identical measurement and observation stream; return the
    pipeline result and metrics.json's content. ``frontend_workers``: processes for the front-ends
    that run apart (default one per core; a study running one mission per core wants 1).
    ``hold_out_gps``: GPS fixes kept from the estimators as the reference (semslam.eval.gps_reference);
    ``check_warnings``: the mission check's, for metrics.json's ``input`` (:func:`input_after_the_pass`)."""
    names = list(frontends) if frontends is not None else default_frontends(mission.metadata)
    fes = create_frontends(names, mission.metadata, config.frontends)
    ests = [create_estimator(n, mission.metadata, config) for n in estimators]
    reference = GpsReference.hold_out(mission, hold_out_gps) if hold_out_gps is not None else None
    seen = estimators_input(mission, config, reference)
    result = run_pipeline(seen, ests, fes, view_estimator="graph", progress=progress, frontend_workers=frontend_workers)
    metrics = add_gps_reference(build_metrics(result, mission.metadata), reference, result, mission.metadata)
    metrics["input"], _ = input_after_the_pass(mission, result, check_warnings)
    metrics["frontends"] = names
    return result, metrics


def at_mission_time(diagnostic: str, result: EstimatorResult) -> str:
    """A diagnostic led by its stamp in ns, with the stamp as seconds after the estimate's start."""
    stamp, sep, text = diagnostic.partition(": ")
    if not (sep and stamp.isdigit() and len(result.trajectory)):
        return diagnostic
    return f"at {(int(stamp) - int(result.trajectory.stamps[0])) * 1e-9:.1f} s: {text}"


def input_after_the_pass(mission: Mission, result: PipelineResult, check_warnings: Sequence[str] = ()):
    """After the pipeline's complete pass over ``mission``: metrics.json's ``input`` block (dropped and
    invalid counts, and every warning when there is any: the check's, the stream's, the assumptions'
    and an estimator that estimated no pose) and the warnings found after the pass (to be said)."""
    said = [f"{where(mission)}: {f.text}" for f in stream_findings(mission) if f.severity == "warning"]
    for name, r in result.results.items():
        if len(r.trajectory) == 0:
            why = "; ".join(r.diagnostics[-1:]) or "no attitude or velocity reading to start from"
            said.append(f"{name}: no pose estimated ({why}): its trajectory and map are empty")
        elif failures := recovered_failures(r.diagnostics):
            said.append(
                f"{name}: recovered from {len(failures)} solver failure(s), the first {at_mission_time(failures[0], r)}; "
                "its estimate may be off from there (all its diagnostics in metrics.json)"
            )
    block = input_block(mission)
    if check_warnings or said:  # only then: the block of a clean mission has counts alone
        block["warnings"] = [*check_warnings, *said]
    return block, said


def compare_to_dir(
    mission: Mission,
    config: SemslamConfig,
    out: str | Path,
    frontends: Sequence[str] | None = None,
    progress: bool = False,
    overwrite: bool = False,
) -> tuple[dict, Path]:
    """:func:`run_comparison`, its results and report written to ``out`` as one transaction;
    returns metrics.json's content and the report's path."""
    with staged_output(out, overwrite) as stage:  # opened first: the run spills into it
        result, metrics = run_comparison(mission, config, frontends, progress=progress)
        write_staged(stage, config, result, metrics, mission.metadata, report=True)
    return metrics, Path(out) / "report.html"
