"""Global descriptors (ESF, VFH, CVFH): PCL-faithful internals, invariances and shape discrimination."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from frontends.laser.recognition import esf as esf_mod
from frontends.laser.recognition.cvfh import cvfh, stable_regions
from frontends.laser.recognition.esf import ESF_BINS, esf, trace_lines
from frontends.laser.recognition.normals import normals_and_curvature
from frontends.laser.recognition.vfh import SHAPE_BINS, VFH_BINS, pair_features, vfh, vfh_from_normals


def chi2(a, b):
    s = a + b
    m = s > 0
    return 0.5 * float(np.sum((a[m] - b[m]) ** 2 / s[m]))


def sphere(n, rng, r=0.15):
    p = rng.normal(size=(n, 3))
    return r * p / np.linalg.norm(p, axis=1, keepdims=True)


def cylinder(n, rng, r=0.08, h=0.45):
    th = rng.uniform(0, 2 * np.pi, n)
    return np.c_[r * np.cos(th), r * np.sin(th), rng.uniform(-h / 2, h / 2, n)]


def box(n, rng, size=(0.3, 0.2, 0.1)):
    size = np.asarray(size)
    areas = np.array([size[1] * size[2], size[0] * size[2], size[0] * size[1]])
    axis = rng.choice(3, size=n, p=areas / areas.sum())
    p = rng.uniform(-0.5, 0.5, size=(n, 3))
    p[np.arange(n), axis] = rng.choice([-0.5, 0.5], size=n)
    return p * size


def lci_reference(lut3, s, t):
    """Scalar port of PCL's ``ESFEstimation::lci`` voxel walk (inside count, voxel count)."""
    x1, y1, z1 = s
    dx, dy, dz = t[0] - x1, t[1] - y1, t[2] - z1
    inc = [1 if dx >= 0 else -1, 1 if dy >= 0 else -1, 1 if dz >= 0 else -1]
    l, m, n = abs(dx), abs(dy), abs(dz)
    v = [x1, y1, z1]
    count = inside = 0
    if l >= m and l >= n:
        major, minors, L = 0, ((1, m), (2, n)), l
    elif m >= l and m >= n:
        major, minors, L = 1, ((0, l), (2, n)), m
    else:
        major, minors, L = 2, ((1, m), (0, l)), n
    err = [2 * e - L for _, e in minors]
    for _ in range(1, L):
        count += 1
        inside += int(lut3[v[0], v[1], v[2]])
        for j, (ax, e) in enumerate(minors):
            if err[j] > 0:
                v[ax] += inc[ax]
                err[j] -= 2 * L
            err[j] += 2 * e
        v[major] += inc[major]
    count += 1
    inside += int(lut3[v[0], v[1], v[2]])
    return inside, count


def test_vectorised_voxel_walk_matches_pcl_loop():
    rng = np.random.default_rng(3)
    lut = rng.random(64**3) < 0.3
    start = rng.integers(0, 64, size=(400, 3))
    end = rng.integers(0, 64, size=(400, 3))
    end[:20] = start[:20]  # zero-length segments
    end[20:40, :2] = start[20:40, :2]  # axis-aligned ones
    inside, count = trace_lines(lut, start, end, chunk=512)
    lut3 = lut.reshape(64, 64, 64)
    ref = np.array([lci_reference(lut3, s, t) for s, t in zip(start, end)])
    np.testing.assert_array_equal(count, ref[:, 1])
    np.testing.assert_array_equal(inside, ref[:, 0])


def test_esf_walk_skipping_the_voxels_known_on_the_surface_matches_pcl_loop():
    # In ESF the lines join voxels of points and the grid is their 3×3×3 dilation: the first two
    # and the last visited voxels are on it, and the walk counts them without looking them up.
    rng = np.random.default_rng(4)
    vox = rng.integers(0, 64, size=(300, 3)).astype(np.int32)
    vox[:20, 1:] = vox[20:40, 1:]  # some axis-aligned and short lines
    vox[40:60] = np.clip(vox[60:80] + rng.integers(-3, 4, size=(20, 3)), 0, 63)
    lut = esf_mod._surface_lut(vox)
    p, q = rng.integers(0, 300, 6000), rng.integers(0, 300, 6000)
    p[:200], q[:200] = np.arange(200), np.arange(20, 220)
    lut3 = lut.reshape(66, 66, 66)[1:-1, 1:-1, 1:-1]
    ref = np.array([lci_reference(lut3, s, t) for s, t in zip(vox[p], vox[q])])
    for band in (None, 4, 16):
        inside, count = esf_mod._walk(lut, tuple(vox[p].T), tuple(vox[q].T), band=band, head=2, tail=1)
        np.testing.assert_array_equal(count, ref[:, 1])
        np.testing.assert_array_equal(inside, ref[:, 0])


def test_esf_is_a_normalised_640_histogram_and_seedable():
    rng = np.random.default_rng(0)
    cloud = box(2000, rng)
    h1, h2 = esf(cloud, seed=7), esf(cloud, seed=7)
    assert h1.shape == (ESF_BINS,)
    assert h1.sum() == pytest.approx(1.0)
    np.testing.assert_array_equal(h1, h2)
    assert not np.array_equal(h1, esf(cloud, seed=8))


def test_esf_voxel_index_follows_pcl_convention():
    # floor(x)+32 below zero, ceil(x)+31 from zero up: (-1, 0) -> 31, 0 -> 31, (0, 1] -> 32.
    x = np.array([-32.0, -0.5, 0.0, 0.5, 1.0, 32.0])
    np.testing.assert_array_equal(esf_mod._voxel_index(x), [0, 31, 31, 32, 32, 63])


def test_esf_bins_round_as_pcl():
    # pcl_round is floor(x + 0.5) (half away from zero); the D2 ratio is float32 as in PCL.
    assert esf_mod._RATIO_BIN[10, 12] == 53  # 10/12·63 = 52.5 (half to even would give 52)
    assert esf_mod._RATIO_BIN[11, 18] == 39  # 38.5
    assert esf_mod._RATIO_BIN[9, 18] == 32  # 31.5
    assert esf_mod._RATIO_BIN[12, 12] == 63
    np.testing.assert_array_equal(esf_mod._pcl_round(np.array([0.49, 0.5, 1.5, 2.5, 62.5])), [0, 1, 2, 3, 63])


def test_esf_invariant_to_translation_and_rotation_and_separates_shapes():
    rng = np.random.default_rng(1)
    shapes = {"sphere": sphere(2000, rng), "cylinder": cylinder(2000, rng), "box": box(2000, rng)}
    desc = {k: esf(v, seed=0) for k, v in shapes.items()}
    between = min(chi2(desc[a], desc[b]) for a in desc for b in desc if a < b)

    for name, cloud in shapes.items():
        moved = cloud + np.array([5.0, -3.0, 12.0])
        # Same seed, same points: only floating-point differences in the centring.
        assert chi2(desc[name], esf(moved, seed=0)) < 1e-3 * between
        R = Rotation.from_euler("xyz", [0.4, -1.1, 2.0]).as_matrix()
        rotated = cloud @ R.T + np.array([1.0, 2.0, 3.0])
        # The grid is axis-aligned, so rotation invariance is statistical: as close as another
        # random draw of the triplets, and far below the distance between different shapes.
        within = chi2(desc[name], esf(cloud, seed=1))
        d_rot = chi2(desc[name], esf(rotated, seed=0))
        assert d_rot < 0.25 * between, (name, d_rot, between)
        assert d_rot < 4 * within + 1e-3, (name, d_rot, within)


def test_pair_features_do_not_depend_on_pair_order():
    rng = np.random.default_rng(2)
    p1, p2 = rng.normal(size=3), rng.normal(size=(50, 3))
    n1 = rng.normal(size=3)
    n1 /= np.linalg.norm(n1)
    n2 = rng.normal(size=(50, 3))
    n2 /= np.linalg.norm(n2, axis=1, keepdims=True)
    fwd = pair_features(p1, n1, p2, n2)
    for i in range(50):
        back = pair_features(p2[i], n2[i], p1[None], n1[None])
        for f, b in zip(fwd[:4], back[:4]):
            assert f[i] == pytest.approx(b[0], abs=1e-9)


def _half_cylinder_view(rng, n=2000):
    """The visible half of a pipe of radius 0.1 m seen from the origin at 1 m."""
    th = rng.uniform(-np.pi / 2, np.pi / 2, n)
    return np.c_[0.1 * np.sin(th), rng.uniform(-0.15, 0.15, n), 1.0 - 0.1 * np.cos(th)]


def test_vfh_shape_part_invariant_viewpoint_part_is_not():
    rng = np.random.default_rng(4)
    cloud = _half_cylinder_view(rng)
    normals, _ = normals_and_curvature(cloud, (0, 0, 0))
    h = vfh_from_normals(cloud, normals, (0, 0, 0))
    assert h.shape == (VFH_BINS,)
    assert h[:SHAPE_BINS].sum() == pytest.approx(400.0, rel=1e-3)
    assert h[SHAPE_BINS:].sum() == pytest.approx(100.0)

    # Rotate and translate the cloud (with its normals) in front of a fixed viewpoint.
    R = Rotation.from_euler("zyx", [0.3, 0.7, -0.2]).as_matrix()
    c = cloud.mean(axis=0)
    moved = (cloud - c) @ R.T + c + np.array([0.2, -0.1, 0.5])
    h_moved = vfh_from_normals(moved, normals @ R.T, (0, 0, 0))
    np.testing.assert_allclose(h_moved[:SHAPE_BINS], h[:SHAPE_BINS], atol=1e-6)
    assert np.abs(h_moved[SHAPE_BINS:] - h[SHAPE_BINS:]).sum() > 50.0  # of 200 possible

    # End to end (normals re-estimated): moving cloud and viewpoint together changes nothing.
    vp = np.array([0.2, -0.1, 0.5])
    h_all = vfh(cloud @ R.T + vp, viewpoint=vp)
    assert np.abs(h_all - vfh(cloud)).sum() < 1.0


def test_vfh_separates_shapes():
    rng = np.random.default_rng(5)
    vp = np.array([0.0, 0.0, -2.0])
    shapes = [sphere(2000, rng), cylinder(2000, rng), box(2000, rng)]
    visible = [s[s[:, 2] < np.median(s[:, 2])] for s in shapes]  # the half facing the viewpoint
    d = [vfh(v, viewpoint=vp)[:SHAPE_BINS] for v in visible]
    d_noise = [vfh(v + rng.normal(scale=0.001, size=v.shape), viewpoint=vp)[:SHAPE_BINS] for v in visible]
    within = max(chi2(a, b) for a, b in zip(d, d_noise))
    between = min(chi2(d[i], d[j]) for i in range(3) for j in range(i + 1, 3))
    assert between > 3 * within, (between, within)


def test_cvfh_one_descriptor_per_smooth_region():
    rng = np.random.default_rng(6)
    # A box corner seen diagonally: three planar faces, 1 m away, 5 mm spacing.
    g = np.arange(0.005, 0.3, 0.005)
    u, v = np.meshgrid(g, g)
    u, v = u.ravel(), v.ravel()
    faces = [np.c_[u, 0.5 * v, 0 * u], np.c_[u, 0 * u, v], np.c_[0 * u, 0.5 * u, v]]  # 30×15, 30×30, 15×30 cm
    corner = np.concatenate(faces) - 0.1
    vp = np.array([1.0, 1.0, 1.0])
    # min_points above the one-row strips that survive the curvature filter along the edges.
    cloud = corner + rng.normal(scale=0.0005, size=corner.shape)
    desc = cvfh(cloud, viewpoint=vp, min_points=100)
    assert desc.shape == (3, VFH_BINS)
    point_normals, centroids, normals = stable_regions(cloud, viewpoint=vp, min_points=100)
    # The regions are the three faces: normals along the axes, facing the viewpoint.
    assert np.all(np.abs(normals).max(axis=1) > 0.999)
    assert sorted(np.abs(normals).argmax(axis=1)) == [0, 1, 2]
    assert np.all(normals.sum(axis=1) > 0)
    # Each region's descriptor is the VFH of the whole cloud in that region's frame.
    for d, c, n in zip(desc, centroids, normals):
        np.testing.assert_allclose(d, vfh_from_normals(cloud, point_normals, vp, centroid=c, mean_normal=n))
    # A sphere has no stable planar region at this scale... but it is smooth: still ≥ 1 descriptor.
    assert cvfh(sphere(2000, rng), viewpoint=(0, 0, -1)).shape[1] == VFH_BINS
