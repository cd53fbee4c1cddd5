"""Cylinder RANSAC pipes: hypotheses, fit, covariance, detection on a ray-cast scene, merge."""

import numpy as np

from frontends.laser import LaserConfig, segment_scan
from frontends.laser.config import PipeConfig
from frontends.laser.evaluation import score_scan
from frontends.laser.pipes import _make_pipe, endpoint_covariance, fit_cylinder, hypotheses, merge_duplicates
from tests.support.synthetic import cached_scan, truth_of


def _cylinder(c, a, r, n, rng, length=1.0, noise=0.0):
    """Points and outward normals on the half of a cylinder facing −z (the sensor side)."""
    a = a / np.linalg.norm(a)
    e1 = np.cross(a, [0, 0, 1.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(a, e1)
    e2 = e2 if e2[2] < 0 else -e2  # towards the sensor
    th = rng.uniform(-1.3, 1.3, n)
    t = rng.uniform(0, length, n)
    nrm = np.outer(np.cos(th), e2) + np.outer(np.sin(th), e1)
    pts = c + np.outer(t, a) + r * nrm + rng.normal(0, noise, (n, 3))
    return pts, nrm


def test_hypothesis_from_two_points_is_exact():
    rng = np.random.default_rng(0)
    c, a, r = np.array([0.2, -0.1, 2.0]), np.array([1.0, 0.4, 0.1]), 0.05
    pts, nrm = _cylinder(c, a, r, 40, rng)
    cc, aa, rr, ok = hypotheses(pts[:20], nrm[:20], pts[20:], nrm[20:], PipeConfig())
    good = ok & (np.linalg.norm(np.cross(nrm[:20], nrm[20:]), axis=1) > 0.3)
    assert good.sum() >= 10
    au = a / np.linalg.norm(a)
    assert np.allclose(np.abs(aa[good] @ au), 1.0, atol=1e-9)
    assert np.allclose(rr[good], r, atol=1e-9)
    off = cc[good] - c
    assert np.allclose(np.linalg.norm(off - np.outer(off @ au, au), axis=1), 0.0, atol=1e-9)  # on the axis


def test_hypotheses_reject_radius_out_of_range_and_prior():
    rng = np.random.default_rng(1)
    pts, nrm = _cylinder(np.zeros(3), np.array([0, 1.0, 0]), 0.10, 40, rng)
    *_, ok = hypotheses(pts[:20], nrm[:20], pts[20:], nrm[20:], PipeConfig())
    assert not ok.any()  # 10 cm > the 6.4 cm maximum
    pts, nrm = _cylinder(np.zeros(3), np.array([0, 1.0, 0]), 0.03, 40, rng)
    *_, ok = hypotheses(pts[:20], nrm[:20], pts[20:], nrm[20:], PipeConfig(radius_prior=0.05))
    assert not ok.any()


def test_fit_cylinder_noisy():
    rng = np.random.default_rng(2)
    c, a, r = np.array([0.0, 0.0, 2.0]), np.array([1.0, 1.0, 0.0]), 0.045
    pts, nrm = _cylinder(c, a, r, 600, rng, length=0.8, noise=0.003)
    cc, aa, rr = fit_cylinder(pts, nrm, a, PipeConfig())
    au = a / np.linalg.norm(a)
    assert np.degrees(np.arccos(abs(aa @ au))) < 0.5
    assert abs(rr - r) < 0.003
    off = cc - c
    assert np.linalg.norm(off - (off @ au) * au) < 0.003
    # with the radius known, the centre still comes out right
    cc, aa, rr = fit_cylinder(pts, nrm, a, PipeConfig(radius_prior=r))
    off = cc - c
    assert rr == r and np.linalg.norm(off - (off @ au) * au) < 0.003


def test_endpoint_covariance_structure():
    cfg = PipeConfig()
    a = np.array([0.0, 1.0, 0.0])
    c1 = endpoint_covariance(np.zeros(3), a, a, 100, 2.0, cfg)
    c2 = endpoint_covariance(np.zeros(3), a, a, 400, 2.0, cfg)
    c3 = endpoint_covariance(np.zeros(3), a, a, 100, 4.0, cfg)
    for c in (c1, c2, c3):
        assert np.allclose(c, c.T) and np.linalg.eigvalsh(c).min() > 0
    lat = np.array([1.0, 0, 0])
    floor = cfg.axis_shift_sigma**2 + cfg.axis_tilt_sigma**2
    # across the axis: the fit's floor plus 4σ²/n of the point noise
    assert np.isclose(lat @ c1[:3, :3] @ lat - floor, 4 * (lat @ c2[:3, :3] @ lat - floor))
    assert lat @ c3[:3, :3] @ lat > lat @ c1[:3, :3] @ lat  # grows with range
    assert np.isclose(a @ c1[:3, :3] @ a, a @ c2[:3, :3] @ a)  # along: sampling, not count
    assert lat @ c1[:3, 3:] @ lat < 0  # the two ends of a fitted line swing oppositely
    # the floor alone: shift and tilt make the ends' offsets correlate (σs² − σt²) / (σs² + σt²)
    big = endpoint_covariance(np.zeros(3), a, a, 10**9, 2.0, cfg)
    expected = (cfg.axis_shift_sigma**2 - cfg.axis_tilt_sigma**2) / floor
    assert np.isclose((lat @ big[:3, 3:] @ lat) / (lat @ big[:3, :3] @ lat), expected, rtol=1e-4)


def test_pipes_found_on_ray_cast_scene():
    scan = cached_scan()
    seg = segment_scan(scan.points, LaserConfig())
    score = score_scan(scan.points, seg, truth_of(scan))
    assert score.n_visible_pipes == 6
    assert score.n_recalled_pipes == 6
    assert score.n_true_detections == score.n_detections == 6
    assert np.median(score.endpoint_errors) < 0.05 and max(score.endpoint_errors) < 0.10
    assert max(score.axis_errors_deg) < 2.0
    radii = sorted(p.radius for p in seg.pipes)
    assert abs(radii[0] - 0.04) < 0.008 and all(abs(r - 0.05) < 0.008 for r in radii[1:])


def test_duplicate_detections_merge():
    rng = np.random.default_rng(3)
    c, a = np.array([0.0, 0.0, 2.0]), np.array([1.0, 0.0, 0.0])
    pts, nrm = _cylinder(c, a, 0.05, 800, rng, length=1.0, noise=0.002)
    cfg = PipeConfig()
    t = pts[:, 0]
    allp, alln = np.vstack([pts, pts + [0, 0.5, 0]]), np.vstack([nrm, nrm])
    first = _make_pipe(allp, alln, np.flatnonzero(t < 0.6), a, cfg)
    second = _make_pipe(allp, alln, np.flatnonzero(t > 0.45), a, cfg)  # overlapping halves
    other = _make_pipe(allp, alln, np.arange(800, 1600), a, cfg)  # a parallel pipe 0.5 m away
    merged = merge_duplicates([first, second, other], allp, alln, cfg)
    assert len(merged) == 2
    whole = min(merged, key=lambda p: abs(p.p[1]) + abs(p.q[1]))
    assert whole.length > 0.97


def test_split_at_fittings_socket_and_body_but_not_occlusion():
    from frontends.laser.pipes import split_at_fittings

    cfg = PipeConfig()
    rng = np.random.default_rng(4)
    t = np.sort(rng.uniform(0, 1.2, 1200))
    residual = rng.normal(0, 0.003, len(t))
    socket = (t > 0.30) & (t < 0.39)
    residual[socket] += 0.007  # a socket, 7 mm wider than the pipe
    hidden = (t > 0.60) & (t < 0.75)  # a pipe in front hides 15 cm: a gap, not a fitting
    t, residual = t[~hidden], residual[~hidden]
    body = rng.uniform(0.95, 1.05, 40)  # a valve body around the axis at t = 1
    keep = ~((t > 0.95) & (t < 1.05))  # ... where the pipe itself is not seen
    t, residual = t[keep], residual[keep]
    runs = split_at_fittings(t, residual, body, cfg)
    spans = sorted((t[r].min(), t[r].max()) for r in runs if len(r) > 5)
    assert len(spans) == 3
    assert spans[0][1] < 0.31 and 0.38 < spans[1][0] < 0.42  # cut at the socket, its points dropped
    assert spans[1][1] > 0.9  # the occlusion gap is bridged
    assert spans[2][0] > 1.04


def test_lone_bin_does_not_cut_but_a_body_in_a_gap_does():
    from frontends.laser.pipes import split_at_fittings

    cfg = PipeConfig()
    rng = np.random.default_rng(5)
    t = np.sort(rng.uniform(0, 1.0, 1000))
    residual = rng.normal(0, 0.002, len(t))
    stray = np.full(8, 0.41)  # 8 points of something passing close by in one 2 cm bin
    runs = split_at_fittings(t, residual, stray, cfg)
    assert len(runs) == 1 and len(runs[0]) == len(t)
    # a 12 cm gap: bridged when empty (occlusion), cut when a body fills it (faces not cylinder inliers)
    keep = (t < 0.5) | (t > 0.62)
    around = rng.uniform(0.5, 0.62, 30)
    assert len(split_at_fittings(t[keep], residual[keep], np.zeros(0), cfg)) == 1
    assert len(split_at_fittings(t[keep], residual[keep], np.zeros(0), cfg, around)) == 2


def test_a_fitting_found_as_a_short_pipe_is_not_merged_across():
    """A socket (6 mm wider than its pipe) found as a segment of its own between the two pipes it
    joins: merging must not bridge it (the union is cut again at its bump)."""
    rng = np.random.default_rng(5)
    a = np.array([1.0, 0.0, 0.0])
    parts = [
        _cylinder(np.array([-0.5, 0.0, 2.0]), a, 0.0315, 500, rng, length=0.45, noise=0.001),
        _cylinder(np.array([-0.05, 0.0, 2.0]), a, 0.0375, 120, rng, length=0.10, noise=0.001),
        _cylinder(np.array([0.05, 0.0, 2.0]), a, 0.0315, 500, rng, length=0.45, noise=0.001),
    ]
    pts, nrm = np.vstack([p for p, _ in parts]), np.vstack([n for _, n in parts])
    cfg = PipeConfig(radius_prior=0.0315)
    left = _make_pipe(pts, nrm, np.arange(0, 500), a, cfg)
    socket = _make_pipe(pts, nrm, np.arange(500, 620), a, cfg)
    right = _make_pipe(pts, nrm, np.arange(620, 1120), a, cfg)
    merged = merge_duplicates([left, socket, right], pts, nrm, cfg)
    extents = sorted(sorted((p.p[0], p.q[0])) for p in merged)
    assert len(merged) == 2
    assert extents[0][1] < -0.02 and extents[1][0] > 0.02  # nothing runs through the socket


def test_a_strip_as_wide_as_the_pipe_is_not_a_pipe():
    """A valve lever (a 32 mm strip) on its gear head fits the visible half of a 31.5 mm pipe; the
    rays through the rest of that cylinder reach the body behind it, so it is no pipe."""
    from tests.support.synthetic import SynthObject, SynthPipe, SynthScene, raycast

    fz = 2.0
    scene = SynthScene(
        floor_z=fz,
        wall_x=None,
        pipes=[SynthPipe((-0.6, 0.3, fz - 0.1), (0.4, 0.3, fz - 0.1), radius=0.0315)],
        objects=[
            SynthObject((0.0, -0.2, fz - 0.1), (0.12, 0.17, 0.17)),  # valve body
            SynthObject((0.0, -0.2, fz - 0.29), (0.07, 0.07, 0.025)),  # gear head
            SynthObject((0.0, -0.17, fz - 0.305), (0.032, 0.23, 0.006)),  # lever across the pipe
        ],
    )
    scan = raycast(scene, seed=1)

    def lever_pipes(**over):
        cfg = LaserConfig.model_validate({"pipes": {"radius_prior": 0.0315, **over}})
        seg = segment_scan(scan.points, cfg)
        assert any(abs(p.p[1] - 0.3) < 0.02 and p.length > 0.9 for p in seg.pipes)  # the real pipe
        return [p for p in seg.pipes if abs(0.5 * (p.p[1] + p.q[1]) - 0.3) > 0.1]

    assert lever_pipes(max_see_through=1.0)  # the strip fits a cylinder ...
    assert not lever_pipes()  # ... but the sensor sees through it


def test_in_long_runs_keeps_only_runs_of_the_length_needed():
    from frontends.laser.pipes import _in_long_runs

    flag = np.array([1, 0, 1, 1, 0, 1, 1, 1, 0, 1], bool)
    assert _in_long_runs(flag, 2).tolist() == [0, 0, 1, 1, 0, 1, 1, 1, 0, 0]
    assert _in_long_runs(flag, 3).tolist() == [0, 0, 0, 0, 0, 1, 1, 1, 0, 0]
    assert _in_long_runs(flag, 1).tolist() == flag.tolist()
    assert not _in_long_runs(flag[:2], 3).any()  # shorter than a run can be


def test_bin_medians_match_numpy_per_bin():
    from frontends.laser.pipes import _bin_medians

    rng = np.random.default_rng(3)
    b = np.sort(rng.integers(0, 12, 200))
    b[0], b[-1] = 0, 14  # bins 12 and 13 empty, as may be any bin but the first and the last
    res = rng.normal(size=200)
    cnt, med = _bin_medians(b, res, 15)
    assert cnt.tolist() == np.bincount(b, minlength=15).tolist()
    for k in range(15):
        if cnt[k]:
            assert med[k] == np.median(res[b == k])
        else:
            assert np.isnan(med[k])


def test_eigh_is_numpys_eigh_bit_for_bit():
    from frontends.laser.pipes import _eigh

    rng = np.random.default_rng(4)
    for _ in range(50):
        X = rng.normal(size=(30, 3))
        w, v = _eigh(X.T @ X)
        W, V = np.linalg.eigh(X.T @ X)
        assert np.array_equal(w, W) and np.array_equal(v, V)


def test_near_axis_test_matches_the_test_of_every_point():
    """``_Points.test_near`` finds the points within ``r + reach`` of the axis, and their inliers,
    exactly as the distances of every point would (it takes square roots near the axis only), also
    for points within a few rounding steps of the limit."""
    from frontends.laser.pipes import _Points

    rng = np.random.default_rng(7)
    cfg = PipeConfig(radius_prior=None)
    c, a, r, reach = np.array([0.3, -0.2, 2.0]), np.array([0.6, 0.0, 0.8]), 0.0315, 0.03
    e1 = np.cross(a, [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(a, e1)
    phi = rng.uniform(0, 2 * np.pi, 6000)
    lim = r + reach
    rho = np.concatenate(
        [rng.uniform(0, 3 * lim, 2000), lim * (1 + rng.integers(-6, 7, 2000) * 2.0**-52), rng.normal(r, 0.004, 2000)]
    )
    radial = np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2
    pts = c + rng.uniform(-1, 1, 6000)[:, None] * a + rho[:, None] * radial
    normals = radial + rng.normal(0, 0.1, (6000, 3))
    normals /= np.linalg.norm(normals, axis=1)[:, None]
    P = _Points(pts, normals, np.arange(6000))
    along, dist = P._along_dist(c, a)
    ref = np.flatnonzero(dist <= lim)
    near, inl = P.test_near(c, a, r, cfg, reach)
    assert np.array_equal(near, ref)
    assert np.array_equal(inl, P.test(c, a, r, cfg)[ref])
    assert 0 < inl.sum() < len(ref) and len(ref) < 6000


def _count_one_by_one(rays, sel, c, a, r, t0, t1, cfg, deep=None):
    """The see-through count of one cylinder as written before the rays of several were taken
    together (a reference for ``Rays._counts``)."""
    d, rng = rays.directions.take(sel, axis=0).astype(np.float64), rays.ranges[sel]
    da = d @ a
    w = d - da[:, None] * a
    cp = c - (c @ a) * a
    A = np.maximum((w * w).sum(axis=1), 1e-12)
    B = -2.0 * (w @ cp)
    disc = B * B - 4.0 * A * (cp @ cp - r * r)
    hit = disc > 0
    A, B, disc, da, rng = A[hit], B[hit], disc[hit], da[hit], rng[hit]
    root = np.sqrt(np.maximum(disc, 0.0))
    s1, s2 = (-B - root) / (2 * A), (-B + root) / (2 * A)
    t_mid = 0.5 * (s1 + s2) * da - c @ a
    crossing = (s1 > 0) & (s2 - s1 >= cfg.see_through_chord) & (t_mid > t0 + 0.01) & (t_mid < t1 - 0.01)
    behind = crossing & (rng > (s2 + cfg.see_through_margin if deep is None else s1 + deep))
    return int(behind.sum()), int(crossing.sum())


def test_see_through_counts_of_several_cylinders_are_those_one_by_one():
    from frontends.laser.pipes import Rays

    rng = np.random.default_rng(11)
    cfg = PipeConfig()
    # a floor 1.5 m below the sensor with pipes on it, and rays ending on, behind and short of them
    floor = np.column_stack([rng.uniform(-1, 1, 30000), rng.uniform(-1, 1, 30000), np.full(30000, 1.5)])
    rays = Rays(floor * rng.uniform(0.9, 1.0, (30000, 1)))
    cylinders, sels = [], []
    for k in range(12):
        a = rng.normal(size=3) * [1.0, 1.0, 0.1]
        a /= np.linalg.norm(a)
        c = np.array([rng.uniform(-0.6, 0.6), rng.uniform(-0.6, 0.6), rng.uniform(1.3, 1.5)])
        t0, t1 = 0.0, float(rng.uniform(0.05, 0.6))
        (sel,) = rays._cones((c + a * 0.5 * (t0 + t1))[None], np.array([np.hypot(0.5 * (t1 - t0), 0.03)]))
        cylinders.append((c, a, 0.03, t0, t1))
        sels.append(sel[:1] if k == 5 else sel[:0] if k == 7 else sel)  # a cone of one ray, one of none
    for deep in (None, [0.015] * 12):
        behind, crossing = rays._counts(sels, cylinders, cfg, deep)
        for k, (sel, cyl) in enumerate(zip(sels, cylinders)):
            want = _count_one_by_one(rays, sel, *cyl, cfg, None if deep is None else deep[k])
            assert (int(behind[k]), int(crossing[k])) == want
    assert (crossing > 0).sum() >= 6  # the cylinders are crossed: the counts are not all zeros
