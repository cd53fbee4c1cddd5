"""An in-line object seen in a few scans of one pass, whose tentative track was forgotten for the timeout
before the vehicle came back, still keeps the collinear pipes either side of it apart
(semslam.mapping.tracks.TrackSet.object_points counts the lapsed object tracks' places). Pipeline seed 34
(stop 46): valve 2 was seen in two scans of the outbound pass, its track lapsed 60 s later; on the return
pass the pipe beyond it (mapped, 1.34 m) lay 0.17 m past the pipe before it, nothing between them, and the
EKF merged the two; at the end the valve, mapped on that pass, cut the merged pipe and the pipe beyond it
left the map."""

import numpy as np

from semslam.config import AssociationConfig
from semslam.mapping.book import LandmarkBook
from semslam.mapping.builder import MapBuilder
from semslam.mapping.tracks import TrackSet, TrackView
from semslam.observations import LineObservation, PointObservation
from tests.test_mapping_uncrossed_object import _TwoPipes as _MappedPair

C, D = np.array([0.0, 0.0, -15.0]), np.array([1.0, 0.0, 0.0])
NONE = np.zeros((0, 3))
S = 1_000_000_000  # ns per second
VALVE = C + 2.08 * D


def _seg(s0, s1):
    return np.array([C + s0 * D, C + s1 * D])


def _lapsed_valve(assoc: AssociationConfig) -> TrackSet:
    """A tentative valve seen in two scans (not promoted), then not seen for longer than the timeout."""
    tracks = TrackSet(assoc)
    for k, stamp in enumerate((48 * S, 48 * S + S // 2)):
        z = PointObservation(stamp, "stereo", position=VALVE + [0.0, 0.01 * k, 0.0], covariance=np.eye(3) * 1e-4)
        went, promoted = tracks.extend([TrackView(stamp, z, z.position, np.eye(3) * 1e-4)], NONE)
        assert went[0].kind == "object" and not promoted
    tracks.purge(48 * S + int((assoc.track_timeout_s + 1) * S))
    assert len(tracks) == 0  # forgotten: the valve is neither mapped nor a live track
    return tracks


class _TwoPipes(_MappedPair):
    """Two mapped pipes on one line (ids 2 and 4), no mapped object, their lines compatible by χ²
    (``tests/test_mapping_uncrossed_object.py``); the merges the builder asks for are recorded."""

    def __init__(self):
        self.merges = []

    def merge(self, keep, drop, constrain):
        self.merges.append((keep, drop))


def _book() -> LandmarkBook:
    """Pipe 2 seen along 0-2.0 m up to the valve at 2.08 m; pipe 4 seen from 2.17 m on, beyond it."""
    book = LandmarkBook()
    for s0, s1 in [(0.0, 0.5), (0.4, 1.0), (0.9, 1.5), (1.4, 1.95), (1.5, 2.0)]:
        book.extent(2).add(_seg(s0, s1), 0.01)
    for s0, s1 in [(2.17, 2.4), (2.18, 2.6), (2.2, 2.8), (2.5, 3.2)]:
        book.extent(4).add(_seg(s0, s1), 0.01)
    return book


def test_a_lapsed_object_track_still_separates_the_pipes_either_side():
    assoc = AssociationConfig()
    state = _TwoPipes()
    builder = MapBuilder(state, assoc, _book(), [])
    builder.tracks = _lapsed_valve(assoc)
    assert len(builder.tracks.object_points()) == 1  # the lapsed valve's place
    builder.merge_duplicates({4})  # pipe 4 touched on the return pass
    assert state.merges == []


def test_without_the_valve_the_two_stretches_are_one_pipe():
    """The same two pipes with no object ever seen between them are one pipe seen in two parts."""
    assoc = AssociationConfig()
    state = _TwoPipes()
    builder = MapBuilder(state, assoc, _book(), [])
    builder.merge_duplicates({4})
    assert state.merges == [(2, 4)]


def test_the_return_pass_view_beyond_the_lapsed_valve_is_not_the_pipe_before_it():
    """A view of the pipe beyond the valve, the valve forgotten, is beyond the pipe before it (no pairing)."""
    from semslam.mapping.builder import Scan

    assoc = AssociationConfig()
    tracks = _lapsed_valve(assoc)
    book = _book()
    scan = Scan(book, assoc, tracks.object_points(), NONE)
    z = LineObservation(0, "stereo", p=C + 2.2 * D, q=C + 2.6 * D, covariance=np.eye(6) * 1e-4, radius=0.02)
    assert scan.excludes(2, np.stack([z.p, z.q]), C, D)
    assert not Scan(book, assoc, NONE, NONE).excludes(2, np.stack([z.p, z.q]), C, D)
