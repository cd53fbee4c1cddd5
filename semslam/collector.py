"""The cyclic garbage collector's pace during the long passes of a run (the pipeline, the metrics, the
output files and the report): they allocate and drop small containers by the million, and with Python's
default (a young-generation collection every 700 net allocations, a full one as the heap grows) the
collector walked the run's whole heap again and again (experiments/speed/README.md, stop 50). What is
collected does not change, only when: no number of a run depends on it."""

from __future__ import annotations

import gc
from collections.abc import Iterator
from contextlib import contextmanager

# The young generation's collection threshold inside :func:`fewer_collections` (Python's default: 700).
YOUNG_THRESHOLD = 50_000

_depth = 0  # open blocks: only the outermost one freezes and restores


@contextmanager
def fewer_collections(young: int = YOUNG_THRESHOLD) -> Iterator[None]:
    """Inside the block (or a function decorated with ``@fewer_collections()``), the youngest generation
    is collected every ``young`` net allocations (never more often than before), and the objects that
    existed at its start (modules, the mission, the front-ends' models; in the report, the run's result)
    are frozen out of the collections (:func:`gc.freeze`); the older generations' thresholds are kept.
    Restored on leaving, also on an error; blocks may nest."""
    global _depth
    before = gc.get_threshold()
    outermost = _depth == 0
    _depth += 1
    gc.set_threshold(max(young, before[0]), *before[1:])
    if outermost:
        gc.freeze()
    try:
        yield
    finally:
        _depth -= 1
        if outermost:
            gc.unfreeze()
        gc.set_threshold(*before)
