"""Clocks that jump: a reset of the vehicle's clock (every header stamp −30 s mid-mission), the
recorder's clock going back with it (two stretches interleaved), a sensor's own clock, repeated
stamps and duplicated messages. Refused with the mission time, split on request, never read as one."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from faults.bags import LATENCY, RATES, T0, Faults, recording
from faults.cli import assert_accepted, assert_refused, check_section, info
from semslam.errors import MissionError
from semslam.mission import Mission
from semslam.mission.bag import read_mission, write_mission
from semslam.mission.config import ReaderConfig

S = 1_000_000_000
RESET = Faults(reset_at_s=50.0, back_s=30.0)  # the vehicle's clock goes back 30 s at 50 s; the recorder's runs on
SECONDS = 80.0


def count(rate: float, t0: float, t1: float) -> int:
    """Messages of a topic at ``rate`` stamped in [t0, t1) of the original mission time."""
    times = np.arange(0.0, SECONDS, 1.0 / rate)
    return int(((times >= t0) & (times < t1)).sum())


@pytest.fixture(scope="module", params=["mcap", "ros1", "sqlite3"])
def reset_bag(request, tmp_path_factory):
    return recording(request.param, SECONDS, RESET).write(tmp_path_factory.mktemp(request.param))


def test_a_clock_reset_is_refused_with_its_mission_time(reset_bag):
    m = read_mission(reset_bag)
    with pytest.raises(MissionError) as err:
        list(m)
    text = str(err.value)
    assert "\n" not in text
    assert text.startswith(
        f"{reset_bag}: clock reset at mission time 49.950 s (stamp 1700000049.950000 s): the header stamps of "
    )
    assert "went back 30.000 s at once" in text and all(t in text for t in RATES)
    assert "reader.stamp: receive reads the mission as one" in text and "reader.on_clock_jump: split" in text


def test_info_refuses_it_and_lists_the_parts(reset_bag):
    r = info(reset_bag)
    assert_refused(r, str(reset_bag), "clock reset at mission time 49.950 s")
    section = check_section(r.stdout)
    n1 = sum(count(rate, 0, 50) for rate in RATES.values())
    n2 = sum(count(rate, 50, SECONDS) for rate in RATES.values())
    assert f"note: parts that split would read: 1: {n1} messages over 49.950 s (read); 2: {n2} messages" in section[-1]


@pytest.mark.parametrize("segment", [1, 2])
def test_split_reads_one_part_on_its_own_clock(reset_bag, segment):
    m = read_mission(reset_bag, ReaderConfig(on_clock_jump="split", segment=segment))
    got = list(m)
    stamps = np.array([x.stamp for x in got])
    assert np.all(np.diff(stamps) >= 0)
    lo, hi = (0.0, 50.0) if segment == 1 else (50.0, SECONDS)
    for topic, rate in RATES.items():
        sensor = topic.lstrip("/")
        mine = np.array([x.stamp for x in got if x.sensor == sensor])
        assert mine.size == count(rate, lo, hi), sensor
        shift = 0 if segment == 1 else -30 * S
        assert mine[0] == T0 + int(round(lo * S)) + shift + (0 if segment == 1 else _first_after(rate, lo))
    assert sum(m.dropped.values()) == 0
    assert m.clock_problems[0].kind == "reset"


def _first_after(rate: float, t: float) -> int:
    """How far after ``t`` the first message of a topic at ``rate`` falls (ns)."""
    times = np.arange(0.0, SECONDS, 1.0 / rate)
    return int(round((times[times >= t][0] - t) * S))


def test_a_part_that_is_not_there(reset_bag):
    with pytest.raises(
        MissionError, match=r"reader.segment: 3, but the recording has 2 part\(s\) \(clock resets at 49"
    ):
        list(read_mission(reset_bag, ReaderConfig(on_clock_jump="split", segment=3)))


def test_the_recorders_clock_reads_it_as_one(reset_bag):
    m = read_mission(reset_bag, ReaderConfig(stamp="receive"))
    got = list(m)
    assert len(got) == sum(count(rate, 0, SECONDS) for rate in RATES.values())
    assert m.clock_problems == [] and sum(m.dropped.values()) == 0


def test_a_topic_read_by_receive_time_follows_the_reset(tmp_path):
    """An AHRS with zero header stamps is read by receive time; in part 2 it is moved onto the new clock.
    It changes part when the first header-stamped topic's jump is confirmed (by that topic's next message,
    here the pressure's, 1/8 s later): up to 3 of its messages of 1/20 s fall on the old side."""
    path = recording("mcap", SECONDS, dataclasses.replace(RESET, ahrs_zero_stamps=True)).write(tmp_path)
    m = read_mission(path, ReaderConfig(on_clock_jump="split", segment=2))
    assert m.plan.stamps["ahrs"].source == "receive"
    ahrs = np.array([x.stamp for x in m if x.sensor == "ahrs"])
    pressure = np.array([x.stamp for x in m if x.sensor == "pressure"])
    assert count(20.0, 50.0, SECONDS) - 3 <= ahrs.size <= count(20.0, 50.0, SECONDS)
    # On part 2's clock: within a message period of where the header-stamped topics are.
    assert abs(int(ahrs[0]) - (T0 + 20 * S)) <= LATENCY + 150_000_000
    assert abs(int(ahrs[-1]) - int(pressure[-1])) <= 130_000_000


def test_a_sensor_clock_of_its_own_is_refused_even_when_splitting(tmp_path):
    path = recording("mcap", 60.0, Faults(reset_at_s=40.0, reset_only=("/laser",))).write(tmp_path)
    for cfg in (ReaderConfig(), ReaderConfig(on_clock_jump="split", segment=2)):
        with pytest.raises(MissionError) as err:
            list(read_mission(path, cfg))
        assert str(err.value) == (
            f"{path}: clock jump at mission time 39.000 s (stamp 1700000039.000000 s): the header stamps of /laser "
            "went back 30.000 s, those of /ahrs, /dvl, /pressure did not (a sensor's own clock?); read laser by "
            "receive time (reader.sensors.<name>.stamp: receive)"
        )


@pytest.mark.parametrize("back_s", [30.0, 30.031])
def test_the_recorders_clock_going_back_too_is_refused(tmp_path, back_s):
    """Both clocks back 30 s: the bag, read in time order, interleaves two stretches. With 30 s exactly
    the stamps repeat; with 30.031 s they fall between each other."""
    path = recording("ros1", 70.0, Faults(reset_at_s=50.0, back_s=back_s, recorder_too=True)).write(tmp_path)
    for cfg in (ReaderConfig(), ReaderConfig(on_clock_jump="split", segment=2)):
        with pytest.raises(MissionError) as err:
            list(read_mission(path, cfg))
        text = str(err.value)
        assert text.startswith(f"{path}: interleaved recording from mission time ")
        assert 19.9 <= float(text.split("mission time ")[1].split(" s")[0]) <= 20.1  # where the stretches overlap
        assert "/ahrs" in text and "/pressure" in text and text.endswith("so it cannot be split")
    r = info(path)
    assert_refused(r, "interleaved recording from mission time")


def test_the_issues_clock_reset_through_write_mission(tmp_path, sample_mission):
    """How the fault was first made: every stamp after 25 s moved back 15 s, the mission written again."""
    m = sample_mission(seconds=40.0)
    shifted = [x if x.stamp < 125 * S else dataclasses.replace(x, stamp=x.stamp - 15 * S) for x in m]
    path = write_mission(Mission.from_measurements(m.metadata, shifted), tmp_path / "reset.mcap")
    with pytest.raises(MissionError, match=rf"^{path}: interleaved recording from mission time 10\.0"):
        list(read_mission(path))
    r = info(path)
    assert_refused(r, "interleaved recording from mission time 10.0")
    # Once interleaved, the stamps say nothing more: one refusal, and the repeats it caused, counted.
    section = check_section(r.stdout)
    assert [x for x in section if x.startswith("refused")] == [section[0]]
    repeats = "warning: ahrs: 300 message(s) dropped: header stamp repeats the previous one"  # 15 s at 20 Hz
    assert any(x.startswith(repeats) for x in section)


def test_a_lone_repeated_stamp_a_duplicate_and_a_wild_stamp_are_dropped_and_reported(tmp_path):
    faults = Faults(repeat_dvl_at=(40,), duplicate_dvl_at=(60,), wild_dvl_at=(80,))
    path = recording("mcap", 30.0, faults).write(tmp_path)
    m = read_mission(path)
    dvl = [x.stamp for x in m if x.sensor == "dvl"]
    assert len(dvl) == 150 - 2  # the repeat and the wild one; the duplicate's twin is dropped
    assert m.dropped_fields["dvl"] == {
        "header stamp repeats the previous one": 1,
        "duplicate message": 1,
        "header stamp runs backwards": 1,
    }
    assert m.clock_problems == []
    section = check_section(assert_accepted(info(path)))
    assert (
        "warning: dvl: 1 message(s) dropped: header stamp repeats the previous one (the first at mission time 7.800 s)"
        in section
    )
    assert "warning: dvl: 1 message(s) dropped: duplicate message (the first at mission time 12.000 s)" in section
    assert (
        "warning: dvl: 1 message(s) dropped: header stamp runs backwards (the first at mission time -84.000 s)"
        in section
    )


def test_stamps_that_keep_repeating_are_refused(tmp_path):
    path = recording("mcap", 30.0, Faults(repeat_dvl_at=(40, 43, 46))).write(tmp_path)
    with pytest.raises(MissionError) as err:
        list(read_mission(path))
    assert str(err.value) == (
        f"{path}: different messages with the same header stamp on /dvl at mission time 7.800 s (stamp "
        "1700000007.800000 s): a coarse or stalled clock; read dvl by receive time (reader.sensors.<name>.stamp: receive)"
    )
    assert_refused(info(path), "different messages with the same header stamp on /dvl")
