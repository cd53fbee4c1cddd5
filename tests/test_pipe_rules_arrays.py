"""The scan's pipe rules for all pairs at once (:meth:`Scan.excludes_all`, :class:`Lines`) decide as the rules pair
by pair did on main (the references below, copied from main's ``PipeExtent.seen_span`` / ``excludes`` and
``MapBuilder._on_pipe``), to the bit: many pipes with different numbers of views, one view, parallel lines, a seen
stretch of zero length, no / one / several objects. The one-pair entry points (:meth:`Scan.excludes`,
:meth:`PipeExtent.seen_span`, :meth:`PipeExtent.excludes`) are the array form of one row: they too."""

import math

import numpy as np
import pytest

from semslam.config import AssociationConfig
from semslam.mapping.book import LandmarkBook
from semslam.mapping.builder import Scan
from semslam.mapping.extent import CROSSING_M, Lines, off_axis
from semslam.mapping.pipes import object_between

NONE = np.zeros((0, 3))


# ------------------------------------------------------------------ main's pair-by-pair rules, the reference
def _uncrossed(ext, objects, c, d, radius):
    """main's ``PipeExtent.uncrossed``: the objects on the line (c, d) no view of the pipe runs across (the views
    along the line as main's ``PipeExtent._positions`` gives them: the views are not public)."""
    objects = np.asarray(objects, float).reshape(-1, 3)
    r = objects - c
    s_obj = r @ d
    on = np.linalg.norm(r - np.outer(s_obj, d), axis=1) < radius
    if not on.any() or not len(ext):
        return objects[on]
    s = ext._positions(c, d)
    lo, hi = np.minimum(s[:, 0], s[:, 1]), np.maximum(s[:, 0], s[:, 1])
    crossed = ((lo[:, None] < s_obj[on] - CROSSING_M) & (hi[:, None] > s_obj[on] + CROSSING_M)).any(axis=0)
    return objects[on][~crossed]


def _seen_span(ext, c, d, separators, cutters, radius):
    """main's ``PipeExtent.seen_span``: the interval cut at the cutters and the uncrossed separators."""
    mapped = np.asarray(cutters, float).reshape(-1, 3)
    uncrossed = _uncrossed(ext, separators, c, d, radius)
    return ext.interval(c, d, np.vstack([mapped, uncrossed]) if len(uncrossed) else mapped, radius)


def _excludes(ext, ends_W, c, d, separators, cutters, radius, max_gap):
    """main's ``PipeExtent.excludes`` (its ``gap`` and ``separated``)."""
    a, b = span = _seen_span(ext, c, d, separators, cutters, radius)
    s = (ends_W - c) @ d
    if max(0.0, float(s.min()) - b, a - float(s.max())) > max_gap:
        return True
    if len(separators) == 0:
        return False
    r = separators - c
    on_line = separators[np.linalg.norm(r - (r @ d)[:, None] * d, axis=1) < radius]
    return object_between(span, ends_W, c, d, on_line, radius)


def _scan_excludes(scan, pipe, seg_W, c, d):
    """main's ``Scan.excludes`` (its memo of the seen stretch changes no answer)."""
    a = scan.assoc
    return _excludes(
        scan.book.extent(pipe),
        seg_W,
        c,
        d,
        scan.separators,
        scan.cutters,
        a.inline_object_radius_m,
        a.pipe_extent_gap_m,
    )


def _on_pipe(builder, ends, pipe, c, d, scan):
    """main's ``MapBuilder._on_pipe``: the paper's collinear merge of a segment with a pipe."""
    a = builder.assoc
    u = (ends[1] - ends[0]) / np.linalg.norm(ends[1] - ends[0])
    if abs(float(u @ d)) < math.cos(a.merge_angle_rad) or off_axis(ends, c, d) > a.merge_distance_m:
        return False
    return not _scan_excludes(scan, pipe, ends, c, d)


def _unit(v):
    return v / np.linalg.norm(v)


def _world(rng, n_pipes):
    """Pipes (id → point, direction, views) around a few directions: some lines parallel, some one view long,
    one seen as a single point (every view's ends at one place)."""
    book = LandmarkBook()
    lines = {}
    base = [_unit(rng.normal(size=3)) for _ in range(3)]
    for pid in range(n_pipes):
        d = base[pid % 3] if pid < 6 else _unit(rng.normal(size=3))  # pipes 0/3, 1/4, 2/5 parallel
        c = rng.normal(size=3) * 3.0
        if pid == 3:
            c = lines[0][0] + 0.3 * _unit(np.cross(d, rng.normal(size=3)))  # side by side with pipe 0
        n_views = 1 if pid % 4 == 1 else int(rng.integers(2, 60))
        start, length = rng.uniform(-1, 1), rng.uniform(0.3, 3.0)
        for _ in range(n_views):
            s0 = start + rng.uniform(0, 0.6) * length + rng.normal(0, 0.02)
            s1 = start + rng.uniform(0.4, 1.0) * length + rng.normal(0, 0.02)
            if pid == 7:  # a seen stretch of zero length
                s0 = s1 = start
            ends = np.array([c + s0 * d, c + s1 * d]) + rng.normal(0, 0.01, size=(2, 3))
            book.extent(pid).add(ends, abs(rng.normal(0.02, 0.01)))
        lines[pid] = (c, d, start, length)
    return book, lines


def _objects(rng, lines, n, on_share=0.6):
    """n objects, most on a pipe's line (within a few cm), at places along it around what was seen."""
    out = []
    for _ in range(n):
        c, d, start, length = lines[int(rng.integers(len(lines)))]
        p = c + (start + rng.uniform(-0.5, 1.5) * length) * d
        out.append(p + (rng.normal(0, 0.03, 3) if rng.uniform() < on_share else rng.normal(0, 0.5, 3)))
    return np.array(out).reshape(-1, 3)


def _pairs(rng, lines, n_pairs):
    """Segments near the pipes' lines (before, inside and beyond what was seen), each with its pipe and line (the
    line moved a little for some pairs: another line of the same pipe; the direction sometimes a strided column)."""
    pipes, segs, cs, ds = [], [], [], []
    for _ in range(n_pairs):
        pid = int(rng.integers(len(lines)))
        c, d, start, length = lines[pid]
        if rng.uniform() < 0.2:
            c, d = c + rng.normal(0, 1e-3, 3), _unit(d + rng.normal(0, 1e-3, 3))
        s0 = start + rng.uniform(-1.0, 2.0) * length
        s1 = s0 + rng.uniform(0.05, 1.0) * length
        segs.append(np.array([c + s0 * d, c + s1 * d]) + rng.normal(0, 0.01, (2, 3)))
        pipes.append(pid)
        cs.append(c)
        ds.append(np.column_stack([d, d, d])[:, 1] if rng.uniform() < 0.5 else d)  # graph: R_L's column
    return pipes, np.array(segs), cs, ds


@pytest.mark.parametrize("n_seps, n_cut", [(0, 0), (1, 0), (0, 1), (1, 1), (2, 1), (7, 3), (25, 12)])
def test_the_rules_of_all_pairs_at_once_equal_those_pair_by_pair(n_seps, n_cut):
    a = AssociationConfig()
    decided = []
    for seed in range(12):
        rng = np.random.default_rng(1000 * n_seps + 10 * n_cut + seed)
        book, lines = _world(rng, n_pipes=int(rng.integers(8, 16)))
        cut = _objects(rng, lines, n_cut)
        seps = np.vstack([cut, _objects(rng, lines, max(n_seps - n_cut, 0))])[:n_seps] if n_seps else NONE
        pipes, segs, cs, ds = _pairs(rng, lines, 60)
        scan = Scan(book, a, seps, cut)
        expected = np.array([_scan_excludes(scan, p, s, c, d) for p, s, c, d in zip(pipes, segs, cs, ds)])
        got = scan.excludes_all(pipes, segs, np.array(cs), np.array(ds))
        assert got.dtype == bool and np.array_equal(got, expected), seed
        # the one-pair entry points: the array form of one row
        assert [scan.excludes(p, s, c, d) for p, s, c, d in zip(pipes, segs, cs, ds)] == expected.tolist(), seed
        r, gap = a.inline_object_radius_m, a.pipe_extent_gap_m
        one_pipe = [book.extent(p).excludes(s, c, d, seps, cut, r, gap) for p, s, c, d in zip(pipes, segs, cs, ds)]
        assert one_pipe == expected.tolist(), seed
        decided.append(expected)
        # the seen stretches themselves, number for number
        pids = sorted(lines)
        at_once = Lines(
            [book.extent(p) for p in pids],
            [lines[p][0] for p in pids],
            [lines[p][1] for p in pids],
            seps,
            cut,
            a.inline_object_radius_m,
        )
        r = a.inline_object_radius_m
        one = [_seen_span(book.extent(p), lines[p][0], lines[p][1], seps, cut, r) for p in pids]
        assert np.array_equal(at_once.spans, np.array(one)), seed
        assert [book.extent(p).seen_span(lines[p][0], lines[p][1], seps, cut, r) for p in pids] == one, seed
        for row, p in enumerate(pids):  # the separators on each line, where object_between puts them
            on = at_once.on[row]
            assert np.array_equal(at_once.between[row][on], (seps[on] - lines[p][0]) @ lines[p][1])
    decided = np.concatenate(decided)
    assert 0.2 < decided.mean() < 0.8  # both answers well represented


def test_each_pair_is_judged_against_its_own_pipe_and_line():
    """Two collinear pipes apart and a third parallel one: a segment within the first pipe's stretch, one within
    the second's, each asked of both, in an order that mixes the pipes (an index shifted by one pair, or a line
    taken from the neighbouring pair, flips answers)."""
    a = AssociationConfig()
    book = LandmarkBook()
    c, d = np.array([1.0, 2.0, -10.0]), _unit(np.array([1.0, 0.2, 0.0]))
    side = _unit(np.cross(d, [0.0, 0.0, 1.0]))
    for k in range(5):
        book.extent(10).add(np.array([c + (0.0 + 0.01 * k) * d, c + (1.0 - 0.01 * k) * d]), 0.01)
        book.extent(11).add(np.array([c + (3.0 + 0.01 * k) * d, c + (4.0 - 0.01 * k) * d]), 0.01)
    book.extent(12).add(np.array([c + 2 * side, c + 2 * side + d]), 0.01)
    first = np.array([c + 0.2 * d, c + 0.8 * d])
    second = np.array([c + 3.2 * d, c + 3.8 * d])
    pipes = [10, 11, 10, 11, 12, 12]
    segs = np.array([first, first, second, second, first + 2 * side, second + 2 * side])
    lines_c = np.array([c, c, c, c, c + 2 * side, c + 2 * side])
    lines_d = np.array([d] * 6)
    got = Scan(book, a, NONE, NONE).excludes_all(pipes, segs, lines_c, lines_d)
    assert got.tolist() == [False, True, True, False, False, True]
    one = Scan(book, a, NONE, NONE)
    assert got.tolist() == [_scan_excludes(one, *q) for q in zip(pipes, segs, lines_c, lines_d)]
    assert got.tolist() == [one.excludes(*q) for q in zip(pipes, segs, lines_c, lines_d)]
    # a valve between the two pipes keeps the second's segment from the first even where the gap would allow it
    valve = (c + 1.1 * d)[None, :]
    near = np.array([c + 1.2 * d, c + 2.5 * d])
    assert a.pipe_extent_gap_m > 0.2
    assert Scan(book, a, NONE, NONE).excludes_all([10], near[None], c[None], d[None]).tolist() == [False]
    assert Scan(book, a, valve, NONE).excludes_all([10], near[None], c[None], d[None]).tolist() == [True]


def test_no_pairs():
    assert Scan(LandmarkBook(), AssociationConfig(), NONE, NONE).excludes_all([], NONE, NONE, NONE).shape == (0,)


class _Pipes:
    """A landmark state of pipes (and objects) only, as the duplicate test asks of it."""

    def __init__(self, lines, objects, rng):
        self.lines = lines
        self.pos = objects
        self.nis = {}
        self.rng = rng

    def pipes(self):
        return [(pid, c, d) for pid, (c, d, _, _) in self.lines.items()]

    def objects(self):
        return list(range(100, 100 + len(self.pos))), self.pos

    def difference_nis(self, a, b):
        if (a, b) not in self.nis:
            self.nis[(a, b)] = None if self.rng.uniform() < 0.1 else float(self.rng.chisquare(4) * 2)
        return self.nis[(a, b)]


def _duplicate_pipes_pair_by_pair(builder, touched, separators):
    """The duplicate test of pipes as main had it: pair by pair (the screen one touched pipe at a time, ``_on_pipe``,
    each screened pipe's stretch by ``PipeExtent.ends``); the verdict on a screened pair is the builder's."""
    from semslam.mapping.association import chi2_gate

    self = builder
    a_cfg, (ids, cutters), pipes = self.assoc, self.state.objects(), self.state.pipes()
    points, dirs = (np.array([line[k] for line in pipes]) for k in (1, 2))
    mids = np.array([self.book.extent(pid).centre() for pid, _, _ in pipes])
    gate = chi2_gate(a_cfg.confidence, 4)
    fittings = None
    scan = Scan(self.book, a_cfg, separators, cutters)
    ends_of = {}
    out = []
    for a, (pid_a, c_a, d_a) in enumerate(pipes):
        if pid_a not in touched:
            continue
        r = mids - c_a
        off = np.linalg.norm(r - np.outer(r @ d_a, d_a), axis=1)
        r = mids[a] - points
        back = np.linalg.norm(r - np.sum(r * dirs, axis=1)[:, None] * dirs, axis=1)
        cos_ab = np.abs(dirs @ d_a)
        near = np.minimum(off, back) <= a_cfg.merge_distance_m
        screen = (cos_ab >= math.cos(a_cfg.duplicate_pipe_angle_rad)) & near
        for b in np.flatnonzero(screen):
            pid_b, c_b, d_b = pipes[b]
            if pid_b == pid_a or (pid_b in touched and pid_b < pid_a):
                continue
            on_pipe = None
            collinear = bool(cos_ab[b] >= math.cos(a_cfg.merge_angle_rad))
            if collinear:
                if fittings is None:
                    fittings = self._fittings(ids, cutters)
                ends_b = ends_of.get(pid_b)
                if ends_b is None:
                    ext_b, rad = self.book.extent(pid_b), a_cfg.inline_object_radius_m
                    uncrossed = _uncrossed(ext_b, separators, c_b, d_b, rad)  # main's PipeExtent.cutting
                    mapped = np.asarray(fittings, float).reshape(-1, 3)
                    cut = np.vstack([mapped, uncrossed]) if len(uncrossed) else mapped
                    ends_b = ends_of[pid_b] = ext_b.ends(c_b, d_b, cut, rad)
                on_pipe = _on_pipe(self, ends_b, pid_a, c_a, d_a, scan)
            verdict = self._duplicate_pair(pipes[a], pipes[b], collinear, on_pipe, gate, cutters)
            if verdict is not None:
                out.append(verdict)
    return out


def test_the_duplicate_test_of_pipes_at_once_equals_it_pair_by_pair(monkeypatch):
    """Pipes in line (fragments of one pipe, with and without an object between), twins a few degrees off,
    parallel neighbours: the pairs found and their order are those of the pair-by-pair test."""
    from semslam.mapping.builder import MapBuilder

    a = AssociationConfig()
    found = []
    for seed in range(40):
        rng = np.random.default_rng(seed)
        book, lines = _world(rng, n_pipes=int(rng.integers(4, 12)))
        for pid in list(lines)[: int(rng.integers(1, 5))]:  # a fragment or twin of some pipes
            c, d, start, length = lines[pid]
            twin = len(lines)
            d2 = _unit(d + rng.normal(0, 0.08, 3)) if rng.uniform() < 0.4 else d
            c2 = c + rng.normal(0, 0.02, 3) + rng.uniform(-0.5, 0.5) * length * d
            for _ in range(int(rng.integers(1, 20))):
                s0, s1 = start + rng.uniform(0, 0.5) * length, start + rng.uniform(0.5, 1.0) * length
                book.extent(twin).add(np.array([c2 + s0 * d2, c2 + s1 * d2]) + rng.normal(0, 0.01, (2, 3)), 0.02)
            lines[twin] = (c2, d2, start, length)
        objects = _objects(rng, lines, int(rng.integers(0, 6)))
        seps = np.vstack([objects, _objects(rng, lines, int(rng.integers(0, 4)))])
        touched = {pid for pid in lines if rng.uniform() < 0.5} | {0}
        fittings = rng.uniform(size=len(objects)) < 0.5
        monkeypatch.setattr(MapBuilder, "_fittings", lambda self, ids, pos, f=fittings: pos[f])
        builder = MapBuilder(_Pipes(lines, objects, np.random.default_rng(seed)), a, book, [])
        expected = _duplicate_pipes_pair_by_pair(builder, touched, seps)
        builder.state.rng = np.random.default_rng(seed)  # the same χ² answers, asked in the same order
        builder.state.nis = {}
        assert builder._duplicate_pipes(touched, seps) == expected, seed
        found += expected
    assert len(found) > 20 and any(n < float("inf") for n, *_ in found)


def test_the_duplicate_screen_gives_the_numbers_of_one_pipe_at_a_time():
    from semslam.mapping.builder import _duplicate_screen

    a = AssociationConfig()
    rng = np.random.default_rng(7)
    for n in (2, 3, 9, 30):
        points = rng.normal(size=(n, 3))
        dirs = np.array([_unit(v) for v in rng.normal(size=(n, 3))])
        dirs[1] = dirs[0]  # parallel
        mids = points + rng.normal(size=(n, 1)) * dirs + rng.normal(0, 0.05, (n, 3))
        rows = sorted(rng.choice(n, size=max(1, n // 2), replace=False).tolist())
        screen, cos_ab = _duplicate_screen(rows, points, dirs, mids, a)
        for t, i in enumerate(rows):
            r = mids - points[i]
            off = np.linalg.norm(r - np.outer(r @ dirs[i], dirs[i]), axis=1)
            r = mids[i] - points
            back = np.linalg.norm(r - np.sum(r * dirs, axis=1)[:, None] * dirs, axis=1)
            cos_i = np.abs(dirs @ dirs[i])
            near = np.minimum(off, back) <= a.merge_distance_m
            assert np.array_equal(cos_ab[t], cos_i)
            assert np.array_equal(screen[t], (cos_i >= math.cos(a.duplicate_pipe_angle_rad)) & near)
