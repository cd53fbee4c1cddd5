"""Pipe-connectivity constraints on an object's class (Vallicrosa et al. 2021, Table 2).

An object seen with pipes attached is in one of four configurations:

    1  one pipe
    2  two collinear pipes
    3  two orthogonal pipes
    4  three pipes

A class is compatible with a configuration when that many pipes, at those angles, can sit on its
ports. The default table below is derived from the port geometry of the six classes of the tank
mission (the paper's Table 2 could not be retrieved verbatim with our search tools, so it is
rebuilt from the fittings' geometry and the paper's description: in-line valves and sockets join
two collinear pipes, an elbow two orthogonal ones, a tee and a 3-way valve three):

    class              ports                            compatible with
    Ball-Valve         2 collinear                      1, 2
    Butterfly-Valve    2 collinear                      1, 2
    R-Socket           2 collinear (reducing)           1, 2
    Elbow              2 orthogonal                     1, 3
    R-Tee              3, T-shaped (2 collinear + 1 ⟂)  1, 2, 3, 4
    3-Way-Ball-Valve   3, T-shaped (T-port body)        1, 2, 3, 4

A tee or 3-way valve seen with only its run (or only one branch and the run) attached is in
configuration 2 (or 3), hence their compatibility with every configuration. The table can be
rebuilt for any model from its port directions (:func:`compatible_configurations`), so a user's
own CAD model with ports gets its row automatically.

Over a landmark's life the constraint is the intersection of the compatible sets of every
configuration seen (seen: recurring in at least a tenth of the landmark's views, see
:mod:`semslam.semantics.fusion`). Because 1 ⊃ 2 ⊃ 4 and 1 ⊃ 3 ⊃ 4, that is the paper's "most restrictive
configuration seen so far"; it also settles the case the paper's rule leaves open (2 and 3 both
seen: only a three-port class fits).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence

import numpy as np

ONE_PIPE, TWO_COLLINEAR, TWO_ORTHOGONAL, THREE_PIPES = 1, 2, 3, 4
CONFIGURATIONS = (ONE_PIPE, TWO_COLLINEAR, TWO_ORTHOGONAL, THREE_PIPES)

DEFAULT_COMPATIBILITY: dict[str, frozenset[int]] = {
    "Ball-Valve": frozenset({1, 2}),
    "Butterfly-Valve": frozenset({1, 2}),
    "R-Socket": frozenset({1, 2}),
    "Elbow": frozenset({1, 3}),
    "R-Tee": frozenset({1, 2, 3, 4}),
    "3-Way-Ball-Valve": frozenset({1, 2, 3, 4}),
}


def configuration_of(directions: Sequence[Sequence[float]], angle_tol_rad: float = np.deg2rad(20.0)) -> int | None:
    """The configuration (1–4) of pipes leaving an object along unit ``directions`` (any frame).

    Two pipes are collinear when their outward directions are opposite within ``angle_tol_rad``,
    otherwise orthogonal (fittings join pipes at 180° or 90°); three or more pipes give 4.
    None when no pipe is attached.
    """
    d = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    if len(d) == 0:
        return None
    if len(d) == 1:
        return ONE_PIPE
    if len(d) >= 3:
        return THREE_PIPES
    u = d / np.linalg.norm(d, axis=1, keepdims=True)
    return TWO_COLLINEAR if float(u[0] @ u[1]) < -np.cos(angle_tol_rad) else TWO_ORTHOGONAL


def compatible_configurations(
    port_directions: Sequence[Sequence[float]], angle_tol_rad: float = np.deg2rad(20.0)
) -> frozenset[int]:
    """The configurations a model with ports along unit ``port_directions`` (model frame) admits:
    every configuration that some subset of its ports realises."""
    d = np.asarray(port_directions, dtype=np.float64).reshape(-1, 3)
    n = len(d)
    out: set[int] = set()
    if n >= 1:
        out.add(ONE_PIPE)
    for i in range(n):
        for j in range(i + 1, n):
            c = configuration_of(d[[i, j]], angle_tol_rad)
            if c is not None:
                out.add(c)
    if n >= 3:
        out.add(THREE_PIPES)
    return frozenset(out)


class ConnectivityTable:
    """Which classes admit which configurations; unknown classes admit every configuration."""

    def __init__(self, compatibility: Mapping[str, Iterable[int]] | None = None):
        src = DEFAULT_COMPATIBILITY if compatibility is None else compatibility
        self.compatibility = {k: frozenset(v) for k, v in src.items()}

    def compatible(self, cls: str, configurations: Iterable[int | None]) -> bool:
        allowed = self.compatibility.get(cls, frozenset(CONFIGURATIONS))
        return all(c in allowed for c in configurations if c is not None)

    def mask(self, classes: Sequence[str], configurations: Iterable[int | None]) -> np.ndarray:
        """1.0 for the classes compatible with every configuration seen, 0.0 for the others."""
        seen = [c for c in configurations if c is not None]
        return np.array([1.0 if self.compatible(c, seen) else 0.0 for c in classes])


def most_restrictive(configurations: Iterable[int | None]) -> int | None:
    """The most restrictive configuration seen (for reporting): 4 over 2 and 3 over 1; with both
    2 and 3 seen, 4 (only a three-port class fits both)."""
    seen = {c for c in configurations if c is not None}
    if not seen:
        return None
    if THREE_PIPES in seen or {TWO_COLLINEAR, TWO_ORTHOGONAL} <= seen:
        return THREE_PIPES
    return max(seen)
