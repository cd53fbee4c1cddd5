"""The disk that a run spills to (what it appends for hours: the ground truth, the labelled views,
the estimators' logs; :class:`semslam.estimation.SpillLog`) fills up mid-mission: `semslam run` as a
user starts it, with the spill's write failing as a full disk fails it (ENOSPC), while the
front-end worker is running. One line naming the directory and the reason, exit code 1, no
traceback, no output or staging directory, nothing left in the spill directory, no process left."""

from __future__ import annotations

import errno
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

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
    # the directory named: the system's temporary one (TMPDIR), or the run's staging directory beside the output
    where, _, reason = lines[0].removeprefix("semslam: error: ").partition(": the run's spill file: ")
    assert reason == os.strerror(errno.ENOSPC), lines[0]
    assert where == str(spill) or Path(where).parent == out.parent, lines[0]
    assert left_in_session(proc.pid) == []  # the command, its front-end worker and the fork server gone
    assert list(out.parent.iterdir()) == []  # no output, no staging directory
    assert list(spill.iterdir()) == []  # the spill files were anonymous: nothing to clean


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
