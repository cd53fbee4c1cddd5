"""One variable's marginal covariance from iSAM2, cheaply when the variable is in the root clique.

The graph back-end needs the newest keyframe pose's marginal after every update (association gate,
online ±2σ, NEES). iSAM2 orders the keys of new factors last, so that pose is a frontal of the root
clique, whose conditional p(F) has no parents: it is the joint marginal of the root's frontals, with
information RᵀR. ``ISAM2.marginalCovariance`` re-eliminates that whole conditional down to the one
variable, and a root is large where every landmark is seen from every pose (the tank's: see
experiments/estimators/README.md). From R itself, Σ_jj = YᵀY with Rᵀ Y = E_j, one triangular
solve (rows of Y before j's block are zero, so only R's trailing block is used).

The Python wrapper does not expose the Bayes tree's root. ``marginalFactor(j, function)`` calls the
elimination ``function`` first with the root conditional alone (after the root's empty separator
marginal); the probe below takes it there and stops the elimination by raising. Anything else (j
not in the root, a constrained model, an unknown symbol) falls back to ``marginalCovariance``.
"""

from __future__ import annotations

import gtsam
import numpy as np
from scipy.linalg.lapack import dtrtrs

# Tangent dimension of every symbol character the graph back-end uses (keyframe pose, velocity,
# heading bias and its rate, gyro bias, object point, pipe line, structure pose).
KEY_DIM = {ord("x"): 6, ord("v"): 3, ord("b"): 1, ord("d"): 1, ord("g"): 3, ord("l"): 3, ord("p"): 4, ord("s"): 6}


class _Caught(Exception):
    """Raised by the probe to stop iSAM2's elimination once it has the root conditional."""


def _root_conditional(isam: gtsam.ISAM2, key: int) -> gtsam.GaussianConditional | None:
    box = []

    def probe(graph, ordering):
        box.append(graph)
        raise _Caught

    try:
        isam.marginalFactor(key, probe)
    except _Caught:
        pass
    if not box or box[0].size() != 1:
        return None
    c = box[0].at(0)
    return c if isinstance(c, gtsam.GaussianConditional) else None


def root_marginal_covariance(isam: gtsam.ISAM2, key: int) -> np.ndarray | None:
    """Marginal covariance of ``key`` from the root clique's conditional; None if ``key`` is not
    a frontal of the root (or the conditional is not one this reads)."""
    return root_joint_covariance(isam, [key])


def root_joint_covariance(isam: gtsam.ISAM2, keys: list[int]) -> np.ndarray | None:
    """Joint marginal covariance of ``keys`` (in that order, each key's tangent block after the
    other) from the root clique's conditional, one triangular solve; None if a key is not a frontal
    of the root (or the conditional is not one this reads)."""
    c = _root_conditional(isam, keys[0])
    if c is None or c.S().size:  # not the root: it has parents
        return None
    ckeys = c.keys()
    try:
        dims = [KEY_DIM[k >> 56] for k in ckeys]  # a Symbol's character is the key's top byte
        idx = [ckeys.index(k) for k in keys]
    except (ValueError, KeyError):
        return None
    R = c.R()
    if sum(dims) != R.shape[0]:
        return None
    offsets = np.cumsum([0, *dims])
    a = int(min(offsets[i] for i in idx))
    R = R[a:, a:]
    model = c.get_model()
    if model is not None:
        sigmas = model.sigmas()[a:]
        if not np.all(sigmas > 0):
            return None
        R = R / sigmas[:, None]
    cols = [j for i in idx for j in range(offsets[i] - a, offsets[i] + dims[i] - a)]
    E = np.zeros((R.shape[0], len(cols)), order="F")
    E[cols, np.arange(len(cols))] = 1.0
    Y, info = dtrtrs(R, E, lower=0, trans=1)
    if info != 0:
        return None
    return Y.T @ Y


def marginal_covariance(isam: gtsam.ISAM2, key: int) -> np.ndarray:
    """iSAM2's marginal covariance of ``key`` (raises as ``marginalCovariance`` does)."""
    cov = root_marginal_covariance(isam, key)
    return cov if cov is not None else isam.marginalCovariance(key)


def joint_covariance(isam: gtsam.ISAM2, keys: list[int]) -> np.ndarray:
    """iSAM2's joint marginal covariance of ``keys`` (blocks in that order), from the root clique when
    they are all its frontals, else ``jointMarginalCovariance`` (raises as it does)."""
    cov = root_joint_covariance(isam, keys)
    if cov is not None:
        return cov
    joint = isam.jointMarginalCovariance(gtsam.KeyVector(keys))
    return np.block([[np.asarray(joint.at(a, b)) for b in keys] for a in keys])
