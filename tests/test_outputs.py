"""The output directory as one transaction: whole or not at all, replaced only when asked, errors
as one line; the dead-reckoning map written as what it is."""

import errno
import json
import os

import numpy as np
import pytest
from typer.testing import CliRunner

from semslam.config import SemslamConfig
from semslam.estimation import EstimatorResult, LandmarkEstimate, Trajectory
from semslam.eval.outputs import OutputError, check_output_dir, staged_output, write_outputs
from semslam.registry import FrontendSummary
from semslam.results import PipelineResult


def _result(files=None) -> PipelineResult:
    stamps = np.arange(5, dtype=np.int64) * 10**9
    traj = Trajectory(stamps, np.zeros((5, 3)), np.tile([0.0, 0, 0, 1], (5, 1)))
    lms = [LandmarkEstimate(0, "object", position=np.ones(3), class_posterior={"Elbow": 1.0})]
    summaries = {"fe": FrontendSummary(files=files)} if files else {}
    return PipelineResult({"graph": EstimatorResult("graph", traj, lms)}, None, frontend_summaries=summaries)


def _write(out, overwrite=False, files=None):
    return write_outputs(out, SemslamConfig(), _result(files), {"estimators": {}}, overwrite=overwrite)


def _hidden(parent):
    return [p.name for p in parent.iterdir() if p.name.startswith(".")]


def test_written_whole_and_staging_removed(tmp_path):
    out = _write(tmp_path / "run")
    assert {"config.yaml", "metrics.json", "trajectory_graph.tum", "map_graph.json", "map_graph.ply"} <= {
        p.name for p in out.iterdir()
    }
    assert _hidden(tmp_path) == []
    assert oct(out.stat().st_mode & 0o777) == oct(0o777 & ~_umask())  # not mkdtemp's private 0700


def _umask():
    m = os.umask(0)
    os.umask(m)
    return m


def test_an_existing_directory_is_refused_unless_overwrite_which_replaces_it_whole(tmp_path):
    out = _write(tmp_path / "run")
    (out / "stale_from_another_run.json").write_text("{}")
    with pytest.raises(OutputError, match="exists already.*--overwrite"):
        _write(out)
    assert (out / "stale_from_another_run.json").exists()  # refused: untouched
    _write(out, overwrite=True)
    assert not (out / "stale_from_another_run.json").exists()
    assert (out / "metrics.json").is_file() and _hidden(tmp_path) == []


def test_overwrite_never_replaces_a_directory_that_is_no_semslam_output(tmp_path):
    precious = tmp_path / "home"
    precious.mkdir()
    (precious / "thesis.tex").write_text("years of work")
    with pytest.raises(OutputError, match="not a semslam output directory"):
        check_output_dir(precious, overwrite=True)
    empty = tmp_path / "empty"
    empty.mkdir()
    assert check_output_dir(empty, overwrite=True) == empty  # an empty directory is fine


def test_a_file_in_the_way_or_an_unwritable_parent_is_a_one_line_error(tmp_path):
    (tmp_path / "file").write_text("x")
    with pytest.raises(OutputError, match="exists and is not a directory"):
        check_output_dir(tmp_path / "file")
    with pytest.raises(OutputError) as exc:
        check_output_dir(tmp_path / "file" / "run")  # its parent is a file
    assert str(tmp_path / "file") in str(exc.value) and "\n" not in str(exc.value)
    with pytest.raises(OutputError, match="/proc"):
        check_output_dir("/proc/semslam-run")


@pytest.mark.parametrize("failure", [RuntimeError("figure failed"), KeyboardInterrupt()])
def test_a_failure_or_an_interrupt_while_writing_leaves_nothing(tmp_path, failure):
    def boom(path):
        raise failure

    with pytest.raises(type(failure)):
        _write(tmp_path / "run", files={"figures/x.png": boom})
    assert list(tmp_path.iterdir()) == []


def test_a_full_disk_is_a_one_line_error_and_leaves_nothing(tmp_path):
    def full(path):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))

    with pytest.raises(OutputError) as exc:
        _write(tmp_path / "run", files={"world_model.ply": full})
    msg = str(exc.value)
    assert "world_model.ply" in msg and "No space left on device" in msg and "\n" not in msg
    assert list(tmp_path.iterdir()) == []
    # over an existing output: the old one stays as it was
    _write(tmp_path / "run")
    before = sorted(p.name for p in (tmp_path / "run").iterdir())
    with pytest.raises(OutputError):
        _write(tmp_path / "run", overwrite=True, files={"world_model.ply": full})
    assert sorted(p.name for p in (tmp_path / "run").iterdir()) == before and _hidden(tmp_path) == []


def test_a_directory_that_appears_during_the_run_is_not_overwritten(tmp_path):
    out = tmp_path / "run"
    with pytest.raises(OutputError, match="exists already"):
        with staged_output(out) as stage:
            (stage / "metrics.json").write_text("{}")
            out.mkdir()
            (out / "someone_elses.txt").write_text("x")
    assert [p.name for p in out.iterdir()] == ["someone_elses.txt"] and _hidden(tmp_path) == []


def test_a_stage_no_run_holds_is_removed_by_the_next_run_into_that_output(tmp_path):
    out = tmp_path / "run"
    with staged_output(out) as stage:  # held by this run: another run into "run" leaves it alone
        (stage / "metrics.json").write_text("{}")
        with pytest.raises(OutputError, match="exists already"):
            with staged_output(out) as other:
                (other / "metrics.json").write_text("{}")
                out.mkdir()  # appears meanwhile (as another run's output would)
                (out / "theirs.txt").write_text("x")
        (out / "theirs.txt").unlink()
        out.rmdir()
        assert stage.is_dir()
    abandoned = tmp_path / ".run.x1y2.partial"  # what a run killed by SIGKILL leaves
    (abandoned / ".spill").mkdir(parents=True)
    elsewhere = tmp_path / ".other.x1y2.partial"  # another output's: not this one's to remove
    elsewhere.mkdir()
    _write(out, overwrite=True)
    assert _hidden(tmp_path) == [elsewhere.name]


def test_the_cli_checks_the_output_before_any_work(tmp_path):
    from semslam.cli import app

    out = tmp_path / "run"
    out.mkdir()
    (out / "metrics.json").write_text("{}")
    # the mission does not even exist: the output is what the user hears about first
    for cmd in (["run", str(tmp_path / "missing.bag"), "--out", str(out)], ["compare", "x.bag", "--out", str(out)]):
        res = CliRunner().invoke(app, cmd)
        assert res.exit_code == 1
        assert "exists already (--overwrite replaces it)" in res.output and "Traceback" not in res.output


def test_the_dead_reckoning_map_is_written_as_placed_observations(tmp_path):
    import open3d as o3d

    stamps = np.arange(3, dtype=np.int64)
    traj = Trajectory(stamps, np.zeros((3, 3)), np.tile([0.0, 0, 0, 1], (3, 1)))
    obs = [
        LandmarkEstimate(
            i,
            "object",
            position=np.array([i, 0.5, 2.0]),
            covariance=np.eye(3),
            class_posterior={"R-Tee": 0.7, "Elbow": 0.3},
        )
        for i in range(300)
    ] + [LandmarkEstimate(300 + i, "pipe", p=np.array([0, i, 1.0]), q=np.array([1, i, 1.0])) for i in range(100)]
    res = PipelineResult({"dr": EstimatorResult("dr", traj, obs)}, None)
    out = write_outputs(tmp_path / "run", SemslamConfig(), res, {})
    m = json.loads((out / "map_dr.json").read_text())
    assert m["map"] == "observations" and len(m["objects"]) == 300 and len(m["pipes"]) == 100
    assert m["objects"][7] == [7.0, 0.5, 2.0, "R-Tee"] and m["pipes"][2] == [0.0, 2.0, 1.0, 1.0, 2.0, 1.0]
    cloud = o3d.io.read_point_cloud(str(out / "map_dr.ply"))  # vertices (edges are ignored by the reader)
    assert len(cloud.points) == 300 + 2 * 100
    assert np.allclose(np.asarray(cloud.points)[7], [7.0, 0.5, 2.0])
    assert (out / "map_dr.ply").stat().st_size < 20 * (300 + 200) + 8 * 100 + 400  # ~15 B a vertex, 8 an edge


def test_an_empty_map_is_an_empty_ply_not_a_missing_file(tmp_path):
    import open3d as o3d

    traj = Trajectory(np.zeros(1, np.int64), np.zeros((1, 3)), np.array([[0.0, 0, 0, 1]]))
    out = write_outputs(
        tmp_path / "run", SemslamConfig(), PipelineResult({"graph": EstimatorResult("graph", traj)}, None), {}
    )
    mesh = o3d.io.read_triangle_mesh(str(out / "map_graph.ply"))
    assert len(mesh.vertices) == 0 and (out / "map_graph.ply").read_text().startswith("ply\n")


def test_the_map_mesh_reads_back_in_open3d_as_written(tmp_path):
    import open3d as o3d

    from semslam.eval.outputs import map_geometry, write_mesh

    lms = [
        LandmarkEstimate(0, "object", position=np.array([1.0, 2, 3])),
        LandmarkEstimate(1, "pipe", p=np.zeros(3), q=np.array([1.0, 0, 0])),
    ]
    mesh = map_geometry(lms)
    write_mesh(tmp_path / "m.ply", mesh)
    back = o3d.io.read_triangle_mesh(str(tmp_path / "m.ply"))
    assert len(back.triangles) == len(mesh.triangles) > 100
    np.testing.assert_allclose(np.asarray(back.vertices), np.asarray(mesh.vertices), atol=1e-6)  # float32
    np.testing.assert_array_equal(np.asarray(back.triangles), np.asarray(mesh.triangles))
    np.testing.assert_allclose(np.asarray(back.vertex_colors), np.asarray(mesh.vertex_colors), atol=1 / 255)
