"""The disk that a run spills to (what it appends for hours: the ground truth, the labelled views,
the estimators' logs; :class:`semslam.estimation.SpillLog`) fills up mid-mission: `semslam run` as a
user starts it, with the spill's write failing as a full disk fails it (ENOSPC), while the
front-end worker is running. One line naming the output and the reason, exit code 1, no
traceback, no output or staging directory, nothing left in the spill directory, no process left.
And a run that succeeds spilled into its output's hidden staging directory, and left nothing of it."""

from __future__ import annotations

import errno
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest
from typer.testing import CliRunner

from faults.commands import short_tank_mission
from faults.processes import left_in_session

pytestmark = pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads the process tree from /proc")

# `semslam run` in a process of its own whose spill files are on a disk with no room left: each
# log's first write fails as write(2) fails on a full disk; logs spill after 64 rows (3 s of the
# 20 Hz ground truth), so that a short mission reaches the disk while the front-end worker runs.
FULL_DISK_RUN = """
import errno, os, sys
import semslam.estimation as estimation

opened = estimation.TemporaryFile

class FullDisk:
    def __init__(self, **kwargs):
        self.file = opened(**kwargs)

    def write(self, data):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

estimation.SPILL_CHUNK_ROWS = 64
estimation.TemporaryFile = FullDisk
from semslam.cli import app
app(sys.argv[1:], prog_name="semslam")
"""


@pytest.fixture(scope="module")
def mission(tmp_path_factory) -> Path:
    return short_tank_mission(tmp_path_factory.mktemp("spill") / "tank.bag", seconds=8.0)


@pytest.fixture
def spill() -> Path:
    """The spill's directory, as TMPDIR: a short path (multiprocessing puts its fork server's socket
    there, and a socket's path has at most 107 bytes; pytest's tmp_path under xdist can be longer)."""
    d = Path(tempfile.mkdtemp(prefix="semslam-spill-"))
    yield d
    shutil.rmtree(d, ignore_errors=True)


def test_a_full_spill_disk_is_one_line_and_leaves_no_output_and_no_process(mission, spill, tmp_path):
    out = tmp_path / "outputs" / "out"
    out.parent.mkdir()
    cmd = [sys.executable, "-c", FULL_DISK_RUN, "run", str(mission), "-e", "graph", "--frontends", "oracle"]
    proc = subprocess.Popen(
        [*cmd, "--out", str(out)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
        env={**os.environ, "TMPDIR": str(spill)},  # where the spill goes when the run names no directory
    )
    stdout, stderr = proc.communicate(timeout=300)  # until every process that holds stderr is gone too
    assert proc.returncode == 1, stderr
    assert "Traceback" not in stderr, stderr  # whole, to see which exception escaped
    lines = stderr.strip().splitlines()
    assert len(lines) == 1, stderr
    # the directory named: the output, as the user knows it (the spill is in its hidden staging directory,
    # on the output's filesystem, not in TMPDIR)
    where, _, reason = lines[0].removeprefix("semslam: error: ").partition(": the run's spill file: ")
    assert reason == os.strerror(errno.ENOSPC), lines[0]
    assert where == str(out), lines[0]
    assert left_in_session(proc.pid) == []  # the command, its front-end worker and the fork server gone
    assert list(out.parent.iterdir()) == []  # no output, no staging directory
    assert list(spill.iterdir()) == []  # nothing spilled to TMPDIR


def test_a_temporary_directory_too_long_for_the_fork_servers_socket_is_one_line(mission, tmp_path):
    """multiprocessing's fork server binds a socket in TMPDIR, whose path may have at most 107 bytes:
    a longer TMPDIR is one line naming it, not a traceback from the front-end process's start."""
    long = tmp_path / ("d" * 110)
    long.mkdir()
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "semslam.cli", "run", str(mission), "-e", "graph", "--frontends", "oracle"]
    proc = subprocess.run(
        [*cmd, "--out", str(out)], capture_output=True, text=True, env={**os.environ, "TMPDIR": str(long)}, timeout=300
    )
    assert proc.returncode == 1, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "cannot start a front-end process" in lines[0] and str(long) in lines[0], proc.stderr
    assert not out.exists()


class SpillWatcher:
    """A pipeline observer: where the run spills, and the files open there, at every step."""

    def __init__(self):
        self.directories: set[str] = set()
        self.open_files: set[str] = set()

    def step(self, stamp, measurement, observations, views) -> None:
        from semslam.estimation import spill_directory

        where = spill_directory()
        self.directories.add(str(where))
        for fd in Path("/proc/self/fd").iterdir():
            try:
                target = os.readlink(fd)
            except OSError:  # closed meanwhile
                continue
            if where is not None and target.startswith(f"{where}/"):
                self.open_files.add(target)


@pytest.mark.parametrize("command", [["run", "-e", "graph"], ["compare"]])
def test_a_run_spills_into_its_outputs_stage_and_leaves_nothing_of_it(mission, tmp_path, monkeypatch, command):
    """The spill files are open in a hidden directory of the output's staging directory (a sibling of
    the output, on its filesystem) while the run goes on; once the output is in place, neither they nor
    their directory are anywhere to be seen."""
    import semslam.estimation
    from semslam.cli import app
    from semslam.pipeline import observed_by

    monkeypatch.setattr(semslam.estimation, "SPILL_CHUNK_ROWS", 64)  # 3 s of the 20 Hz ground truth
    out = tmp_path / "outputs" / "out"
    watcher = SpillWatcher()
    with observed_by(watcher):
        res = CliRunner().invoke(
            app, [command[0], str(mission), *command[1:], "--frontends", "oracle", "--out", str(out)]
        )
    assert res.exit_code == 0, res.output
    assert len(watcher.directories) == 1, watcher.directories
    where = Path(watcher.directories.pop())
    stage = where.parent
    assert where.name == ".spill" and stage.parent == out.parent, where
    assert stage.name.startswith(f".{out.name}.") and stage.name.endswith(".partial"), where
    assert watcher.open_files, "no spill file was open in the stage during the run"
    assert all(f.endswith(" (deleted)") for f in watcher.open_files), watcher.open_files  # anonymous
    assert [p.name for p in out.parent.iterdir()] == ["out"]  # the stage renamed into place, nothing beside
    assert not list(out.rglob(".*")), list(out.rglob(".*"))  # nothing hidden in the output
    assert (out / "metrics.json").is_file()
