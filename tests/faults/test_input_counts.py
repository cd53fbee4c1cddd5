"""Non-finite and invalid messages: dropped or passed on as invalid, and counted where a run and
metrics.json can say so (``input_block``, ``input_line``), not only in ``semslam info``."""

from __future__ import annotations

import json

import numpy as np
import pytest

from faults.bags import Faults, recording
from faults.cli import assert_accepted, info
from semslam.errors import MissionError
from semslam.mission import Depth, DvlVelocity, Mission
from semslam.mission.bag import read_mission, write_mission
from semslam.mission.check import input_block, input_line
from semslam.mission.config import ReaderConfig


def test_nan_readings_are_dropped_and_counted_per_sensor(tmp_path):
    path = recording("ros1", 20.0, Faults(nan_dvl_at=(3, 4, 50))).write(tmp_path)
    m = read_mission(path)
    got = list(m)
    assert sum(isinstance(x, DvlVelocity) for x in got) == 100 - 3
    block = input_block(m)
    assert block == {
        "dropped": {"ahrs": 0, "dvl": 3, "laser": 0, "pressure": 0},
        "invalid": {"ahrs": 0, "dvl": 0, "laser": 0, "pressure": 0},
    }
    json.dumps(block)  # what metrics.json holds
    assert input_line(m) == "input: dropped dvl 3 (velocity ×3), no invalid reading"
    out = assert_accepted(info(path))
    assert "dvl: 3 message(s) dropped (non-finite or unusable field: velocity ×3)" in out
    with pytest.raises(MissionError, match=rf"^{path}: topic /dvl: field velocity is not finite"):
        list(read_mission(path, ReaderConfig(on_nonfinite="error")))


def test_invalid_dvl_readings_are_counted_apart_from_dropped_ones(tmp_path, sample_mission):
    """The sample mission's DVL loses bottom lock twice in 2 s (invalid, passed on); one more reading
    here has an infinite velocity (dropped)."""
    m = sample_mission(seconds=2.0)
    bad = DvlVelocity(100_100_000_000, "dvl", velocity=(np.inf, 0, 0), covariance=np.eye(3))
    path = write_mission(Mission.from_measurements(m.metadata, [*m, bad]), tmp_path / "m.mcap")
    back = read_mission(path)
    zeros = {s: 0 for s in back.metadata.sensors}
    assert input_block(back) == {"dropped": zeros, "invalid": zeros}  # those of the last complete pass: none yet
    list(back)
    block = input_block(back)
    assert block["dropped"]["dvl"] == 1 and block["invalid"]["dvl"] == 2
    assert sum(block["dropped"].values()) == 1 and sum(block["invalid"].values()) == 2
    assert input_line(back) == "input: dropped dvl 1 (velocity ×1); invalid dvl 2"


def test_a_mission_in_memory_counts_its_invalid_readings(sample_mission):
    m = sample_mission(seconds=2.0)
    assert input_block(m)["invalid"]["dvl"] == 0  # before a pass
    assert len(list(m)) > 0
    assert input_block(m)["invalid"] == {s: (2 if s == "dvl" else 0) for s in m.metadata.sensors}
    assert input_line(m) == "input: no message dropped; invalid dvl 2"


def test_a_part_read_is_said_in_the_block(tmp_path):
    path = recording("mcap", 40.0, Faults(reset_at_s=30.0, back_s=20.0)).write(tmp_path)
    m = read_mission(path, ReaderConfig(on_clock_jump="split", segment=2))
    list(m)
    assert input_block(m)["segment"] == 2


def test_finite_nonsense_is_dropped_and_counted_like_non_finite_readings(tmp_path):
    """A DVL velocity of 1e188 m/s with a sane covariance, a pressure of 1e12 Pa (~1e8 m deep): finite,
    and no vehicle's; before, the reader passed them on and the estimators took them."""
    path = recording("ros1", 20.0, Faults(huge_dvl_at=(7, 60), huge_pressure_at=(30,))).write(tmp_path)
    m = read_mission(path)
    got = list(m)
    dvl = [x for x in got if isinstance(x, DvlVelocity)]
    assert len(dvl) == 100 - 2 and max(abs(x.velocity).max() for x in dvl) < 1.0
    assert max(x.depth for x in got if isinstance(x, Depth)) < 2.0  # 0.1 m/s for 15 s
    assert input_block(m)["dropped"] == {"ahrs": 0, "dvl": 2, "laser": 0, "pressure": 1}
    assert input_line(m) == (
        "input: dropped dvl 2 (velocity beyond 10 m/s ×2), pressure 1 (depth beyond ±12000 m ×1), no invalid reading"
    )
    assert "dvl: 2 message(s) dropped" in assert_accepted(info(path))
    # the bounds are configuration; the policy of non-finite readings holds for them too
    wide = read_mission(path, ReaderConfig(plausible={"speed_m_s": 1e200, "depth_m": 1e9}))
    assert max(x.velocity[0] for x in wide if isinstance(x, DvlVelocity)) == 1e188
    assert input_block(wide)["dropped"] == {"ahrs": 0, "dvl": 0, "laser": 0, "pressure": 0}
    with pytest.raises(MissionError, match=rf"^{path}: topic /dvl: velocity beyond 10 m/s \(message at t="):
        list(read_mission(path, ReaderConfig(on_nonfinite="error")))
