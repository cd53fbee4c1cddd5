"""What has been seen of a pipe: the ends of every view of it, in {W}, with their along-axis σ.

The saved ends are projected onto the line as it is estimated now whenever the extent is used, so
they follow every update of the line. The pipe's ends are a noise-robust extreme of them
(:func:`semslam.mapping.pipes.robust_ends`), cut at the mapped in-line objects
(:func:`~semslam.mapping.pipes.cut_at_objects`). A line is given as a point c on it and its unit
direction d; positions along it are measured along d from c.
"""

from __future__ import annotations

import numpy as np

from semslam.mapping.pipes import cut_at_objects, robust_ends, small_median
from semslam.observations import LineObservation


def along_sigma(z: LineObservation) -> float:
    """Endpoint σ along the segment, from its 6×6 covariance (the mean of both ends' variances)."""
    d = (z.q - z.p) / np.linalg.norm(z.q - z.p)
    C = np.asarray(z.covariance)
    return float(np.sqrt(0.5 * (d @ C[:3, :3] @ d + d @ C[3:, 3:] @ d)))


def track_gap(view: LineObservation, seen: list[LineObservation], extent_gap: float, n_sigma: float) -> float:
    """How far along the axis ``view`` may lie beyond what a tentative pipe track's views ``seen`` saw
    and still continue it: the mapped pipes' ``extent_gap``, or ``n_sigma`` σ of the gap where the ends
    are less certain along the axis than that allows (the view's σ and the largest of the track's)."""
    if n_sigma <= 0:
        return extent_gap
    sigma = float(np.hypot(along_sigma(view), max(along_sigma(z) for z in seen)))
    return max(extent_gap, n_sigma * sigma)


def off_axis(points: np.ndarray, c: np.ndarray, d: np.ndarray) -> float:
    """The largest distance of the points (N×3) from the line (c, d)."""
    r = np.asarray(points) - c
    return float(np.linalg.norm(r - np.outer(r @ d, d), axis=1).max())


CROSSING_M = 0.05  # how far past an object's centre, both ways, a view must reach to run across it
MEMO_LINES = 16  # lines (and cuts) an extent remembers: a scan asks of a pipe along a few lines only


class PipeExtent:
    """The views of one pipe (ends in {W}) and what they say about where the pipe is along its line.
    What was computed for a line (and for a set of cutting objects) is kept until a view is added, so
    that one scan's checks, which ask of each pipe along its own line many times, compute it once."""

    def __init__(self):
        self._pts = np.zeros((8, 2, 3))  # (2, 3) per view, in a buffer that grows by doubling
        self._sig = np.zeros(8)
        self._k = 0
        self._lines: dict[bytes, tuple] = {}  # line key → (view count, robust interval, views' median middle)
        self._cuts: dict[tuple, tuple] = {}  # (line key, cutters, radius, depths) → (view count, interval)
        self._centre: tuple | None = None  # (view count, centre)
        self._w: tuple | None = None  # (view count, 6 × median σ)

    def __len__(self) -> int:
        return self._k

    def add(self, ends_W: np.ndarray, sigma: float) -> None:
        """One view: its two ends in {W} and their along-axis σ."""
        if self._k == len(self._sig):
            self._pts = np.concatenate([self._pts, np.zeros_like(self._pts)])
            self._sig = np.concatenate([self._sig, np.zeros_like(self._sig)])
        self._pts[self._k] = ends_W
        self._sig[self._k] = sigma
        self._k += 1

    def merge(self, other: PipeExtent) -> None:
        for k in range(other._k):
            self.add(other._pts[k], other._sig[k])

    def centre(self) -> np.ndarray:
        """Mean of the saved view ends in {W}: a point near the pipe, inside what was seen of it."""
        if self._centre is None or self._centre[0] != self._k:
            self._centre = (self._k, self._pts[: self._k].reshape(-1, 3).mean(axis=0))
        return self._centre[1]

    def _positions(self, c: np.ndarray, d: np.ndarray) -> np.ndarray:
        """Every view's two ends along the line (c, d), K×2 (one matrix-vector product over the ends:
        numpy's stacked one costs twice as much, same numbers)."""
        return ((self._pts[: self._k] - c).reshape(-1, 3) @ d).reshape(-1, 2)

    def outer(self, c: np.ndarray, d: np.ndarray) -> tuple[float, float]:
        """The extreme view ends along the line (every view's, noise included)."""
        s = self._positions(c, d)
        return float(s.min()), float(s.max())

    def interval(
        self,
        c: np.ndarray,
        d: np.ndarray,
        cutters: np.ndarray | None = None,
        radius: float = 0.0,
        depths: np.ndarray | None = None,
    ) -> tuple[float, float]:
        """Where the pipe (c, d) was seen, robust to endpoint noise; cut at the mapped objects
        ``cutters`` (N×3, {W}) within ``radius`` of the line inside it, keeping the side that holds
        most of the views (at their port mouths where ``depths`` gives them, see
        :func:`~semslam.mapping.pipes.cut_at_objects`)."""
        line = _line_key(c, d)
        out, middle = self._along(line, c, d)
        if cutters is None or not len(cutters):
            return out
        cutters = np.ascontiguousarray(cutters, float)
        key = (line, cutters.tobytes(), float(radius), None if depths is None else np.asarray(depths, float).tobytes())
        memo = self._cuts.get(key)
        if memo is None or memo[0] != self._k:
            memo = (self._k, cut_at_objects(out, c, d, cutters, radius, middle, depths=depths))
            _remember(self._cuts, key, memo)
        return memo[1]

    def _along(self, line: bytes, c: np.ndarray, d: np.ndarray) -> tuple[tuple[float, float], float]:
        """The robust interval on the line (c, d) and the median of the views' middles along it."""
        memo = self._lines.get(line)
        if memo is not None and memo[0] == self._k:
            return memo[1], memo[2]
        s = self._positions(c, d)  # (K, 2)
        lo, hi = _ends_along(s)
        if self._w is None or self._w[0] != self._k:
            self._w = (self._k, 6.0 * small_median(self._sig[: self._k]))
        memo = (self._k, robust_ends(lo, hi, self._w[1]), small_median((s[:, 0] + s[:, 1]) / 2))  # the mean of each row
        _remember(self._lines, line, memo)
        return memo[1], memo[2]

    def ends(
        self,
        c: np.ndarray,
        d: np.ndarray,
        cutters: np.ndarray | None = None,
        radius: float = 0.0,
        depths: np.ndarray | None = None,
    ) -> np.ndarray:
        """The pipe's two ends on the line (c, d), 2×3 (see :meth:`interval`)."""
        a, b = self.interval(c, d, cutters, radius, depths)
        return np.array([c + a * d, c + b * d])

    def overlap_fraction(
        self, ends_b: np.ndarray, c: np.ndarray, d: np.ndarray, cutters: np.ndarray | None = None, radius: float = 0.0
    ) -> float:
        """Length shared by the seen extent (cut at ``cutters``, see :meth:`interval`) and the segment
        ends_b along the line (c, d), over the shorter one's length."""
        a0, a1 = self.interval(c, d, cutters, radius)
        s = (ends_b - c) @ d
        b0, b1 = float(s.min()), float(s.max())
        shorter = min(a1 - a0, b1 - b0)
        return max(0.0, min(a1, b1) - max(a0, b0)) / shorter if shorter > 0 else 0.0

    def seen_span(
        self, c: np.ndarray, d: np.ndarray, separators: np.ndarray, cutters: np.ndarray, radius: float
    ) -> tuple[float, float]:
        """What was seen of the pipe (c, d) when a segment's place beside it is judged: its robust interval cut
        at the mapped objects ``cutters`` and at the tentative ones of ``separators`` that no view runs across
        (:class:`Lines` of this one pipe)."""
        lo, hi = Lines([self], c, d, separators, cutters, radius).spans[0]
        return float(lo), float(hi)

    def excludes(
        self,
        ends_W: np.ndarray,
        c: np.ndarray,
        d: np.ndarray,
        separators: np.ndarray,
        cutters: np.ndarray,
        radius: float,
        max_gap: float,
    ) -> bool:
        """A segment (2×3, {W}) cannot be this pipe (c, d): it lies more than ``max_gap`` beyond what
        was seen of it (:meth:`seen_span`: cut at the mapped objects ``cutters``, a pipe seen through a socket
        or a tee must not keep the views of the pipe beyond it), or an object (``separators``: mapped and
        tentative) lies between them (:meth:`Lines.excludes` of this one pair)."""
        lines = Lines([self], c, d, separators, cutters, radius)
        return bool(lines.excludes(np.zeros(1, int), np.asarray(ends_W, float)[None], max_gap)[0])


def _ends_along(s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each view's lower and upper end along the line from its two ends' positions (K×2): the
    ``min`` / ``max`` of each row, as two element-wise comparisons (numpy's reduction over an axis of
    two costs ~6× as much)."""
    return np.minimum(s[:, 0], s[:, 1]), np.maximum(s[:, 0], s[:, 1])


def _line_key(c: np.ndarray, d: np.ndarray) -> bytes:
    """The exact numbers of a line (c, d): what the memos of an extent are kept by."""
    return np.asarray(c, np.float64).tobytes() + np.asarray(d, np.float64).tobytes()


def _remember(memo: dict, key, value) -> None:
    """Keep ``value`` under ``key``, forgetting everything once ``MEMO_LINES`` entries are kept (the
    lines of earlier scans are not asked again: every update moves them)."""
    if len(memo) >= MEMO_LINES and key not in memo:
        memo.clear()
    memo[key] = value


# ---------------------------------------------------------------------------------------------- many pipes at once
# A scan asks the rules of many (pipe, segment) pairs: :class:`Lines` is the one implementation of the rules, for
# every pair of the scan at once (:meth:`PipeExtent.seen_span` and :meth:`PipeExtent.excludes` are it for one): the
# pipes' views padded to the most views of any pipe (masked where a pipe has fewer), the objects as one set for
# every line. A lone pipe gets the numbers it got pair by pair, to the bit: every step is element-wise but the
# positions along a line, and those are stacked products that numpy hands to BLAS item by item as it hands one
# pipe's (:func:`stacked_dots`).


class Lines:
    """What the pipe rules find of a set of lines (pipe p: ``extents[p]`` on the line c[p], d[p]) given the
    objects that keep collinear pipes apart (``separators``, N×3: mapped and tentative) and those that cut a
    pipe's extent (``cutters``, M×3: mapped): ``spans`` (P×2), what was seen of each pipe when a segment's place
    beside it is judged (its robust interval, :func:`~semslam.mapping.pipes.robust_ends`, cut at the cutters and
    at the separators on the line that no view runs across, :func:`~semslam.mapping.pipes.cut_at_objects`);
    ``on`` (P×N), the separators within ``radius`` of each line; ``between`` (P×N), their positions along the
    line as :func:`~semslam.mapping.pipes.object_between` finds them (from the separators on the line alone).

    A separator no view runs across (from ``CROSSING_M`` before its centre to ``CROSSING_M`` beyond it) cuts:
    where the views meet only across an in-line object, they may be of two pipes, joined by it. A view that
    reached past an in-line part before the part was seen (seed 34's pipe 3: a view of the next pipe 0.18 m
    beyond the seen end, the valve between them seen a scan later) must not make the two pipes one; a pipe that
    runs on through an object (a valve on a run, a false object view) has views across it."""

    def __init__(
        self,
        extents: list[PipeExtent],
        c: np.ndarray,
        d: np.ndarray,
        separators: np.ndarray,
        cutters: np.ndarray,
        radius: float,
    ):
        P = len(extents)
        self.c = c = np.ascontiguousarray(c, float).reshape(P, 3)
        self.d = d = np.ascontiguousarray(d, float).reshape(P, 3)
        seps = np.asarray(separators, float).reshape(-1, 3)
        cut = np.asarray(cutters, float).reshape(-1, 3)
        N, M = len(seps), len(cut)
        ks = np.array([len(e) for e in extents], int)
        if P and ks.min() == 0:  # a pipe without views has no extent
            raise ValueError("a pipe without views has no seen extent")
        K = int(ks.max()) if P else 1
        pts = np.zeros((P, K, 2, 3))
        sig = np.zeros((P, K))
        for p, e in enumerate(extents):
            pts[p, : e._k] = e._pts[: e._k]
            sig[p, : e._k] = e._sig[: e._k]
        views = np.arange(K) < ks[:, None]  # (P, K)
        s = stacked_dots((pts - c[:, None, None, :]).reshape(P, 2 * K, 3), d).reshape(P, K, 2)  # as _positions
        lo, hi = _ends_along_rows(s)

        # robust ends (robust_ends, with the window of PipeExtent._along) and the views' median middle
        w = 6.0 * _row_medians(sig, views)
        lo_min = np.where(views, lo, np.inf).min(axis=1)
        hi_max = np.where(views, hi, -np.inf).max(axis=1)
        a = _row_medians(lo, views & (lo <= (lo_min + w)[:, None]))
        b = _row_medians(hi, views & (hi >= (hi_max - w)[:, None]))
        ok = b > a
        out_lo, out_hi = np.where(ok, a, lo_min), np.where(ok, b, hi_max)
        middle = _row_medians((s[..., 0] + s[..., 1]) / 2, views)

        # every object along every line: as a matrix of several rows gives it, and as a lone row does
        objects = np.vstack([seps, cut])
        r = objects[None, :, :] - c[:, None, :]  # (P, N + M, 3)
        several = stacked_dots(np.concatenate([r, np.zeros((P, 1, 3))], axis=1), d)[:, : N + M]  # ≥ 2 rows: gemv
        alone = stacked_dots(r.reshape(-1, 1, 3), np.repeat(d, N + M, axis=0)).reshape(P, N + M) if N + M else several
        self.r, self.several, self.alone = r, several, alone

        # the separators on the line that no view runs across cut too
        s_sep = (several if N >= 2 else alone)[:, :N]
        self.on = on = self._near(r[:, :N], s_sep, radius)
        crossed = (
            views[:, :, None]
            & (lo[:, :, None] < s_sep[:, None, :] - CROSSING_M)
            & (hi[:, :, None] > s_sep[:, None, :] + CROSSING_M)
        ).any(axis=1)
        cuts = np.concatenate([on & ~crossed, np.ones((P, M), bool)], axis=1)  # (P, N + M)
        n_cuts = cuts.sum(axis=1)

        # cut_at_objects (no port depths: the slack is its margin, the faces the centres)
        s_cut = np.where((n_cuts >= 2)[:, None], several, alone)
        on_cut = cuts & self._near(r, s_cut, radius)
        slack = 0.05
        face_above, face_below = s_cut - 0.0, s_cut + 0.0
        inside_above = (face_above > (out_lo + slack)[:, None]) & (face_above < (out_hi - slack)[:, None])
        inside_below = (face_below > (out_lo + slack)[:, None]) & (face_below < (out_hi - slack)[:, None])
        above = on_cut & (s_cut > middle[:, None]) & inside_above
        below = on_cut & (s_cut <= middle[:, None]) & inside_below
        ca = np.where(below.any(axis=1), np.where(below, face_below, -np.inf).max(axis=1, initial=-np.inf), out_lo)
        cb = np.where(above.any(axis=1), np.where(above, face_above, np.inf).min(axis=1, initial=np.inf), out_hi)
        cut_ok = cb > ca
        self.spans = np.stack([np.where(cut_ok, ca, out_lo), np.where(cut_ok, cb, out_hi)], axis=1)

        # object_between: the separators on the line, along it as a matrix of only them gives it
        n_on = on.sum(axis=1)
        self.between = np.where((n_on >= 2)[:, None], several[:, :N], alone[:, :N])
        self.between_on = on & self._near(r[:, :N], self.between, radius)
        self.radius = radius

    def _near(self, r: np.ndarray, s: np.ndarray, radius: float) -> np.ndarray:
        """Which objects (offsets r, P×n×3, at positions s along the lines) lie within ``radius`` of them."""
        return np.linalg.norm(r - s[:, :, None] * self.d[:, None, :], axis=2) < radius

    def excludes(self, line: np.ndarray, segments: np.ndarray, max_gap: float, margin: float = 0.1) -> np.ndarray:
        """For each segment q (Q×2×3, {W}) against line ``line[q]``: the segment cannot be that pipe: it lies more
        than ``max_gap`` beyond the seen stretch (:attr:`spans`), or a separator on the line lies between them
        (reaching less than ``margin`` into either: a laser fit runs a few cm into a socket)."""
        line = np.asarray(line, int)
        c, d = self.c[line], self.d[line]
        s = stacked_dots(np.ascontiguousarray(segments, float).reshape(-1, 2, 3) - c[:, None, :], d)  # (Q, 2)
        a, b = self.spans[line, 0], self.spans[line, 1]
        s_min, s_max = np.minimum(s[:, 0], s[:, 1]), np.maximum(s[:, 0], s[:, 1])
        gap = np.maximum(np.maximum(0.0, s_min - b), a - s_max)
        after = (s[:, 0] + s[:, 1]) / 2 > 0.5 * (a + b)  # the segment after the seen stretch (object_between)
        lo = np.where(after, b - margin, s_max - margin)
        hi = np.where(after, s_min + margin, a + margin)
        between = self.between[line]
        sep = (self.between_on[line] & (between > lo[:, None]) & (between < hi[:, None])).any(axis=1)
        return (gap > max_gap) | sep


def stacked_dots(r: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Each r[p] @ d[p] (r: P×n×3, d: P×3), the numbers numpy gives for the lone n×3 matrix: a stacked product
    that numpy hands to BLAS item by item (gemv for n ≥ 2 rows, dot for one), where an element-wise sum or
    einsum rounds otherwise."""
    return np.matmul(np.ascontiguousarray(r), np.ascontiguousarray(d)[:, :, None])[:, :, 0]


def _ends_along_rows(s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_ends_along` of each pipe's views (P×K×2)."""
    return np.minimum(s[..., 0], s[..., 1]), np.maximum(s[..., 0], s[..., 1])


def _row_medians(v: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Each row's :func:`~semslam.mapping.pipes.small_median` of its masked values (P×K; NaN where a row
    has none)."""
    n = mask.sum(axis=1)
    srt = np.sort(np.where(mask, v, np.inf), axis=1)
    rows = np.arange(len(v))
    upper = srt[rows, np.minimum(n // 2, v.shape[1] - 1)]
    lower = srt[rows, np.maximum(n // 2 - 1, 0)]
    return np.where(n == 0, np.nan, np.where(n % 2 == 1, upper, 0.5 * (lower + upper)))
