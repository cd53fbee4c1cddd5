"""What the map building keeps between two asks (stop 45, its cost per update) follows what it was made
from: a pipe's line follows its estimate, its seen ends the estimate and the views, an object's gating
spread its information, and a batch's seen stretch of a pipe (:class:`Scan`) the line and the views."""

import numpy as np

from factors.landmarks import LineAnchor
from semslam.backend.landmarks import GraphLandmarks, Landmark, _pipe_ends
from semslam.config import AssociationConfig
from semslam.mapping.book import LandmarkBook
from semslam.mapping.builder import Scan

C, D = np.array([0.0, 0.0, -15.0]), np.array([1.0, 0.0, 0.0])
NONE = np.zeros((0, 3))


def _seg(s0, s1, c=C, d=D):
    return np.array([c + s0 * d, c + s1 * d])


def _pipe() -> Landmark:
    lm = Landmark(3, "pipe", 0, anchor=LineAnchor.from_points(C - D, C + D))  # c0 = C
    lm.estimate = np.zeros(4)
    return lm


def test_a_batchs_seen_stretch_follows_the_views_and_the_line():
    a = AssociationConfig()
    book = LandmarkBook()
    for s0, s1 in ((0.0, 0.5), (0.3, 1.0), (0.4, 1.0)):
        book.extent(2).add(_seg(s0, s1), 0.01)
    scan = Scan(book, a, NONE, NONE)
    far = _seg(1.5, 1.9)  # 0.5 m beyond the seen end: more than the extent gap
    assert a.pipe_extent_gap_m < 0.5
    assert scan.excludes(2, _seg(1.1, 1.4), C, D) is False
    assert scan.excludes(2, far, C, D) is True
    for s0, s1 in ((0.8, 1.6), (0.9, 1.6), (1.0, 1.7)):  # the pipe seen further within the same batch
        book.extent(2).add(_seg(s0, s1), 0.01)
    assert scan.excludes(2, far, C, D) is False
    # another line (the estimate moved): what was seen is measured along it, as without the memo
    c2 = C + np.array([0.0, 0.02, 0.0])
    d2 = np.array([1.0, 0.01, 0.0]) / np.hypot(1.0, 0.01)
    fresh = book.extent(2).excludes(far, c2, d2, NONE, NONE, a.inline_object_radius_m, a.pipe_extent_gap_m)
    assert scan.excludes(2, far, c2, d2) is fresh


def test_a_pipes_line_and_seen_ends_follow_its_estimate_and_views():
    lm, book = _pipe(), LandmarkBook()
    book.extent(lm.id).add(_seg(0.0, 1.0), 0.01)
    c, d = lm.line()
    np.testing.assert_allclose(c, C, atol=1e-12)
    np.testing.assert_allclose(d, D, atol=1e-12)
    a, b = _pipe_ends(lm, book)
    np.testing.assert_allclose([a, b], _seg(0.0, 1.0), atol=1e-12)
    lm.estimate = np.array([0.0, 0.0, 0.1, 0.0])  # a new estimate: the line moves 0.1 m across
    c1, _ = lm.line()
    assert abs(np.linalg.norm(c1 - C) - 0.1) < 1e-12
    lm.estimate[3] = 0.2  # changed in place: the line still follows
    c2, _ = lm.line()
    assert abs(np.linalg.norm(c2 - C) - np.hypot(0.1, 0.2)) < 1e-12
    book.extent(lm.id).add(_seg(0.5, 2.0), 0.01)  # seen further: the ends follow
    a, b = _pipe_ends(lm, book)
    assert abs(np.linalg.norm(b - a) - 2.0) < 1e-9


def test_an_objects_gating_spread_follows_its_information():
    state = GraphLandmarks.__new__(GraphLandmarks)  # only the landmarks are asked for
    lm = Landmark(0, "object", 0)
    lm.add_information(np.eye(3) * 100.0, np.eye(3) * 100.0)
    state.landmarks = {0: lm}
    assert abs(state.gating_spread([0])[0] - np.sqrt(0.03)) < 1e-6
    lm.add_information(np.eye(3) * 200.0, np.eye(3) * 200.0)  # three times the information
    assert abs(state.gating_spread([0])[0] - np.sqrt(0.01)) < 1e-6


def test_the_pairs_linearised_at_once_are_those_linearised_one_by_one():
    """:meth:`GraphAssociationProblem.pairs` (object and pipe pairs stacked) gives each allowed pair
    what :meth:`GraphAssociationProblem.pair` gives it alone, in the same order."""
    import gtsam

    from semslam.backend.problem import Candidate, GraphAssociationProblem
    from semslam.observations import LineObservation, PointObservation

    rng = np.random.default_rng(4)
    pose = gtsam.Pose3(gtsam.Rot3.RzRyRx(0.1, -0.05, 1.2), np.array([1.0, -2.0, 3.0]))
    T_a = np.eye(4)
    T_b = gtsam.Pose3(gtsam.Rot3.RzRyRx(0.0, 0.4, 0.2), np.array([0.3, 0.0, 0.2])).matrix()
    cands = []
    for n in range(3):
        lm = Landmark(n, "object", n)
        lm.estimate = rng.normal(size=3)
        cands.append(Candidate(lm, np.eye(3) * 1e-3))
    for n in range(3, 6):
        p = rng.normal(size=3)
        lm = Landmark(n, "pipe", n, anchor=LineAnchor.from_points(p, p + rng.normal(size=3)))
        lm.estimate = rng.normal(size=4) * 0.1
        cands.append(Candidate(lm, np.eye(4) * 1e-3))
    obs, T_BS = [], []
    for n in range(6):
        A = rng.normal(size=(6, 6))
        if n % 2:
            obs.append(LineObservation(0, "s", p=rng.normal(size=3), q=rng.normal(size=3), covariance=A @ A.T))
        else:
            obs.append(PointObservation(0, "s", position=rng.normal(size=3), covariance=A[:3, :3] @ A[:3, :3].T))
        T_BS.append(T_a if n < 3 else T_b)
    allowed = rng.random((6, 6)) < 0.7
    one = GraphAssociationProblem(pose, obs, T_BS, cands, allowed, None)
    alone = [(i, j, one.pair(i, j)) for i in range(6) for j in np.flatnonzero(allowed[i])]
    stacked = GraphAssociationProblem(pose, obs, T_BS, cands, allowed, None).pairs()
    assert [(i, j) for i, j, _ in stacked] == [(i, int(j)) for i, j, _ in alone]
    assert sum(lin is not None for _, _, lin in alone) >= 8  # objects and pipes both
    for (_, _, a), (_, _, b) in zip(alone, stacked):
        assert (a is None) == (b is None)
        if a is not None:
            for f in ("innovation", "H_x", "H_l", "R"):
                np.testing.assert_allclose(getattr(b, f), getattr(a, f), rtol=1e-12, atol=1e-12)
