"""What was seen of a pipe (semslam.mapping.extent, both estimators' rule): robust ends from many noisy,
partly clipped views, cuts at in-line objects, gaps and separation by an in-line object."""

import numpy as np
import pytest

from semslam.mapping.extent import PipeExtent
from semslam.mapping.fittings import port_depths
from semslam.mapping.pipes import object_between, robust_ends
from semslam.models import cad


def test_ends_of_many_noisy_views_are_not_biased_outwards():
    rng = np.random.default_rng(3)
    sigma, n = 0.05, 300  # the oracle's along-axis endpoint noise; a pipe seen all mission long
    lo = rng.normal(0.0, sigma, n)
    hi = rng.normal(0.4, sigma, n)
    clipped = rng.random(n) < 0.3  # views clipped by the field of view end further in
    hi[clipped] -= rng.uniform(0.05, 0.3, clipped.sum())
    a, b = robust_ends(lo, hi, 6 * sigma)
    assert abs(a) < 0.015 and abs(b - 0.4) < 0.015
    # the extreme views alone would be about 3σ out at each end
    assert lo.min() < -0.1 and hi.max() > 0.5


def test_a_few_views_give_their_median_ends():
    a, b = robust_ends(np.array([0.01, -0.01, 0.0]), np.array([0.39, 0.41, 0.4]), 0.06)
    assert (a, b) == (0.0, 0.4)


def _views(ranges, sigma=0.01, y=0.0, z=0.0):
    """A PipeExtent of views along the x axis (world ends), each (lo, hi) in x."""
    ext = PipeExtent()
    for lo, hi in ranges:
        ext.add(np.array([[lo, y, z], [hi, y, z]]), sigma)
    return ext


def test_association_extent_stays_short_of_the_next_valve():
    # pipe 18 of the tank: 0.40 m long, a 3-way valve 0.12 m beyond its end, then pipe 16
    rng = np.random.default_rng(5)
    ext = _views([(rng.normal(0.0, 0.05), rng.normal(0.40, 0.05)) for _ in range(220)], sigma=0.05)
    c, d = np.zeros(3), np.array([1.0, 0.0, 0.0])
    valve = np.array([[0.52, 0.0, 0.0]])
    next_pipe = np.array([[0.53, 0.0, 0.0], [1.05, 0.0, 0.0]])  # a view of pipe 16 (from 0.64), its near end 2σ long
    # every view's extreme reaches into the valve and the next pipe's view overlaps it: only the margin
    # around the facing ends (fits run a few cm into a socket) still finds the valve between them
    assert ext.outer(c, d)[1] > 0.52
    assert object_between(ext.outer(c, d), next_pipe, c, d, valve, 0.15)
    assert not object_between(ext.outer(c, d), next_pipe, c, d, valve, 0.15, margin=0.0)
    lo, hi = ext.interval(c, d)
    assert abs(hi - 0.40) < 0.02
    assert object_between((lo, hi), next_pipe, c, d, valve, 0.15)
    assert ext.excludes(next_pipe, c, d, valve, np.zeros((0, 3)), 0.15, 0.3)
    assert not ext.excludes(next_pipe, c, d, np.zeros((0, 3)), np.zeros((0, 3)), 0.15, 0.3)


def test_a_pipe_seen_through_a_mapped_tee_is_cut_at_it_on_the_side_of_its_views():
    # a landmark started by laser fits through an in-line tee at x = 0.5: most views then see the
    # part before it, a few the whole 1 m
    ext = _views([(0.0, 0.45)] * 30 + [(0.0, 1.0)] * 5, y=1.0, z=4.0)
    c, d = np.array([0.0, 1.0, 4.0]), np.array([1.0, 0.0, 0.0])
    tee = np.array([0.5, 1.02, 4.0])  # 2 cm off the axis, as estimated
    elbow = np.array([1.05, 1.0, 4.0])  # at the end: not inside
    assert ext.interval(c, d, np.zeros((0, 3)), 0.15) == ext.interval(c, d)
    lo, hi = ext.interval(c, d, np.array([tee, elbow]), 0.15)
    assert lo == pytest.approx(ext.interval(c, d)[0]) and hi == pytest.approx(0.5, abs=1e-9)
    np.testing.assert_allclose(ext.ends(c, d, np.array([tee]), 0.15), [[0.0, 1.0, 4.0], [0.5, 1.0, 4.0]], atol=1e-9)
    # the views mostly beyond the tee keep that side instead
    other = _views([(0.55, 1.0)] * 30 + [(0.0, 1.0)] * 5, y=1.0, z=4.0)
    lo, hi = other.interval(c, d, np.array([tee]), 0.15)
    assert lo == pytest.approx(0.5, abs=1e-9) and hi == pytest.approx(1.0, abs=1e-9)


def test_a_pipe_running_into_a_classified_fitting_ends_at_its_port_mouth():
    # the tank's pipes end at their fittings' socket mouths; the laser's segments run on into the
    # socket (the pipe's shape) up to the fitting's centre, here an elbow at x = 0.6
    elbow_depth = port_depths([{"Elbow": 1.0}])[0]
    assert elbow_depth == pytest.approx(np.linalg.norm(cad.builtin("Elbow").ports[0][0]))
    ext = _views([(0.0, 0.6)] * 40 + [(0.0, 0.55)] * 10, y=1.0, z=4.0)
    c, d = np.array([0.0, 1.0, 4.0]), np.array([1.0, 0.0, 0.0])
    elbow = np.array([[0.6, 1.01, 4.0]])
    assert ext.interval(c, d, elbow, 0.15) == ext.interval(c, d)  # at the end, centre cut: nothing
    lo, hi = ext.interval(c, d, elbow, 0.15, np.array([elbow_depth]))
    assert hi == pytest.approx(0.6 - elbow_depth, abs=1e-9) and lo == pytest.approx(0.0, abs=1e-9)
    # an object whose class is unknown has no depth: the centre rule as before
    assert port_depths([None])[0] == 0.0
    assert ext.interval(c, d, elbow, 0.15, port_depths([None])) == ext.interval(c, d)
    # a fitting whose mouth lies beyond what was seen does not lengthen the pipe
    far = np.array([[0.75, 1.0, 4.0]])
    assert ext.interval(c, d, far, 0.15, np.array([elbow_depth])) == ext.interval(c, d)


def test_port_depth_follows_the_class_posterior():
    both = port_depths([{"Elbow": 0.5, "Ball-Valve": 0.5}, {"Ball-Valve": 1.0}, {}])
    elbow, valve = (np.linalg.norm(cad.builtin(c).ports[0][0]) for c in ("Elbow", "Ball-Valve"))
    np.testing.assert_allclose(both, [0.5 * (elbow + valve), valve, 0.0])


def _seg(a, b, rng=None, sigma=0.0):
    e = np.array([[a, 2.0, 4.0], [b, 2.0, 4.0]])
    if rng is not None:
        e[:, 0] += rng.normal(scale=sigma, size=2)
        e[:, 1:] += rng.normal(scale=0.02, size=(2, 2))  # off-line noise: re-projection removes it
    return e


C, D = np.array([0.0, 2.0, 4.0]), np.array([1.0, 0.0, 0.0])  # the line y = 2, z = 4 along x


def test_robust_ends_are_not_biased_outwards_by_noise():
    rng = np.random.default_rng(0)
    ext = PipeExtent()
    for _ in range(200):  # views that all reach the true ends 0 and 3, noisy along the axis
        ext.add(_seg(0.0, 3.0, rng, 0.05), 0.05)
    lo, hi = ext.interval(C, D)
    assert abs(lo) < 0.03 and abs(hi - 3.0) < 0.03  # the extremes alone would be ~±0.14 out
    p, q = ext.ends(C, D)
    np.testing.assert_allclose(p[1:], [2.0, 4.0], atol=1e-12)  # on the line
    # the positions are along d from the point given: another point on the line gives the same ends
    np.testing.assert_allclose(ext.ends(C + 5 * D, D), ext.ends(C, D), atol=1e-12)


def test_gap_and_separation_by_an_in_line_object():
    ext = PipeExtent()
    ext.add(_seg(0.0, 2.0), 0.05)
    none = np.zeros((0, 3))
    assert ext.seen_span(C, D, none, none, 0.15) == ext.interval(C, D)
    assert not ext.excludes(_seg(1.0, 2.5), C, D, none, none, 0.15, 0.0)  # overlapping: no gap
    assert ext.excludes(_seg(2.4, 3.5), C, D, none, none, 0.15, 0.39)  # 0.4 m beyond the seen end
    assert not ext.excludes(_seg(2.4, 3.5), C, D, none, none, 0.15, 0.41)
    valve = np.array([[2.2, 2.0, 4.0]])
    off_line = np.array([[2.2, 2.5, 4.0]])
    assert ext.excludes(_seg(2.3, 3.5), C, D, valve, none, 0.15, 1.0)  # pipe B beyond the valve
    assert not ext.excludes(_seg(2.3, 3.5), C, D, off_line, none, 0.15, 1.0)
    assert not ext.excludes(_seg(0.5, 1.8), C, D, valve, none, 0.15, 1.0)  # a view inside pipe A
    elbow_at_end = np.array([[2.08, 2.0, 4.0]])
    assert not ext.excludes(_seg(1.0, 1.9), C, D, elbow_at_end, none, 0.15, 1.0)


def test_pipe_extent_gap_and_inline_object_radius_are_the_shared_association_settings(tmp_path):
    """Both estimators pair a pipe view with a pipe by one rule, with the gap beyond its seen extent
    and the radius of an in-line object from ``association``; the ``ekf`` section has neither."""
    from semslam.config import SemslamConfig, load_config
    from semslam.errors import ConfigError

    ext = PipeExtent()
    ext.add(np.array([[0.0, 2.0, 4.0], [2.0, 2.0, 4.0]]), 0.01)
    beyond = np.array([[2.4, 2.0, 4.0], [3.0, 2.0, 4.0]])  # 0.4 m beyond what was seen
    valve = np.array([[2.2, 2.1, 4.0]])  # 0.1 m off the axis, in between
    none = np.zeros((0, 3))
    for gap, radius, apart, apart_valve in (
        (0.5, 0.05, False, False),
        (0.3, 0.05, True, True),
        (0.5, 0.15, False, True),
    ):
        a = SemslamConfig(association={"pipe_extent_gap_m": gap, "inline_object_radius_m": radius}).association
        assert ext.excludes(beyond, C, D, none, none, a.inline_object_radius_m, a.pipe_extent_gap_m) == apart
        assert ext.excludes(beyond, C, D, valve, none, a.inline_object_radius_m, a.pipe_extent_gap_m) == apart_valve
    for key in ("pipe_extent_gap_m", "pipe_object_radius_m"):
        f = tmp_path / "old.yaml"
        f.write_text(f"ekf:\n  {key}: 0.5\n")
        with pytest.raises(ConfigError, match=rf"ekf\.{key}"):
            load_config(f)


def test_what_is_kept_between_queries_follows_new_views_lines_and_cutting_objects():
    """An extent keeps what it computed for a line and a set of cutting objects: asked again along
    another line, with other objects, or after a new view, it answers as a fresh extent would."""
    ranges = [(-1.0, 1.0)] * 5
    ext = _views(ranges)
    c, d = np.zeros(3), np.array([1.0, 0.0, 0.0])
    tee = np.array([[0.5, 0.0, 0.0]])  # on the line: cuts the pipe's far end
    aside = np.array([[0.5, 1.0, 0.0]])  # a metre off the line: cuts nothing
    assert ext.interval(c, d, tee, 0.15) == pytest.approx((-1.0, 0.5))
    assert ext.interval(c, d, aside, 0.15) == pytest.approx((-1.0, 1.0))
    assert ext.interval(c, d) == pytest.approx((-1.0, 1.0))
    assert ext.interval(c, d, tee, 0.15) == pytest.approx((-1.0, 0.5))
    shifted = np.array([0.3, 0.0, 0.0])  # the same line, measured from another point
    assert ext.interval(shifted, d) == pytest.approx((-1.3, 0.7))
    before = ext.centre().copy()
    for _ in range(5):  # the pipe seen further now
        ext.add(np.array([[0.2, 0.0, 0.0], [1.6, 0.0, 0.0]]), 0.01)
    assert ext.interval(c, d) == _views(ranges + [(0.2, 1.6)] * 5).interval(c, d)
    assert ext.interval(c, d)[1] == pytest.approx(1.6)
    assert ext.centre()[0] > before[0]
    assert ext.interval(c, d, tee, 0.15) == _views(ranges + [(0.2, 1.6)] * 5).interval(c, d, tee, 0.15)
