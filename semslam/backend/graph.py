"""The graph back-end: iSAM2 online (and Levenberg–Marquardt batch) smoothing over keyframes with
navigation factors between them and object / pipe / structure landmarks.

The parts: :class:`~semslam.backend.session.IsamSession` (iSAM2 with recovery from a failed update,
the batch, marginals), :class:`~semslam.backend.keyframes.Keyframes` (keyframes at every observation
batch and at least every ``graph.keyframe_max_interval_s``, their navigation factors),
:class:`~semslam.backend.window.SlidingWindow` (online, iSAM2 holds ``graph.window_s`` seconds; the
batch spans the whole mission), :class:`~semslam.backend.landmarks.GraphLandmarks` (the landmarks
as iSAM2 variables), the map-building rules both estimators share
(:class:`semslam.mapping.builder.MapBuilder`), and the result (:mod:`semslam.backend.result`).
"""

from __future__ import annotations

import time
from collections.abc import Sequence

import numpy as np

from factors.navigation import GYRO_BIAS_UNIT_S
from semslam.backend.gps import GraphGps
from semslam.backend.keyframes import Keyframes
from semslam.backend.landmarks import GraphLandmarks
from semslam.backend.result import final_values, keyframe_trajectory, online_trajectory
from semslam.backend.session import IsamSession
from semslam.backend.window import SlidingWindow
from semslam.config import GraphConfig, SemslamConfig
from semslam.estimation import EstimateView, Estimator, EstimatorResult, LandmarkEstimate, SpillLog, Trajectory
from semslam.mapping.book import LandmarkBook
from semslam.mapping.builder import MapBuilder
from semslam.mission.measurements import GpsFix, Measurement
from semslam.mission.mission import MissionMetadata
from semslam.observations import Observation, OdometryObservation

UPDATE_KINDS = ("gps", "keyframe", "observations")  # what an update was (the timings' ``kind`` column)
UPDATE_ROW = np.dtype([("wall_s", "f8"), ("cpu_s", "f8"), ("n_landmarks", "i8"), ("kind", "u1")])


class GraphView(EstimateView):
    """Read-only view of the graph estimate handed to front-ends."""

    def __init__(self, est: GraphEstimator):
        self._est = est

    def pose_at(self, stamp: int) -> np.ndarray | None:
        p = self._est.keyframes.pose_at(stamp)
        return None if p is None else p.matrix()

    def landmarks(self) -> Sequence[LandmarkEstimate]:
        return self._est.map.estimates(covariance=False)


class GraphEstimator(Estimator):
    """iSAM2 graph estimator (name ``graph``): the facade over its parts (see the module)."""

    name = "graph"

    def __init__(self, metadata: MissionMetadata, config: SemslamConfig | None = None, batch: bool | None = None):
        config = config or SemslamConfig()
        self.cfg: GraphConfig = config.graph
        self.batch = self.cfg.batch if batch is None else bool(batch)
        self.assoc = config.association
        self.diagnostics: list[str] = []
        # Every factor of the mission is kept only for the batch; without it, what leaves the window
        # keeps its covariance then, for the result (memory stays bounded on long missions).
        self.session = IsamSession(
            self.cfg.relinearize_threshold, self.cfg.relinearize_skip, self.diagnostics, keep_all=self.batch
        )
        self.window = SlidingWindow(
            self.cfg.window_s, self.diagnostics, keep_covariances=not self.batch and self.cfg.covariance_in_result
        )
        self.keyframes = Keyframes(metadata, config, self.session, self.window)
        self.book = LandmarkBook()  # views, class evidence and extents of the landmarks
        self.map = GraphLandmarks(
            metadata, config, self.session, self.keyframes, self.window, self.book, self.diagnostics
        )
        self.mapper = MapBuilder(self.map, self.assoc, self.book, self.diagnostics)
        self.gps = GraphGps(metadata, config.initial.pose, self.keyframes, self.session, self.diagnostics)
        # One row an update (wall and CPU seconds, landmarks then, kind), on disk past a chunk: CPU
        # seconds of the process too, as wall time says little under load.
        self.updates = SpillLog(UPDATE_ROW)

    # ------------------------------------------------------------------ protocol
    def view(self) -> GraphView:
        return GraphView(self)

    def process_measurement(self, measurement: Measurement) -> None:
        if isinstance(measurement, GpsFix):  # a position factor, or the start (semslam.backend.gps)
            self._timed(lambda: self.gps.take(measurement, self._keyframe_for), "gps")
            return
        due = self.keyframes.add(measurement)
        if due == "first" and not self.gps.starts(measurement):
            self._timed(lambda: self.keyframes.first(measurement.stamp), "keyframe")
        elif due == "next":
            self._timed(lambda: self._keyframe(measurement.stamp), "keyframe")

    def process_observations(self, stamp: int, observations: Sequence[Observation]) -> None:
        if not observations:
            return
        if not self.keyframes.stamps:
            self.diagnostics.append(f"{stamp}: {len(observations)} observations before the first keyframe, ignored")
            return
        self._timed(lambda: self._observations(stamp, list(observations)), "observations")

    def _timed(self, fn, kind: str) -> None:
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        self.updates.append(wall, cpu, len(self.map), UPDATE_KINDS.index(kind))

    # ------------------------------------------------------------------ updates
    def _keyframe(self, stamp: int) -> int:
        """A new keyframe, then the window slides if it is due."""
        k = self.keyframes.next(stamp)
        slid = self.window.slide(self.session, self.keyframes.stamps)
        if slid is not None:
            self.map.left_window(*slid)
            self.keyframes.refresh()
        return k

    def _keyframe_for(self, stamp: int) -> int | None:
        stamps = self.keyframes.stamps
        if stamp == stamps[-1]:
            return len(stamps) - 1
        if stamp > stamps[-1]:
            return self._keyframe(stamp)
        return self.keyframes.older(stamp, self.diagnostics)

    def _observations(self, stamp: int, observations: list[Observation]) -> None:
        k = self._keyframe_for(stamp)
        if k is None:
            return
        odom = [z for z in observations if isinstance(z, OdometryObservation)]
        factors = [(f, None) for f in self.keyframes.odometry_factors(odom, self.diagnostics)]
        self.map.begin(k, factors)
        self.mapper.process(stamp, observations)
        self.map.settle()  # the odometry alone, when no landmark was observed

    # ------------------------------------------------------------------ result
    def finish(self) -> EstimatorResult:
        self.keyframes.flush()  # deferred keyframes into iSAM2
        n = len(self.keyframes)
        updates = self.updates.array()
        history: dict = {
            "update_kinds": [UPDATE_KINDS[i] for i in updates["kind"]],
            "update_cpu_s": np.array(updates["cpu_s"]),
            "n_keyframes": n,
            "window_slides": list(self.window.slides),
            "window_returns": self.window.returns,
        }
        if n == 0:
            self.diagnostics.append("no keyframe: the mission had no AHRS (or no start pose)")
            empty = Trajectory(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 4)))
            return EstimatorResult(self.name, empty, diagnostics=list(self.diagnostics))
        values = final_values(self.session, self.window, self.cfg, self.batch, history)
        marginals = self.session.marginals(values) if self.cfg.covariance_in_result else None
        in_window = self.session.window_keys()
        left = {k: c for k, c in self.window.left_covariance.items() if k not in in_window}  # not come back
        landmarks = self.mapper.confirmed(self.map.estimates(self.cfg.covariance_in_result, values, marginals, left))
        self.book.connect(landmarks, self.assoc.merge_distance_m)
        ids = [lm.id for lm in landmarks]
        history["landmark_kind"] = {lm.id: lm.kind for lm in landmarks}
        history["landmark_volume"] = {
            lid: (np.array([s for s, _ in v], np.int64), np.array([x for _, x in v]))
            for lid, v in self.map.volume.items()
        }
        history["duplicates_merged"] = self.mapper.merged
        kf = self.keyframes
        if kf.has_gyro_bias:  # the newest keyframe's gyro bias (rad/s, body axes) and its σ per axis
            history["gyro_bias_rad_s"] = kf.gyro_bias / GYRO_BIAS_UNIT_S
            if kf.state_cov is not None:
                history["gyro_bias_sigma_rad_s"] = np.sqrt(np.diag(kf.state_cov)[-3:]) / GYRO_BIAS_UNIT_S
        history["objects_left_out"] = len(self.mapper.left_out)
        history.update(self.book.history(ids))
        return EstimatorResult(
            name=self.name,
            trajectory=keyframe_trajectory(self.keyframes.stamps, values, marginals, self.session, self.cfg, left),
            landmarks=landmarks,
            online_trajectory=online_trajectory(self.keyframes.online.array()),
            update_times_s=np.array(updates["wall_s"]),
            update_n_landmarks=np.array(updates["n_landmarks"], int),
            history=history,
            diagnostics=list(self.diagnostics),
        )
