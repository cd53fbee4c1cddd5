"""`semslam run --record`: the replay and its Foxglove layout beside the outputs, and where to open them."""

import json

from typer.testing import CliRunner

from semslam.cli import app


def test_run_records_a_replay_and_overwrite_replaces_the_whole_directory(tmp_path):
    from semslam.mission.bag import write_mission
    from tests.support.synthetic_mission import SyntheticConfig, simulate

    bag = write_mission(simulate(SyntheticConfig(duration_s=30.0, seed=2)), tmp_path / "m.bag")
    out = tmp_path / "run"
    args = ["run", str(bag), "-e", "ekf", "--frontends", "oracle", "--out", str(out)]
    res = CliRunner().invoke(app, [*args, "--record", "--record-points", "50"])
    assert res.exit_code == 0, res.output
    assert (out / "replay.mcap").stat().st_size > 0
    assert "configById" in json.loads((out / "foxglove_layout.json").read_text())
    assert f"replay: {(out / 'replay.mcap').resolve()}" in res.output
    assert "Foxglove" in res.output and "ros2 bag play" in res.output
    res = CliRunner().invoke(app, args)
    assert res.exit_code == 1 and "exists already (--overwrite replaces it)" in res.output
    res = CliRunner().invoke(app, [*args, "--overwrite"])
    assert res.exit_code == 0, res.output
    assert (out / "metrics.json").is_file() and not (out / "replay.mcap").exists()  # nothing stale
    assert "replay:" not in res.output
