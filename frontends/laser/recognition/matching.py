"""Matching a descriptor against the view database (Himri et al. 2018): chi-square nearest
neighbour, and an RBF support-vector machine (scikit-learn), with leave-one-out evaluation.

The SVM itself lives in ``svm.py`` (scikit-learn, imported only when an SVM is made).

The chi-square distance between histograms a and b is ½ Σ (a − b)² / (a + b) over the bins where
a + b > 0. For CVFH, whose views carry several descriptors, the distance between two views is the
smallest over their pairs of descriptors.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np


def principal_extents(cloud: np.ndarray) -> np.ndarray:
    """Standard deviations (m) of a cloud along its principal axes, largest first (3,).

    A metric size cue, invariant to rotation and translation. ESF and VFH are scale-free by
    design (PCL scales the cloud to a unit sphere), but CAD models and laser clouds are metric,
    and the fittings of the tank differ in size as much as in shape.
    """
    c = np.asarray(cloud, dtype=np.float64)
    c = c - c.mean(axis=0)
    ev = np.linalg.eigvalsh(c.T @ c / max(len(c), 1))[::-1]
    return np.sqrt(np.maximum(ev, 1e-10))


def size_distances(query: np.ndarray, database: np.ndarray) -> np.ndarray:
    """L1 distance between log principal extents (query 3 or Q×3, database V×3)."""
    q = np.log(np.atleast_2d(query))
    out = np.abs(q[:, None, :] - np.log(database)[None, :, :]).sum(axis=2)
    return out[0] if np.ndim(query) == 1 else out


class Chi2Index:
    """A database of histograms (V×D rows, non-negative) laid out for chi-square queries.

    Where the query's bin is empty, (a − b)²/(a + b) is just the view's b; so a query costs one
    pass over its own non-empty bins only (a few hundred of ESF's 640, read as contiguous rows of
    the transposed database) plus the rest of each view's mass (its total minus those bins),
    instead of a V×D pass with a division per element. The totals are summed in the same order as
    the query's bins, so that a histogram's distance to itself is exactly 0.
    """

    def __init__(self, database: np.ndarray):
        x = np.asarray(database, dtype=np.float64)
        self.bins_by_view = np.ascontiguousarray(x.T)  # D×V: all views
        self.views = np.ascontiguousarray(x)  # V×D: a few views (their rows, then the query's bins)
        self.row_sums = self.bins_by_view.sum(axis=0)

    def __len__(self) -> int:
        return len(self.row_sums)

    def distances(self, query: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray:
        """Chi-square distances (Q×V, or V for one query) from the query rows to every database
        row, or to the rows ``rows`` only."""
        q = np.atleast_2d(np.asarray(query, dtype=np.float64))
        sums = self.row_sums if rows is None else self.row_sums[rows]
        out = np.empty((len(q), len(sums)))
        for k, qk in enumerate(q):  # one query (object) at a time: its own non-empty bins
            nz = np.flatnonzero(qk > 0)
            xs = self.bins_by_view[nz] if rows is None else self.views[rows][:, nz].T
            qs = qk[nz][:, None]
            out[k] = 0.5 * (((qs - xs) ** 2 / (qs + xs)).sum(axis=0) + (sums - xs.sum(axis=0)))
        return out[0] if np.ndim(query) == 1 else out


def chi2_distances(query: np.ndarray, database: np.ndarray) -> np.ndarray:
    """Chi-square distances (Q×V, or V for one query) between query rows and database rows:
    ½ Σ (a − b)² / (a + b) over the bins where a + b > 0 (see :class:`Chi2Index`)."""
    return Chi2Index(database).distances(query)


def set_distances(query: np.ndarray, database: Sequence[np.ndarray]) -> np.ndarray:
    """Distance from a set of descriptors (R×D) to each database set: the closest pair's chi-square."""
    flat = np.concatenate(database)
    owner = np.repeat(np.arange(len(database)), [len(d) for d in database])
    d = chi2_distances(np.atleast_2d(query), flat).min(axis=0)
    out = np.full(len(database), np.inf)
    np.minimum.at(out, owner, d)
    return out


class ChiSquareNN:
    """1-nearest-neighbour classifier under the chi-square distance (scikit-learn-like API)."""

    def fit(self, X: np.ndarray, y: Sequence[str]) -> ChiSquareNN:
        self.X_ = np.asarray(X, dtype=np.float64)
        self.index_ = Chi2Index(self.X_)
        self.y_ = np.asarray(y)
        self.classes_ = np.unique(self.y_)
        return self

    def kneighbors(self, Q: np.ndarray, k: int = 1) -> tuple[np.ndarray, np.ndarray]:
        d = self.index_.distances(np.atleast_2d(Q))
        idx = np.argsort(d, axis=1)[:, :k]
        return np.take_along_axis(d, idx, axis=1), idx

    def predict(self, Q: np.ndarray) -> np.ndarray:
        _, idx = self.kneighbors(Q)
        return self.y_[idx[:, 0]]

    def class_distances(self, q: np.ndarray) -> dict[str, float]:
        """Distance from one query to the nearest view of every class."""
        d = self.index_.distances(q)
        return {str(c): float(d[self.y_ == c].min()) for c in self.classes_}


def svm_features(hist: np.ndarray, extents: np.ndarray | None = None) -> np.ndarray:
    """SVM inputs: square-rooted histograms (Hellinger's map tames the dominant bins), then the log
    principal extents when a size cue is wanted."""
    x = np.sqrt(np.atleast_2d(hist))
    return x if extents is None else np.hstack([x, np.log(np.atleast_2d(extents))])


def make_svm(C: float = 10.0, gamma: str | float = "scale", n_size: int = 0, size_gain: float = 16.0):
    """An RBF SVM on standardised features (see :func:`svm_features`); the last ``n_size``
    columns (the size cue) are up-weighted by ``size_gain`` after standardisation."""
    # scikit-learn imported only here: ~1.2 s of a front-end process's start-up otherwise paid by
    # the default chi-square NN recogniser, which never uses it.
    from frontends.laser.recognition.svm import make_svm as _make_svm

    return _make_svm(C, gamma, n_size, size_gain)


def leave_one_out(
    make: Callable[[], object], X: np.ndarray, y: Sequence[str], groups: Sequence | None = None
) -> np.ndarray:
    """Leave-one-out predictions: each sample classified by a model fitted on all the others (or,
    with ``groups``, on all the other groups — e.g. leave one model out)."""
    X = np.asarray(X)
    y = np.asarray(y)
    g = np.arange(len(y)) if groups is None else np.asarray(groups)
    pred = np.empty(len(y), dtype=y.dtype)
    for grp in np.unique(g):
        test = g == grp
        clf = make().fit(X[~test], y[~test])
        pred[test] = clf.predict(X[test])
    return pred
