"""Laser pre-processing and local geometry: voxel grid, outliers, normals, curvature, 3×3 eigen."""

import numpy as np

from frontends.laser.config import LaserConfig
from frontends.laser.grid import VoxelGrid, adjacency_of, offsets
from frontends.laser.preprocess import (
    eigen3,
    hop_covariances,
    knn_search,
    local_geometry,
    preprocess,
    shape_of,
    small_clusters,
    smallest_eigen,
    voxel_downsample,
)


def test_smallest_eigen_matches_lapack():
    rng = np.random.default_rng(0)
    X = rng.normal(size=(500, 3, 3))
    C = X @ X.transpose(0, 2, 1) * rng.uniform(1e-6, 1.0, (500, 1, 1))
    # nearly planar covariances, the case that matters for normals
    Q = np.linalg.qr(rng.normal(size=(200, 3, 3)))[0]
    ev = np.column_stack([rng.uniform(1e-8, 1e-6, 200), rng.uniform(1e-3, 1e-2, (200, 2))])
    C[:200] = np.einsum("nij,nj,nkj->nik", Q, ev, Q)
    lam, v = smallest_eigen(C)
    w, V = np.linalg.eigh(C)
    l0, l1, l2, _ = eigen3(C)
    assert np.allclose(np.column_stack([l0, l1, l2]), w, atol=1e-10 * w[:, 2].max(), rtol=1e-6)
    assert np.allclose(lam, w[:, 0], atol=1e-12 * w[:, 2].max(), rtol=1e-6)
    assert np.allclose(np.abs(np.einsum("ij,ij->i", v, V[:, :, 0])), 1.0, atol=1e-6)


def test_voxel_downsample_centroids_and_inverse():
    rng = np.random.default_rng(1)
    pts = rng.uniform(0, 1, (5000, 3))
    cent, inv = voxel_downsample(pts, 0.25)
    assert len(cent) == 64  # 4×4×4 voxels all occupied
    for v in (0, 17, 63):
        assert np.allclose(cent[v], pts[inv == v].mean(axis=0))
    assert np.all(np.floor(pts / 0.25) == np.floor(cent[inv] / 0.25))


def test_grid_neighbours_match_brute_force():
    rng = np.random.default_rng(2)
    # a sparse cloud spanning several 8³-cell blocks, with negative coordinates
    pts = rng.uniform(-0.7, 0.5, (4000, 3)) * [1.0, 1.0, 0.3]
    g = VoxelGrid(pts, 0.05)
    keys = {tuple(k): i for i, k in enumerate(np.floor(g.points / 0.05).astype(int))}
    assert len(keys) == len(g)
    cells = np.array(list(keys))
    for h in (1, 2):
        nb = g.neighbours(h)
        assert nb.shape == (len(g), (2 * h + 1) ** 3) and np.all(nb[:, 0] == np.arange(len(g)))
        for i in rng.choice(len(g), 50, replace=False):
            expected = [keys.get(tuple(cells[i] + o), -1) for o in offsets(h)]
            assert nb[i].tolist() == expected
    cols = rng.integers(0, 125, (len(g), 4))
    assert np.array_equal(g.neighbours(2, columns=cols), np.take_along_axis(g.neighbours(2), cols, axis=1))


def test_small_clusters_are_stray_returns():
    rng = np.random.default_rng(2)
    plane = np.column_stack([rng.uniform(0, 1, (3000, 2)), np.zeros(3000)])
    stem = np.column_stack([np.full(40, 0.5), np.full(40, 0.5), np.linspace(0.02, 0.3, 40)])  # a thin part
    far = rng.uniform(3, 4, (10, 3))  # isolated returns
    g = VoxelGrid(np.vstack([plane, stem, far]), 0.03)
    stray = small_clusters(adjacency_of(g.neighbours(1)), 4)
    assert stray[g.inverse[-10:]].all()
    assert not stray[g.inverse[:-10]].any()


def test_normals_and_curvature_plane_vs_pipe():
    rng = np.random.default_rng(3)
    plane = np.column_stack([rng.uniform(-1, 1, (8000, 2)), 2.0 + rng.normal(0, 0.002, 8000)])
    knn, _ = knn_search(plane, 50)
    n, k = local_geometry(plane, knn)
    assert np.median(n[:, 2]) < -0.999  # facing the sensor at the origin
    assert np.percentile(k, 95) < 0.025
    # at the density of a 2 cm voxel grid (what the front-end sees)
    th, z = np.meshgrid(np.arange(0, np.pi, 0.02 / 0.05), np.arange(0, 1.0, 0.02))
    pipe = np.column_stack([z.ravel(), 0.05 * np.cos(th.ravel()), 2.0 - 0.05 * np.sin(th.ravel())])
    knn, _ = knn_search(pipe, 50)
    n, k = local_geometry(pipe, knn)
    # a 50-point neighbourhood on a 5 cm pipe is strongly curved: above the flat threshold
    assert np.median(k) > 0.025
    knn, _ = knn_search(pipe, 10)
    n, _ = local_geometry(pipe, knn)
    # the same from the voxel grid: a 3-step neighbourhood (~50 voxels of a plane) and one step
    g = VoxelGrid(plane, 0.03)
    A = adjacency_of(g.neighbours(1))
    ng, kg, _ = shape_of(hop_covariances(g.points, A, 3), g.points)
    inner_plane = np.all(np.abs(g.points[:, :2]) < 0.85, axis=1)
    assert np.median(ng[inner_plane, 2]) < -0.999 and np.percentile(kg[inner_plane], 95) < 0.025
    g = VoxelGrid(pipe, 0.02)
    _, kg, _ = shape_of(hop_covariances(g.points, adjacency_of(g.neighbours(1)), 3), g.points)
    assert np.median(kg) > 0.025
    radial = pipe - np.column_stack([pipe[:, 0], np.zeros(len(pipe)), np.full(len(pipe), 2.0)])
    radial /= np.linalg.norm(radial, axis=1, keepdims=True)
    inner = np.abs(pipe[:, 0] - 0.5) < 0.45  # away from the cut ends
    assert np.median(np.einsum("ij,ij->i", n, radial)[inner]) > 0.98  # small neighbourhoods: radial normals


def test_preprocess_crops_and_maps_raw_points():
    rng = np.random.default_rng(4)
    cfg = LaserConfig.model_validate({"preprocess": {"max_range": 3.0, "voxel_size": 0.05}})
    near = np.column_stack([rng.uniform(-1, 1, (20000, 2)), np.full(20000, 2.0)])
    far = np.array([[0, 0, 5.0], [0, 0, 0.1]])
    pre = preprocess(np.vstack([near, far]), cfg.preprocess, cfg.planes)
    assert np.all(pre.raw_to_voxel[-2:] == -1)  # cropped by range
    mapped = pre.raw_to_voxel[:-2]
    ok = mapped >= 0
    np.all(np.abs(near[:, :2]) < 0.9, axis=1)
    assert ok.all()  # one connected patch: no stray returns
    assert np.all(np.linalg.norm(pre.points[mapped[ok]] - near[ok], axis=1) <= 0.05 * np.sqrt(3))
    assert np.all(pre.neighbours[:, 0] == np.arange(len(pre.points)))


def test_single_threaded_blas_restores_the_thread_count():
    import threadpoolctl  # a dependency: never skipped

    from frontends.laser.grid import single_threaded_blas

    def blas_threads():
        return [p["num_threads"] for p in threadpoolctl.threadpool_info() if p["user_api"] == "blas"]

    before = blas_threads()
    inside = single_threaded_blas(blas_threads)()
    assert inside and all(n == 1 for n in inside)
    assert blas_threads() == before


def test_row_dot_is_the_row_sum_to_the_last_bit():
    from frontends.laser.grid import row_dot

    rng = np.random.default_rng(5)
    a, b = rng.normal(size=(1000, 3)) * 1e3, rng.normal(size=(1000, 3))
    assert np.array_equal(row_dot(a, b), (a * b).sum(axis=1))


def test_split_sorted_is_np_split():
    from frontends.laser.grid import split_sorted

    x = np.arange(10) * 3
    for cuts in ([], [0], [4], [1, 2, 9], [0, 10], [3, 3, 7]):
        got, want = split_sorted(x, np.array(cuts, np.int64)), np.split(x, cuts)
        assert len(got) == len(want) and all(np.array_equal(g, w) for g, w in zip(got, want))


def test_norms2_is_np_linalg_norm_to_the_last_bit():
    from frontends.laser.pipes import _norms2

    v = np.random.default_rng(6).normal(size=(1000, 2)) * 1e2
    assert np.array_equal(_norms2(v), np.linalg.norm(v, axis=1))
    assert np.array_equal(_norms2(v), np.sqrt((v * v).sum(axis=1)))


def test_least_float32_not_below_compares_like_float64():
    from frontends.laser.pipes import least_float32_not_below

    rng = np.random.default_rng(7)
    x = rng.uniform(0.0, 1.0, 200)
    x[:3] = (0.5, 1.0, 0.0)  # exactly float32 values: their own bound
    lim = least_float32_not_below(x)
    assert lim.dtype == np.float32
    # float32 values at, just below and just above every bound and every x's nearest float32
    near = x.astype(np.float32)
    v = np.concatenate([lim, np.nextafter(lim, np.float32(0)), np.nextafter(lim, np.float32(2)), near])
    for xi, li in zip(x, lim):
        assert np.array_equal(v >= li, v.astype(np.float64) >= xi)


def test_eigen3_parts_equals_eigen3_on_the_assembled_matrices():
    from frontends.laser.eigen import eigen3_parts

    rng = np.random.default_rng(6)
    X = rng.normal(size=(2000, 3, 4))
    C = X @ X.transpose(0, 2, 1)
    C[:5] = 0.0  # degenerate: no preferred normal
    parts = np.stack([C[:, 0, 0], C[:, 0, 1], C[:, 0, 2], C[:, 1, 1], C[:, 1, 2], C[:, 2, 2]])
    for got, want in zip(eigen3_parts(parts), eigen3(C)):
        assert np.array_equal(got, want)


def test_stable_order_is_numpys_stable_argsort():
    from frontends.laser.grid import stable_order

    rng = np.random.default_rng(8)
    cases = [
        rng.integers(0, 50, 5000),  # one 16-bit digit, many ties
        rng.integers(0, 1 << 25, 20000),  # two digits, as a scan's voxel keys
        rng.integers(0, 1 << 40, 3000) // 7 * 7,  # three digits, ties
        np.repeat(rng.integers(0, 1 << 33, 40), 30),  # runs of equal keys (cells come in runs)
        rng.integers(0, 1 << 20, 1000).astype(np.uint32),
        np.array([(1 << 48) + 1, 1 << 48, 5, 0, 1 << 48]),
        np.zeros(0, np.int64),
        np.array([3, -1, 2, -1]),  # negative: numpy's own sort
    ]
    for keys in cases:
        assert np.array_equal(stable_order(keys), np.argsort(keys, kind="stable"))


def test_stable_order_float_is_numpys_stable_argsort():
    from frontends.laser.grid import stable_order_float

    rng = np.random.default_rng(9)
    x = rng.normal(size=4000) * 10.0 ** rng.integers(-300, 300, 4000)
    x[::7] = np.round(x[::7], 1) * 0.0 + rng.integers(-3, 3, len(x[::7]))  # ties
    x[::11] = -0.0  # equal to 0.0 for a comparison sort: the order of the two is kept
    x[5::13] = 0.0
    x[::17] = np.array([5e-324, -5e-324, np.inf, -np.inf])[rng.integers(0, 4, len(x[::17]))]
    heights = np.round(rng.normal(size=3000) * 0.3, 3)  # heights in mm: many ties
    for v in (x, heights, np.zeros(0), np.array([np.nan, 1.0, np.nan, -2.0])):
        assert np.array_equal(stable_order_float(v), np.argsort(v, kind="stable"))


def test_raw_index_built_on_first_use_finds_the_raw_points_of_voxels():
    from frontends.laser.frontend import RawIndex

    rng = np.random.default_rng(10)
    raw_to_structure = rng.integers(-1, 300, 5000)
    index = RawIndex(raw_to_structure, 300)
    assert index._built is None  # nothing sorted until asked (a scan without colour never asks)
    for voxels in (np.array([3]), rng.integers(0, 300, 40), np.array([299, 0, 299])):
        assert np.array_equal(index(voxels), np.flatnonzero(np.isin(raw_to_structure, voxels)))
    assert index._built is not None
