"""Measurement types: what the sensors said, in their own frames, stamped in integer nanoseconds.

Conventions (see DESIGN.md): world {W} is NED (z = depth, positive down), body {B} is
x forward / y right / z down, each sensor {S} has a fixed extrinsic T_BS in the mission
metadata. Quaternions are stored (x, y, z, w), as ROS and the TUM format store them.
Arrays are made read-only so that a measurement really is immutable once built.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from semslam.mission.ground_truth import homogeneous


def _frozen(a, dtype=np.float64, shape=None) -> np.ndarray:
    arr = np.array(a, dtype=dtype, copy=True)
    if shape is not None and arr.shape != shape:
        raise ValueError(f"expected shape {shape}, got {arr.shape}")
    arr.flags.writeable = False
    return arr


def _all_finite(a: np.ndarray) -> bool:
    """No NaN or inf in the float array ``a``. Small arrays (a pose, a 3×3 covariance: most of a
    mission's measurements) through Python floats, ~4× cheaper than NumPy's per-call overhead."""
    if a.size <= 64 and a.dtype.itemsize <= 8:
        return all(map(math.isfinite, a.ravel().tolist()))
    return bool(np.isfinite(a).all())


def _is_covariance(c: np.ndarray) -> bool:
    """Whether the square matrix ``c`` can be a covariance, to round-off (relative 1e-6 of its largest
    entry: a message's floats): symmetric, no negative variance, no correlation beyond ±1 (what
    positive semi-definiteness asks of every 2×2 minor; checked through Python floats, as every
    message passes here)."""
    if c.ndim != 2 or c.shape[0] != c.shape[1] or not c.size:
        return True  # not a matrix (the field's own checks say what it holds)
    rows = c.tolist()
    n = len(rows)
    tol = 1e-6 * max(max(abs(v) for v in row) for row in rows)
    diag = [rows[i][i] for i in range(n)]
    if min(diag) < -tol:
        return False
    for i in range(n):
        for j in range(i + 1, n):
            if abs(rows[i][j] - rows[j][i]) > tol or abs(rows[i][j]) > math.sqrt(max(diag[i] * diag[j], 0.0)) + tol:
                return False
    return True


@dataclass(frozen=True)
class Measurement:
    """Base of all measurements: ``stamp`` in ns, ``sensor`` the sensor name of the mission."""

    stamp: int
    sensor: str

    def is_finite(self) -> bool:
        """False if any numeric field holds NaN or inf, or a covariance is none (such measurements are
        dropped and counted)."""
        return self.nonfinite_field() is None

    def nonfinite_field(self) -> str | None:
        """Name of the first field holding NaN or inf, or of a ``covariance`` that is not symmetric
        positive semi-definite, else None (the rule of :meth:`is_finite`). Why the covariance: bytes
        damaged in a recording make finite nonsense (an off-diagonal of -1e188) that the filters turn
        into NaN without a word."""
        for name, value in vars(self).items():
            if isinstance(value, np.ndarray):
                if value.dtype.kind == "f" and not _all_finite(value):
                    return name
                if name == "covariance" and not _is_covariance(value):
                    return name
            elif isinstance(value, float) and not math.isfinite(value):
                return name
        return None


@dataclass(frozen=True)
class DvlVelocity(Measurement):
    """Velocity of the DVL head with respect to the ground, in the DVL frame {S}.

    ``valid`` is False during dropouts (bottom lock lost); ``beam_valid`` keeps the per-beam flags
    when the message had them. An invalid reading carries no velocity information.
    """

    velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    covariance: np.ndarray = field(default_factory=lambda: np.eye(3))
    valid: bool = True
    beam_valid: tuple[bool, ...] | None = None
    altitude: float | None = None

    def __post_init__(self):
        object.__setattr__(self, "velocity", _frozen(self.velocity, shape=(3,)))
        object.__setattr__(self, "covariance", _frozen(self.covariance, shape=(3, 3)))

    def nonfinite_field(self) -> str | None:
        # An invalid DVL reading may legitimately carry NaN velocity; it is kept as a dropout marker.
        return super().nonfinite_field() if self.valid else None


@dataclass(frozen=True)
class Attitude(Measurement):
    """AHRS orientation R_WS of the sensor frame in the world (NED), quaternion (x, y, z, w).

    ``covariance`` is 3×3 over (roll, pitch, yaw) errors; ``angular_rate`` (rad/s, sensor frame)
    is optional.
    """

    orientation: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 0.0, 1.0]))
    covariance: np.ndarray = field(default_factory=lambda: np.eye(3))
    angular_rate: np.ndarray | None = None

    def __post_init__(self):
        q = np.asarray(self.orientation, dtype=np.float64)
        n = np.linalg.norm(q)
        if n > 0 and abs(n - 1.0) > 1e-12:  # leave unit quaternions bit-exact (lossless bag round trips)
            q = q / n
        object.__setattr__(self, "orientation", _frozen(q, shape=(4,)))
        object.__setattr__(self, "covariance", _frozen(self.covariance, shape=(3, 3)))
        if self.angular_rate is not None:
            object.__setattr__(self, "angular_rate", _frozen(self.angular_rate, shape=(3,)))


@dataclass(frozen=True)
class Depth(Measurement):
    """Depth of the pressure sensor below the surface (m, positive down) and its variance (m²)."""

    depth: float = 0.0
    variance: float = 1.0

    def __post_init__(self):
        object.__setattr__(self, "depth", float(self.depth))
        object.__setattr__(self, "variance", float(self.variance))


@dataclass(frozen=True)
class PointCloud(Measurement):
    """Laser / stereo scan: N×3 float32 points in the sensor frame, optional N intensities and
    optional N×3 uint8 colours (``rgb``, from a stereo camera's PointCloud2 ``rgb``/``rgba`` field)."""

    points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.float32))
    intensity: np.ndarray | None = None
    rgb: np.ndarray | None = None

    def __post_init__(self):
        pts = _frozen(self.points, dtype=np.float32)
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise ValueError(f"points must be N×3, got {pts.shape}")
        object.__setattr__(self, "points", pts)
        if self.intensity is not None:
            object.__setattr__(self, "intensity", _frozen(self.intensity, dtype=np.float32, shape=(len(pts),)))
        if self.rgb is not None:
            object.__setattr__(self, "rgb", _frozen(self.rgb, dtype=np.uint8, shape=(len(pts), 3)))


@dataclass(frozen=True)
class SonarSwath(Measurement):
    """One multibeam swath in the sensor frame: beam angles across track (rad), ranges (m), intensities.

    Only beams with a return are kept (a ``LaserScan``'s inf / out-of-range beams are removed on read).
    Beam i points along (0, sin(angle_i), cos(angle_i)) in {S}: the sensor's z axis looks down at
    angle 0 and positive angles go to starboard (y).
    """

    angles: np.ndarray = field(default_factory=lambda: np.zeros(0))
    ranges: np.ndarray = field(default_factory=lambda: np.zeros(0))
    intensities: np.ndarray | None = None

    def __post_init__(self):
        angles = _frozen(self.angles)
        object.__setattr__(self, "angles", angles)
        object.__setattr__(self, "ranges", _frozen(self.ranges, shape=angles.shape))
        if self.intensities is not None:
            object.__setattr__(self, "intensities", _frozen(self.intensities, shape=angles.shape))

    def points(self) -> np.ndarray:
        """The returns as N×3 points in the sensor frame."""
        return np.stack(
            [np.zeros_like(self.ranges), self.ranges * np.sin(self.angles), self.ranges * np.cos(self.angles)],
            axis=1,
        )


@dataclass(frozen=True)
class GpsFix(Measurement):
    """A GPS fix of the antenna, in the mission's local NED frame about its datum (m), with its 3×3
    covariance (m², NED). Only taken at the surface: the reader drops fixes without a position, and
    those taken while the depth sensor reads deeper than ``reader.gps_max_depth_m``."""

    position: np.ndarray = field(default_factory=lambda: np.zeros(3))
    covariance: np.ndarray = field(default_factory=lambda: np.eye(3))

    def __post_init__(self):
        object.__setattr__(self, "position", _frozen(self.position, shape=(3,)))
        object.__setattr__(self, "covariance", _frozen(self.covariance, shape=(3, 3)))


@dataclass(frozen=True)
class GroundTruthPose(Measurement):
    """True body pose T_WB: position (m, NED) and orientation quaternion (x, y, z, w)."""

    position: np.ndarray = field(default_factory=lambda: np.zeros(3))
    orientation: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 0.0, 1.0]))

    def __post_init__(self):
        object.__setattr__(self, "position", _frozen(self.position, shape=(3,)))
        object.__setattr__(self, "orientation", _frozen(self.orientation, shape=(4,)))

    def matrix(self) -> np.ndarray:
        """T_WB as a 4×4 homogeneous matrix."""
        return homogeneous(self.position, self.orientation)


MEASUREMENT_TYPES: tuple[type[Measurement], ...] = (
    DvlVelocity,
    Attitude,
    Depth,
    PointCloud,
    SonarSwath,
    GpsFix,
    GroundTruthPose,
)
