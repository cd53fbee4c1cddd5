"""Observations: what a front-end extracts from a measurement, handed to the estimators.

Every observation is expressed in the frame of the sensor named by ``sensor`` (its extrinsic T_BS
is in the mission metadata) at time ``stamp`` (ns), with a covariance. ``truth_id`` is the
ground-truth landmark id when the front-end knows it (the oracle does): it is for evaluation
only, and no estimator may read it.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np


def _arr(a, shape):
    arr = np.array(a, dtype=np.float64, copy=True)
    if arr.shape != shape:
        raise ValueError(f"expected shape {shape}, got {arr.shape}")
    arr.flags.writeable = False
    return arr


@dataclass(frozen=True)
class Observation:
    stamp: int
    sensor: str


@dataclass(frozen=True)
class Connectivity:
    """Pipes attached to an object, as seen in one view.

    ``directions`` are unit pipe axes leaving the object, in the sensor frame. ``configuration`` is
    the paper's Table 2: 1 = one pipe, 2 = two collinear pipes, 3 = two orthogonal pipes,
    4 = three pipes (None when no pipe was seen).
    """

    n_pipes: int = 0
    configuration: int | None = None
    directions: tuple[tuple[float, float, float], ...] = ()


@dataclass(frozen=True)
class PointObservation(Observation):
    """An object's position in the sensor frame with its 3×3 covariance.

    ``cloud`` is the object's segmented cloud (sensor frame), ``class_likelihood`` is P(Z | X) over
    the object classes (class name → likelihood), ``connectivity`` the pipes seen at the object.
    """

    position: np.ndarray = field(default_factory=lambda: np.zeros(3))
    covariance: np.ndarray = field(default_factory=lambda: np.eye(3))
    cloud: np.ndarray | None = None
    class_likelihood: Mapping[str, float] | None = None
    connectivity: Connectivity | None = None
    truth_id: int | None = None

    def __post_init__(self):
        object.__setattr__(self, "position", _arr(self.position, (3,)))
        object.__setattr__(self, "covariance", _arr(self.covariance, (3, 3)))


@dataclass(frozen=True)
class LineObservation(Observation):
    """A pipe segment with endpoints ``p`` and ``q`` in the sensor frame; ``covariance`` is 6×6 over [p; q].

    ``connected_models`` names the CAD structures (by model) the segment was seen to end at, e.g. a
    pipeline leaving a manifold: the semantic map links the pipe to those structure landmarks.
    """

    p: np.ndarray = field(default_factory=lambda: np.zeros(3))
    q: np.ndarray = field(default_factory=lambda: np.array([1.0, 0.0, 0.0]))
    covariance: np.ndarray = field(default_factory=lambda: np.eye(6))
    radius: float | None = None
    truth_id: int | None = None
    connected_models: tuple[str, ...] = ()

    def __post_init__(self):
        object.__setattr__(self, "p", _arr(self.p, (3,)))
        object.__setattr__(self, "q", _arr(self.q, (3,)))
        object.__setattr__(self, "covariance", _arr(self.covariance, (6, 6)))


@dataclass(frozen=True)
class StructureObservation(Observation):
    """A CAD model recognised at relative pose T_S,model (4×4) in the sensor frame at ``stamp``.

    ``covariance`` is 6×6 in GTSAM's Pose3 tangent order (rotation, then translation), on the model side.
    """

    model: str = ""
    pose: np.ndarray = field(default_factory=lambda: np.eye(4))
    covariance: np.ndarray = field(default_factory=lambda: np.eye(6))
    truth_id: int | None = None

    def __post_init__(self):
        object.__setattr__(self, "pose", _arr(self.pose, (4, 4)))
        object.__setattr__(self, "covariance", _arr(self.covariance, (6, 6)))


@dataclass(frozen=True)
class OdometryObservation(Observation):
    """Relative body pose T_B(from),B(to) between ``stamp_from`` and ``stamp`` (= to), 6×6 covariance
    in GTSAM's Pose3 tangent order (rotation, then translation)."""

    stamp_from: int = 0
    relative_pose: np.ndarray = field(default_factory=lambda: np.eye(4))
    covariance: np.ndarray = field(default_factory=lambda: np.eye(6))

    def __post_init__(self):
        object.__setattr__(self, "relative_pose", _arr(self.relative_pose, (4, 4)))
        object.__setattr__(self, "covariance", _arr(self.covariance, (6, 6)))


OBSERVATION_TYPES = (PointObservation, LineObservation, StructureObservation, OdometryObservation)
