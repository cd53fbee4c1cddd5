"""What the laser studies of this folder share: distances to the simulator's true pipes (scripts run
as ``python experiments/laser/<script>.py``, so this folder is on their path)."""

from __future__ import annotations

import numpy as np


def segment_distance(x: np.ndarray, p: np.ndarray, q: np.ndarray) -> float:
    """Distance of the point ``x`` from the segment p–q."""
    d = q - p
    s = float(np.clip((x - p) @ d / max(d @ d, 1e-12), 0.0, 1.0))
    return float(np.linalg.norm(x - p - s * d))
