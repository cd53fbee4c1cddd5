"""Sonar front-end: elevation maps (robust cells, empty cells) and the seabed level."""

import numpy as np
import pytest

from frontends.sonar.grid import ElevationMap, GridSpec, cell_medians, estimate_ground


def test_cell_median_and_quantile():
    keys = np.array([3, 3, 3, 3, 7, 7, 7])
    vals = np.array([4.0, 1.0, 3.0, 2.0, 10.0, 30.0, 20.0])
    k, med, cnt = cell_medians(keys, vals)
    assert k.tolist() == [3, 7] and cnt.tolist() == [4, 3]
    assert med.tolist() == [2.5, 20.0]
    _, q, _ = cell_medians(keys, vals, 0.0)
    assert q.tolist() == [1.0, 10.0]


def test_elevation_map_is_robust_to_outliers_and_keeps_empty_cells_empty():
    rng = np.random.default_rng(1)
    # a tilted seabed sampled densely over 1 × 1 m, except a hole
    n = 40000
    pts = np.column_stack([rng.uniform(0, 1, n), rng.uniform(0, 1, n)])
    hole = (np.abs(pts[:, 0] - 0.5) < 0.1) & (np.abs(pts[:, 1] - 0.5) < 0.1)
    pts = pts[~hole]
    depth = 20.0 + 0.1 * pts[:, 0] + rng.normal(0, 0.005, len(pts))
    # 5 % wild outliers (fish, multipath) one metre off
    out = rng.random(len(pts)) < 0.05
    depth[out] -= 1.0
    em = ElevationMap.from_points(np.column_stack([pts, depth]), cell=0.05)
    N, E = em.spec.centres()
    truth = 20.0 + 0.1 * N[:, None] + 0 * E[None, :]
    err = np.abs(em.depth - truth)[em.filled]
    assert np.percentile(err, 95) < 0.012  # the median per cell ignores the outliers
    # the hole's cells are empty (NaN, count 0), never interpolated
    i, j = em.spec.index(np.array([0.5]), np.array([0.5]))
    assert np.isnan(em.depth[i[0], j[0]]) and em.count[i[0], j[0]] == 0
    # a mean would have been dragged ~5 cm up by the outliers
    assert np.mean(em.depth[em.filled] - truth[em.filled]) > -0.01


def test_bilinear_sample_does_not_cross_holes():
    spec = GridSpec(0.0, 0.0, 1.0, (3, 3))
    D = np.arange(9, dtype=float).reshape(3, 3)
    D[2, 2] = np.nan
    em = ElevationMap(spec, D, np.ones((3, 3), int))
    assert em.sample(np.array([1.0]), np.array([1.0]))[0] == pytest.approx(2.0)  # between centres 0,1 / 3,4
    assert np.isnan(em.sample(np.array([2.0]), np.array([2.0]))[0])  # touches the empty cell


def test_ground_under_a_structure_is_the_surrounding_seabed():
    cell = 0.08
    spec = GridSpec(0.0, 0.0, cell, (200, 200))
    N, E = spec.centres()
    seabed = 20.0 + 0.03 * N[:, None] - 0.02 * E[None, :]
    D = seabed.copy()
    box = (np.abs(N[:, None] - 8) < 2.5) & (np.abs(E[None, :] - 8) < 1.5)
    D[box] -= 2.0  # a 5 × 3 m structure 2 m tall
    D[(np.abs(N[:, None] - 4) < 0.25) & (E[None, :] > 10)] -= 0.4  # a pipe
    g = estimate_ground(D, cell)
    assert np.nanmax(np.abs(g - seabed)) < 0.05
