"""A pipe view continues a tentative pipe track across a gap along the axis as wide as the views' ends
are uncertain along it (``association.pipe_track_gap_sigmas``, semslam.mapping.extent.track_gap); the
mapped pipes keep ``pipe_extent_gap_m``."""

import numpy as np

from semslam.config import AssociationConfig
from semslam.mapping.book import LandmarkBook
from semslam.mapping.builder import Scan
from semslam.mapping.extent import along_sigma
from semslam.mapping.tracks import TrackSet, TrackView
from semslam.observations import LineObservation

SONAR_ALONG = 0.3 * np.sqrt(2.0)  # the sonar's along_sigma_m, its covariance inflated by the windows' reuse (2)
LASER_ALONG = 0.021  # the laser's endpoint_sigma (0.02) and its range noise at a few metres


def _view(stamp, s0, s1, along, y=0.0):
    """A pipe view along x from s0 to s1 (m), its ends σ ``along`` along the axis and 3 cm across."""
    p, q = np.array([s0, y, -20.0]), np.array([s1, y, -20.0])
    c = np.diag([along**2, 0.03**2, 0.03**2])
    cov = np.zeros((6, 6))
    cov[:3, :3] = cov[3:, 3:] = c
    z = LineObservation(stamp, "sonar", p=p, q=q, covariance=cov, radius=0.1)
    return TrackView(stamp, z, np.stack([p, q]))


def _tracks_after(views, assoc):
    tracks = TrackSet(assoc)
    for v in views:
        tracks.extend([v], np.zeros((0, 3)))
    return sorted(len(tr.views) for tr in tracks.tracks)


def test_sonar_views_of_one_pass_across_a_gap_continue_one_track():
    """Field 53: one pass's views of a partly buried pipe at 0.8–5.0 m, then 6.1–7.5 m (1.1 m apart
    along the axis). The sonar's windows cut the pipe: its ends have σ 0.42 m along the axis, the gap
    between two views' ends σ 0.6 m, so 1.1 m is no evidence of another pipe. One track, promoted at
    its third view; with the mapped pipes' 0.3 m gap (today's rule, the key at 0) two tracks, of 2 and 1 views."""
    views = [_view(1, 0.8, 5.0, SONAR_ALONG), _view(2, 6.1, 7.5, SONAR_ALONG), _view(3, 0.9, 4.9, SONAR_ALONG)]
    assert abs(along_sigma(views[0].z) - SONAR_ALONG) < 1e-12
    tracks = TrackSet(AssociationConfig(min_observations=3))
    promoted = []
    for v in views:
        promoted += tracks.extend([v], np.zeros((0, 3)))[1]
    assert len(promoted) == 1 and len(promoted[0].views) == 3
    assert _tracks_after(views, AssociationConfig(min_observations=10, pipe_track_gap_sigmas=0)) == [1, 2]


def test_laser_views_and_a_gap_beyond_the_sonar_ends_uncertainty_start_new_tracks():
    """The laser's ends are certain to 2 cm: a view 0.5 m beyond a track's stretch is another pipe (the
    0.3 m gap holds, as before). And a sonar view 3 m beyond (5σ of the gap) starts a track too."""
    laser = [_view(1, 0.0, 1.0, LASER_ALONG), _view(2, 1.5, 2.5, LASER_ALONG)]
    assert _tracks_after(laser, AssociationConfig(min_observations=10)) == [1, 1]
    sonar = [_view(1, 0.0, 4.0, SONAR_ALONG), _view(2, 7.0, 9.0, SONAR_ALONG)]
    assert _tracks_after(sonar, AssociationConfig(min_observations=10)) == [1, 1]


def test_the_mapped_pipes_keep_pipe_extent_gap_m():
    """The key widens the tracks' gap only: a segment 1.1 m beyond what a mapped pipe's views saw
    is not that pipe, whatever pipe_track_gap_sigmas says."""
    book = LandmarkBook()
    seen = _view(1, 0.8, 5.0, SONAR_ALONG)
    book.extent(7).add(seen.world, along_sigma(seen.z))
    c, d = np.array([0.0, 0.0, -20.0]), np.array([1.0, 0.0, 0.0])
    beyond = np.array([[6.1, 0.0, -20.0], [7.5, 0.0, -20.0]])
    for sig in (0.0, 3.0, 10.0):
        scan = Scan(book, AssociationConfig(pipe_track_gap_sigmas=sig), np.zeros((0, 3)), np.zeros((0, 3)))
        assert scan.excludes(7, beyond, c, d)
