"""Marginalisation for the graph back-end's bounded smoothing window.

A full smoother's cost per update grows on long missions: on a lawnmower coverage the graph is a
2-D grid, and iSAM2's separators grow with the width covered. The online smoother therefore keeps a
window of recent keyframes and the landmarks they see; what leaves the window (old keyframes, and
landmarks no kept keyframe observes) is marginalised, its information kept as a linear factor on
the variables it was connected to (the separator), linearised at the current estimate. This is the
factor BatchFixedLagSmoother computes (GTSAM's ``CalculateMarginalFactors``); GTSAM's incremental
fixed-lag smoother is not used because its in-tree marginalisation of iSAM2 leaves has open
failures on Bayes trees like ours (borglab/gtsam #1638, #1680).
"""

from __future__ import annotations

from collections.abc import Iterable

import gtsam

LANDMARK_CHARS = frozenset(map(ord, "lps"))  # object points, pipe lines, structures
POSE_CHARS = frozenset(map(ord, "xs"))  # Pose3-valued keys (keyframes, structures)
POINT_CHARS = frozenset(map(ord, "l"))  # Point3-valued keys


def value_of(src: gtsam.Values | gtsam.ISAM2, key: int):
    """A variable of ``src`` (Values, or iSAM2's current estimate) by its symbol character: a Pose3,
    or a numpy vector (point, line, velocity, bias)."""
    c = gtsam.Symbol(key).chr()
    if isinstance(src, gtsam.Values):
        if c in POSE_CHARS:
            return src.atPose3(key)
        return src.atPoint3(key) if c in POINT_CHARS else src.atVector(key)
    if c in POSE_CHARS:
        return src.calculateEstimatePose3(key)
    return src.calculateEstimatePoint3(key) if c in POINT_CHARS else src.calculateEstimateVector(key)


def subset(values: gtsam.Values, keys: Iterable[int]) -> gtsam.Values:
    out = gtsam.Values()
    for k in keys:
        out.insert(k, value_of(values, k))
    return out


def split_factors(factors: list[tuple], drop: set[int]) -> tuple[list[tuple], list[tuple]]:
    """(kept, leaving): the factors touching no dropped key, and the others."""
    kept, leaving = [], []
    for item in factors:
        (leaving if any(k in drop for k in item[0].keys()) else kept).append(item)
    return kept, leaving


def marginal_factors(leaving: list[tuple], values: gtsam.Values, drop: set[int]) -> list[gtsam.LinearContainerFactor]:
    """The information the ``leaving`` factors carry on their non-dropped variables, with the
    dropped ones eliminated: linear factors at ``values`` (which must hold every variable the
    factors touch). Raises RuntimeError if the dropped variables are not determined."""
    graph = gtsam.NonlinearFactorGraph()
    for f, *_ in leaving:
        graph.add(f)
    linear = graph.linearize(values)
    present = sorted({k for f, *_ in leaving for k in f.keys() if k in drop})
    _, remaining = linear.eliminatePartialMultifrontal(gtsam.KeyVector(present))  # COLAMD order
    out = []
    for i in range(remaining.size()):
        g = remaining.at(i)
        if g is None or len(g.keys()) == 0:
            continue
        out.append(gtsam.LinearContainerFactor(g, subset(values, g.keys())))
    return out
