"""The Dask task of a study: one mission, computed in a child process, committed or recorded as failed.

:func:`run_mission` is what the client submits. It gets the mission as plain data (a
:meth:`MissionTask.to_dict`) and returns a small dict: the mission's status, the wall time and
either its record (with the summary) or its failure. It imports nothing heavy: the worker that
runs it never loads GTSAM or Open3D (:mod:`semslam.study.compute` does, in its own process).

A mission that fails (an exception, a crash, ``timeout_s`` exceeded) is *returned* as a failure,
not raised, so that Dask does not re-run a deterministic error; a worker that dies while running
a mission is another matter, which Dask handles by running the task again elsewhere.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import site
import socket
import subprocess
import sys
import time
from pathlib import Path

import semslam
from semslam.study.plan import MissionTask
from semslam.study.store import StudyStore


def _last_line(log: Path) -> str:
    if not log.is_file():
        return ""
    lines = [line.strip() for line in log.read_text(errors="replace").splitlines() if line.strip()]
    return lines[-1] if lines else ""


def _error(returncode: int, log: Path) -> str:
    last = _last_line(log).removeprefix("semslam: error: ")
    if returncode < 0:
        sig = signal.Signals(-returncode).name
        return f"crashed ({sig})" + (f"; last output: {last}" if last else "")
    return last or f"exit code {returncode}"


def _child_environment() -> dict:
    """The environment of a mission's child process: it imports the semslam this worker imports.
    ``python -m`` puts the current directory first on the child's path, so a semslam checkout there (a
    clone of another version, a copy kept for a paired run) would compute the missions instead of the
    code that planned them. The child gets no current directory before its path (``PYTHONSAFEPATH``,
    Python >= 3.11) and this semslam's root first on it, unless that root is a site directory (an
    installed package: found there anyway, and kept behind the standard library)."""
    root = str(Path(semslam.__file__).resolve().parents[1])  # resolved: comparable with the real site paths
    sites = {os.path.realpath(p) for p in (*site.getsitepackages(), site.getusersitepackages())}
    path = [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]
    if root not in sites:
        path.insert(0, root)
    return dict(os.environ, PYTHONPATH=os.pathsep.join(path), PYTHONSAFEPATH="1")


def run_mission(task_dict: dict) -> dict:
    """Compute one mission of a study (the Dask task); see the module's docstring."""
    task = MissionTask.from_dict(task_dict)
    store = StudyStore(task.study_dir)
    t0 = time.perf_counter()
    done = store.finished(task.mission)
    if done is not None:  # an earlier attempt of this task finished it
        return {"mission": task.mission, "status": "ok", "wall_s": 0.0, "record": done}
    stage = store.new_stage(task.mission)
    log = stage / "study.log"
    with open(log, "wb") as out:
        proc = subprocess.Popen(
            [sys.executable, "-m", "semslam.study.compute", str(stage)],
            stdin=subprocess.PIPE,
            stdout=out,
            stderr=subprocess.STDOUT,
            env=_child_environment(),
            start_new_session=True,  # its own process group: a timeout kills its front-end workers too
        )
        try:
            proc.communicate(json.dumps(task_dict).encode(), timeout=task.timeout_s)
            status = "ok" if proc.returncode == 0 else "failed"
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
            status = "timeout"
    wall = time.perf_counter() - t0
    if status == "ok":
        if log.stat().st_size == 0:
            log.unlink()
        return {"mission": task.mission, "status": "ok", "wall_s": wall, "record": store.commit(stage, task.mission)}
    error = f"exceeded the timeout of {task.timeout_s:g} s" if status == "timeout" else _error(proc.returncode, log)
    failure = {
        "mission": task.mission,
        "status": status,
        "error": error,
        "exit_code": proc.returncode,
        "wall_s": wall,
        "host": socket.gethostname(),
    }
    failure = store.record_failure(task.mission, failure, log)
    shutil.rmtree(stage, ignore_errors=True)
    return {"mission": task.mission, "status": status, "wall_s": wall, "failure": failure}
