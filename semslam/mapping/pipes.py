"""Pipe geometry both estimators' maps share: collinear segments and their merge within one scan, the
extent seen of a pipe (robust ends, cut at in-line objects), and in-line objects that keep collinear
pipes apart. Lines are given as a point c on them and a unit direction d; positions along a line are
measured along d from c."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from semslam.observations import LineObservation


def segment_axis(p: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, float]:
    d = q - p
    n = float(np.linalg.norm(d))
    return d / n, n


def collinear(p1, q1, p2, q2, max_angle: float, max_distance: float) -> bool:
    """Segments on one axis: directions within ``max_angle``, each one's endpoints within
    ``max_distance`` of the other's line, and a gap along the axis below ``max_distance``."""
    d1, l1 = segment_axis(p1, q1)
    d2, l2 = segment_axis(p2, q2)
    if np.arccos(min(1.0, abs(float(d1 @ d2)))) > max_angle:
        return False
    for a, d, pts in ((p1, d1, (p2, q2)), (p2, d2, (p1, q1))):
        for x in pts:
            r = x - a
            if np.linalg.norm(r - (r @ d) * d) > max_distance:
                return False
    s = sorted([(p2 - p1) @ d1, (q2 - p1) @ d1])
    gap = max(s[0] - l1, 0.0 - s[1], 0.0)
    return gap <= max_distance


def merge_collinear(
    observations: Sequence[LineObservation],
    max_angle: float,
    max_distance: float,
    separators: np.ndarray | None = None,
    separator_radius: float = 0.15,
    side_by_side: float = 0.08,
    members: bool = False,
) -> list[LineObservation] | list[tuple[LineObservation, list[int]]]:
    """Merge pipe segments of one batch that lie on one axis (the paper's 0.175 rad / 0.3 m).

    Union-find over collinear pairs; a merged segment spans the extreme projections of all its
    endpoints on the longest member's axis, each end keeping the covariance of the endpoint that
    produced it. Same sensor only (segments are in its frame). Two segments with an object of the
    batch (``separators``, N×3 in the sensor frame) on the axis between them stay apart, and so do two
    that overlap along the axis with their axes farther apart than ``side_by_side``: fragments of one
    pipe follow each other, they do not run side by side (parallel pipes of a rack, 15 cm apart, are
    collinear by the paper's distance). With ``members``: (segment, indices of the segments it stands
    for) pairs, in the order of their first member.
    """
    n = len(observations)
    seps = np.zeros((0, 3)) if separators is None else np.asarray(separators, float).reshape(-1, 3)
    parent = list(range(n))

    def find(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    # a screen of all pairs at once: directions further apart than max_angle (with a margin for rounding)
    # cannot be collinear, so the exact test below runs only on the pairs it leaves
    dirs = np.array([segment_axis(z.p, z.q)[0] for z in observations]).reshape(-1, 3)
    near_parallel = np.abs(dirs @ dirs.T) >= np.cos(max_angle + 1e-6)
    for i in range(n):
        for j in (np.flatnonzero(near_parallel[i, i + 1 :]) + i + 1).tolist():
            a, b = observations[i], observations[j]
            if a.sensor == b.sensor and collinear(a.p, a.q, b.p, b.q, max_angle, max_distance):
                d, length = segment_axis(a.p, a.q)
                seg = np.stack([b.p, b.q])
                r = seg - a.p
                s_b = r @ d
                overlap = min(length, float(s_b.max())) - max(0.0, float(s_b.min()))
                apart = np.linalg.norm(r - np.outer(s_b, d), axis=1).max()
                if overlap > 0 and apart > side_by_side:
                    continue
                if not object_between((0.0, length), seg, a.p, d, seps, separator_radius):
                    parent[find(i)] = find(j)
    groups: dict[int, list[int]] = {}
    for i in range(n):
        groups.setdefault(find(i), []).append(i)
    out = []
    for group in groups.values():
        out.append((_merged([observations[i] for i in group]), group))
    return out if members else [m for m, _ in out]


def _merged(obs: list[LineObservation]) -> LineObservation:
    """The segment spanning the members' extreme ends on the longest member's axis, each end keeping
    the covariance of the endpoint that produced it."""
    if len(obs) == 1:
        return obs[0]
    longest = max(obs, key=lambda o: np.linalg.norm(o.q - o.p))
    d, _ = segment_axis(longest.p, longest.q)
    ends = [(o.p, o.covariance[:3, :3]) for o in obs] + [(o.q, o.covariance[3:, 3:]) for o in obs]
    s = [float((e - longest.p) @ d) for e, _ in ends]
    lo, hi = ends[int(np.argmin(s))], ends[int(np.argmax(s))]
    cov = np.zeros((6, 6))
    cov[:3, :3], cov[3:, 3:] = lo[1], hi[1]
    return LineObservation(
        stamp=longest.stamp,
        sensor=longest.sensor,
        p=lo[0],
        q=hi[0],
        covariance=cov,
        radius=longest.radius,
        truth_id=longest.truth_id,
    )


def object_between(
    seen: tuple[float, float],
    seg: np.ndarray,
    c: np.ndarray,
    d: np.ndarray,
    objects: np.ndarray,
    radius: float,
    margin: float = 0.1,
) -> bool:
    """True when an object lies on the line (c, d) between the stretch ``seen`` (axial interval)
    and the segment ``seg`` (2×3), on the segment's side: collinear pipes joined by an in-line part (a
    valve, a socket) are different pipes. ``objects`` N×3 in the frame of c, d; ``radius`` how close to
    the line an object must be; ``margin`` how far into either stretch the object may reach, so that
    two fits overlapping by less than it (a laser fit runs a few cm into a socket) at an object are
    still apart."""
    if len(objects) == 0:
        return False
    r = np.asarray(objects, float).reshape(-1, 3) - c
    s_obj = r @ d
    on_line = np.linalg.norm(r - s_obj[:, None] * d, axis=1) < radius
    if not on_line.any():
        return False
    a, b = seen
    s = (np.asarray(seg) - c) @ d
    if s.mean() > 0.5 * (a + b):  # the segment lies after the seen stretch (or reaches beyond its end)
        lo, hi = b - margin, s.min() + margin
    else:  # ... or before it
        lo, hi = s.max() - margin, a + margin
    return bool(np.any(on_line & (s_obj > lo) & (s_obj < hi)))


def cut_at_objects(
    seen: tuple[float, float],
    c: np.ndarray,
    d: np.ndarray,
    objects: np.ndarray,
    radius: float,
    middle: float,
    margin: float = 0.05,
    depths: np.ndarray | None = None,
) -> tuple[float, float]:
    """The stretch ``seen`` of the line (c, d) (positions along d from c) cut at the objects (N×3,
    {W}) within ``radius`` of the line, keeping the side that holds ``middle`` (the median of the
    views' middles). An object cuts at its centre when that lies more than ``margin`` inside; one
    with a port depth (``depths``, N; 0: unknown) cuts where the pipe enters it, at the port mouth
    ``depth`` before its centre, wherever that lies inside: the front-end's segments run on into a
    fitting's socket, which has the pipe's shape, and would put the pipe's end at the fitting's centre."""
    lo, hi = seen
    r = np.asarray(objects, float).reshape(-1, 3) - c
    s = r @ d
    depth = np.zeros(len(s)) if depths is None else np.asarray(depths, float)
    on = np.linalg.norm(r - s[:, None] * d, axis=1) < radius
    if not on.any():  # nothing on the line cuts it
        return lo, hi
    slack = np.where(depth > 0, 0.0, margin)
    face_above, face_below = s - depth, s + depth
    above = on & (s > middle) & (face_above > lo + slack) & (face_above < hi - slack)
    below = on & (s <= middle) & (face_below > lo + slack) & (face_below < hi - slack)
    a = float(face_below[below].max()) if below.any() else lo
    b = float(face_above[above].min()) if above.any() else hi
    return (a, b) if b > a else (lo, hi)


def robust_ends(lo: np.ndarray, hi: np.ndarray, window: float) -> tuple[float, float]:
    """A pipe's ends along its axis from every view's ends (lo, hi), robust to endpoint noise.

    Each view sees a stretch inside the pipe, its ends noisy along the axis (σ). Views that saw the
    real end put their endpoint around it, clipped views lie further in, and the extreme one is
    biased outwards by the noise (by about 3σ over a few hundred views), as is a mean of the ends
    near it. Each end is the median of the view ends within ``window`` (6σ) of the extreme one:
    the views around the real end, centred on it."""
    lo_min, hi_max = float(lo.min()), float(hi.max())
    a = small_median(lo[lo <= lo_min + window])
    b = small_median(hi[hi >= hi_max - window])
    return (a, b) if b > a else (lo_min, hi_max)


def small_median(v: np.ndarray) -> float:
    """np.median of a small 1-D array, without its per-call overhead."""
    v = np.sort(v)
    n = len(v)
    return float(v[n // 2]) if n % 2 else 0.5 * float(v[n // 2 - 1] + v[n // 2])


def point_segment_distance(pts: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance of each point (N×3) from the segment a–b."""
    ab = b - a
    s = np.clip((pts - a) @ ab / max(float(ab @ ab), 1e-12), 0.0, 1.0)
    return np.linalg.norm(pts - (a + s[:, None] * ab), axis=1)


def segment_matches_line(
    seg: np.ndarray, c: np.ndarray, d: np.ndarray, seen: np.ndarray, max_angle, max_dist, gap
) -> bool:
    """A world segment (2,3) on the line (c, d): angle, perpendicular offsets and extent overlap."""
    u = seg[1] - seg[0]
    u /= np.linalg.norm(u)
    if np.arccos(min(1.0, abs(float(u @ d)))) > max_angle:
        return False
    r = seg - c
    perp = r - np.outer(r @ d, d)
    if np.linalg.norm(perp, axis=1).max() > max_dist:
        return False
    s = r @ d
    s_seen = (seen - c) @ d
    return not (s.max() < s_seen.min() - gap or s.min() > s_seen.max() + gap)
