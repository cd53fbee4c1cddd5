"""What tells a pipe lying on the seabed from the seabed's own shapes (sand crests, mounds, stones).

A cylinder fit finds more than pipes on a natural seabed: a sand ripple's crest or a mound's flank
turns its normals like a pipe of a few cm radius, a stone's flank too. Off the ground nothing but
structure stands (the tank's pipes stand ≥ 9 cm clear of its floor), so only a segment lying on
the ground (its axis less than ``ground_clearance`` radii above the ground model) is tested, for
what a pipe has and those shapes lack:

* it is at most half buried: its axis lies at least ``min_axis_height`` radii above the ground
  around it (a crest fitted by a cylinder has its axis below the sand);
* its points cover the visible half of its circumference: the arc they span around the axis (5th
  to 95th percentile of their angles about the direction towards the sensor) is at least
  ``min_arc_deg`` (a crest or a stone's flank shows a shallow arc);
* with colour (an RGB cloud): it does not look like the ground around it, its median colour at
  least ``min_color_contrast`` (0-255 scale) from the ground's within ``color_reach`` of it.
"""

from __future__ import annotations

import numpy as np

from frontends.laser.config import PipeConfig
from frontends.laser.grid import row_dot
from frontends.laser.pipes import Pipe

_AXIS_SAMPLES = 9  # points along the axis where the ground's height is read


def arc_span_deg(pipe: Pipe, points: np.ndarray) -> float:
    """The arc (deg) the pipe's inliers span about its axis: the 5th to 95th percentile of their
    angles about the direction from the axis towards the sensor (at the origin)."""
    P = np.take(points, pipe.inliers, axis=0) - pipe.p
    radial = P - np.outer(P @ pipe.axis, pipe.axis)
    mid = 0.5 * (pipe.p + pipe.q)
    toward = -(mid - (mid @ pipe.axis) * pipe.axis)  # from the axis towards the sensor, across it
    toward /= max(np.linalg.norm(toward), 1e-12)
    side = np.cross(pipe.axis, toward)
    phi = np.degrees(np.arctan2(radial @ side, radial @ toward))
    lo, hi = np.percentile(phi, [5, 95])
    return float(hi - lo)


def axis_height(pipe: Pipe, ground) -> float | None:
    """Median height (m) of the pipe's axis above the ground model, None where it knows no ground."""
    t = np.linspace(0.0, pipe.length, _AXIS_SAMPLES)
    h = ground.height(pipe.p + np.outer(t, pipe.axis))
    h = h[np.isfinite(h)]
    return float(np.median(h)) if len(h) else None


def color_contrast(
    pipe: Pipe, seg_raw_indices, raw_points: np.ndarray, rgb: np.ndarray, on_ground_raw: np.ndarray, reach: float
) -> float | None:
    """Distance (0-255 scale) between the median colour of the pipe's raw points and that of the
    ground's raw points within ``reach`` of its axis segment; None when either has too few points."""
    own = seg_raw_indices(pipe.inliers)
    if len(own) < 10:
        return None
    P = raw_points - pipe.p
    t = P @ pipe.axis
    near = (t > -reach) & (t < pipe.length + reach)
    near &= row_dot(P, P) - t * t <= (pipe.radius + reach) ** 2
    ground = np.flatnonzero(near & on_ground_raw)
    if len(ground) < 10:
        return None
    return float(np.linalg.norm(np.median(rgb[own], axis=0) - np.median(rgb[ground], axis=0)))


def lies_like_a_pipe(pipe: Pipe, points: np.ndarray, ground, cfg: PipeConfig, contrast=None) -> bool:
    """Whether a segment passes the tests of a pipe lying on the ground (True for one standing clear
    of it, or where there is no ground model). ``contrast``: a callable giving the segment's colour
    contrast with the ground (:func:`color_contrast`), or None without colour."""
    if ground is None:
        return True
    h = axis_height(pipe, ground)
    if h is None or h >= cfg.ground_clearance * pipe.radius:
        return True
    if h < cfg.min_axis_height * pipe.radius:
        return False
    if arc_span_deg(pipe, points) < cfg.min_arc_deg:
        return False
    if contrast is not None and cfg.min_color_contrast > 0:
        c = contrast(pipe)
        if c is not None and c < cfg.min_color_contrast:
            return False
    return True
