"""Configuration: defaults, YAML overrides, and one-line errors naming the key."""

import yaml
from typer.testing import CliRunner

from semslam.cli import app
from semslam.config import SemslamConfig, load_config

runner = CliRunner()


def test_yaml_overrides_only_what_it_names(tmp_path):
    f = tmp_path / "c.yaml"
    f.write_text("reader:\n  water_density_kg_m3: 1000\nassociation:\n  min_observations: 5\n")
    cfg = load_config(f)
    assert cfg.reader.water_density_kg_m3 == 1000
    assert cfg.association.min_observations == 5
    assert cfg.association.confidence == SemslamConfig().association.confidence


def test_config_dump_round_trips_through_load(tmp_path):
    res = runner.invoke(app, ["config", "dump"])
    assert res.exit_code == 0
    f = tmp_path / "dumped.yaml"
    f.write_text(res.output)
    assert load_config(f) == SemslamConfig()
    assert "water_density_kg_m3" in yaml.safe_load(res.output)["reader"]


def test_invalid_config_is_one_line_naming_file_and_key(tmp_path):
    f = tmp_path / "bad.yaml"
    f.write_text("association:\n  confidence: 2.0\n")
    res = runner.invoke(app, ["config", "dump", "--config", str(f)])
    assert res.exit_code == 1
    assert "Traceback" not in res.output
    lines = [line for line in res.output.splitlines() if line.strip()]
    assert len(lines) == 1 and str(f) in lines[0] and "association.confidence" in lines[0]


def test_unknown_key_and_missing_file_are_errors(tmp_path):
    f = tmp_path / "typo.yaml"
    f.write_text("asociation: {}\n")
    res = runner.invoke(app, ["config", "dump", "--config", str(f)])
    assert res.exit_code == 1 and "asociation" in res.output
    res = runner.invoke(app, ["config", "dump", "--config", str(tmp_path / "none.yaml")])
    assert res.exit_code == 1 and "not found" in res.output


def test_version():
    res = runner.invoke(app, ["--version"])
    assert res.exit_code == 0 and res.output.startswith("semslam ")


def test_heading_bias_prior_comes_from_the_mission_unless_configured():
    """The heading bias's start σ is the mission's declared one (the tank simulator's bias starts at 0:
    its AHRS heading at the start defines the world's yaw), floored to a proper prior; a configured
    value wins; a mission that declares nothing gets the 1° default."""
    from types import SimpleNamespace

    from semslam.config import DEFAULT_BIAS_SIGMA0, MIN_BIAS_SIGMA0
    from semslam.sim.config import TankSimConfig
    from semslam.sim.simulate import declared_noise

    tank = SimpleNamespace(extras={"noise": declared_noise(TankSimConfig())})
    declared = SimpleNamespace(extras={"noise": {"ahrs": {"heading_bias_initial_sigma_rad": 0.01}}})
    silent = SimpleNamespace(extras={})
    sensors = SemslamConfig().sensors
    assert sensors.heading_bias_sigma0(tank) == MIN_BIAS_SIGMA0
    assert sensors.heading_bias_sigma0(declared) == 0.01
    assert sensors.heading_bias_sigma0(silent) == DEFAULT_BIAS_SIGMA0
    assert SemslamConfig(sensors={"heading_bias_initial_sigma_rad": 0.03}).sensors.heading_bias_sigma0(tank) == 0.03
