"""The interface every estimator (``graph``, ``ekf``, ``dr``) shares, and the results it returns.

An estimator consumes measurements and observations in time order, answers its current estimate
through an :class:`EstimateView`, and at the end returns an :class:`EstimatorResult`.
"""

from __future__ import annotations

import os
import tempfile
from abc import ABC, abstractmethod
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass, field
from tempfile import TemporaryFile
from typing import ClassVar

import numpy as np

from semslam.errors import SemslamError
from semslam.mission.measurements import Measurement
from semslam.observations import Observation

LANDMARK_KINDS = ("object", "pipe", "structure")


class SpillError(SemslamError):
    """A run's spill file (what it appends for hours, on disk) cannot be written or read back:
    a full disk, a quota, a directory gone."""


SPILL_CHUNK_ROWS = 4096  # rows a SpillLog holds in memory, by default

# (the directory, what an error calls it)
_SPILL_DIR: ContextVar[tuple[str | os.PathLike | None, str | os.PathLike | None]] = ContextVar(
    "semslam_spill_dir", default=(None, None)
)


@contextmanager
def spilling_into(directory: str | os.PathLike | None, named: str | os.PathLike | None = None) -> Iterator[None]:
    """Every :class:`SpillLog` that opens its file inside the block and was given no directory of its
    own opens it in ``directory`` (None: the enclosing block's, else the system's temporary directory):
    a run puts them on its output's filesystem (its staging directory), not on a /tmp that may be memory.
    ``named``: what a failure's message calls the directory (default: its path), e.g. the output
    directory as the user knows it rather than the hidden stage that is removed with the failure."""
    token = _SPILL_DIR.set((directory, named) if directory is not None else _SPILL_DIR.get())
    try:
        yield
    finally:
        _SPILL_DIR.reset(token)


def spill_directory() -> str | os.PathLike | None:
    """The directory where a :class:`SpillLog` opening its file now would open it (None: the
    system's temporary directory)."""
    return _SPILL_DIR.get()[0]


class SpillLog:
    """Rows of one numpy ``dtype`` appended one at a time over a run of any length (a survey's
    ground truth, views, timings), kept on disk: only the last ``chunk`` rows are in memory, the
    rest in an anonymous temporary file in ``directory`` (default: that of the enclosing
    :func:`spilling_into` when the file is opened, else the system's), which no directory lists and
    which goes with the process however it ends. :meth:`array` reads them all back. A file that
    cannot be written or read (a full disk) raises :class:`SpillError`, one line naming the directory."""

    __slots__ = ("dtype", "_plain", "_directory", "_named", "_file", "_buffer", "_buffered", "_spilled")

    def __init__(self, dtype, chunk: int | None = None, directory=None):
        self.dtype = np.dtype(dtype)
        self._plain = self.dtype.names is None  # one value a row, not a record
        self._directory = directory
        self._named = None  # what a failure's message calls the directory (spilling_into's ``named``)
        self._file = None  # opened when the first chunk is full
        self._buffer = np.empty(chunk or SPILL_CHUNK_ROWS, self.dtype)
        self._buffered = 0
        self._spilled = 0

    def __len__(self) -> int:
        return self._spilled + self._buffered

    def append(self, *row) -> None:
        """One row: a value per field of ``dtype``, in its order (sub-arrays as sequences)."""
        if self._buffered == len(self._buffer):  # its spill failed (a full disk) and the run goes on
            self._spill()  # (a cleanup that records one more row): the same SpillError, not an IndexError
        self._buffer[self._buffered] = row[0] if self._plain else row
        self._buffered += 1
        if self._buffered == len(self._buffer):
            self._spill()

    def _spill(self) -> None:
        try:
            if self._file is None:
                if self._directory is None:
                    self._directory, self._named = _SPILL_DIR.get()
                self._file = TemporaryFile(prefix="semslam-", suffix=".rows", dir=self._directory)
            self._file.write(self._buffer.tobytes())
        except OSError as exc:
            raise SpillError(self._failure(exc)) from None
        self._spilled += self._buffered
        self._buffered = 0

    def _failure(self, exc: OSError) -> str:
        where = self._named or (self._directory if self._directory is not None else tempfile.gettempdir())
        return f"{where}: the run's spill file: {exc.strerror or exc}"

    def array(self) -> np.ndarray:
        """Every row appended, in order (a new array: the log goes on)."""
        rows = np.empty(len(self), self.dtype)
        if self._spilled:
            try:
                self._file.flush()
                self._file.seek(0)
                got = self._file.readinto(rows[: self._spilled].view(np.uint8))
                self._file.seek(0, 2)
            except OSError as exc:
                raise SpillError(self._failure(exc)) from None
            if got != self._spilled * self.dtype.itemsize:
                raise SpillError(
                    self._failure(OSError(f"{got} bytes read back of {self._spilled * self.dtype.itemsize}"))
                )
        rows[self._spilled :] = self._buffer[: self._buffered]
        return rows


@dataclass
class LandmarkEstimate:
    """One mapped landmark with its global id, in {W}.

    - object: ``position`` (3,), ``covariance`` 3×3, ``class_posterior`` class → probability.
    - pipe: ``p``, ``q`` endpoints (3,) on the estimated line, ``covariance`` of the line
      parameters (4×4, the estimator's own minimal parametrisation).
    - structure: ``pose`` T_W,model (4×4), ``covariance`` 6×6 (rotation, translation).
    """

    id: int
    kind: str
    position: np.ndarray | None = None
    p: np.ndarray | None = None
    q: np.ndarray | None = None
    pose: np.ndarray | None = None
    covariance: np.ndarray | None = None
    model: str | None = None
    class_posterior: Mapping[str, float] | None = None
    n_observations: int = 0
    connected: tuple[int, ...] = ()  # global ids of connected landmarks (object ↔ pipes)


@dataclass
class Trajectory:
    """Body poses T_WB over time. ``position_cov`` is the 3×3 position covariance in {W}."""

    stamps: np.ndarray  # (N,) int64 ns
    positions: np.ndarray  # (N, 3)
    orientations: np.ndarray  # (N, 4) quaternion (x, y, z, w)
    position_cov: np.ndarray | None = None  # (N, 3, 3)
    velocities: np.ndarray | None = None  # (N, 3) body frame
    velocity_cov: np.ndarray | None = None  # (N, 3, 3)

    def __len__(self) -> int:
        return len(self.stamps)

    def poses_at(self, stamps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Rotations (N, 3, 3) and positions (N, 3) at ``stamps``: linear in position and
        spherical-linear in attitude between the poses, held at the first and last pose outside them."""
        return self.interpolator()(stamps)

    def interpolator(self):
        """:meth:`poses_at` as a function of the stamps, its slerp built once (for many calls)."""
        from scipy.spatial.transform import Rotation, Slerp

        ts = np.asarray(self.stamps, np.int64)
        rots = Rotation.from_quat(self.orientations)
        slerp = Slerp(ts, rots) if len(ts) > 1 else None
        positions = self.positions

        def at(stamps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            s = np.clip(np.asarray(stamps, np.int64), ts[0], ts[-1])
            pos = np.column_stack([np.interp(s, ts, positions[:, k]) for k in range(3)])
            R = slerp(s).as_matrix() if slerp is not None else rots.as_matrix()[np.zeros(len(s), int)]
            return R, pos

        return at

    def to_tum(self, path) -> None:
        """Write ``stamp x y z qx qy qz qw`` lines (stamp in seconds), readable by evo."""
        data = np.column_stack([self.stamps * 1e-9, self.positions, self.orientations])
        np.savetxt(path, data, fmt="%.9f", header="timestamp tx ty tz qx qy qz qw")


@dataclass
class EstimatorResult:
    """What an estimator returns at the end of a mission."""

    name: str
    trajectory: Trajectory
    landmarks: list[LandmarkEstimate] = field(default_factory=list)
    online_trajectory: Trajectory | None = None  # each pose as the estimator gave it at its time
    update_times_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    update_n_landmarks: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    # Over-time histories for the comparison figures (any key may be absent):
    #   "landmark_volume": {landmark id: (stamps (K,) int64 ns, volume (K,) = sum of log eigenvalues)}
    #   "landmark_kind":   {landmark id: "object" | "pipe" | "structure"}
    history: dict = field(default_factory=dict)
    diagnostics: list[str] = field(default_factory=list)  # recovered failures, warnings


class EstimateView(ABC):
    """Read-only view of an estimator's current estimate, handed to front-ends."""

    @abstractmethod
    def pose_at(self, stamp: int) -> np.ndarray | None:
        """Current estimate of T_WB (4×4) at ``stamp`` (ns), or None if the estimator cannot tell."""

    @abstractmethod
    def landmarks(self) -> Sequence[LandmarkEstimate]:
        """The current map, with global ids."""


class Estimator(ABC):
    """The base class of every estimator: it consumes measurements and observations in time order,
    answers its current estimate through :meth:`view`, and returns its result at the end."""

    name: ClassVar[str]

    @abstractmethod
    def process_measurement(self, measurement: Measurement) -> None:
        """Navigation (and ground-truth) measurements, in stamp order."""

    @abstractmethod
    def process_observations(self, stamp: int, observations: Sequence[Observation]) -> None:
        """All observations a front-end drew from one measurement at ``stamp`` (associated jointly)."""

    @abstractmethod
    def view(self) -> EstimateView:
        """The current estimate, for the front-ends."""

    @abstractmethod
    def finish(self) -> EstimatorResult:
        """The trajectory, the map and the timings, at the end of the mission."""
