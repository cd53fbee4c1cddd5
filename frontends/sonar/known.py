"""A structure the sonar front-end has recognised, as it keeps it between swaths."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from frontends.sonar.recognition import Detection
from frontends.sonar.registration import Registration


@dataclass
class KnownStructure:
    """A recognised structure: its model and the latest estimate of T_WM (the graph's landmark once
    it exists, else the front-end's own registration)."""

    model: str
    T_WM: np.ndarray
    detection: Detection
    stamp: int
    landmark_id: int | None = None
    n_observations: int = 0
    final: Registration | None = None
    confirmed: bool = True  # False: its registration on all the data failed the quality test (end of mission)
    settled_by_passes: bool = False  # confirmed by its passes' votes (summary.settled_by_passes)
    seen_track_m: float = 0.0  # the front-end's odometer at its last accepted view (or its recognition)
    history: list = field(default_factory=list)  # (stamp, patch id, T_SM, cov) of the observations
    # the patches its final registration used: (anchor stamp, points near it, T_W,B of the anchor as placed)
    support: list = field(default_factory=list)

    @property
    def centre(self) -> np.ndarray:
        return self.T_WM[:2, 3]
