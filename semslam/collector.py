"""The cyclic garbage collector during the long passes of a run (the pipeline, the metrics, the output files
and the report): what exists when one starts (the modules, the mission, the front-ends' models; after the
run, its whole result) is frozen out of the collections for its length, so that each full collection walks
only what the pass itself made, not the heap again and again (experiments/speed/README.md, stop 50). What
is collected, and when the young generations are, does not change: no number of a run depends on it."""

from __future__ import annotations

import gc
from collections.abc import Iterator
from contextlib import contextmanager

_depth = 0  # open blocks: only the outermost one freezes and unfreezes


@contextmanager
def heap_frozen() -> Iterator[None]:
    """Inside the block (or a function decorated with ``@heap_frozen()``), the objects that existed at its
    start are out of the collector's generations (:func:`gc.freeze`): never walked, never collected (one of
    them that becomes garbage meanwhile waits for the block's end); back in the oldest generation on leaving,
    also on an error. Blocks may nest: the outermost one decides."""
    global _depth
    outermost = _depth == 0
    _depth += 1
    if outermost:
        gc.freeze()
    try:
        yield
    finally:
        _depth -= 1
        if outermost:
            gc.unfreeze()
