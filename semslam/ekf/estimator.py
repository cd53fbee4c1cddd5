"""EKF-SLAM (``ekf``) and dead reckoning (``dr``): the estimators of Vallicrosa et al. 2021, Section 4.

Both run the same filter (:class:`~semslam.ekf.navigation.FilterNavigation`: the constant-velocity
prediction driven by the AHRS body rate, the depth, AHRS and DVL updates, the AHRS heading bias of the
shared sensor model when the mission declares one). The EKF maps the objects (points) and pipes (lines)
the front-ends extract into its state (:class:`~semslam.ekf.features.FeatureMap`) by the map-building
rules both estimators share (:class:`semslam.mapping.builder.MapBuilder`: JCBB association, tentative
features promoted after ``association.min_observations`` consistent views, pipe extents, duplicates,
class fusion with connectivity); navigation steps reach the map in compressed form
(:mod:`semslam.ekf.filter`), so they cost the same whatever its size. Dead reckoning places every
observation on its own with its pose (:class:`~semslam.ekf.dead_reckoning.PlacedMap`).
"""

from __future__ import annotations

import time
from abc import abstractmethod
from collections.abc import Sequence

import numpy as np

from semslam.config import SemslamConfig
from semslam.ekf.dead_reckoning import PlacedMap
from semslam.ekf.features import FeatureMap
from semslam.ekf.navigation import FilterNavigation
from semslam.estimation import EstimateView, Estimator, EstimatorResult, LandmarkEstimate, Trajectory
from semslam.mapping.book import LandmarkBook
from semslam.mapping.builder import MapBuilder
from semslam.mission.measurements import Measurement
from semslam.mission.mission import MissionMetadata
from semslam.observations import LineObservation, Observation, OdometryObservation, PointObservation


class FilterView(EstimateView):
    """Read-only view of a filter's estimate handed to front-ends."""

    def __init__(self, est: _Filter):
        self._est = est

    def pose_at(self, stamp: int) -> np.ndarray | None:
        return self._est.nav.pose_at(stamp)

    def landmarks(self) -> Sequence[LandmarkEstimate]:
        return self._est.map.estimates()


class _Filter(Estimator):
    """What the EKF and dead reckoning share: the filter, its timing and its result."""

    def __init__(self, metadata: MissionMetadata, config: SemslamConfig | None):
        config = config or SemslamConfig()
        self.metadata = metadata
        self.assoc = config.association
        self.diagnostics: list[str] = []
        self.nav = FilterNavigation(metadata, config, self.diagnostics)
        self.book = LandmarkBook()  # views, class evidence and extents of the map
        self.map: FeatureMap | PlacedMap
        self.update_times: list[float] = []
        self.update_n_landmarks: list[int] = []

    def process_measurement(self, measurement: Measurement) -> None:
        self.nav.process(measurement)

    def process_observations(self, stamp: int, observations: Sequence[Observation]) -> None:
        if self.nav.state is None:
            return
        t0 = time.perf_counter()
        if stamp > self.nav.t:
            self.nav.predict_to(stamp)
        observations = list(observations)
        for z in observations:  # motion, not map: for the EKF and dead reckoning alike
            if isinstance(z, OdometryObservation):
                self.nav.odometry(z)
        observations = [z for z in observations if not isinstance(z, OdometryObservation)]
        if self._observe(stamp, observations):
            self.nav.record(max(stamp, self.nav.t))
            self._observed(stamp)
        self.update_times.append(time.perf_counter() - t0)
        self.update_n_landmarks.append(len(self.map))

    @abstractmethod
    def _observe(self, stamp: int, observations: list[Observation]) -> bool:
        """Map (or place) a batch; True if any of it reached the map."""

    def _observed(self, stamp: int) -> None:
        """After a batch that reached the map (the EKF records its features' uncertainty)."""

    def view(self) -> FilterView:
        return FilterView(self)

    def finish(self) -> EstimatorResult:
        out = self.nav.trajectory()
        if out is None:
            empty = Trajectory(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 4)))
            return EstimatorResult(
                self.name, empty, diagnostics=self.diagnostics + ["the filter was never initialised"]
            )
        traj, history = out
        landmarks = self._confirmed(self.map.estimates())
        history["landmark_kind"] = {lm.id: lm.kind for lm in landmarks}
        history["landmark_volume"] = self._volumes()
        history.update(self.book.history([lm.id for lm in landmarks]))
        self._finish_map(landmarks, history)
        return EstimatorResult(
            name=self.name,
            trajectory=traj,
            landmarks=landmarks,
            online_trajectory=traj,  # a filter's estimate at each time is its online estimate
            update_times_s=np.array(self.update_times),
            update_n_landmarks=np.array(self.update_n_landmarks, int),
            history=history,
            diagnostics=list(self.diagnostics),
        )

    @abstractmethod
    def _volumes(self) -> dict:
        """Each map entry's uncertainty volume over time, by id."""

    def _confirmed(self, landmarks: list[LandmarkEstimate]) -> list[LandmarkEstimate]:
        """The map at the end of the mission, as the map building confirms it (a filter without one: all)."""
        return landmarks

    def _finish_map(self, landmarks: list[LandmarkEstimate], history: dict) -> None:
        """The map's last word at the end of the mission."""


class EkfEstimator(_Filter):
    """The paper's EKF-SLAM. ``EkfEstimator(metadata, config)`` with the full :class:`SemslamConfig`
    (sections ``initial``, ``motion``, ``sensors``, ``association`` and ``ekf``)."""

    name = "ekf"

    def __init__(self, metadata: MissionMetadata, config: SemslamConfig | None = None):
        super().__init__(metadata, config)
        cfg = config or SemslamConfig()
        self.map = FeatureMap(self.nav, cfg, self.book)
        self.mapper = MapBuilder(
            self.map, self.assoc, self.book, self.diagnostics, cfg.ekf.pipe_promote_direction_sigma_rad
        )

    def _observe(self, stamp: int, observations: list[Observation]) -> bool:
        self.map.begin()
        self.mapper.process(stamp, observations)
        return any(isinstance(z, (PointObservation, LineObservation)) for z in observations)

    def _observed(self, stamp: int) -> None:
        self.map.record_volumes(stamp)

    def _volumes(self) -> dict:
        return {f.id: (np.array(f.vol_stamps, np.int64), np.array(f.vol)) for f in self.map.features}

    def _confirmed(self, landmarks: list[LandmarkEstimate]) -> list[LandmarkEstimate]:
        return self.mapper.confirmed(landmarks)

    def _finish_map(self, landmarks: list[LandmarkEstimate], history: dict) -> None:
        self.book.connect(landmarks, self.assoc.merge_distance_m)
        history["duplicates_merged"] = self.mapper.merged
        history["objects_left_out"] = len(self.mapper.left_out)


class DeadReckoning(_Filter):
    """The same filter without the map in its state; its map is every observation placed with the
    dead-reckoning pose (the paper's Figure 10a)."""

    name = "dr"

    def __init__(self, metadata: MissionMetadata, config: SemslamConfig | None = None):
        super().__init__(metadata, config)
        self.nav.gps.updates = False  # dead reckoning takes only its start from the GPS
        self.map = PlacedMap(self.nav, config or SemslamConfig(), self.book)

    def _observe(self, stamp: int, observations: list[Observation]) -> bool:
        return self.map.observe(stamp, observations)

    def _volumes(self) -> dict:
        return dict(self.map.volume)
