"""The odometry's local map holds only the scans of its last ``map_window_s``: kiss-icp forgets by
distance alone, and a vehicle circling a structure never leaves its range, so without the window
the map would keep a loop-old copy of the scene placed with that loop's drift."""

import numpy as np

from frontends.odometry.config import OdometryConfig
from frontends.odometry.matcher import ScanMatcher

S = 1_000_000_000  # ns per s


def _box_surface(rng, centre, half, n):
    """``n`` points on the surface of an axis-aligned box."""
    p = rng.uniform(-1, 1, (n, 3)) * half
    axis = rng.integers(0, 3, n)
    p[np.arange(n), axis] = np.sign(rng.uniform(-1, 1, n)) * half[axis]
    return p + centre


def _scene(rng, marker: bool):
    """Boxes 2–5 m ahead of the sensor (its z axis), none holding a large plane; with ``marker`` a
    further box where no other lies."""
    centres = [(x, y, z) for x in (-1.0, 0.0, 1.0) for y in (-0.8, 0.8) for z in (3.0, 4.0)]
    parts = [_box_surface(rng, np.array(c), np.array([0.15, 0.2, 0.1]), 1500) for c in centres]
    if marker:
        parts.append(_box_surface(rng, np.array([1.8, 1.6, 2.2]), np.array([0.15, 0.15, 0.15]), 1500))
    return np.concatenate(parts)


def _marker_points_in_map(window_s: float) -> int:
    rng = np.random.default_rng(0)
    matcher = ScanMatcher(OdometryConfig.model_validate({"map_window_s": window_s}))
    assert matcher.start(_scene(rng, marker=True), np.eye(4), stamp=0)
    for t in (10, 20, 45):  # the scene seen again, without the marker
        reg = matcher.register(_scene(rng, marker=False), np.eye(4), stamp=t * S)
        assert reg.rejected is None and np.linalg.norm(reg.pose[:3, 3]) < 0.05  # resampled boxes: ICP within cm
    points = np.asarray(matcher.kiss.local_map.point_cloud())
    return int((np.linalg.norm(points - [1.8, 1.6, 2.2], axis=1) < 0.3).sum())


def test_scans_older_than_the_window_leave_the_map():
    assert _marker_points_in_map(window_s=100.0) > 20  # the first scan's marker is still mapped at 45 s
    assert _marker_points_in_map(window_s=30.0) == 0  # 45 s later, out of a 30 s window: gone
