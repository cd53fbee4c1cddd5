"""Randomised worlds: what a seed draws (semslam.sim.vary), seed 0 untouched, the user's keys kept."""

from __future__ import annotations

import numpy as np
import pytest
from typer.testing import CliRunner

from semslam.cli import app
from semslam.errors import ConfigError
from semslam.sim.config import TankSimConfig
from semslam.sim.field_config import FieldSimConfig
from semslam.sim.scenarios import resolve_config
from semslam.sim.vary import ASPECTS, draws, parse_aspects
from tests.test_sim_mission import _digest as digest

SHORT = {
    "trajectory": {"duration_s": 20.0, "rest_s": 1.0, "ramp_s": 6.0, "loops": 0.2},
    "laser": {"resolution": [40, 30]},
}


def test_seed_0_is_the_default_mission_whatever_varies():
    """The demo's mission: seed 0 draws nothing, through the library and through the command."""
    from semslam.sim.simulate import simulate_tank

    assert draws("tank", 0, ASPECTS) == {} and draws("field", 0, ASPECTS) == {}
    assert resolve_config("tank", 0, ASPECTS) == TankSimConfig()
    assert resolve_config("field", 0, ASPECTS) == FieldSimConfig()
    short = resolve_config("tank", 0, ASPECTS, SHORT)
    assert digest(simulate_tank(short)) == digest(simulate_tank(TankSimConfig.model_validate(SHORT)))


def test_each_aspect_draws_its_own_keys_from_its_own_stream():
    keys = {
        "layout": {"structure"},
        "trajectory": {"trajectory"},
        "noise": {"dvl", "ahrs", "depth", "laser"},
        "dropouts": {"dvl"},
        "start": {"trajectory"},
    }
    everything = draws("tank", 7, ASPECTS)
    for aspect, expected in keys.items():
        alone = draws("tank", 7, [aspect])
        assert set(alone) == expected
        for section, values in alone.items():  # the same values when every aspect varies
            assert {k: everything[section][k] for k in values} == values
    assert draws("tank", 7, ["noise"]) != draws("tank", 8, ["noise"])
    assert set(draws("field", 7, ["noise"])) == {"dvl", "ahrs", "depth", "sonar"}


def test_draws_stay_in_the_documented_ranges():
    for seed in range(1, 200):
        t = resolve_config("tank", seed, ASPECTS)
        nx, ny, nz = t.structure.grid
        assert 3 <= nx <= 4 and 3 <= ny <= 4 and 2 <= nz <= 3
        assert 12 <= t.structure.n_edges <= min(round(0.8 * nx * ny * nz), 26)
        half = np.array(t.structure.spacing_m[:2]) * (np.array([nx, ny]) - 1) / 2 + np.abs(t.structure.center_xy_m)
        assert np.all(np.array(t.trajectory.semi_axes_m) - half >= 1.3)  # the vehicle keeps clear of the rack
        assert 0.005 <= t.dvl.sigma_m_s <= 0.02 and 0.01 <= t.depth.sigma_m <= 0.05
        assert 0.002 <= t.laser.range_sigma_m <= 0.01 and 0.25 <= t.ahrs.heading_sigma_deg <= 1.0
        assert 0 <= t.dvl.random_dropout_rate <= 0.15 and t.dvl.burst_s[0] < t.dvl.burst_s[1]
        assert 130 <= t.trajectory.loop_period_s <= 190 and 0 <= t.trajectory.start_angle_deg < 360
        f = resolve_config("field", seed, ASPECTS)
        assert 4.5 <= f.trajectory.line_spacing_m <= 6.0 and 0.4 <= f.trajectory.speed_m_s <= 0.7
        assert 0.01 <= f.sonar.range_sigma_m <= 0.03 and 0 <= f.dvl.random_dropout_rate <= 0.05


@pytest.mark.parametrize("seed", [1, 2, 3, 4, 5, 6])
def test_drawn_layouts_are_generated(seed):
    """Every drawn lattice admits a layout (the ranges were checked over seeds 1–1000)."""
    from semslam.models import cad
    from semslam.sim.tank import check_layout, generate_layout

    cfg = resolve_config("tank", seed, ["layout"])
    lay = generate_layout(cfg.structure, cfg.tank, seed)
    assert {o.cls for o in lay.objects} == set(cad.CLASSES) and check_layout(lay) == []
    assert len(lay.objects) >= cfg.structure.min_objects and len(lay.pipes) >= cfg.structure.min_pipes


def test_the_users_keys_win_over_the_draws():
    cfg = resolve_config("tank", 5, ASPECTS, {"dvl": {"sigma_m_s": 0.03}}, dvl__random_dropout_rate=0.0)
    drawn = draws("tank", 5, ASPECTS)
    assert cfg.dvl.sigma_m_s == 0.03 and cfg.dvl.random_dropout_rate == 0.0
    assert list(cfg.dvl.burst_s) == drawn["dvl"]["burst_s"]  # what the user left alone stays drawn
    assert cfg.ahrs.heading_sigma_deg == drawn["ahrs"]["heading_sigma_deg"]


def test_the_simulated_world_is_the_drawn_one():
    from semslam.sim.simulate import simulate_tank

    cfg = resolve_config("tank", 5, ASPECTS, SHORT)
    m = simulate_tank(cfg)
    noise = m.metadata.extras["noise"]
    assert noise["dvl"]["velocity_sigma_m_s"] == cfg.dvl.sigma_m_s
    assert noise["depth"]["sigma_m"] == cfg.depth.sigma_m
    assert m.metadata.extras["simulator"]["config"]["structure"]["grid"] == list(cfg.structure.grid)
    xy = np.array([o.position[:2] for o in m.metadata.ground_truth.objects])
    extent = np.array(cfg.structure.spacing_m[:2]) * (np.array(cfg.structure.grid[:2]) - 1)
    assert np.all(np.ptp(xy, axis=0) <= extent + 0.3)  # within the drawn lattice (+ fittings)
    assert np.allclose(xy.mean(0), cfg.structure.center_xy_m, atol=0.45)
    assert TankSimConfig.model_validate(cfg.model_dump(mode="json")) == cfg  # what a study's task carries


def test_parse_aspects():
    assert parse_aspects("all") == ASPECTS and parse_aspects("none") == () and parse_aspects("") == ()
    assert parse_aspects("start,noise") == ("noise", "start")
    with pytest.raises(ConfigError, match="unknown aspect 'wind'"):
        parse_aspects("noise,wind")


def test_cli_vary(tmp_path):
    runner = CliRunner()
    res = runner.invoke(app, ["simulate", "tank", "--out", str(tmp_path / "m.bag"), "--vary", "wind"])
    assert res.exit_code == 1 and "--vary" in res.output and not (tmp_path / "m.bag").exists()
    sim = tmp_path / "sim.yaml"
    sim.write_text("trajectory: {lines: 1, line_length_m: 6.0}\nsonar: {n_beams: 16}\n")
    out = tmp_path / "f.bag"
    res = runner.invoke(
        app, ["simulate", "field", "--seed", "4", "--vary", "noise", "--sim-config", str(sim), "--out", str(out)]
    )
    assert res.exit_code == 0, res.output
    from semslam.mission.bag import read_mission

    resolved = read_mission(out).metadata.extras["simulator"]["config"]
    assert resolved["sonar"]["range_sigma_m"] == draws("field", 4, ["noise"])["sonar"]["range_sigma_m"]
    assert resolved["trajectory"]["line_spacing_m"] == FieldSimConfig().trajectory.line_spacing_m  # not varied
