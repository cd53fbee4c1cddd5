"""The one driver: reads a mission once, runs the front-ends once per measurement, and feeds the
identical measurement and observation stream, in time order, to every estimator being compared."""

from __future__ import annotations

import time
from collections import defaultdict
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from semslam.estimation import Estimator, EstimatorResult, Trajectory
from semslam.mission.measurements import GroundTruthPose
from semslam.mission.mission import Mission
from semslam.observations import Observation
from semslam.registry import Frontend, FrontendSummary


@dataclass
class ObservationRecord:
    """One observation as a front-end produced it (kept for evaluation, e.g. recognition tables)."""

    frontend: str
    stamp: int
    observation: Observation


@dataclass
class PipelineResult:
    results: dict[str, EstimatorResult]
    truth: Trajectory | None
    observations: list[ObservationRecord] = field(default_factory=list)
    timing_s: dict[str, float] = field(default_factory=dict)  # "read", "frontend:<name>", "estimator:<name>"
    n_measurements: int = 0
    duration_s: float = 0.0
    frontend_summaries: dict[str, FrontendSummary] = field(default_factory=dict)
    # Each front-end's configuration as it ran (its defaults filled in), for config.yaml.
    frontend_configs: dict[str, dict] = field(default_factory=dict)


def _truth_trajectory(poses: list[GroundTruthPose]) -> Trajectory | None:
    if not poses:
        return None
    return Trajectory(
        stamps=np.array([p.stamp for p in poses], np.int64),
        positions=np.array([p.position for p in poses]),
        orientations=np.array([p.orientation for p in poses]),
    )


def run_pipeline(
    mission: Mission,
    estimators: Sequence[Estimator],
    frontends: Sequence[Frontend] = (),
    view_estimator: str | None = None,
    progress: bool = False,
    keep_observations: bool = True,
) -> PipelineResult:
    """Feed ``mission`` through ``frontends`` into every estimator.

    Front-ends see the estimate of ``view_estimator`` (default: "graph" if present, else the first
    estimator) — the semantic feedback of the paper (global ids for class fusion).

    BLAS runs single-threaded meanwhile: the matrices here are small (an EKF of a few hundred
    states, 3×3 to 100×100 blocks), and OpenBLAS's threads spinning against GTSAM's and each other
    on a busy machine made the EKF 4.8× and the graph 1.6× slower (tank mission, 2 cores).
    """
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1, user_api="blas"):
        return _run_pipeline(mission, estimators, frontends, view_estimator, progress, keep_observations)


def _run_pipeline(mission, estimators, frontends, view_estimator, progress, keep_observations) -> PipelineResult:
    if not estimators:
        raise ValueError("at least one estimator is needed")
    by_name = {e.name: e for e in estimators}
    view_source = by_name.get(view_estimator or "graph", estimators[0])
    timing: dict[str, float] = defaultdict(float)
    truth: list[GroundTruthPose] = []
    records: list[ObservationRecord] = []
    consumers = [(fe, tuple(fe.consumes)) for fe in frontends]

    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=getattr(mission, "message_count", None), unit=" msg", desc="mission", dynamic_ncols=True,
                   mininterval=0.5)
        wall0 = time.perf_counter()
    first = last = None
    n = 0
    it = iter(mission)
    while True:
        t0 = time.perf_counter()
        try:
            m = next(it)
        except StopIteration:
            break
        timing["read"] += time.perf_counter() - t0
        n += 1
        first = m.stamp if first is None else first
        last = m.stamp
        if isinstance(m, GroundTruthPose):
            truth.append(m)
        for est in estimators:
            t0 = time.perf_counter()
            est.process_measurement(m)
            timing[f"estimator:{est.name}"] += time.perf_counter() - t0
        for fe, types in consumers:
            if not isinstance(m, types):
                continue
            t0 = time.perf_counter()
            obs = fe.process(m, view_source.view())
            timing[f"frontend:{fe.name}"] += time.perf_counter() - t0
            if not obs:
                continue
            if keep_observations:
                records.extend(ObservationRecord(fe.name, m.stamp, o) for o in obs)
            for est in estimators:
                t0 = time.perf_counter()
                est.process_observations(m.stamp, obs)
                timing[f"estimator:{est.name}"] += time.perf_counter() - t0
        if bar is not None:
            bar.update(1)
            if n % 200 == 0:
                mission_s = (m.stamp - first) * 1e-9
                bar.set_postfix_str(f"mission t={mission_s:6.1f} s, {mission_s / max(time.perf_counter() - wall0, 1e-9):5.1f}× real time")
    summaries = {}
    for fe, _ in consumers:  # the front-ends' last word, before the estimators close
        if not hasattr(fe, "finish"):
            continue
        t0 = time.perf_counter()
        summary = fe.finish(view_source.view())
        timing[f"frontend:{fe.name}"] += time.perf_counter() - t0
        if summary is None:
            continue
        summaries[fe.name] = summary
        if summary.observations and last is not None:
            if keep_observations:
                records.extend(ObservationRecord(fe.name, last, o) for o in summary.observations)
            for est in estimators:
                t0 = time.perf_counter()
                est.process_observations(last, summary.observations)
                timing[f"estimator:{est.name}"] += time.perf_counter() - t0
    results = {}
    for est in estimators:
        t0 = time.perf_counter()
        results[est.name] = est.finish()
        timing[f"estimator:{est.name}"] += time.perf_counter() - t0
    if bar is not None:
        bar.close()
    duration = 0.0 if first is None else (last - first) * 1e-9
    resolved = {fe.name: fe.config.model_dump(mode="json") for fe in frontends if hasattr(getattr(fe, "config", None), "model_dump")}
    return PipelineResult(results, _truth_trajectory(truth), records, dict(timing), n, duration, summaries, resolved)
