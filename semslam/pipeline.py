"""The one driver: reads a mission once, runs the front-ends once per measurement, and feeds the
identical measurement and observation stream, in time order, to every estimator being compared."""

from __future__ import annotations

import time
from collections import defaultdict, deque
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from contextvars import ContextVar
from pathlib import Path
from typing import Protocol

from semslam.collector import heap_frozen
from semslam.determinism import one_thread_per_library
from semslam.estimation import EstimateView, Estimator, spilling_into
from semslam.frontend_process import FrontendProcess, default_workers, runs_in_process
from semslam.mapping.book import labelled
from semslam.mission.measurements import GroundTruthPose, Measurement
from semslam.mission.mission import Mission
from semslam.observations import Observation
from semslam.registry import Frontend
from semslam.results import LabelledViews, ObservationRecord, PipelineResult, PoseLog


class PipelineObserver(Protocol):
    """Watches a run as it happens (e.g. :class:`semslam.eval.replay.ReplayRecorder`). It only
    reads: what it is handed must not be changed, so a run gives the same result with or without it."""

    def step(
        self,
        stamp: int,
        measurement: Measurement | None,
        observations: Sequence[tuple[str, Sequence[Observation]]],
        views: Mapping[str, EstimateView],
    ) -> None:
        """After every estimator took ``measurement`` and the observations the front-ends drew from
        it, as (front-end name, observations) in the order fed; ``views`` are the estimators' current
        estimates, by name. ``measurement`` is None for the front-ends' last word at the mission's end."""


_AMBIENT: ContextVar[tuple[PipelineObserver, ...]] = ContextVar("semslam_pipeline_observers", default=())


@contextmanager
def observed_by(*observers: PipelineObserver) -> Iterator[None]:
    """Every pipeline run inside the block is watched by ``observers`` too: for callers that reach
    :func:`run_pipeline` through a function that does not pass observers on (``compare.run_comparison``)."""
    token = _AMBIENT.set(_AMBIENT.get() + tuple(observers))
    try:
        yield
    finally:
        _AMBIENT.reset(token)


def run_pipeline(
    mission: Mission,
    estimators: Sequence[Estimator],
    frontends: Sequence[Frontend] = (),
    view_estimator: str | None = None,
    progress: bool = False,
    keep_observations: bool | str = True,
    frontend_process: bool = True,
    frontend_workers: int | None = None,
    observers: Sequence[PipelineObserver] = (),
    spill_dir: str | Path | None = None,
) -> PipelineResult:
    """Feed ``mission`` through ``frontends`` into every estimator.

    Front-ends see the estimate of ``view_estimator`` (default: "graph" if present, else the first
    estimator) — the semantic feedback of the paper (global ids for class fusion). Front-ends that
    never read it (``uses_view = False``) run in worker processes a few scans ahead
    (``frontend_process``; see :mod:`semslam.frontend_process`): the same observations, in the same
    order, in less wall time. Of ``frontend_workers`` workers (default: one per core, at most 4),
    front-ends that declare ``parallel_consumes`` (the laser's scans) have a replica in each, sharing
    those measurements; the others live in one each. On any exception (Ctrl-C included) the workers
    are killed before it propagates. ``keep_observations``: the result keeps every observation (True),
    none (False), or "labelled": the numbers the recognition tables read of each labelled object
    observation (:func:`semslam.mapping.book.labelled`; ``PipelineResult.labelled``, kept with True
    too), not the observations: a long survey's observations are much of its memory. ``observers``
    (and those of an enclosing :func:`observed_by`) see every step; without any, nothing is
    collected for them. What the run appends for hours (the ground truth, the labelled views, the
    estimators' logs) goes to anonymous files in ``spill_dir`` as it comes
    (:class:`semslam.estimation.SpillLog`), so that an hours-long survey's memory stays flat; give
    the output's staging directory, so that they are on its filesystem (default: that of an
    enclosing :func:`semslam.estimation.spilling_into`, else the system's temporary directory, on
    some machines memory). A full disk there is a :class:`semslam.estimation.SpillError`.

    The numeric libraries (BLAS, OpenMP, Open3D's TBB) run on one thread each meanwhile, here and in
    the front-end workers (:func:`semslam.determinism.one_thread_per_library`): a parallel sum's
    last bits depend on the thread count and the machine's load, and a borderline decision of a
    front-end that reads the estimate would flip with them; so a mission gives the same result in a
    study worker, in ``compare`` and on a machine with another core count. The matrices are small
    anyway (an EKF of a few hundred states, 3×3 to 100×100 blocks): OpenBLAS's threads spinning
    against each other on a busy machine made the EKF 4.8× and the graph 1.6× slower (tank, 2 cores).
    """

    if not isinstance(keep_observations, bool) and keep_observations != "labelled":
        raise ValueError(f"keep_observations: True, False or 'labelled', not {keep_observations!r}")
    watchers = (*observers, *_AMBIENT.get())
    apart = [fe for fe in frontends if frontend_process and runs_in_process(fe)]
    worker = FrontendProcess(apart, frontend_workers or default_workers()) if apart else None
    try:
        with one_thread_per_library(), spilling_into(spill_dir), heap_frozen():
            result = _run_pipeline(
                mission, estimators, frontends, view_estimator, progress, keep_observations, worker, watchers
            )
    except BaseException:  # an error, Ctrl-C or SIGTERM: the workers' work is of no use, kill them now
        if worker is not None:
            worker.abort()
        raise
    if worker is not None:
        worker.close()
    return result


def _notify(watchers, stamp: int, measurement, fed: list, estimators) -> None:
    """Hand one step to every watcher, then start the next step's list of observations."""
    views = {est.name: est.view() for est in estimators}
    step = tuple(fed)
    for w in watchers:
        w.step(stamp, measurement, step, views)
    fed.clear()


# Measurements read ahead of the estimators when front-ends run apart: ~12 s of the tank mission
# (83 a second), a few scans for the front-end process to work on.
LOOKAHEAD = 1024


def _in_order(mission: Mission, worker: FrontendProcess | None, timing: dict):
    """The mission's measurements in order, each with whether a result will come back for it from
    the front-end process; reads up to LOOKAHEAD ahead, submitting to the process as it reads."""
    it = iter(mission)
    pending: deque = deque()
    exhausted = False
    while True:
        while not exhausted and (len(pending) < LOOKAHEAD if worker is not None else not pending):
            t0 = time.perf_counter()
            m = next(it, None)
            timing["read"] += time.perf_counter() - t0
            if m is None:
                exhausted = True
                break
            sent = worker is not None and worker.consumes(m) and worker.submit(m)
            pending.append((m, sent))
        if not pending:
            return
        yield pending.popleft()


def _run_pipeline(
    mission, estimators, frontends, view_estimator, progress, keep_observations, worker, watchers
) -> PipelineResult:
    if not estimators:
        raise ValueError("at least one estimator is needed")
    wall0 = time.perf_counter()
    by_name = {e.name: e for e in estimators}
    view_source = by_name.get(view_estimator or "graph", estimators[0])
    timing: dict[str, float] = defaultdict(float)
    truth = PoseLog()  # on disk (run_pipeline's spill_dir): the ground truth of a long survey is its largest stream
    records: list[ObservationRecord] = []
    labelled_views = LabelledViews()
    consumers = [(fe, tuple(fe.consumes)) for fe in frontends]
    apart = set(worker.names) if worker is not None else set()
    timed = [(est, f"estimator:{est.name}") for est in estimators]  # each estimator with its stage's name

    fed: list[tuple[str, list]] = []  # this step's observations, for the watchers

    def feed(fe_name: str, stamp: int, obs, step: list) -> None:
        """Keeps ``fe_name``'s observations and adds them to this measurement's ``step``."""
        if watchers:
            fed.append((fe_name, obs))
        if keep_observations:
            for o in obs:
                if labelled(o):
                    labelled_views.append(stamp, o)
        if keep_observations is True:
            records.extend(ObservationRecord(fe_name, stamp, o) for o in obs)
        step.extend(obs)

    def deliver(stamp: int, step: list) -> None:
        """One measurement's observations, of every front-end, to each estimator in one call: a graph
        makes one update of them (one update per front-end made the iSAM2 result depend on how many
        front-ends ran, even for one whose observations carry no information: experiments/odometry/README.md,
        stop 45)."""
        if not step:
            return
        for est, stage in timed:
            t0 = time.perf_counter()
            est.process_observations(stamp, step)
            timing[stage] += time.perf_counter() - t0

    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(
            total=getattr(mission, "message_count", None),
            unit=" msg",
            desc="mission",
            dynamic_ncols=True,
            mininterval=0.5,
        )
    first = last = None
    n = 0
    for m, sent in _in_order(mission, worker, timing):
        n += 1
        first = m.stamp if first is None else first
        last = m.stamp
        if isinstance(m, GroundTruthPose):
            truth.append(m.stamp, m.position, m.orientation)
        for est, stage in timed:
            t0 = time.perf_counter()
            est.process_measurement(m)
            timing[stage] += time.perf_counter() - t0
        done = worker.result() if sent else {}
        step: list = []
        for fe, types in consumers:  # in the front-ends' order, wherever they ran
            if fe.name in apart:
                if fe.name not in done:
                    continue
                obs, dt = done[fe.name]
            elif isinstance(m, types):
                t0 = time.perf_counter()
                obs = fe.process(m, view_source.view())
                dt = time.perf_counter() - t0
            else:
                continue
            timing[f"frontend:{fe.name}"] += dt
            if obs:
                feed(fe.name, m.stamp, obs, step)
        deliver(m.stamp, step)
        if watchers:
            _notify(watchers, m.stamp, m, fed, estimators)
        if bar is not None:
            bar.update(1)
            if n % 200 == 0:
                mission_s = (m.stamp - first) * 1e-9
                bar.set_postfix_str(
                    f"mission t={mission_s:6.1f} s, {mission_s / max(time.perf_counter() - wall0, 1e-9):5.1f}× real time"
                )
    summaries = {}
    step = []
    finished = worker.finish() if worker is not None else {}
    for fe, _ in consumers:  # the front-ends' last word, before the estimators close
        if fe.name in finished:
            summary, dt = finished[fe.name]
        elif fe.name not in apart and hasattr(fe, "finish"):
            t0 = time.perf_counter()
            summary = fe.finish(view_source.view())
            dt = time.perf_counter() - t0
        else:
            continue
        timing[f"frontend:{fe.name}"] += dt
        if summary is None:
            continue
        summaries[fe.name] = summary
        if summary.observations and last is not None:
            feed(fe.name, last, summary.observations, step)
    if last is not None:
        deliver(last, step)
    if watchers and fed:
        _notify(watchers, last, None, fed, estimators)
    results = {}
    for est in estimators:
        t0 = time.perf_counter()
        results[est.name] = est.finish()
        timing[f"estimator:{est.name}"] += time.perf_counter() - t0
    if bar is not None:
        bar.close()
    if worker is not None:  # the stages overlapped: their sum is not the time it took
        timing["wall"] = time.perf_counter() - wall0
    duration = 0.0 if first is None else (last - first) * 1e-9
    resolved = {
        fe.name: fe.config.model_dump(mode="json")
        for fe in frontends
        if hasattr(getattr(fe, "config", None), "model_dump")
    }
    return PipelineResult(
        results, truth.trajectory(), records, dict(timing), n, duration, summaries, resolved, labelled_views
    )
