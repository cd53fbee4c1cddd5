"""Configuration: defaults, YAML overrides, and one-line errors naming the key."""

import yaml
from pydantic import BaseModel, ValidationError
from typer.testing import CliRunner

from semslam.cli import app
from semslam.config import SemslamConfig, load_config
from semslam.registry import available_frontends, frontend_sections

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
    loaded = load_config(f)
    assert loaded.model_copy(update={"frontends": {}}) == SemslamConfig()
    assert frontend_sections(loaded.frontends) == frontend_sections()  # every front-end key, at its default
    assert "water_density_kg_m3" in yaml.safe_load(res.output)["reader"]
    again = runner.invoke(app, ["config", "dump", "--config", str(f)])
    assert again.exit_code == 0 and again.output == res.output


def _sections(model: type[BaseModel], path: tuple[str, ...] = ()):
    """(path, model) of every section of a configuration model, nested ones included."""
    yield path, model
    for name, info in model.model_fields.items():
        t = info.annotation
        if isinstance(t, type) and issubclass(t, BaseModel):
            yield from _sections(t, (*path, name))


def _changed(model: type[BaseModel]):
    """A key of ``model`` and a valid value for it other than its default (None: no scalar key)."""
    defaults = model()
    for name in model.model_fields:
        old = getattr(defaults, name)
        if old is None:  # an optional number
            candidates = [0.5, 1]
        elif isinstance(old, bool):
            candidates = [not old]
        elif isinstance(old, (int, float)):
            candidates = [old * 0.5, old + 1, old * 2, old - 1] if old else [1, 0.5]
            candidates = [type(old)(c) for c in candidates if type(old)(c) != old]
        else:
            continue
        for new in candidates:
            try:
                model.model_validate({name: new})
            except ValidationError:
                continue
            return name, new
    return None


def _set(tree: dict, path: tuple[str, ...], key: str, value) -> None:
    for p in path:
        tree = tree.setdefault(p, {})
    tree[key] = value


def _get(tree: dict, path: tuple[str, ...], key: str):
    for p in path:
        tree = tree[p]
    return tree[key]


def test_a_key_of_every_section_round_trips_through_a_yaml_file(tmp_path):
    """One key of every section, front-ends' included, changed in a YAML file: `config dump --config`
    prints the changed value, and every section has a key that can be changed."""
    sections = [(("",) + path, model) for path, model in _sections(SemslamConfig)]
    for name, model in frontend_sections().items():
        sections += [(("frontends", name, *path), m) for path, m in _sections(type(model))]
    data, expected = {}, []
    for path, model in sections:
        path = tuple(p for p in path if p)
        change = _changed(model)
        if change is None:  # a section of sections, lists and mappings only
            assert not any(isinstance(getattr(model(), k), (bool, int, float)) for k in model.model_fields), path
            continue
        _set(data, path, *change)
        expected.append((path, *change))
    assert {p[:2] for p, *_ in expected if p[:1] == ("frontends",)} == {("frontends", n) for n in available_frontends()}
    f = tmp_path / "changed.yaml"
    f.write_text(yaml.safe_dump(data))
    res = runner.invoke(app, ["config", "dump", "--config", str(f)])
    assert res.exit_code == 0, res.output
    dumped = yaml.safe_load(res.output)
    for path, key, value in expected:
        assert _get(dumped, path, key) == value, (path, key)


def test_every_key_of_the_estimators_and_the_oracle_says_what_it_does():
    from frontends.oracle import OracleConfig

    for path, model in [*_sections(SemslamConfig), ((), OracleConfig)]:
        if path == ("reader",):
            continue  # the bag reader's section (semslam.mission) is documented with the reader
        for name, info in model.model_fields.items():
            assert info.description, (path, name)


def test_a_section_for_an_unregistered_front_end_is_an_error(tmp_path):
    f = tmp_path / "c.yaml"
    f.write_text("frontends:\n  lazer: {}\n")
    res = runner.invoke(app, ["config", "dump", "--config", str(f)])
    assert res.exit_code == 1 and "frontends.lazer" in res.output
    f.write_text("frontends:\n  oracle:\n    max_range: 3\n")  # the key is max_range_m
    res = runner.invoke(app, ["config", "dump", "--config", str(f)])
    assert res.exit_code == 1 and "frontends.oracle.max_range" in res.output


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


def test_a_gyro_bias_declared_constant_still_reaches_its_prior_sigma_in_finite_time():
    """A constant bias (walk 0, as the simulators declare it) keeps the least walk; with a loose prior σ (a
    user's 0.005 rad/s on such a recording) the walk is at least σ over CONSTANT_BIAS_OVER_S, so the graph's
    chain of bias states is not rigid against the prior (the 1e-7 floor alone made iSAM2's system
    indeterminate on tank world 62, stop 44)."""
    from types import SimpleNamespace

    from semslam.config.estimation import CONSTANT_BIAS_OVER_S, MIN_GYRO_BIAS_WALK
    from semslam.sim.config import TankSimConfig
    from semslam.sim.simulate import declared_noise

    tank = SimpleNamespace(extras={"noise": declared_noise(TankSimConfig())})
    assert SemslamConfig().sensors.gyro_bias_walk(tank) == MIN_GYRO_BIAS_WALK  # the simulators' σ: the floor
    loose = SemslamConfig(sensors={"gyro_bias_sigma_rad_s": 0.005}).sensors
    assert loose.gyro_bias_walk(tank) * CONSTANT_BIAS_OVER_S**0.5 >= 0.005 * (1 - 1e-12)
    explicit = SemslamConfig(sensors={"gyro_bias_sigma_rad_s": 0.005, "gyro_bias_walk_rad_s_per_sqrt_s": 1e-7})
    assert explicit.sensors.gyro_bias_walk(tank) > 10 * MIN_GYRO_BIAS_WALK
