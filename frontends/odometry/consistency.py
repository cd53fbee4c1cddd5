"""Whether the accepted registrations travel the path the DVL measured over the same scan pairs.

A registration biased towards no motion (a stereo view of a seabed whose texture barely fixes the
motion along it: experiments/odometry/README.md, stop 51) passes every per-scan gate, since each
pair's shortfall is a few millimetres, yet over a mission its factors pull the graph's trajectory
back along the track by decimetres. Summed over the pairs with a fresh DVL reading at both ends, the
registrations' horizontal path against the prior's shows it: a DVL's own scale error is well under
a percent, so a ratio off by more than ``PATH_RATIO_TOLERANCE`` is the odometry's (or a
misconfigured extrinsic's), and the run says so.
"""

from __future__ import annotations

import numpy as np

from frontends.odometry.information import VERTICAL

FRESH_DVL_S = 1.0  # a DVL reading at most this old at both ends of a pair: the prior is measured, not held
PATH_RATIO_TOLERANCE = 0.05
MIN_PATH_M = 2.0  # the prior's horizontal path the ratio is judged on, at least
MIN_PAIRS = 10


class PathAgreement:
    """Sums, over registrations with the DVL fresh at both ends, the registered horizontal motion along the
    prior's and the prior's horizontal path length."""

    def __init__(self) -> None:
        self.along = 0.0  # Σ registered horizontal motion along the prior's direction (m)
        self.path = 0.0  # Σ the prior's horizontal motion (m)
        self.pairs = 0

    def add(self, registered_B: np.ndarray, prior_B: np.ndarray, R_from: np.ndarray) -> None:
        """One pair: the registered and the prior's translations (body frame at the pair's first scan) and that
        body's attitude R_DB (for the vertical)."""
        up = R_from.T @ VERTICAL
        r = registered_B - (registered_B @ up) * up
        p = prior_B - (prior_B @ up) * up
        length = float(np.linalg.norm(p))
        if length <= 0.0:
            return
        self.along += float(r @ p) / length
        self.path += length
        self.pairs += 1

    @property
    def ratio(self) -> float | None:
        """The registrations' path over the prior's, None while too short a path or too few pairs say little."""
        if self.pairs < MIN_PAIRS or self.path < MIN_PATH_M:
            return None
        return self.along / self.path

    @property
    def disagrees(self) -> bool:
        return self.ratio is not None and abs(self.ratio - 1.0) > PATH_RATIO_TOLERANCE
