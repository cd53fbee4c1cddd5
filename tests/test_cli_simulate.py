"""`semslam simulate` user errors: one line, exit 1, nothing written."""

from typer.testing import CliRunner

from semslam.cli import app

runner = CliRunner()


def test_unknown_scene(tmp_path):
    res = runner.invoke(app, ["simulate", "pond", "--out", str(tmp_path / "m.bag")])
    assert res.exit_code == 1
    assert "unknown scene 'pond'" in res.output and "Traceback" not in res.output
    assert not list(tmp_path.iterdir())


def test_existing_output_is_not_overwritten(tmp_path):
    out = tmp_path / "m.bag"
    out.write_bytes(b"precious")
    res = runner.invoke(app, ["simulate", "tank", "--out", str(out), "--loops", "0.05"])
    assert res.exit_code == 1 and str(out) in res.output
    assert out.read_bytes() == b"precious"


def test_invalid_simulation_option_names_the_key(tmp_path):
    res = runner.invoke(app, ["simulate", "tank", "--out", str(tmp_path / "m.bag"), "--dvl-dropout-rate", "2"])
    assert res.exit_code == 1 and "random_dropout_rate" in res.output
    assert len([line for line in res.output.splitlines() if line.strip()]) == 1
