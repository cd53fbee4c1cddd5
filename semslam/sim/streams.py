"""Independent random streams, one per purpose, so that changing one never shifts another.

A stream is ``default_rng(SeedSequence([seed, purpose id]))``: the ids below are fixed forever (a
simulated mission is reproducible from its seed), new purposes get new ids.
"""

from __future__ import annotations

import numpy as np

STREAMS: dict[str, int] = {
    "dvl_noise": 1,
    "dvl_dropout": 2,
    "ahrs": 3,
    "depth": 4,
    "laser": 5,
    "heading_bias": 6,
    "sonar": 7,
    "seabed": 8,
    "field_layout": 9,
    "gps": 10,
    "gyro_bias": 11,
    # the world's parameters a seed draws (semslam.sim.vary), one stream per aspect
    "vary_layout": 20,
    "vary_trajectory": 21,
    "vary_noise": 22,
    "vary_dropouts": 23,
    "vary_start": 24,
}


def rng_stream(seed: int, purpose: str) -> np.random.Generator:
    """The random stream of ``purpose`` (a key of :data:`STREAMS`) for ``seed``."""
    return np.random.default_rng(np.random.SeedSequence([seed, STREAMS[purpose]]))
