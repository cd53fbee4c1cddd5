"""Sonar front-end: the world model (CAD meshes + pipelines + bare seabed) and its size bound."""

import numpy as np
import open3d as o3d

from frontends.sonar.config import WorldModelConfig
from frontends.sonar.grid import GridSpec
from frontends.sonar.pipes import PipeSegment
from frontends.sonar.world_model import build_world_model, write_ply
from semslam.models.structures import pose_matrix, structure_library


def _seabed(cell=0.5):
    spec = GridSpec(-18.0, -33.0, cell, (int(36 / cell), int(66 / cell)))
    N, E = spec.centres()
    n, e = np.meshgrid(N, E, indexing="ij")
    depth = 20.0 + 0.01 * n - 0.005 * e + 0.6 * np.exp(-((n - 5) ** 2 + (e + 8) ** 2) / 60.0)
    depth += 0.1 * np.sin(n / 1.5) * np.cos(e / 2.0)  # sand waves: the seabed mesh needs its triangles
    depth[:4, :20] = np.nan  # unsurveyed corner
    return spec, depth


def _world(raw_bytes, cfg=None):
    lib = structure_library()
    structs = [
        (lib["manifold"], pose_matrix((-6.6, -5.0, 20.4), 1.0)),
        (lib["plet"], pose_matrix((-10.6, 11.0, 20.4), -1.5)),
        (lib["wellhead"], pose_matrix((0.0, -15.0, 20.2), 2.5)),
    ]
    pipes = [PipeSegment(np.array([-10.4, 8.9, 20.2]), np.array([-9.0, -1.0, 20.2]), 0.25, 100, 0.01)]
    spec, depth = _seabed()
    return build_world_model(structs, pipes, depth, spec, cfg or WorldModelConfig(), raw_bytes)


def test_world_model_is_under_one_percent_of_the_raw_cloud(tmp_path):
    raw = 4_523_520 * 12  # the default field's cloud: 4.5 M points × 3 float32
    mesh, info = _world(raw)
    assert info["bytes"] <= 0.01 * raw
    assert info["seabed_triangles"] > 1000
    assert info["seabed_vertical_error_p99_m"] <= WorldModelConfig().seabed_max_error_m + 1e-9
    write_ply(mesh, tmp_path / "world_model.ply")
    assert (tmp_path / "world_model.ply").stat().st_size == info["bytes"]
    back = o3d.io.read_triangle_mesh(str(tmp_path / "world_model.ply"))
    assert len(back.triangles) == info["triangles"]
    # the three CAD meshes are in it, whole
    lib = structure_library()
    assert info["triangles"] > sum(len(lib[n].triangles) for n in lib)


def test_a_tight_budget_simplifies_the_seabed_further():
    loose, info_loose = _world(50_000_000)
    seabed_bytes = info_loose["bytes"] - info_loose["fixed_bytes"]
    tight_budget = int(info_loose["fixed_bytes"] + 0.4 * seabed_bytes)
    cfg = WorldModelConfig()
    _, info = _world(int(tight_budget / cfg.max_fraction), cfg)
    assert info["seabed_triangles"] < info_loose["seabed_triangles"]
    assert info["bytes"] <= tight_budget


def test_world_model_rendering_reads_no_uninitialised_memory(monkeypatch, tmp_path):
    """Facets clipped to a close-up have 3 to 7 vertices. Rendered as they are, matplotlib pads
    them into np.empty and autoscaled on the padding (matplotlib#32272): an infinite axis limit
    now and then. Here every np.empty is filled with the largest float (what uninitialised memory
    may hold), so that reading it shows every time."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from frontends.sonar.figures import _clip_box, _render

    real_empty = np.empty

    def garbage_empty(*a, **k):
        out = real_empty(*a, **k)
        if out.dtype.kind == "f":
            out.fill(np.finfo(out.dtype).max)
        return out

    monkeypatch.setattr(np, "empty", garbage_empty)
    tri = np.array(
        [[[0.0, 0.0, 1.0], [2.0, 0.0, 1.5], [0.0, 2.0, 2.0]], [[0.3, 0.3, 1.0], [0.9, 0.3, 1.0], [0.3, 0.9, 1.2]]]
    )
    polys = [P for t in tri for P in _clip_box(t[None], np.array([0.2, 0.2]), np.array([1.0, 1.0]))]
    assert len({len(P) for P in polys}) > 1  # ragged: what triggered it
    fig = plt.figure()
    ax = fig.add_subplot(projection="3d")
    _render(ax, polys, np.full((len(polys), 3), 0.5))
    assert np.all(np.isfinite(ax.get_zlim()))
    fig.savefig(tmp_path / "close_up.png")
    plt.close(fig)
