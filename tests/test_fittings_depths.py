"""The port depths by class are worked out once and kept while the CAD library holds the same models:
a model registered (or unregistered) in between counts at the next call."""

import numpy as np
import open3d as o3d
import pytest

from semslam.mapping.fittings import depth_by_class, port_depths
from semslam.models import cad


def test_a_registered_model_counts_at_the_next_call(tmp_path):
    before = depth_by_class()
    assert depth_by_class() == before  # kept: the same library
    assert "Flange" not in before
    box = o3d.geometry.TriangleMesh.create_box(0.1, 0.05, 0.02)
    path = tmp_path / "flange.ply"
    o3d.io.write_triangle_mesh(str(path), box)
    cad.register_model(path, "Flange", ports=[((0.03, 0.0, 0.04), (1, 0, 0))])
    try:
        assert depth_by_class()["Flange"] == pytest.approx(0.05)
        np.testing.assert_allclose(port_depths([{"Flange": 1.0}, None]), [0.05, 0.0])
    finally:
        cad.unregister_model("flange")
    assert depth_by_class() == before
    depth_by_class()["Flange"] = 1.0  # a caller's copy: the kept table is not changed
    assert "Flange" not in depth_by_class()
