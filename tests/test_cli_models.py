"""`semslam models` (contributed by the laser front-end through the semslam.commands entry point)."""

import open3d as o3d
from typer.testing import CliRunner

from semslam.cli import app

runner = CliRunner()


def test_add_list_remove_a_user_model(tmp_path, monkeypatch):
    monkeypatch.setenv("SEMSLAM_CACHE_DIR", str(tmp_path / "cache"))
    mesh = o3d.geometry.TriangleMesh.create_box(0.2, 0.1, 0.08)
    mesh.compute_triangle_normals()
    path = tmp_path / "flange.stl"
    o3d.io.write_triangle_mesh(str(path), mesh)
    res = runner.invoke(app, ["models", "add", str(path), "--class", "Flange"])
    assert res.exit_code == 0, res.output
    assert "'flange' (Flange)" in res.output and "views" in res.output
    assert "flange" in runner.invoke(app, ["models", "list"]).output
    assert runner.invoke(app, ["models", "remove", "flange"]).exit_code == 0
    assert "no user models" in runner.invoke(app, ["models", "list"]).output
    res = runner.invoke(app, ["models", "remove", "flange"])
    assert res.exit_code == 1 and "no user model named 'flange'" in res.output


def test_missing_mesh_is_one_line(tmp_path, monkeypatch):
    monkeypatch.setenv("SEMSLAM_CACHE_DIR", str(tmp_path / "cache"))
    res = runner.invoke(app, ["models", "add", str(tmp_path / "none.stl"), "--class", "X"])
    assert res.exit_code == 1 and "none.stl" in res.output and "Traceback" not in res.output
    assert len([line for line in res.output.splitlines() if line.strip()]) == 1
