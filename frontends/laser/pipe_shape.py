"""What tells a pipe lying on the seabed from the seabed's own shapes (sand crests, mounds, stones).

A cylinder fit finds more than pipes on a natural seabed: a sand ripple's crest or a mound's flank
turns its normals like a pipe of a few cm radius, a stone's flank too. Off the ground nothing but
structure stands (the tank's pipes stand ≥ 9 cm clear of its floor), so only a segment lying on
the ground (its underside less than ``ground_gap`` above the ground model) is tested, for
what a pipe has and those shapes lack:

* it is at most half buried: its axis lies at least ``min_axis_height`` radii above the ground
  around it (a crest fitted by a cylinder has its axis below the sand);
* its points cover the visible half of its circumference: the arc they span around the axis (5th
  to 95th percentile of their angles about the direction towards the sensor) is at least
  ``min_arc_deg`` (a crest or a stone's flank shows a shallow arc);
* it is straight along its axis: its surface does not bow towards the axis at the segment's
  ends (a stone's or a mound's top is a dome: a cylinder fitted to 0.15-0.3 m of it leaves its
  inliers' distance to the axis falling off towards both ends; :func:`bow`), by more than
  ``max_bow`` or ``bow_sigmas`` standard errors of that bow, whichever is larger;
* with colour (an RGB cloud), a segment shorter than ``color_max_length`` (a partial view, as long
  as a stone's top): it does not look like the ground around it, its median colour at least
  ``min_color_contrast`` (0-255 scale) from the ground's within ``color_reach`` of it. A longer
  straight cylinder is a pipe by its shape, however dull its colour in turbid water; so are the
  runs of one cylinder cut at a fitting (:meth:`Seabed.accept_runs`) when those that pass the
  geometric tests are that long together: one axis and one radius over that length, interrupted by
  a valve or a socket, which a stone's top does not have.
"""

from __future__ import annotations

import numpy as np

from frontends.laser.config import PipeConfig
from frontends.laser.grid import row_dot
from frontends.laser.pipes import Pipe

_AXIS_SAMPLES = 9  # points along the axis where the ground's height is read
_SAMPLE_STEPS = np.arange(float(_AXIS_SAMPLES))


def arc_span_deg(pipe: Pipe, points: np.ndarray) -> float:
    """The arc (deg) the pipe's inliers span about its axis: the 5th to 95th percentile of their
    angles about the direction from the axis towards the sensor (at the origin)."""
    P = points.take(pipe.inliers, axis=0) - pipe.p
    radial = P - np.outer(P @ pipe.axis, pipe.axis)
    mid = 0.5 * (pipe.p + pipe.q)
    toward = -(mid - (mid @ pipe.axis) * pipe.axis)  # from the axis towards the sensor, across it
    toward /= max(np.linalg.norm(toward), 1e-12)
    side = np.cross(pipe.axis, toward)
    phi = np.degrees(np.arctan2(radial @ side, radial @ toward))
    lo, hi = np.percentile(phi, [5, 95])
    return float(hi - lo)


def bow(pipe: Pipe, points: np.ndarray) -> tuple[float, float]:
    """(bow, its standard error) in metres: how far the pipe's inliers lie further from its axis in
    its middle than at its ends. The inliers' distance to the axis minus the radius is fitted by a
    parabola in the position along the axis, u ∈ [−1, 1] from end to end; the bow is minus its u²
    coefficient (positive for a dome, ~0 for a straight pipe); its standard error is that of the
    coefficient under the fit's own scatter (1.4826 × median absolute residual)."""
    P = points.take(pipe.inliers, axis=0) - pipe.p
    t = P @ pipe.axis
    residual = np.sqrt(np.maximum(row_dot(P, P) - t * t, 0.0)) - pipe.radius
    u = (t - 0.5 * pipe.length) / max(0.5 * pipe.length, 1e-9)
    if len(u) < 6:
        return 0.0, np.inf
    A = np.column_stack([np.ones_like(u), u, u * u])
    coef = np.linalg.lstsq(A, residual, rcond=None)[0]
    scatter = 1.4826 * float(np.median(np.abs(residual - A @ coef)))
    return float(-coef[2]), scatter * float(np.sqrt(max(np.linalg.pinv(A.T @ A)[2, 2], 0.0)))


def axis_height(pipe: Pipe, ground) -> float | None:
    """Median height (m) of the pipe's axis above the ground model, None where it knows no ground."""
    return axis_height_of(pipe.p, pipe.axis, pipe.length, ground)


def axis_height_of(p: np.ndarray, axis: np.ndarray, length: float, ground) -> float | None:
    """Median height (m) above the ground model of the axis from ``p`` along ``axis`` over
    ``length``, None where it knows no ground."""
    # np.linspace(0, length, 9)'s values (k × length / 8, the last exactly length) and np.outer's
    # products, without their Python overhead: this runs a few times per pipe segment
    t = _SAMPLE_STEPS * (length / (_AXIS_SAMPLES - 1))
    t[-1] = length
    h = ground.height(p + t[:, None] * axis)
    h = np.sort(h[np.isfinite(h)])
    if not len(h):
        return None
    # (np.median's value, by one sort of the 9 samples: np.median costs ~10 times more on so few,
    # and this runs about 3 times per pipe segment)
    k = len(h) // 2
    return float(h[k] if len(h) % 2 else (h[k - 1] + h[k]) / 2)


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


def lies_on_ground(axis_height: float, radius: float, cfg: PipeConfig) -> bool:
    """A cylinder whose axis lies ``axis_height`` above the ground lies on it: its underside is less
    than ``ground_gap`` above the ground."""
    return axis_height - radius < cfg.ground_gap


class Seabed:
    """What the pipe stage knows of the seabed under a scan: its ground model, the structure
    ``points``, and, with an RGB scan, the colour cue (the ground's raw points found once, when
    first needed). ``raw_index`` maps structure indices to raw point indices."""

    def __init__(self, ground, points: np.ndarray, cfg: PipeConfig, raw=None, rgb=None, raw_index=None):
        self.ground, self.points, self.cfg = ground, points, cfg
        self._raw, self._rgb, self._raw_index = raw, rgb, raw_index
        self._raw_ground: np.ndarray | None = None

    def on_or_unknown(self, c: np.ndarray, a: np.ndarray, r: float, t0: float, t1: float) -> bool:
        """Whether the cylinder (axis point c, unit a, radius r) between t0 and t1 along a lies on
        the ground (its underside less than ``ground_gap`` above it) or over unknown ground."""
        h = axis_height_of(c + t0 * a, a, t1 - t0, self.ground)
        return h is None or lies_on_ground(h, r, self.cfg)

    def _contrast(self, pipe: Pipe) -> float | None:
        if self._raw_ground is None:
            raw = self._raw
            finite = np.isfinite(raw).all(axis=1)
            self._raw_ground = np.zeros(len(raw), bool)
            self._raw_ground[finite] = self.ground.is_ground(raw[finite])
        return color_contrast(
            pipe, self._raw_index, self._raw, np.asarray(self._rgb, float), self._raw_ground, self.cfg.color_reach
        )

    def _colour(self) -> bool:
        return self._rgb is not None and self._raw is not None and self.cfg.min_color_contrast > 0

    def accept(self, pipe: Pipe, seen_length: float = 0.0, colour: bool = True) -> bool:
        """The tests of a pipe on the seabed (:func:`lies_like_a_pipe`), with colour when the scan has
        it (and ``colour``); ``seen_length``: the length of straight cylinder the segment is part of
        (see there)."""
        contrast = self._contrast if colour and self._colour() else None
        return lies_like_a_pipe(pipe, self.points, self.ground, self.cfg, contrast, seen_length)

    def accept_runs(self, runs: list[Pipe]) -> list[Pipe]:
        """The ``runs`` (the segments cut from one cylinder fit at its fittings, or at gaps too long to
        bridge: :func:`frontends.laser.pipes.split_at_fittings`) that pass the tests
        of a pipe on the seabed. Those that pass the geometric tests lie on one axis with one radius
        (one fit to all their points): the colour test judges them only when their lengths add up
        to less than ``color_max_length``, as it judges a lone segment by its own length."""
        if len(runs) < 2 or not self._colour():
            return [pipe for pipe in runs if self.accept(pipe)]
        shaped = [pipe for pipe in runs if lies_like_a_pipe(pipe, self.points, self.ground, self.cfg)]
        seen = float(sum(pipe.length for pipe in shaped))
        return [pipe for pipe in shaped if self.accept(pipe, seen)]


def lies_like_a_pipe(
    pipe: Pipe, points: np.ndarray, ground, cfg: PipeConfig, contrast=None, seen_length: float = 0.0
) -> bool:
    """Whether a segment passes the tests of a pipe lying on the ground (True for one standing clear
    of it, or where there is no ground model). ``contrast``: a callable giving the segment's colour
    contrast with the ground (:func:`color_contrast`), or None without colour; the colour test
    applies when both the segment and ``seen_length`` (the straight cylinder it is part of, m) are
    shorter than ``color_max_length``."""
    if ground is None:
        return True
    h = axis_height(pipe, ground)
    if h is not None and not lies_on_ground(h, pipe.radius, cfg):
        return True
    # on the ground, or where the scan's ground model knows no ground (a boulder's top, a strip
    # between stones): the tests of a pipe on the seabed, those that can be made
    if h is not None and h < cfg.min_axis_height * pipe.radius:
        return False
    if arc_span_deg(pipe, points) < cfg.min_arc_deg:
        return False
    if cfg.max_bow > 0:
        b, se = bow(pipe, points)
        if b > max(cfg.max_bow, cfg.bow_sigmas * se):
            return False
    if contrast is not None and cfg.min_color_contrast > 0 and max(pipe.length, seen_length) < cfg.color_max_length:
        c = contrast(pipe)
        if c is not None and c < cfg.min_color_contrast:
            return False
    return True
