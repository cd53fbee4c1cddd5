"""``run_study``: the missions of a study on Dask, resumable, then ``study.json`` and ``report.html``."""

from __future__ import annotations

import sys
import time
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import semslam
from semslam.errors import SemslamError
from semslam.study.cluster import dask_client, frontend_workers_per_mission, local_workers, run_tasks
from semslam.study.output import build_study, write_json
from semslam.study.plan import MissionTask
from semslam.study.report import write_study_report
from semslam.study.store import StudyStore


def _progress(total: int, done: int, enabled: bool):
    from tqdm import tqdm

    return tqdm(total=total, initial=done, unit="mission", desc="study", disable=not enabled, dynamic_ncols=True)


def run_study(
    tasks: Sequence[MissionTask],
    out: str | Path,
    *,
    description: dict | None = None,
    scheduler: str | None = None,
    workers: int | None = None,
    progress: bool | None = None,
    log=print,
) -> dict:
    """Run the missions of ``tasks`` not finished yet in ``out`` (each one Dask task), then write
    ``out/study.json`` and ``out/report.html`` over all of them; returns study.json's content.

    Finished missions are reused untouched, failed ones run again. A finished mission computed from
    another source or configuration than its task's is an error (the study would mix two studies).
    ``log`` gets one line per mission as it ends (and the failures as they happen); ``progress``
    (default: stderr is a terminal) shows a bar instead of the per-mission lines.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    store = StudyStore(out)
    store.lock()
    try:
        store.clear_staging()
        results: dict[str, dict] = {}
        previous_failures: dict[str, dict] = {}
        todo = []
        for t in tasks:
            rec = store.finished(t.mission)
            if rec is None:
                todo.append(t)
                previous_failures[t.mission] = store.failure(t.mission)
            elif rec.get("identity") != t.identity_hash():
                raise SemslamError(
                    f"{out / t.mission}: was computed from another source or configuration than this study's "
                    "(use another --out, or remove that mission to recompute it)"
                )
            else:
                results[t.mission] = _finished(t, rec, reused=True)
        info = {
            "title": out.name,
            **(description or {}),
            "semslam_version": semslam.__version__,
            "scheduler": scheduler or "LocalCluster",
            "workers": None,
            "reused": len(results),
            "started": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
            "wall_s": None,
        }
        t0 = time.perf_counter()
        try:
            if todo:
                _run(tasks, todo, results, store, scheduler, workers, info, progress, log)
        finally:  # interrupted too: what finished is in the study
            info["wall_s"] = time.perf_counter() - t0
            for t in todo:  # a mission that completed while the study shut down, its result unheard
                if t.mission not in results and (rec := store.finished(t.mission)) is not None:
                    results[t.mission] = _finished(t, rec, reused=False)
            study = build_study(tasks, results, {k: v for k, v in previous_failures.items() if v}, info)
            write_json(out / "study.json", study)
            write_study_report(out, study)
            store.clear_staging()
        return study
    finally:
        store.unlock()


def _finished(task: MissionTask, record: dict, reused: bool) -> dict:
    """The result of a mission found finished on disk rather than heard from its task."""
    return {"mission": task.mission, "status": "ok", "wall_s": None, "record": record, "reused": reused}


def _run(tasks, todo, results, store, scheduler, workers, info, progress, log) -> None:
    enabled = sys.stderr.isatty() if progress is None else progress
    n_workers = local_workers(workers, len(todo))
    fe_workers = frontend_workers_per_mission(None if scheduler else n_workers)
    todo = [replace(t, frontend_workers=fe_workers) for t in todo]
    with dask_client(scheduler, n_workers) as client:
        info["workers"] = len(client.nthreads()) if scheduler else n_workers
        info["frontend_workers_per_mission"] = fe_workers
        bar = _progress(len(tasks), len(tasks) - len(todo), enabled)
        failed = 0
        try:
            for res in run_tasks(client, todo, store):
                results[res["mission"]] = res
                failed += res["status"] != "ok"
                bar.update(1)
                bar.set_postfix(failed=failed)
                line = f"{res['mission']}: {res['status']}"
                line += f" ({res['wall_s']:.0f} s)" if res.get("wall_s") is not None else ""
                if res["status"] != "ok":
                    line += f": {res['failure']['error']}"
                if res["status"] != "ok" or not enabled:
                    (bar.write if enabled else log)(line)
        finally:
            bar.close()
