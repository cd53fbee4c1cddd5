"""The study folder on disk: finished missions, failures, staging, and the lock.

``DIR/<mission>/`` appears whole or not at all: a mission is computed in
``DIR/.study/staging/<mission>.<random>/`` and renamed into place when complete, with its record
``study_mission.json`` (what it was computed from, and its summary). A mission that failed leaves
``DIR/.study/failed/<mission>.json`` (status, error) and ``.log`` (everything it printed) instead,
removed when a later run completes it. ``DIR/.study/lock`` keeps two studies out of one folder.
"""

from __future__ import annotations

import fcntl
import json
import os
import shutil
import uuid
from pathlib import Path

from semslam.errors import SemslamError

RECORD = "study_mission.json"


def write_atomic(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` so that a reader never sees half a file."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(text)
    tmp.replace(path)


class StudyStore:
    def __init__(self, root: str | Path):
        self.root = Path(root)
        self.meta = self.root / ".study"
        self.staging = self.meta / "staging"
        self.failed = self.meta / "failed"
        self._lock_fd: int | None = None

    # --- the client's side ---------------------------------------------------------------------

    def lock(self) -> None:
        """Hold the study folder for this process (released when it exits, even on a crash)."""
        self.meta.mkdir(parents=True, exist_ok=True)
        fd = os.open(self.meta / "lock", os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            raise SemslamError(f"{self.root}: another study is running in this folder") from None
        self._lock_fd = fd

    def unlock(self) -> None:
        if self._lock_fd is not None:
            os.close(self._lock_fd)
            self._lock_fd = None

    def clear_staging(self) -> None:
        """Remove what interrupted runs left half-done (only under the lock: no task of ours is running)."""
        shutil.rmtree(self.staging, ignore_errors=True)

    def finished(self, mission: str) -> dict | None:
        """The record of a finished mission, or None."""
        path = self.root / mission / RECORD
        if not path.is_file():
            if (self.root / mission).exists():
                raise SemslamError(f"{self.root / mission}: exists but is not a mission of a study (no {RECORD})")
            return None
        return json.loads(path.read_text())

    def failure(self, mission: str) -> dict | None:
        path = self.failed / f"{mission}.json"
        return json.loads(path.read_text()) if path.is_file() else None

    # --- the task's side -----------------------------------------------------------------------

    def new_stage(self, mission: str) -> Path:
        stage = self.staging / f"{mission}.{uuid.uuid4().hex[:8]}"
        stage.mkdir(parents=True)
        return stage

    def commit(self, stage: Path, mission: str) -> dict:
        """Rename a complete ``stage`` (its record written last) to ``DIR/<mission>`` and return the
        record; if another attempt of the same mission got there first (a task Dask re-ran after
        losing its worker), keep that one."""
        record = json.loads((stage / RECORD).read_text())
        try:
            os.rename(stage, self.root / mission)
        except OSError:
            existing = self.finished(mission)
            if existing is None:
                raise
            shutil.rmtree(stage, ignore_errors=True)
            return existing
        for suffix in (".json", ".log"):
            (self.failed / f"{mission}{suffix}").unlink(missing_ok=True)
        return record

    def record_failure(self, mission: str, record: dict, log: Path | None) -> dict:
        self.failed.mkdir(parents=True, exist_ok=True)
        if log is not None and log.is_file():
            shutil.copyfile(log, self.failed / f"{mission}.log")
            record = {**record, "log": str((self.failed / f"{mission}.log").relative_to(self.root))}
        write_atomic(self.failed / f"{mission}.json", json.dumps(record, indent=1))
        return record
