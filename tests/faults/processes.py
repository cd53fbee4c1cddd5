"""A process tree read from /proc (Linux): what a command started, and what of it outlived it."""

from __future__ import annotations

import os
import time
from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class Proc:
    pid: int
    ppid: int
    start: int  # clock ticks after boot: a pid reused by another process has another start
    state: str
    cmdline: str
    session: int  # the session id: a command started in a session of its own, and all it started


def read_proc(pid: int) -> Proc | None:
    """The process ``pid`` as /proc shows it now, or None if it is gone."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
        cmd = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace").strip()
    except (FileNotFoundError, ProcessLookupError):
        return None
    # "pid (comm) state ppid ...": comm may hold spaces and parentheses, so split after its last ')'
    fields = stat[stat.rindex(")") + 2 :].split()
    return Proc(pid, int(fields[1]), int(fields[19]), fields[0], cmd, int(fields[3]))


def all_processes() -> list[Proc]:
    procs = (read_proc(int(p)) for p in os.listdir("/proc") if p.isdigit())
    return [p for p in procs if p is not None]


def descendants(root: int) -> list[Proc]:
    """Every living process below ``root`` (children, their children, ...)."""
    procs = all_processes()
    children: dict[int, list[Proc]] = {}
    for p in procs:
        children.setdefault(p.ppid, []).append(p)
    out, todo = [], [root]
    while todo:
        for child in children.get(todo.pop(), []):
            out.append(child)
            todo.append(child.pid)
    return out


def in_session(sid: int) -> list[Proc]:
    """Every living process of session ``sid`` (zombies aside): what a command started with
    ``start_new_session`` left behind, even once reparented after its exit."""
    return [p for p in all_processes() if p.session == sid and p.state != "Z"]


def left_in_session(sid: int, within_s: float = 2.0) -> list[Proc]:
    """What of session ``sid`` is still alive ``within_s`` after the command ended (issue 26's bound
    for every worker to stop): a process whose exit has begun (its pipes closed, so the caller's
    ``communicate`` returned) may still be listed for a moment; one still alive at the deadline stayed."""
    deadline = time.monotonic() + within_s
    while (left := in_session(sid)) and time.monotonic() < deadline:
        time.sleep(0.05)
    return left


def survivors(procs: list[Proc]) -> list[Proc]:
    """Those of ``procs`` still running (the same processes: same pid and start time; zombies that
    wait for a parent to reap them do not count, they hold no memory)."""
    alive = []
    for p in procs:
        now = read_proc(p.pid)
        if now is not None and now.start == p.start and now.state != "Z":
            alive.append(now)
    return alive
