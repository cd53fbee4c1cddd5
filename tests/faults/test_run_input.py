"""The mission check as `run` and `compare` apply it, on recordings the tests break: no DVL, no AHRS,
no sidecar, NaN readings, a clock reset, a truncated bag. A refusal is one line naming the bag and
the cause, exit code 1, before any estimation and with no output; an accepted fault is a warning on
stderr, in metrics.json's ``input`` and (counts) in the run's summary."""

from __future__ import annotations

import json
import random
import subprocess

import pytest
from typer.testing import CliRunner

from faults.bags import Faults, recording
from faults.commands import semslam_command
from faults.processes import left_in_session
from semslam.cli import app

DR = ("-e", "dr", "--frontends", "")  # the quickest run: dead reckoning, no front-end


def semslam(*args):
    return CliRunner().invoke(app, [str(a) for a in args])


def assert_refused(r, *fragments: str) -> str:
    assert r.exit_code == 1, r.output
    assert "Traceback" not in r.output
    (line,) = r.stderr.strip().splitlines()
    assert line.startswith("semslam: error: "), line
    for f in fragments:
        assert f in line, (f, line)
    return line


def warnings(r) -> list[str]:
    return [line.removeprefix("semslam: warning: ") for line in r.stderr.splitlines() if "warning" in line]


@pytest.mark.parametrize("command", ["run", "compare"])
def test_no_dvl_is_refused_before_any_estimation(tmp_path, command):
    path = recording("ros1", 20.0, Faults(without=("/dvl",))).write(tmp_path)
    r = semslam(command, path, "--frontends", "", "--out", tmp_path / "out")
    assert_refused(r, f"{path}: no velocity source (no DVL topic", "--allow-missing dvl")
    assert "dr:" not in r.stdout and not (tmp_path / "out").exists()


def test_no_dvl_accepted_is_said_in_the_run_and_in_metrics(tmp_path):
    path = recording("ros1", 20.0, Faults(without=("/dvl",))).write(tmp_path)
    r = semslam("run", path, *DR, "--allow-missing", "dvl", "--out", tmp_path / "out")
    assert r.exit_code == 0, r.output
    said = warnings(r)
    accepted = f"{path}: no velocity source (no DVL topic): accepted (--allow-missing dvl); the horizontal position"
    assert any(w.startswith(accepted) for w in said), said
    metrics = json.loads((tmp_path / "out" / "metrics.json").read_text())
    assert metrics["input"]["warnings"] == said
    assert metrics["frontends"] == []


def test_no_ahrs_is_refused_and_accepted_on_request(tmp_path):
    path = recording("mcap", 20.0, Faults(without=("/ahrs",))).write(tmp_path)
    assert_refused(semslam("run", path, *DR, "--out", tmp_path / "out"), "no attitude source", "--allow-missing ahrs")
    assert not (tmp_path / "out").exists()
    r = semslam("run", path, "-e", "graph", "--frontends", "", "--allow-missing", "ahrs", "--out", tmp_path / "out")
    assert r.exit_code == 0, r.output
    *check, empty = warnings(r)  # the check's (the mounts assumed too: no sidecar), then the result's
    assert any(
        "no attitude source (no AHRS topic): accepted (--allow-missing ahrs); the attitude is not measured" in w
        for w in check
    )
    # Nothing to start from: said, never a silent empty result.
    assert empty == (
        "graph: no pose estimated (no keyframe: the mission had no AHRS (or no start pose)): "
        "its trajectory and map are empty"
    )


def test_an_unknown_kind_to_allow_is_refused_before_the_bag_is_read(tmp_path):
    r = semslam("run", tmp_path / "no-such.bag", "--allow-missing", "gps", "--out", tmp_path / "out")
    assert_refused(r, "--allow-missing: unknown sensor kind 'gps'")


def test_no_sidecar_warns_of_the_mounts_assumed(tmp_path):
    path = recording("ros1", 10.0).write(tmp_path)  # a real bag: no semslam sidecar beside it
    r = semslam("run", path, *DR, "--out", tmp_path / "out")
    assert r.exit_code == 0, r.output
    (warning,) = warnings(r)
    assert warning.startswith(f"{path}: no extrinsics for ahrs, dvl, laser, pressure (no sidecar): identity mounts")
    assert "reader.sensors.<name>.T_BS" in warning
    metrics = json.loads((tmp_path / "out" / "metrics.json").read_text())
    assert metrics["input"]["warnings"] == [warning]


def test_nan_readings_are_counted_in_the_summary_and_in_metrics(tmp_path):
    path = recording("ros1", 20.0, Faults(nan_dvl_at=(3, 4, 50))).write(tmp_path)
    r = semslam("run", path, *DR, "--out", tmp_path / "out")
    assert r.exit_code == 0, r.output
    assert "input: dropped dvl 3 (velocity ×3), no invalid reading" in r.stdout.splitlines()
    block = json.loads((tmp_path / "out" / "metrics.json").read_text())["input"]
    assert block["dropped"] == {"ahrs": 0, "dvl": 3, "laser": 0, "pressure": 0}
    assert block["invalid"] == {"ahrs": 0, "dvl": 0, "laser": 0, "pressure": 0}


def test_a_clock_reset_split_on_request_reads_one_part_and_says_so(tmp_path):
    path = recording("mcap", 40.0, Faults(reset_at_s=30.0, back_s=20.0)).write(tmp_path)
    cfg = tmp_path / "split.yaml"
    cfg.write_text("reader:\n  on_clock_jump: split\n  segment: 1\n")
    r = semslam("run", path, *DR, "--config", cfg, "--out", tmp_path / "out")
    assert r.exit_code == 0, r.output
    assert any("clock reset at mission time 29.950 s" in w for w in warnings(r)), r.stderr
    block = json.loads((tmp_path / "out" / "metrics.json").read_text())["input"]
    assert block["segment"] == 1
    assert any("read part 1 (reader.segment)" in w for w in block["warnings"])


@pytest.mark.parametrize("fmt", ["ros1", "mcap", "sqlite3"])
def test_a_truncated_bag_is_one_line(tmp_path, fmt):
    """A recording cut short (the recorder killed, a copy interrupted): its index is gone."""
    path = recording(fmt, 10.0).write(tmp_path)
    data = path / f"{path.name}.db3" if path.is_dir() else path
    data.write_bytes(data.read_bytes()[: data.stat().st_size * 2 // 3])
    assert_refused(semslam("run", path, *DR, "--out", tmp_path / "out"), str(path), "corrupt or truncated")
    assert not (tmp_path / "out").exists()


def test_damaged_bytes_inside_an_mcap_are_a_one_line_error_or_a_counted_drop(tmp_path):
    """Bytes overwritten inside the file (a bad copy, a failing card), the index intact: wherever
    they land (a record's length, an offset, a message's floats), the run ends in one line or
    exits 0 having read what it could; never a traceback (a damaged chunk length used to escape
    as an OverflowError from the surface-pressure probe at open)."""
    rng = random.Random(1)
    data = recording("mcap", 4.0).write(tmp_path / "intact").read_bytes()
    refused = 0
    for k in range(16):
        at = rng.randrange(8, len(data) - 8)
        damaged = bytearray(data)
        damaged[at : at + 8] = bytes(rng.randrange(256) for _ in range(8))
        path = tmp_path / f"damaged{k}.mcap"
        path.write_bytes(bytes(damaged))
        r = semslam("run", path, *DR, "--out", tmp_path / f"out{k}")
        assert r.exception is None or isinstance(r.exception, SystemExit), f"byte {at}: {r.exception!r}"
        if r.exit_code == 1:  # after the check's warning (no sidecar: identity mounts), one error line
            assert r.stderr.splitlines()[-1].startswith(f"semslam: error: {path}: "), r.stderr
            refused += 1
        elif r.exit_code == 0:  # what it read gave a finite estimate (damaged floats that are finite
            # nonsense, e.g. a covariance with an entry of -1e188, are dropped and counted, not filtered)
            tum = (tmp_path / f"out{k}" / "trajectory_dr.tum").read_text()
            assert "nan" not in tum and "inf" not in tum, f"byte {at}: a non-finite trajectory"
    assert refused > 0  # some of the damage reached the records


def test_a_clock_reset_stops_the_run_and_its_front_end_workers(tmp_path):
    """Found only while the mission streams, the front-end workers running (the laser, chosen by
    sensor kind): one line with the mission time, exit code 1, no output, no process left."""
    path = recording("ros1", 30.0, Faults(reset_at_s=15.0, back_s=10.0)).write(tmp_path)
    out = tmp_path / "out"
    cmd = [*semslam_command(), "run", str(path), "-e", "dr", "--out", str(out)]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    stdout, stderr = proc.communicate(timeout=300)  # until every process that holds stderr is gone too
    assert proc.returncode == 1, stderr
    assert "front-ends: laser (by sensor kind" in stdout
    assert "Traceback" not in stderr
    error = [line for line in stderr.splitlines() if "warning" not in line]
    assert len(error) == 1 and error[0].startswith(f"semslam: error: {path}: clock reset at mission time 14.950 s")
    assert left_in_session(proc.pid) == []
    assert sorted(p.name for p in tmp_path.iterdir()) == [path.name]
