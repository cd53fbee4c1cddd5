"""Sonar front-end: the circular ring × height-bin descriptor, its EMD, and the branch and bound."""

import numpy as np
import pytest
from scipy.stats import wasserstein_distance

from frontends.sonar.descriptor import (
    descriptor_cdf,
    emd_1d,
    exhaustive_scores,
    make_spec,
    model_height_map,
    model_template,
    ring_histograms,
    score,
    search,
)
from semslam.models.structures import pose_matrix, structure_library


def test_emd_closed_form_matches_scipy():
    rng = np.random.default_rng(3)
    centres = np.arange(13) * 0.25
    for _ in range(50):
        a = rng.random(13) * (rng.random(13) < 0.6)
        b = rng.random(13) * (rng.random(13) < 0.6)
        a[rng.integers(13)] += 0.1
        b[rng.integers(13)] += 0.1
        a, b = a / a.sum(), b / b.sum()
        ours = emd_1d(np.cumsum(a), np.cumsum(b), 0.25)
        ref = wasserstein_distance(centres, centres, a, b)
        assert ours == pytest.approx(ref, abs=1e-12)


@pytest.fixture(scope="module")
def templates():
    lib = structure_library()
    out = {}
    for name, m in lib.items():
        spec = make_spec(m.footprint_radius, 8, 0.08, -0.125, 3.125, 13)
        out[name] = model_template(name, m.mesh, spec)
    return out


def _descriptor_of(mesh, spec, T):
    h = model_height_map(mesh, spec.cell, spec.radius, T=T)
    k = h.shape[0] // 2
    hist, _ = ring_histograms(spec.bin_of(h), spec, (k, k))
    return descriptor_cdf(hist)


def test_descriptor_is_rotation_invariant_and_tells_models_apart(templates):
    lib = structure_library()
    for name, tpl in templates.items():
        spec = tpl.spec
        for yaw in (0.4, 1.3, 2.9):
            cdf = _descriptor_of(lib[name].mesh, spec, pose_matrix((0.01, -0.02, 0.0), yaw))
            assert score(cdf, tpl.cdf, spec.bin_width) / tpl.flat_score < 0.15, (name, yaw)
        for other in lib:
            if other == name:
                continue
            cdf = _descriptor_of(lib[other].mesh, spec, np.eye(4))
            assert score(cdf, tpl.cdf, spec.bin_width) / tpl.flat_score > 0.4, (name, other)


def test_branch_and_bound_finds_the_exhaustive_optimum(templates):
    """A small map: seabed noise, the PLET turned by 1 rad at a known cell and a low ridge. The
    pruned search must return exactly the exhaustive best (and nothing above the bound)."""
    tpl = templates["plet"]
    spec = tpl.spec
    rng = np.random.default_rng(0)
    H, W = 90, 110
    h = rng.normal(0, 0.02, (H, W))
    h[40:43, :] += 0.35  # a pipe-like ridge
    hm = model_height_map(structure_library()["plet"].mesh, spec.cell, spec.radius, T=pose_matrix((0, 0, 0), 1.0))
    k = hm.shape[0] // 2
    ci, cj = 60, 50
    h[ci - k : ci + k + 1, cj - k : cj + k + 1] = np.maximum(h[ci - k : ci + k + 1, cj - k : cj + k + 1], hm)
    h[rng.random((H, W)) < 0.1] = np.nan  # empty cells
    bins = spec.bin_of(h)
    ii, jj = np.mgrid[0:H, 0:W]
    cand = np.column_stack([ii.ravel(), jj.ravel()])
    full, cov = exhaustive_scores(bins, tpl, cand)
    full = np.where(cov >= 0.75, full, np.inf)
    j = int(np.argmin(full))
    res = search(bins, tpl, cand, bound=0.5 * tpl.flat_score, min_coverage=0.75)
    assert res.centre == (int(cand[j, 0]), int(cand[j, 1]))
    assert res.score == pytest.approx(full[j], rel=1e-9)
    assert abs(res.centre[0] - ci) <= 1 and abs(res.centre[1] - cj) <= 1
    # pruning did work: far fewer ring evaluations than candidates × rings
    assert res.evaluated_rings < 0.5 * len(cand) * spec.rings
    # a bound below the best score finds nothing
    assert search(bins, tpl, cand, bound=0.99 * full[j], min_coverage=0.75).centre is None
