"""A mapped pipe's views that meet only across an in-line object (tentative, not yet mapped) may be of two
pipes joined by it: the object cuts what was seen of the pipe when a segment beyond it is judged
(semslam.mapping.extent.Lines). Pipeline seed 34 (stop 44): one view of the next pipe,
0.18 m beyond the mapped pipe's seen end, paired with it a scan before the valve between them was seen;
from then on the valve lay inside the seen stretch, every view of the next pipe paired with the first
and the next pipe (1.34 m) was never mapped."""

import numpy as np

from semslam.config import AssociationConfig
from semslam.mapping.book import LandmarkBook
from semslam.mapping.builder import MapBuilder, Scan
from semslam.observations import LineObservation

C, D = np.array([0.0, 0.0, -15.0]), np.array([1.0, 0.0, 0.0])
NONE = np.zeros((0, 3))


def _seg(s0, s1):
    return np.array([C + s0 * D, C + s1 * D])


def _book(stretches, sigma=0.01):
    book = LandmarkBook()
    for s0, s1 in stretches:
        book.extent(2).add(_seg(s0, s1), sigma)
    return book


# pipe 2's views along 0-2.0 m, running up to a valve at 2.06 m (seen 2.0 m), then one view of the pipe
# beyond the valve (2.16-2.34 m) that paired with pipe 2 before the valve was seen
SEEN = [(0.0, 0.4), (0.3, 0.8), (0.7, 1.2), (1.1, 1.6), (1.5, 2.0), (1.6, 2.0)]
STRAY = (2.16, 2.34)
VALVE = np.array([C + 2.06 * D])
NEXT = _seg(2.14, 2.55)  # the next scan's view of the pipe beyond the valve


def test_a_tentative_object_no_view_runs_across_separates_the_pipe_beyond_it():
    book = _book(SEEN + [STRAY])
    scan = Scan(book, AssociationConfig(), VALVE, NONE)  # the valve tentative: a separator, not mapped
    assert scan.excludes(2, NEXT, C, D)
    # without the stray view the valve lies between the seen end and the segment (the rule before)
    assert Scan(_book(SEEN), AssociationConfig(), VALVE, NONE).excludes(2, NEXT, C, D)


def test_a_tentative_object_the_views_run_across_does_not_cut_the_pipe():
    """A pipe that runs on through an object (a valve on a run, a false object view) has views across it:
    the object does not cut, and the pipe's views beyond it still continue it."""
    book = _book(SEEN + [(1.9, 2.4), STRAY])
    assert not Scan(book, AssociationConfig(), VALVE, NONE).excludes(2, NEXT, C, D)
    ext, uncut = book.extent(2), book.extent(2).seen_span(C, D, NONE, NONE, 0.15)
    assert ext.seen_span(C, D, VALVE, NONE, 0.15) == uncut  # a tentative valve the views run across cuts nothing
    assert ext.seen_span(C, D, VALVE + [0.0, 0.3, 0.0], NONE, 0.15) == uncut  # off the line
    assert ext.seen_span(C, D, NONE, VALVE, 0.15)[1] < uncut[1]  # mapped, the valve cuts


class _State:
    """What MapBuilder._overlaps_mapped asks of an estimator: a line observation's place in {W}."""

    def place(self, z):
        return (np.stack([z.p, z.q]),)


def test_the_pipe_beyond_a_tentative_object_is_not_the_mapped_pipe_seen_badly():
    """A segment failing the χ² gates that lies on a mapped pipe's seen stretch is that pipe seen badly
    and starts nothing; the stretch is cut at an object no view runs across, so the pipe beyond it starts
    a track."""
    builder = MapBuilder(_State(), AssociationConfig(), _book(SEEN + [STRAY]), [])
    p, q = _seg(2.14, 2.45)  # over half of it within the seen stretch as the stray view extends it
    z = LineObservation(0, "stereo", p=p, q=q, covariance=np.eye(6) * 1e-4, radius=0.02)
    lines = ([2], C[None, :], D[None, :])
    assert not builder._overlaps_mapped(z, NONE, VALVE, lines)
    # a view on the pipe's own stretch is still that pipe seen badly
    p, q = _seg(1.0, 1.5)
    z = LineObservation(0, "stereo", p=p, q=q, covariance=np.eye(6) * 1e-4, radius=0.02)
    assert builder._overlaps_mapped(z, NONE, VALVE, lines)


class _TwoPipes(_State):
    """Two mapped pipes on one line (ids 2 and 4), no mapped object, their lines compatible by χ²."""

    def pipes(self):
        return [(2, C, D), (4, C, D)]

    def objects(self):
        return [], NONE

    def difference_nis(self, a, b):
        return 0.0


def test_the_pipe_beyond_a_tentative_object_is_no_duplicate_of_the_pipe_before_it():
    """Pipe 4 (mapped from the views beyond the valve) and pipe 2 (whose stray view crossed the valve's
    place) are collinear and compatible, but the valve that no view of pipe 2 runs across lies between
    them: two pipes, not one mapped twice."""
    book = _book(SEEN + [STRAY])
    for s0, s1 in [(2.14, 2.55), (2.2, 2.6), (2.15, 2.58)]:
        book.extent(4).add(_seg(s0, s1), 0.01)
    builder = MapBuilder(_TwoPipes(), AssociationConfig(), book, [])
    assert builder._duplicate_pipes({4}, VALVE) == []
    assert builder._duplicate_pipes({4}, NONE) != []  # without the valve they are one
