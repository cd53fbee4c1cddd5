"""The Dask side of a study: a client on a LocalCluster or on the user's scheduler, and the tasks'
results as they complete.

Default: a ``LocalCluster`` of worker processes with one thread each, one per two cores: a mission
runs its estimators in its own process and its front-ends in two more (as `semslam compare` does),
which keeps about two cores busy; two such missions on two cores only contend (measured:
experiments/speed/README.md, `bench_study.py`). ``--workers N`` asks for more, at most one per
core. ``--scheduler ADDRESS`` joins an existing cluster (``dask scheduler`` / ``dask worker``, jobqueue, Kubernetes, ...); its
workers must have semslam installed and see the study folder (and the bags) at the same paths.
A worker that dies while running a mission is replaced by Dask and its task run again elsewhere
(up to the scheduler's ``distributed.scheduler.allowed-failures`` times, 3 by default).
"""

from __future__ import annotations

import contextlib
import logging
import os
import uuid
from collections.abc import Iterator, Sequence

from semslam.errors import SemslamError
from semslam.study.plan import MissionTask
from semslam.study.store import StudyStore
from semslam.study.task import run_mission

CORES_PER_MISSION = 2  # a mission's main process plus its front-end workers keep ~2 cores busy


def local_workers(requested: int | None, n_tasks: int) -> int:
    """Workers of a LocalCluster: as requested (default: one per two cores), but at most one per
    core and one per mission."""
    cores = os.cpu_count() or 1
    if requested is not None and requested < 1:
        raise SemslamError(f"--workers: must be at least 1 (got {requested})")
    default = max(1, cores // CORES_PER_MISSION)
    return max(1, min(requested or default, cores, n_tasks))


def frontend_workers_per_mission(n_workers: int | None) -> int:
    """The front-end processes each mission starts: the cores of this machine a LocalCluster of
    ``n_workers`` leaves each mission (``--workers 1``: all of them, as `semslam compare` would);
    one on a user's cluster (``None``), whose workers are taken to be one core each."""
    if n_workers is None:
        return 1
    return max(1, (os.cpu_count() or 1) // n_workers)


@contextlib.contextmanager
def dask_client(scheduler: str | None, n_workers: int) -> Iterator:
    """A ``distributed.Client`` on ``scheduler``, or on a LocalCluster of ``n_workers`` processes."""
    from distributed import Client, LocalCluster

    if scheduler:
        try:
            client = Client(scheduler, timeout="30s")
        except (OSError, TimeoutError) as exc:
            raise SemslamError(f"--scheduler {scheduler}: cannot connect ({exc})") from None
        with client:
            yield client
        return
    with (
        LocalCluster(
            n_workers=n_workers,
            threads_per_worker=1,
            processes=True,
            dashboard_address=None,
            silence_logs=logging.ERROR,
        ) as cluster,
        Client(cluster) as client,
    ):
        yield client


def run_tasks(client, tasks: Sequence[MissionTask], store: StudyStore) -> Iterator[dict]:
    """Submit every task and yield :func:`~semslam.study.task.run_mission`'s results as they come.
    A task that errs in Dask itself (e.g. its worker died more often than the scheduler allows) is
    recorded and yielded as a failure. Interrupted, the tasks not yet done are cancelled."""
    from distributed import as_completed

    run = uuid.uuid4().hex[:8]  # a fresh key per run: never a result cached from an earlier one
    futures = {
        client.submit(run_mission, t.to_dict(), key=f"semslam-study-{t.mission}-{run}", pure=False): t for t in tasks
    }
    try:
        for fut in as_completed(futures):
            task = futures[fut]
            try:
                yield fut.result()
            except Exception as exc:  # the task itself (not its mission) failed in Dask
                failure = {"mission": task.mission, "status": "failed", "error": f"{type(exc).__name__}: {exc}"}
                yield {
                    "mission": task.mission,
                    "status": "failed",
                    "wall_s": None,
                    "failure": store.record_failure(task.mission, failure, None),
                }
    finally:
        client.cancel([f for f in futures if not f.done()])
