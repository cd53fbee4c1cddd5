"""Which front-ends `run` and `compare` use: by sensor kind unless `--frontends` says otherwise, always
said; a named front-end that would consume nothing of the mission is refused before any work (it
once ran nothing and exited 0 with an empty map)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from faults.commands import short_tank_mission
from semslam.cli import app


@pytest.fixture(scope="module")
def laser_mission(tmp_path_factory) -> Path:
    return short_tank_mission(tmp_path_factory.mktemp("frontends") / "tank.bag", seconds=8.0)


def semslam(*args):
    return CliRunner().invoke(app, [str(a) for a in args])


def test_run_picks_the_laser_on_a_laser_mission_and_says_so(laser_mission, tmp_path):
    r = semslam("run", laser_mission, "-e", "dr", "--out", tmp_path / "out")
    assert r.exit_code == 0, r.output
    assert "front-ends: laser (by sensor kind" in r.stdout
    metrics = json.loads((tmp_path / "out" / "metrics.json").read_text())
    assert metrics["timing_s"]["frontend:laser"] > 0  # it ran on the scans


@pytest.mark.parametrize("command", ["run", "compare"])
def test_a_front_end_that_consumes_nothing_of_the_mission_is_refused(laser_mission, tmp_path, command):
    r = semslam(command, laser_mission, "--frontends", "sonar", "--out", tmp_path / "out")
    assert r.exit_code == 1 and "Traceback" not in r.output
    (line,) = r.stderr.strip().splitlines()
    assert line == (
        f"semslam: error: --frontends sonar: it consumes SonarSwath, which no sensor of {laser_mission} gives "
        "(sensors: ahrs, depth, dvl, ground_truth, laser)"
    )
    assert not (tmp_path / "out").exists()


def test_no_front_end_on_request_is_said(laser_mission, tmp_path):
    r = semslam("run", laser_mission, "-e", "dr", "--frontends", "", "--out", tmp_path / "out")
    assert r.exit_code == 0, r.output
    assert "front-ends: none (--frontends)" in r.stdout
    assert not any(
        k.startswith("frontend:") for k in json.loads((tmp_path / "out" / "metrics.json").read_text())["timing_s"]
    )
