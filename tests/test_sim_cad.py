"""The CAD library: sizes from the paper, ports on the socket mouths, distinct shapes, user models."""

import numpy as np
import open3d as o3d
import pytest

from semslam.errors import SemslamError
from semslam.models import cad


def _raycast(mesh, origins, dirs):
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
    rays = np.hstack([origins, dirs]).astype(np.float32)
    return scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()


def test_six_classes_with_paper_sizes():
    lib = cad.library()
    assert cad.CLASSES == ("Ball-Valve", "Elbow", "R-Tee", "R-Socket", "Butterfly-Valve", "3-Way-Ball-Valve")
    paper_mm = {
        "Ball-Valve": {198, 160, 120},
        "Elbow": {122.5, 77},
        "R-Tee": {122.5, 168, 77},
        "R-Socket": {88, 75},
        "Butterfly-Valve": {287.5, 243, 121},
        "3-Way-Ball-Valve": {240, 160, 172},
    }
    for c in cad.CLASSES:
        m = lib[c]
        assert m.cls == c and m.name == c
        ext = m.vertices.max(0) - m.vertices.min(0)
        np.testing.assert_allclose(ext, m.size, atol=1e-6)
        assert set(np.round(ext * 1000, 1)) == paper_mm[c]


def test_ports_are_socket_mouths():
    """A ray shot back along each port's outward direction, from just outside, hits the part at the
    port (the mouth is the outermost surface along that direction), and ports are unit and distinct."""
    expected_ports = {
        "Ball-Valve": 2,
        "Elbow": 2,
        "R-Tee": 3,
        "R-Socket": 2,
        "Butterfly-Valve": 2,
        "3-Way-Ball-Valve": 3,
    }
    for c, m in cad.library().items():
        assert len(m.ports) == expected_ports[c]
        P = np.array([p for p, _ in m.ports])
        D = np.array([d for _, d in m.ports])
        np.testing.assert_allclose(np.linalg.norm(D, axis=1), 1.0)
        t = _raycast(m.mesh, P + 0.05 * D, -D)
        np.testing.assert_allclose(t, 0.05, atol=1e-4)
        # the pipe leaving the port runs free of the part: a ray outward from the mouth never re-enters it
        assert np.isinf(_raycast(m.mesh, P + 1e-3 * D, D)).all()


def test_in_line_and_orthogonal_ports():
    lib = cad.library()
    for c in ("Ball-Valve", "R-Socket", "Butterfly-Valve"):
        (_, d0), (_, d1) = lib[c].ports
        assert d0 @ d1 == pytest.approx(-1.0)
    (_, d0), (_, d1) = lib["Elbow"].ports
    assert d0 @ d1 == pytest.approx(0.0)
    for c in ("R-Tee", "3-Way-Ball-Valve"):
        D = np.array([d for _, d in lib[c].ports])
        G = D @ D.T
        assert sorted(np.round(G[np.triu_indices(3, 1)], 6)) == [-1.0, 0.0, 0.0]


def test_handles_make_valves_asymmetric():
    """Valves carry a handle on +z: their mesh reaches much further up than down; fittings do not."""
    lib = cad.library()
    for c in ("Ball-Valve", "Butterfly-Valve", "3-Way-Ball-Valve"):
        v = lib[c].vertices
        assert v[:, 2].max() > 1.5 * -v[:, 2].min()
    for c in ("Elbow", "R-Tee", "R-Socket"):
        v = lib[c].vertices
        assert v[:, 2].max() == pytest.approx(-v[:, 2].min())


def test_deterministic():
    a = cad._build("Butterfly-Valve")
    b = cad._build("Butterfly-Valve")
    assert np.asarray(a.mesh.vertices).tobytes() == np.asarray(b.mesh.vertices).tobytes()


def test_register_user_model(tmp_path):
    box = o3d.geometry.TriangleMesh.create_box(100.0, 50.0, 20.0)  # a part drawn in mm
    path = tmp_path / "flange.ply"
    o3d.io.write_triangle_mesh(str(path), box)
    m = cad.register_model(path, "Flange", scale=0.001, ports=[((0, 0.025, 0.01), (-2, 0, 0))])
    try:
        assert m.name == "flange" and m.cls == "Flange"
        np.testing.assert_allclose(m.size, (0.1, 0.05, 0.02), atol=1e-9)
        np.testing.assert_allclose(m.ports[0][1], (-1, 0, 0))
        assert cad.library()["flange"] is m
        assert set(cad.CLASSES) <= set(cad.library())
    finally:
        cad.unregister_model("flange")
    assert "flange" not in cad.library()


def test_register_errors_are_user_errors(tmp_path):
    with pytest.raises(SemslamError, match="not found"):
        cad.register_model(tmp_path / "nope.stl", "Elbow")
    bad = tmp_path / "empty.obj"
    bad.write_text("# nothing\n")
    with pytest.raises(SemslamError, match="no triangles"):
        cad.register_model(bad, "Elbow")
