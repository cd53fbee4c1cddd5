"""The demo's cached mission (~320 MB): one, of the current simulator; never a cut one."""

from __future__ import annotations

import os
import time

import pytest

from faults.commands import short_tank
from semslam.demo import demo_mission, simulator_fingerprint
from semslam.mission.bag import read_mission


@pytest.fixture(scope="module")
def small():
    return short_tank(seconds=4.0)


@pytest.fixture
def cache(tmp_path, monkeypatch, small):
    """An empty cache folder, and a simulator that gives a short mission instead of the default one."""
    monkeypatch.setenv("SEMSLAM_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setattr("semslam.sim.simulate.simulate_tank", lambda config: small)
    return tmp_path / "cache" / "missions"


def test_the_mission_of_an_older_simulator_is_replaced(cache):
    cache.mkdir(parents=True)
    for name in ("tank-default-0123456789ab.bag", "tank-default-0123456789ab.bag.semslam.json"):
        (cache / name).write_text("an older simulator's mission")
    path = demo_mission()
    current = f"tank-default-{simulator_fingerprint()}.bag"
    assert path == cache / current
    assert sorted(p.name for p in cache.iterdir()) == [current, f"{current}.semslam.json"]
    assert len(list(read_mission(path))) > 100
    assert demo_mission() == path and path.stat().st_mtime_ns == (cache / current).stat().st_mtime_ns  # reused


def test_an_interrupted_simulation_leaves_no_cut_mission(cache, monkeypatch):
    def interrupted(config):
        raise KeyboardInterrupt

    monkeypatch.setattr("semslam.sim.simulate.simulate_tank", interrupted)
    with pytest.raises(KeyboardInterrupt):
        demo_mission()
    assert list(cache.iterdir()) == []


def test_half_written_missions_of_killed_simulations_go_once_old(cache):
    cache.mkdir(parents=True)
    old, fresh = cache / ".tank-default-x.bag.old.partial", cache / ".tank-default-x.bag.new.partial"
    for d in (old, fresh):
        d.mkdir()
        (d / "tank-default-x.bag").write_text("cut")
    two_hours_ago = time.time() - 7200
    os.utime(old, (two_hours_ago, two_hours_ago))
    demo_mission()
    assert not old.exists() and fresh.exists()  # the fresh one may be another demo simulating right now
