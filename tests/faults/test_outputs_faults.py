"""Output paths that cannot be written, as `semslam run` and `compare` meet them: a full disk (a
small tmpfs; without mount rights, a file size limit), a read-only file system, an immutable
directory, a file in the way, /proc, a directory of another command's output. Each is one line
on stderr naming the path and the reason, exit code 1, no traceback, nothing half-written and an
existing output as it was."""

from __future__ import annotations

import errno
import os
import resource
import subprocess
from contextlib import contextmanager
from pathlib import Path

import pytest
from typer.testing import CliRunner

from faults.commands import semslam_command, short_tank_mission
from semslam.cli import app


@pytest.fixture(scope="module")
def mission(tmp_path_factory) -> Path:
    return short_tank_mission(tmp_path_factory.mktemp("outputs") / "tank.bag")


def semslam(*args) -> tuple[int, str]:
    """The command in this process: exit code and stderr."""
    r = CliRunner().invoke(app, [str(a) for a in args])
    return r.exit_code, r.stderr


def assert_one_line_error(code: int, stderr: str, *fragments: str) -> str:
    assert code == 1, stderr
    assert "Traceback" not in stderr
    # what the run assumed about the mission (its warnings) may come first; the error is one line
    lines = [line for line in stderr.strip().splitlines() if not line.startswith("semslam: warning: ")]
    assert len(lines) == 1 and lines[0].startswith("semslam: error: "), stderr
    for f in fragments:
        assert f in lines[0], (f, lines[0])
    return lines[0]


def leftovers(directory: Path) -> list[str]:
    return sorted(p.name for p in directory.iterdir())


@contextmanager
def mounted_tmpfs(path: Path, size: str, read_only: bool = False):
    """A tmpfs of ``size`` at ``path`` (yields False where this process may not mount one)."""
    path.mkdir(exist_ok=True)
    options = f"size={size}" + (",ro" if read_only else "")
    ok = (
        subprocess.run(["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(path)], capture_output=True).returncode == 0
    )
    try:
        yield ok
    finally:
        if ok:
            subprocess.run(["umount", str(path)], check=True)


def test_a_full_disk_while_the_report_is_written_is_one_line_and_leaves_nothing(mission, tmp_path):
    """A 2 MB disk holds the results (config, trajectories, maps, metrics: 0.4 MB) and the figures
    (0.7 MB) but not report.html (3 MB, plotly 2 of it): the error names that file and the reason,
    and the disk is left empty."""
    disk = tmp_path / "disk"
    with mounted_tmpfs(disk, "2m") as mounted:
        limit = {}
        if not mounted:  # no mount rights: every file this command writes is limited to 2 MB instead
            limit = {"preexec_fn": lambda: resource.setrlimit(resource.RLIMIT_FSIZE, (2**21, 2**21))}
        out = disk / "out"
        r = subprocess.run(
            [*semslam_command(), "compare", mission, "--out", out, "--frontends", "oracle"],
            capture_output=True,
            text=True,
            **limit,
        )
        reason = os.strerror(errno.ENOSPC if mounted else errno.EFBIG)
        line = assert_one_line_error(r.returncode, r.stderr)
        assert f"{out / 'report.html'}: cannot write the output ({reason})" in line
        assert leftovers(disk) == []


def test_a_read_only_output_is_refused_before_the_mission_is_read(tmp_path):
    ro = tmp_path / "ro"
    with mounted_tmpfs(ro, "1m", read_only=True) as mounted:
        if not mounted:
            if os.geteuid() == 0:
                pytest.skip("root may write anywhere without a read-only mount, and mount is not allowed here")
            ro.chmod(0o555)
        reason = os.strerror(errno.EROFS if mounted else errno.EACCES)
        code, err = semslam("run", tmp_path / "no-such.bag", "--out", ro / "out")
        assert_one_line_error(code, err, str(ro), reason)


def test_an_immutable_output_being_replaced_is_one_line_and_stays_as_it_was(mission, tmp_path):
    """`chattr +i`: the directory cannot be renamed aside, which only the final commit finds out."""
    out = tmp_path / "out"
    out.mkdir()
    (out / "metrics.json").write_text("{}")
    if subprocess.run(["chattr", "+i", str(out)], capture_output=True).returncode != 0:
        pytest.skip("chattr +i is not allowed here")
    try:
        code, err = semslam("run", mission, "-e", "dr", "--frontends", "", "--out", out, "--overwrite")
        assert_one_line_error(code, err, str(out), os.strerror(errno.EPERM))
    finally:
        subprocess.run(["chattr", "-i", str(out)], check=True)
    assert leftovers(out) == ["metrics.json"] and leftovers(tmp_path) == ["out"]


def test_a_file_in_the_way_is_one_line(tmp_path):
    (tmp_path / "file").write_text("mine")
    code, err = semslam("run", tmp_path / "no-such.bag", "--out", tmp_path / "file")
    assert_one_line_error(code, err, str(tmp_path / "file"), "exists and is not a directory")
    code, err = semslam("compare", tmp_path / "no-such.bag", "--out", tmp_path / "file" / "out")
    assert_one_line_error(code, err, f"{tmp_path / 'file'}: exists and is not a directory")
    assert (tmp_path / "file").read_text() == "mine"


@pytest.mark.parametrize("out", ["/proc/semslam-out", "/proc/self/semslam-out"])
def test_an_output_in_proc_is_one_line(tmp_path, out):
    code, err = semslam("run", tmp_path / "no-such.bag", "--out", out)
    assert_one_line_error(code, err, "/proc", "cannot write the output")


def test_run_over_a_comparison_replaces_it_whole(mission, tmp_path):
    """`run -e dr --overwrite` into a `compare` output: no map, trajectory or report of the other
    estimators is left beside the new metrics."""
    out = tmp_path / "out"
    (out / "figures").mkdir(parents=True)
    for name in ("metrics.json", "map_graph.json", "trajectory_ekf.tum", "report.html", "figures/ate.png"):
        (out / name).write_text("from the comparison")
    code, err = semslam("run", mission, "-e", "dr", "--frontends", "", "--out", out, "--overwrite")
    assert code == 0, err
    assert leftovers(out) == ["config.yaml", "map_dr.json", "map_dr.ply", "metrics.json", "trajectory_dr.tum"]
    assert leftovers(tmp_path) == ["out"]
