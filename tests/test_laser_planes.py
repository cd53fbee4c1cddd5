"""Plane removal by region growing: tank planes out, pipes and objects (even coplanar ones) kept."""

import numpy as np

from frontends.laser.config import LaserConfig
from frontends.laser.evaluation import OBJECT, PIPE, PLANE
from frontends.laser.planes import grow_regions, remove_planes
from frontends.laser.preprocess import preprocess
from tests.support.synthetic import SynthScan, cached_scan, truth_of


def _kept_raw(scan, cfg):
    pre = preprocess(scan.points, cfg.preprocess, cfg.planes)
    res = remove_planes(pre, cfg.planes, cfg.preprocess.voxel_size)
    v = pre.raw_to_voxel
    kept = np.zeros(len(v), bool)
    kept[v >= 0] = res.structure[v[v >= 0]]
    return kept, res


def test_tank_planes_removed_structure_kept():
    scan = cached_scan()
    truth = truth_of(scan)
    kept, res = _kept_raw(scan, LaserConfig())
    plane = truth.kind == PLANE
    struct = (truth.kind == PIPE) | (truth.kind == OBJECT)
    assert 1.0 - kept[plane].mean() >= 0.98
    assert kept[struct].mean() >= 0.98
    assert len(res.planes) == 2  # floor and wall
    normals = np.array([n for n, _ in res.planes])
    assert np.abs(normals @ [0, 0, 1.0]).max() > 0.999 and np.abs(normals @ [1.0, 0, 0]).max() > 0.999


def test_coplanar_pipe_and_flat_object_faces_kept():
    """Pipe 5 rests on the floor and objects have flat tops: plain plane fitting would eat into both."""
    scan = cached_scan()
    kept, res = _kept_raw(scan, LaserConfig())
    on_floor = (scan.kind == SynthScan.PIPE) & (scan.index == 5)
    assert kept[on_floor].mean() >= 0.97
    floor_z = scan.scene.floor_z
    # its visible lower flank lies within 5 cm of the floor, inside a typical RANSAC plane threshold
    low = on_floor & (scan.points[:, 2] > floor_z - 0.05)
    assert low.sum() > 20 and kept[low].mean() >= 0.95
    tops = (scan.kind == SynthScan.OBJECT) & (np.abs(scan.points[:, 2] - (floor_z - 0.18)) < 0.015)
    assert tops.sum() > 50 and kept[tops].mean() >= 0.98


def test_region_growing_separates_perpendicular_planes():
    rng = np.random.default_rng(0)
    floor = np.column_stack([rng.uniform(-1, 1, (6000, 2)), np.full(6000, 2.0)])
    wall = np.column_stack([np.full(3000, 1.0), rng.uniform(-1, 1, 3000), rng.uniform(1.3, 2.0, 3000)])
    pts = np.vstack([floor, wall]) + rng.normal(0, 0.002, (9000, 3))
    cfg = LaserConfig()
    pre = preprocess(pts, cfg.preprocess, cfg.planes)
    labels = grow_regions(pre, cfg.planes)
    on_floor = pre.points[:, 2] > 1.99
    on_wall = pre.points[:, 0] > 0.99
    main_floor = np.bincount(labels[on_floor & ~on_wall]).argmax()
    main_wall = np.bincount(labels[on_wall & ~on_floor]).argmax()
    assert main_floor != main_wall  # 90° between the normals: never one region
    assert (labels[on_floor & ~on_wall] == main_floor).mean() > 0.9
    assert (labels[on_wall & ~on_floor] == main_wall).mean() > 0.9
    res = remove_planes(pre, cfg.planes, cfg.preprocess.voxel_size)
    assert res.structure.mean() < 0.01  # the corner strip joins the planes too


def test_small_flat_patch_above_floor_is_structure():
    """A flat 20 × 20 cm face 15 cm above the floor is an object's face, not a tank plane."""
    rng = np.random.default_rng(1)
    floor = np.column_stack([rng.uniform(-1, 1, (20000, 2)), np.full(20000, 2.0)])
    g = np.arange(-0.1, 0.1, 0.005)
    top = np.column_stack([*(a.ravel() for a in np.meshgrid(g, g)), np.full(g.size**2, 1.85)])
    pts = np.vstack([floor, top]) + rng.normal(0, 0.002, (len(floor) + len(top), 3))
    cfg = LaserConfig()
    pre = preprocess(pts, cfg.preprocess, cfg.planes)
    res = remove_planes(pre, cfg.planes, cfg.preprocess.voxel_size)
    is_top = pre.points[:, 2] < 1.9
    assert res.structure[is_top].mean() > 0.98
    assert res.structure[~is_top].mean() < 0.01


def test_vertical_lattice_of_thin_pipes_is_not_a_wall():
    """Thin pipes in one vertical plane: 50-point neighbourhoods along them are flat ribbons facing
    the sensor, all coplanar. Without the planarity test region growing makes a "wall" of them."""
    rng = np.random.default_rng(2)
    r = 0.0315

    def pipe(p, q, n=2500):
        p, q = np.asarray(p, float), np.asarray(q, float)
        a = (q - p) / np.linalg.norm(q - p)
        e1 = np.cross(a, [0, 0, 1.0])
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(a, e1)
        e2 = e2 if e2[2] < 0 else -e2  # towards the sensor (−z)
        th = rng.uniform(-1.4, 1.4, n)
        t = rng.uniform(0, 1, n)
        return p + np.outer(t, q - p) + r * (np.outer(np.cos(th), e2) + np.outer(np.sin(th), e1))

    # a 3 × 3 lattice in the plane z = 2.5 (facing the sensor), 0.6 m apart
    parts = [pipe((-0.6, y, 2.5), (0.6, y, 2.5)) for y in (-0.6, 0.0, 0.6)]
    parts += [pipe((x, -0.6, 2.5), (x, 0.6, 2.5)) for x in (-0.6, 0.0, 0.6)]
    floor = np.column_stack([rng.uniform(-1.5, 1.5, (30000, 2)), np.full(30000, 3.0)])
    pts = np.vstack(parts + [floor]) + rng.normal(0, 0.003, (len(floor) + 6 * 2500, 3))
    cfg = LaserConfig()
    pre = preprocess(pts, cfg.preprocess, cfg.planes)
    res = remove_planes(pre, cfg.planes, cfg.preprocess.voxel_size)
    is_pipe = pre.points[:, 2] < 2.9
    assert res.structure[is_pipe].mean() > 0.98
    assert res.structure[~is_pipe].mean() < 0.02
    assert len(res.planes) == 1
