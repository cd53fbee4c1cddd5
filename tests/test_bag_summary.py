"""summarize(): statistics of a mission stream, from a bag or from memory."""

from __future__ import annotations

import numpy as np
import pytest

from semslam.mission.bag import read_mission, write_mission
from semslam.mission.summary import summarize


def test_summary_of_memory_and_bag_agree(tmp_path, sample_mission, capsys):
    mission = sample_mission(seconds=3.0)
    mem = summarize(mission)
    bag = summarize(read_mission(write_mission(mission, tmp_path / "m.bag")), progress=True)
    assert "msg" in capsys.readouterr().err  # the tqdm bar went to stderr
    assert [s.name for s in mem.sensors] == [s.name for s in bag.sensors]
    for a, b in zip(mem.sensors, bag.sensors):
        assert (a.stats.count, a.stats.first, a.stats.last, a.stats.invalid) == (
            b.stats.count,
            b.stats.first,
            b.stats.last,
            b.stats.invalid,
        )
    s = bag.sensor("ahrs")
    assert s.stats.count == 60 and s.stats.rate_hz == pytest.approx(20.0) and s.period_s == pytest.approx(0.05)
    assert bag.duration_s == pytest.approx(2.95)
    assert bag.sensor("dvl").stats.invalid == 2
    assert bag.source == str(tmp_path / "m.bag") and mem.source is None


def test_summary_format_is_a_table(sample_mission):
    text = summarize(sample_mission(seconds=1.0)).format()
    lines = text.splitlines()
    head = next(i for i, line in enumerate(lines) if line.startswith("sensor"))
    assert lines[head].split()[:4] == ["sensor", "kind", "topic", "message"]
    assert len(lines) >= head + 7  # one row per sensor
    widths = {len(line) for line in lines[head : head + 7]}
    assert max(widths) - min(widths) < 12  # aligned columns (right-stripped rows)


def test_empty_mission():
    from semslam.mission import Mission, MissionMetadata

    s = summarize(Mission.from_measurements(MissionMetadata(name="empty"), []))
    assert s.start is None and s.duration_s == 0.0 and "no measurements" in s.format()
    assert np.isfinite(s.duration_s)
