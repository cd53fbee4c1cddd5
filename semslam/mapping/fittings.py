"""Where a pipe enters a mapped fitting: the depth of the fitting's ports from its centre, from the
CAD models' ports (:mod:`semslam.models.cad`) of the classes its class posterior names.

A pipe's views run on into a fitting's socket (the socket has the pipe's shape), so the pipe's mapped
end is placed at the port mouth, this depth before the fitting's centre, instead of at the centre
(:func:`semslam.mapping.pipes.cut_at_objects`)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from semslam.models import cad

_DEPTHS: list = [(), {}]  # the library's models when last read (held, compared by identity) → depth_by_class


def depth_by_class() -> dict[str, float]:
    """The median port depth of each class's models (classes whose models declare no port: none).
    Worked out again only when the library holds other models than at the last call (a scan asks
    once or more; reading the ports cost ~0.6 ms)."""
    models = tuple(cad.library().items())
    held, table = _DEPTHS
    if len(held) == len(models) and all(a[0] == b[0] and a[1] is b[1] for a, b in zip(held, models)):
        return dict(table)
    depths: dict[str, list[float]] = {}
    for _, model in models:
        depths.setdefault(model.cls, []).extend(float(np.linalg.norm(p)) for p, _ in model.ports)
    table = {cls: float(np.median(v)) for cls, v in depths.items() if v}
    _DEPTHS[:] = [models, table]
    return dict(table)


def port_depths(posteriors: Sequence[Mapping[str, float] | None]) -> np.ndarray:
    """The expected port depth (m) of each object under its class posterior; 0 without class evidence
    or ports (the pipe is then cut at the object's centre). The models are read at each call: a user's
    registered model counts."""
    table = depth_by_class() if any(posteriors) else {}
    return np.array([sum(p * table.get(c, 0.0) for c, p in (post or {}).items()) for post in posteriors], float)
