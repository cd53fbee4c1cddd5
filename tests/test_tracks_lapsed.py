"""An object track forgotten for the timeout leaves its place's counts (semslam.mapping.tracks, both
estimators' rule): a new track at that place takes the views it had and the scans that had the place in
view, so ``object_view_ratio`` judges the place since its first view, not the newest burst of views."""

import numpy as np

from semslam.config import AssociationConfig
from semslam.mapping.tracks import TrackSet, TrackView
from semslam.observations import PointObservation

END = np.array([0.0, 0.0, 3.0])  # a pipe's free end, where the front-end reports an object now and then
PIPE = np.array([[[0.05, 0.0, 3.0], [0.4, 0.0, 3.0]]])  # the pipe, seen in every scan that looks there
FAR = np.array([[[3.0, 0.0, 3.0], [3.5, 0.0, 3.0]]])  # elsewhere in the tank
NONE = np.zeros((0, 3))
COV = np.eye(3) * 0.02**2
S = 2_000_000_000  # a scan every 2 s


def _run(tracks, scans):
    """``scans``: (segments seen, whether the object's view came) per scan; purges as the builder does.
    Returns the tracks promoted."""
    promoted = []
    for i, (segments, seen) in enumerate(scans, start=1):
        stamp = i * S
        tracks.note_scan(stamp, NONE, segments)
        views = [TrackView(stamp, PointObservation(stamp, "laser", position=END), END.copy(), COV)] if seen else []
        promoted += tracks.extend(views, np.zeros((0, 3)))[1]
        tracks.purge(stamp)
    return promoted


def _assoc():
    return AssociationConfig(min_observations=3, object_view_ratio=0.5, object_view_reach_m=0.3, track_timeout_s=60.0)


def test_a_burst_of_views_at_a_place_seen_rarely_before_is_not_promoted():
    # World 81's pipe end: 3 views in 22 scans that had it in view (not promoted: 0.14 < 0.5), none in
    # the next 40 scans (80 s: the track lapses), then 3 in a row. As a fresh track the burst passes
    # (3 of 3); with the place's counts it is 6 views in 65 scans.
    first = [(PIPE, i in (0, 11, 21)) for i in range(22)]
    gap = [(PIPE, False)] * 40
    burst = [(PIPE, True)] * 3
    tracks = TrackSet(_assoc())
    assert _run(tracks, first + gap + burst) == []
    (tr,) = tracks.tracks
    assert len(tr.views) == 3 and tr.seen_before == 3 and tr.in_view == 65
    # from then on seen scan after scan, the place is promoted once seen in half the scans that had it
    # in view: a real object that the front-end missed for a while is mapped, later
    tracks = TrackSet(_assoc())
    got = _run(tracks, first + gap + [(PIPE, True)] * 70)[0]  # (the views after it start tracks here: no map)
    assert got.seen_before + len(got.views) == 59 and got.in_view == 118  # 3 + 56 views, 62 + 56 scans


def test_a_place_out_of_view_while_its_track_lapsed_keeps_its_share():
    # Seen once, then the vehicle looks elsewhere for 80 s (the place out of view: not counted), then
    # seen scan after scan: promoted at the new track's third view, as a fresh track would be.
    scans = [(PIPE, True)] + [(FAR, False)] * 40 + [(PIPE, True)] * 3
    tracks = TrackSet(_assoc())
    (got,) = _run(tracks, scans)
    assert len(got.views) == 3 and got.seen_before == 1 and got.in_view == 4


def test_a_lapsed_place_out_of_view_for_long_is_forgotten():
    # The place of the first test, then out of view for five track timeouts and more (the survey is
    # elsewhere): its counts are forgotten (a long survey's memory and cost stay bounded), and a burst
    # there is judged as a fresh track.
    first = [(PIPE, i in (0, 11, 21)) for i in range(22)]
    tracks = TrackSet(_assoc())
    (got,) = _run(tracks, first + [(FAR, False)] * 160 + [(PIPE, True)] * 3)  # 320 s > 5 × 60 s
    assert got.seen_before == 0 and got.in_view == 3


def test_a_track_elsewhere_takes_nothing_from_a_lapsed_one():
    tracks = TrackSet(_assoc())
    _run(tracks, [(PIPE, i in (0, 11, 21)) for i in range(22)] + [(PIPE, False)] * 40)
    assert not tracks.tracks
    stamp = 63 * S
    away = END + np.array([0.5, 0.0, 0.0])  # outside the gate of the lapsed track
    tracks.note_scan(stamp, NONE, PIPE)
    view = TrackView(stamp, PointObservation(stamp, "laser", position=away), away, COV)
    (tr,), _ = tracks.extend([view], np.zeros((0, 3)))
    assert tr.seen_before == 0 and tr.in_view == 1


def _rotating(offsets, n_scans, cov):
    """Each scan one view of an object, its centre scattered along the pipe by ``offsets`` in turn."""
    tracks, promoted = TrackSet(_assoc()), []
    for i in range(1, n_scans + 1):
        stamp = i * S
        at = END + np.array([offsets[i % len(offsets)], 0.0, 0.0])
        tracks.note_scan(stamp, NONE, PIPE)
        view = TrackView(stamp, PointObservation(stamp, "laser", position=at), at, cov)
        promoted += tracks.extend([view], np.zeros((0, 3)))[1]
    return tracks, promoted


def test_tracks_side_by_side_at_one_place_share_its_views():
    # World 81's in-line socket: its centre scattered 4 cm along the pipe, more than the views'
    # covariance (5 mm) allows, so its views go to three tracks in turn, each given a third of them.
    # Counted per track (1 of 3 scans) none is promoted; the place was seen in every scan.
    tight = np.eye(3) * 0.005**2
    tracks, promoted = _rotating((0.0, 0.04, 0.08), 7, tight)
    assert len(promoted) == 1 and len(promoted[0].views) == 3 and promoted[0].seen == promoted[0].in_view == 7
    # views beyond object_body_m (0.12 m) of a track are another object's: no credit
    tracks, promoted = _rotating((0.0, 0.2, 0.4), 30, tight)
    assert promoted == [] and all(tr.seen == len(tr.views) for tr in tracks.tracks)
