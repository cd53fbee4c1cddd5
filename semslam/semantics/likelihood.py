"""The recogniser's confusion matrix as the observation model P(Z | X).

Rows of the confusion matrix are the true class X, columns the recognised class Z (counts, e.g.
the paper's SYN stage: held-out synthetic views). Row-normalised, with additive (Laplace)
smoothing so that no class is ever ruled out by a single observation, it is P(Z = z | X = x).
When the recogniser says ``z``, the likelihood vector over the true class is the column ``z``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np


class ConfusionModel:
    """P(Z | X) from a confusion matrix ``confusion[x, z]`` (counts) over ``classes``."""

    def __init__(
        self, confusion: np.ndarray | Sequence[Sequence[float]], classes: Sequence[str], smoothing: float = 1.0
    ):
        c = np.asarray(confusion, dtype=np.float64)
        if c.shape != (len(classes), len(classes)):
            raise ValueError(f"confusion matrix shape {c.shape} does not match {len(classes)} classes")
        if np.any(c < 0) or smoothing < 0:
            raise ValueError("confusion counts and smoothing must be non-negative")
        c = c + smoothing
        rows = c.sum(axis=1, keepdims=True)
        if np.any(rows == 0):
            raise ValueError("every true class needs at least one count (or smoothing > 0)")
        self.classes = list(classes)
        self.index = {k: i for i, k in enumerate(self.classes)}
        self.p_z_given_x = c / rows

    def likelihood(self, recognised: str) -> dict[str, float]:
        """P(Z = recognised | X = x) for every class x."""
        z = self.index[recognised]
        return {x: float(self.p_z_given_x[i, z]) for i, x in enumerate(self.classes)}

    def likelihood_soft(self, scores: Mapping[str, float]) -> dict[str, float]:
        """Likelihood of a soft recognition (``scores``: probability of each recognised class,
        summing to 1): the mixture Σ_z P(z | x) · scores[z]."""
        q = np.array([scores.get(z, 0.0) for z in self.classes], dtype=np.float64)
        if q.sum() <= 0:
            raise ValueError("recognition scores must have positive mass")
        lik = self.p_z_given_x @ (q / q.sum())
        return {x: float(v) for x, v in zip(self.classes, lik)}

    def to_dict(self) -> dict:
        return {"classes": self.classes, "p_z_given_x": self.p_z_given_x.tolist()}
