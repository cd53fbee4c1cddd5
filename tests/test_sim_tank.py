"""The simulated structure: classes, counts, connectivity consistent with geometry, YAML layouts."""

import json
from collections import Counter

import numpy as np
import pytest

from semslam.errors import ConfigError
from semslam.models import cad
from semslam.sim.config import TankSimConfig
from semslam.sim.tank import (
    FLOOR,
    OBJECT,
    PIPE,
    WALL,
    TankScene,
    check_layout,
    generate_layout,
    layout_from_dict,
    load_layout_yaml,
    make_layout,
)

CFG = TankSimConfig()


@pytest.fixture(scope="module")
def layout():
    return generate_layout(CFG.structure, CFG.tank, 0)


def _pipe_dirs_at(o, layout):
    """Unit directions, leaving the object, of the pipes attached to it (from the pipe geometry only)."""
    out = []
    for pid in o.pipes:
        p = layout.pipes[pid]
        near, far = (p.p, p.q) if np.linalg.norm(p.p - o.position) < np.linalg.norm(p.q - o.position) else (p.q, p.p)
        out.append((far - near) / np.linalg.norm(far - near))
    return np.array(out)


@pytest.mark.parametrize("seed", [0, 1, 7, 123])
def test_counts_classes_and_pipes(seed):
    lay = generate_layout(CFG.structure, CFG.tank, seed)
    counts = Counter(o.cls for o in lay.objects)
    assert set(counts) == set(cad.CLASSES), counts
    assert len(lay.objects) >= 20 and len(lay.pipes) >= 12
    assert all(p.radius <= 0.064 for p in lay.pipes)
    assert min(p.length for p in lay.pipes) >= CFG.structure.min_pipe_length_m
    lo, hi = lay.bounds()
    size = hi - lo
    assert np.all(size[:2] < 1.7) and size[2] < 1.45 and np.all(size > 1.1)  # about 1.4 × 1.4 × 1.2 m
    assert hi[2] <= CFG.tank.depth_m  # stands in the water, above the floor
    assert check_layout(lay) == []


@pytest.mark.parametrize("seed", [0, 5])
def test_pipe_ends_within_1cm_of_ports(seed):
    """Every pipe an object lists ends within 1 cm of one of its ports, leaving along the port's
    direction; every pipe end that meets no port is a free end (no object within 1 cm of it)."""
    lay = generate_layout(CFG.structure, CFG.tank, seed)
    used = set()
    for o in lay.objects:
        ports = o.ports()
        for pid in o.pipes:
            p = lay.pipes[pid]
            best = min(
                (np.linalg.norm(a - pp), (b - a) @ d / np.linalg.norm(b - a), i)
                for a, b in ((p.p, p.q), (p.q, p.p))
                for i, (pp, d) in enumerate(ports)
            )
            assert best[0] < 0.01 and best[1] > 0.999
            assert (o.id, best[2]) not in used  # one pipe per port
            used.add((o.id, best[2]))
    attached = Counter(pid for o in lay.objects for pid in o.pipes)
    assert all(n <= 2 for n in attached.values())
    for p in lay.pipes:
        for end in (p.p, p.q):
            near = [o for o in lay.objects if any(np.linalg.norm(end - pp) < 0.01 for pp, _ in o.ports())]
            assert all(p.id in o.pipes for o in near)


def test_fitting_geometry_matches_class(layout):
    for o in layout.objects:
        D = _pipe_dirs_at(o, layout)
        G = D @ D.T
        if o.cls == cad.ELBOW:
            assert len(D) == 2 and abs(G[0, 1]) < 1e-6  # two orthogonal pipes
        elif o.cls in (cad.R_TEE, cad.THREE_WAY_BALL_VALVE):
            assert len(D) == 3  # a T: one opposite pair, the third orthogonal to both
            assert sorted(np.round(G[np.triu_indices(3, 1)], 6)) == [-1.0, 0.0, 0.0]
        elif o.cls == cad.R_SOCKET:
            assert len(D) == 2 and G[0, 1] == pytest.approx(-1.0)  # joins two collinear pipes
        else:  # in-line valves: in line between two pipes, or at the end of one
            assert len(D) in (1, 2)
            if len(D) == 2:
                assert G[0, 1] == pytest.approx(-1.0)
            x_axis = o.T_WM[:3, 0]
            assert abs(D[0] @ x_axis) == pytest.approx(1.0)


def test_default_seed_is_one_fixed_layout(layout):
    again = make_layout(CFG.structure, CFG.tank, 0)
    assert again.to_dict() == layout.to_dict()
    assert generate_layout(CFG.structure, CFG.tank, 1).to_dict() != layout.to_dict()


def test_yaml_round_trip_and_inferred_connectivity(tmp_path, layout):
    path = tmp_path / "layout.yaml"
    layout.save_yaml(path)
    back = load_layout_yaml(path)
    assert [o.pipes for o in back.objects] == [o.pipes for o in layout.objects]
    np.testing.assert_allclose([o.T_WM for o in back.objects], [o.T_WM for o in layout.objects], atol=1e-8)
    # without the 'pipes' lists, the connectivity is recovered from the geometry
    d = layout.to_dict()
    for o in d["objects"]:
        del o["pipes"]
    inferred = layout_from_dict(d)
    assert [o.pipes for o in inferred.objects] == [o.pipes for o in layout.objects]
    # and the YAML can drive a mission layout
    cfg = TankSimConfig(structure={"layout_yaml": str(path)}, seed=99)
    assert make_layout(cfg.structure, cfg.tank, cfg.seed).to_dict() == back.to_dict()


def test_bad_yaml_layouts_are_user_errors(tmp_path, layout):
    d = layout.to_dict()
    d["objects"][0]["model"] = "Gate-Valve"
    with pytest.raises(ConfigError, match=r"objects\[0\]\.model"):
        layout_from_dict(d)
    d = layout.to_dict()
    d["objects"][3]["position"][0] += 0.05  # moved off its pipes
    with pytest.raises(ConfigError, match="inconsistent layout"):
        layout_from_dict(d)
    bad = tmp_path / "bad.yaml"
    bad.write_text("objects: [1, 2\n")
    with pytest.raises(ConfigError, match="bad.yaml"):
        load_layout_yaml(bad)
    with pytest.raises(ConfigError, match="not found"):
        load_layout_yaml(tmp_path / "missing.yaml")
    not_a_layout = tmp_path / "sim.yaml"
    not_a_layout.write_text("trajectory: {loops: 1}\n")
    with pytest.raises(ConfigError, match="unknown key 'trajectory'"):
        load_layout_yaml(not_a_layout)
    with pytest.raises(ConfigError, match="non-empty 'objects'"):
        layout_from_dict({"pipes": []})


def test_docstring_example_layout():
    import yaml as _yaml

    text = layout_from_dict.__doc__.split("::")[1]
    lay = layout_from_dict(_yaml.safe_load(text))
    assert lay.objects[0].pipes == (0, 1) and check_layout(lay) == []


def test_scene_labels(layout):
    """Rays straight down from above a pipe / an object / open floor, and sideways into a wall,
    report the right kind and id at the right distance."""
    scene = TankScene(CFG.tank, layout)
    horizontal = [p for p in layout.pipes if abs(p.q[2] - p.p[2]) < 1e-9]
    top = min(p.p[2] for p in horizontal)
    pipe = max((p for p in horizontal if p.p[2] == top), key=lambda p: p.length)  # nothing above it
    mid = (pipe.p + pipe.q) / 2
    t, kind, ident = scene.cast([mid - [0, 0, 2.0]], [[0, 0, 1.0]])
    assert kind[0] == PIPE and ident[0] == pipe.id
    assert t[0] == pytest.approx(2.0 - pipe.radius, abs=2e-3)  # the 24-gon cylinder is within 0.3 mm of round
    top = min(layout.objects, key=lambda o: o.position[2])
    t, kind, ident = scene.cast([top.position - [0, 0, 2.0]], [[0, 0, 1.0]])
    assert kind[0] in (OBJECT, PIPE)
    t, kind, _ = scene.cast([[3.5, 3.5, 1.0]], [[0, 0, 1.0]])
    assert kind[0] == FLOOR and t[0] == pytest.approx(CFG.tank.depth_m - 1.0, abs=1e-5)
    # a horizontal ray at depth z hits the north wall at x = floor_half_x + (D − z) / tan(slope)
    z = 2.0
    t, kind, _ = scene.cast([[0, 0, z]], [[1.0, 0, 0]])
    x_wall = CFG.tank.floor_half_x_m + (CFG.tank.depth_m - z) / np.tan(np.deg2rad(CFG.tank.wall_slope_deg))
    assert kind[0] == WALL and t[0] == pytest.approx(x_wall, abs=1e-4)
    t, kind, ident = scene.cast([[0, 0, 1.0]], [[0, 0, -1.0]])  # up through the surface: no return
    assert np.isinf(t[0]) and kind[0] == -1 and ident[0] == -1


def test_ground_truth_map(layout):
    gt = layout.ground_truth(seen_objects=(1, 2), seen_pipes=(0,))
    assert gt.classes[:6] == cad.CLASSES
    o = gt.objects[4]
    src = layout.objects[4]
    np.testing.assert_allclose(o.position, src.position)
    assert o.pipes == src.pipes and o.model == src.model and o.cls == src.cls
    from scipy.spatial.transform import Rotation

    np.testing.assert_allclose(Rotation.from_quat(o.orientation).as_matrix(), src.T_WM[:3, :3], atol=1e-9)
    assert gt.pipes[3].radius == layout.pipes[3].radius
    assert json.loads(json.dumps(gt.to_dict()))["objects"][4]["pipes"] == list(src.pipes)  # sidecar-ready


def test_user_model_in_a_yaml_layout(tmp_path):
    """A registered user mesh (any class name) can be placed in a YAML layout; its ports connect pipes."""
    import open3d as o3d

    box = o3d.geometry.TriangleMesh.create_box(0.2, 0.1, 0.1)
    box.translate((-0.1, -0.05, -0.05))
    path = tmp_path / "flange.stl"
    box.compute_triangle_normals()
    o3d.io.write_triangle_mesh(str(path), box)
    cad.register_model(path, "Flange", name="my-flange", ports=[((0.1, 0, 0), (1, 0, 0)), ((-0.1, 0, 0), (-1, 0, 0))])
    try:
        data = {
            "objects": [{"cls": "Flange", "model": "my-flange", "position": [1.0, 2.0, 4.5], "rpy_deg": [0, 0, 90]}],
            "pipes": [
                {"p": [1.0, 2.1, 4.5], "q": [1.0, 2.8, 4.5], "radius": 0.03},
                {"p": [1.0, 1.9, 4.5], "q": [1.0, 1.2, 4.5], "radius": 0.03},
                {"p": [3.0, 3.0, 4.5], "q": [3.5, 3.0, 4.5], "radius": 0.03},
            ],
        }
        lay = layout_from_dict(data)
        assert lay.objects[0].pipes == (0, 1)
        gt = lay.ground_truth()
        assert "Flange" in gt.classes and gt.objects[0].model == "my-flange"
    finally:
        cad.unregister_model("my-flange")
