"""The RBF support-vector machine of the recogniser (scikit-learn), apart from ``matching.py`` so
that scikit-learn is imported only when an SVM is made (see :func:`matching.make_svm`)."""

from __future__ import annotations

import numpy as np
from sklearn.base import BaseEstimator, TransformerMixin
from sklearn.pipeline import make_pipeline
from sklearn.preprocessing import StandardScaler
from sklearn.svm import SVC


class _TailGain(TransformerMixin, BaseEstimator):
    """Multiplies the last ``n`` (standardised) columns by ``gain``: lets 3 size inputs weigh
    against hundreds of histogram bins in the RBF kernel."""

    def __init__(self, n: int = 0, gain: float = 1.0):
        self.n = n
        self.gain = gain

    def fit(self, X, y=None):
        return self

    def transform(self, X):
        X = np.array(X, dtype=np.float64, copy=True)
        if self.n:
            X[:, -self.n :] *= self.gain
        return X


def make_svm(C: float = 10.0, gamma: str | float = "scale", n_size: int = 0, size_gain: float = 16.0):
    """An RBF SVM on standardised features (see :func:`matching.svm_features`); the last ``n_size``
    columns (the size cue) are up-weighted by ``size_gain`` after standardisation."""
    return make_pipeline(StandardScaler(), _TailGain(n_size, size_gain), SVC(kernel="rbf", C=C, gamma=gamma))
