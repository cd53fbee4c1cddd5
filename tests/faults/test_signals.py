"""Signals against `semslam compare` on a short simulated mission, as users and machines send them:
Ctrl-C (SIGINT to the whole process group), `kill` (SIGTERM to the command alone), at the pipeline
stage (front-end workers running) and at the report stage (the output being written), and the
command's own sudden death (SIGKILL, which nothing can handle).

Each must end with the exit code of the signal (130 / 143), one line on stderr and no traceback,
every process the command started gone (front-end workers within 2 s of the signal; the command,
multiprocessing's fork server and resource tracker after their interpreter's exit), and no output
or staging directory left; an existing output being replaced stays as it was."""

from __future__ import annotations

import os
import signal
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path

import pytest

from faults.commands import semslam_command, short_tank_mission
from faults.processes import Proc, descendants, survivors
from semslam.eval.outputs import staged_output

pytestmark = pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads the process tree from /proc")

WORKERS_STOP_S = 2.0  # the requirement, from the signal
# The command's and the fork server's interpreters take ~1.5 s to exit with open3d and scikit-learn
# loaded (a shared 2-core machine); this bounds the signal-to-exit time with a margin for load.
EXIT_S = 10.0


@pytest.fixture(scope="module")
def mission(tmp_path_factory) -> Path:
    return short_tank_mission(tmp_path_factory.mktemp("signals") / "tank.bag")


@dataclass
class Stopped:
    returncode: int
    stderr: str
    workers_s: float  # signal → the last front-end worker gone
    command_s: float  # signal → the command's exit
    all_s: float  # signal → every process it started gone
    left: list[Proc]


class Compare:
    """`semslam compare` in a session of its own (a group signal reaches it and its children only)."""

    def __init__(self, mission: Path, out: Path, *extra: str):
        self.out = out
        self.proc = subprocess.Popen(
            [*semslam_command(), "compare", str(mission), "--out", str(out), "--frontends", "oracle", *extra],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
            start_new_session=True,
        )

    def workers(self) -> list[Proc]:
        """The front-end workers: forked by the fork server, so grandchildren of the command."""
        return [p for p in descendants(self.proc.pid) if p.ppid != self.proc.pid]

    def wait_for(self, condition, what: str, timeout: float = 300.0) -> None:
        t0 = time.monotonic()
        while not condition():
            if self.proc.poll() is not None:
                pytest.fail(
                    f"the command ended (exit code {self.proc.returncode}) before {what}: {self.proc.stderr.read()}"
                )
            if time.monotonic() - t0 > timeout:
                self.proc.kill()
                pytest.fail(f"no {what} after {timeout} s")
            time.sleep(0.01)

    def stop(self, sig: int, group: bool = False) -> Stopped:
        """Send ``sig`` (to the whole group: as Ctrl-C in a terminal) and watch everything go."""
        tree = descendants(self.proc.pid)
        workers = [p for p in tree if p.ppid != self.proc.pid]
        t0 = time.monotonic()
        (os.killpg if group else os.kill)(self.proc.pid, sig)
        workers_s = command_s = None
        while time.monotonic() - t0 < 3 * EXIT_S:
            now = time.monotonic() - t0
            if workers_s is None and not survivors(workers):
                workers_s = now
            if command_s is None and self.proc.poll() is not None:
                command_s = now
            if command_s is not None and not survivors(tree):
                break
            time.sleep(0.01)
        left = survivors(tree)
        for p in left:  # never leave them to the next test
            os.kill(p.pid, signal.SIGKILL)
        if command_s is None:
            self.proc.kill()
        self.proc.wait()
        return Stopped(self.proc.returncode, self.proc.stderr.read(), workers_s, command_s, time.monotonic() - t0, left)


def assert_nothing_written(out: Path) -> None:
    assert not out.exists()
    assert [p.name for p in out.parent.iterdir() if p.name.startswith(f".{out.name}.")] == []


def assert_stopped_cleanly(s: Stopped, sig: int) -> None:
    assert s.left == [], f"left running: {s.left}"
    assert s.returncode == 128 + sig, s.stderr
    assert "Traceback" not in s.stderr and "leaked" not in s.stderr, s.stderr
    assert s.stderr.strip().splitlines()[-1] == f"semslam: stopped by {signal.Signals(sig).name}"
    assert s.workers_s is not None and s.workers_s <= WORKERS_STOP_S, s
    assert s.command_s is not None and s.command_s <= EXIT_S, s


@pytest.mark.parametrize(
    ("sig", "group"), [(signal.SIGINT, True), (signal.SIGTERM, False)], ids=["ctrl-c to the group", "kill"]
)
def test_a_signal_during_the_pipeline_stops_every_process(mission, tmp_path, sig, group):
    run = Compare(mission, tmp_path / "out")
    run.wait_for(run.workers, "front-end worker")
    stopped = run.stop(sig, group)
    assert_stopped_cleanly(stopped, sig)
    assert_nothing_written(tmp_path / "out")


def test_sigterm_while_the_report_is_written_leaves_the_old_output_as_it_was(mission, tmp_path):
    """Replacing an existing output (--overwrite), stopped while the new one is staged: the staging
    directory goes, the old output stays whole."""
    out = tmp_path / "out"
    out.mkdir()
    (out / "metrics.json").write_text('{"old": true}')
    (out / "report.html").write_text("old report")
    run = Compare(mission, out, "--overwrite")
    run.wait_for(lambda: any(tmp_path.glob(".out.*.partial")), "staging directory")
    stopped = run.stop(signal.SIGTERM)
    assert_stopped_cleanly(stopped, signal.SIGTERM)
    assert sorted(p.name for p in out.iterdir()) == ["metrics.json", "report.html"]
    assert (out / "metrics.json").read_text() == '{"old": true}'
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".out.")] == []


def test_the_workers_exit_when_the_command_is_killed(mission, tmp_path):
    """SIGKILL cannot be handled: the workers see their parent gone and exit; the fork server and the
    resource tracker, whose pipes only the command and the workers held, follow."""
    run = Compare(mission, tmp_path / "out")
    run.wait_for(run.workers, "front-end worker")
    stopped = run.stop(signal.SIGKILL)
    assert stopped.left == [], f"left running: {stopped.left}"
    assert stopped.returncode == -signal.SIGKILL
    assert stopped.workers_s is not None and stopped.workers_s <= WORKERS_STOP_S, stopped
    # Nothing visible; the hidden stage the command opened before its run (its spill files were
    # anonymous: gone with it) is removed by the next run into the same output.
    out = tmp_path / "out"
    assert not out.exists()
    left = [p for p in out.parent.iterdir() if p.name.startswith(f".{out.name}.")]
    assert [p.name.endswith(".partial") for p in left] == [True], left
    assert [p.name for p in left[0].iterdir()] == [".spill"] and not any((left[0] / ".spill").iterdir())
    with staged_output(out) as stage:
        (stage / "metrics.json").write_text("{}")
    assert [p.name for p in out.parent.iterdir() if p.name.startswith(f".{out.name}.")] == []
