"""A run as a ROS 2 bag (MCAP) of standard messages, for Foxglove and RViz: ``DIR/replay.mcap``.

:class:`ReplayRecorder` watches the pipeline (it is a ``semslam.pipeline.PipelineObserver``): it
keeps each scan, decimated and labelled with the front-ends' segmentation, and each map update of
the estimators it follows. :meth:`ReplayRecorder.write` then writes, on the mission's clock:

====================================  =============================================  ==========================
topic                                 type                                           when
====================================  =============================================  ==========================
/tf_static                            tf2_msgs/TFMessage                             once, at the first stamp
/tf                                   tf2_msgs/TFMessage                             with every pose below
/semslam/<est>/pose                   geometry_msgs/PoseWithCovarianceStamped        each keyframe / update
                                                                                     (at most ``pose_rate_hz``)
/semslam/<est>/path                   nav_msgs/Path                                  every ``path_period_s``
                                                                                     and at the last stamp
/semslam/<est>/map                    visualization_msgs/MarkerArray                 each map change (below)
/semslam/truth/pose                   geometry_msgs/PoseStamped                      as the poses above
/semslam/truth/path, /truth/map       nav_msgs/Path, visualization_msgs/MarkerArray  path as above; map once
/semslam/scan/<sensor>                sensor_msgs/PointCloud2                        each scan
====================================  =============================================  ==========================

Frames: ``map`` (east-north-up, for viewers) → ``world`` (semslam's {W}, north-east-down; every
message is stamped in it) → ``<est>/base_link`` (the body, forward-right-down; ``truth/base_link``
for the ground truth) → ``<est>/<sensor>`` (each sensor's mount, T_BS).

A pose, its transform and the path are each estimator's estimate at that time (a smoother's online
estimate); at the last stamp the path is the final (smoothed) trajectory. The map of each
estimator in ``map_estimators`` is read after steps that fed observations (at most every
``map_period_s`` of mission time, and after the front-ends' last word) and published when it
changed (a landmark came or went, changed class, or moved or changed its σ by more than
``map_tolerance_m``); the final map (with the covariances a smoother only computes at the end)
follows at the last stamp if it differs. Scans are placed in {W} with the final trajectory of
``scan_estimator`` (else of the first estimator).
"""

from __future__ import annotations

import copy
import functools
import os
import shutil
import tempfile
from collections import defaultdict
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
from pydantic import BaseModel, ConfigDict, Field
from scipy.spatial.transform import Rotation

from semslam.estimation import EstimateView, LandmarkEstimate, Trajectory
from semslam.eval import ros_messages as rm
from semslam.eval.replay_scene import landmark_markers, truth_markers
from semslam.eval.scan_segments import SCAN_TYPES, SegmentedScan, keep_at_most, scan_points, segment
from semslam.mission.mission import MissionMetadata
from semslam.observations import LineObservation, Observation, StructureObservation
from semslam.results import PipelineResult

REPLAY_FILE = "replay.mcap"
LAYOUT_FILE = "foxglove_layout.json"
LAYOUT_PATH = Path(__file__).with_name(LAYOUT_FILE)  # package data of semslam.eval
DISPLAY_FRAME, WORLD_FRAME, TRUTH = "map", "world", "truth"
# map (ENU) → world (NED): x_map = y_ned (east), y_map = x_ned (north), z_map = -z_ned (up).
NED_IN_ENU = (np.sqrt(0.5), np.sqrt(0.5), 0.0, 0.0)


class ReplayConfig(BaseModel):
    """What the replay keeps (the defaults keep the demo's whole output under 15 MB)."""

    model_config = ConfigDict(extra="forbid")
    pose_rate_hz: float = Field(5.0, gt=0, description="poses and transforms of each estimator at most this often")
    path_period_s: float = Field(10.0, gt=0, description="each estimator's path so far, every this many seconds")
    path_spacing_s: float = Field(1.0, ge=0, description="poses in a path at least this far apart in time")
    scan_points: int = Field(
        600, ge=0, description="at most this many points of each scan, the labelled ones first (0: no scans)"
    )
    scan_voxel_m: float = Field(0.02, ge=0, description="a scan is thinned to one point per cube of this size")
    label_tolerance_m: float = Field(
        0.02, gt=0, description="a scan point within this distance of an observation's geometry takes its label"
    )
    scan_estimator: str = Field("graph", description="whose final trajectory places the scans in the world")
    map_estimators: tuple[str, ...] = Field(("graph", "ekf"), description="estimators whose map is followed")
    map_period_s: float = Field(
        2.0, ge=0, description="the maps are read at most this often (mission time; reading a map costs)"
    )
    map_tolerance_m: float = Field(
        0.005, ge=0, description="a map update is published when a landmark moved (or its σ changed) by more"
    )


class ReplayRecorder:
    """Records a run for the replay; hand it to ``run_pipeline(observers=...)``, then :meth:`write`."""

    def __init__(self, metadata: MissionMetadata, config: ReplayConfig | None = None):
        self.metadata = metadata
        self.config = config or ReplayConfig()
        self.first: int | None = None
        self.last: int | None = None
        self.scans: list[SegmentedScan] = []
        # estimator → [(stamp, landmarks)], one entry per published map update
        self.maps: dict[str, list[tuple[int, list[LandmarkEstimate]]]] = defaultdict(list)
        self._signatures: dict[str, tuple] = {}
        self._radii: list[float] = []
        self._map_read: int | None = None  # when the maps were last read

    # ------------------------------------------------------------------ the PipelineObserver
    def step(
        self,
        stamp: int,
        measurement,
        observations: Sequence[tuple[str, Sequence[Observation]]],
        views: Mapping[str, EstimateView],
    ) -> None:
        self.first = stamp if self.first is None else self.first
        self.last = stamp
        obs = [o for _, batch in observations for o in batch]
        self._radii += [o.radius for o in obs if isinstance(o, LineObservation) and o.radius is not None]
        if isinstance(measurement, SCAN_TYPES) and self.config.scan_points > 0:
            self._record_scan(measurement, obs)
        due = self._map_read is None or stamp - self._map_read >= self.config.map_period_s * 1e9
        if obs and (due or measurement is None):  # a map changes with what the estimators are fed
            self._map_read = stamp
            for name in self.config.map_estimators:
                if name in views:
                    self._record_map(name, stamp, list(views[name].landmarks()))

    def _record_scan(self, m, obs: list[Observation]) -> None:
        cfg = self.config
        seed = m.stamp % 2**32
        pts = scan_points(m, cfg.scan_points, cfg.scan_voxel_m, seed)
        mine = [o for o in obs if o.sensor == m.sensor and o.stamp == m.stamp]
        boxes = _structure_boxes() if any(isinstance(o, StructureObservation) for o in mine) else None
        labelled = segment(m.stamp, m.sensor, pts, mine, cfg.label_tolerance_m, boxes)
        self.scans.append(keep_at_most(labelled, cfg.scan_points, seed))

    def _record_map(self, name: str, stamp: int, landmarks: list[LandmarkEstimate]) -> None:
        """Keep ``landmarks`` as a map update of ``name`` if it differs from the last one kept."""
        sig = _signature(landmarks)
        old = self._signatures.get(name)
        if old is None or not _same(old, sig, self.config.map_tolerance_m):
            self._signatures[name] = sig
            self.maps[name].append((stamp, copy.deepcopy(landmarks)))

    def map_updates(self, name: str, final: list[LandmarkEstimate]) -> list[tuple[int, list[LandmarkEstimate]]]:
        """The map updates of ``name`` to publish: those recorded during the run, then its final map
        (with the covariances a smoother computes only at the end) at the last stamp if it differs."""
        if name not in self.config.map_estimators:
            return []
        updates = list(self.maps.get(name, []))
        old = self._signatures.get(name)
        if final and (old is None or not _same(old, _signature(final), self.config.map_tolerance_m)):
            updates.append((self.last, list(final)))
        return updates

    # ------------------------------------------------------------------ writing
    @property
    def pipe_radius(self) -> float:
        """The pipes' radius as the front-ends measured it (median), for the pipe markers."""
        return float(np.median(self._radii)) if self._radii else 0.03

    def messages(self, result: PipelineResult) -> list[tuple[int, str, object]]:
        """Every message of the replay as (stamp, topic, message), in stamp order."""
        if self.first is None:
            return []
        t0 = self.first
        out: list[tuple[int, str, object]] = [(t0, "/tf_static", rm.tf_message(self._static_transforms(result)))]
        for name, res in result.results.items():
            online = res.online_trajectory if res.online_trajectory is not None else res.trajectory
            out += self._trajectory_messages(name, online, res.trajectory, with_cov=True)
            for stamp, lms in self.map_updates(name, res.landmarks):
                out.append((stamp, f"/semslam/{name}/map", rm.marker_array(self._map(stamp, lms))))
        if result.truth is not None and len(result.truth):
            out += self._trajectory_messages(TRUTH, result.truth, result.truth, with_cov=False)
        gt = self.metadata.ground_truth
        if gt is not None:
            out.append((t0, "/semslam/truth/map", rm.marker_array(truth_markers(t0, WORLD_FRAME, gt))))
        out += self._scan_messages(result)
        out.sort(key=lambda m: m[0])  # stable: the static transforms stay first
        return out

    def write(self, path: str | Path, result: PipelineResult) -> dict[str, int]:
        """Write the replay as one MCAP file at ``path``; returns the message count per topic."""
        from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
        from rosbags.rosbag2 import StoragePlugin, Writer
        from rosbags.rosbag2.enums import CompressionFormat, CompressionMode

        path = Path(path)
        zero = QosTime(0, 0)
        latched = Qos(
            QosHistory.KEEP_LAST, 1, QosReliability.RELIABLE, QosDurability.TRANSIENT_LOCAL,
            zero, zero, QosLiveliness.AUTOMATIC, zero, False,
        )  # fmt: skip
        counts: dict[str, int] = defaultdict(int)
        tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", dir=path.parent))
        try:
            bag = tmp / path.stem
            writer = Writer(bag, version=Writer.VERSION_LATEST, storage_plugin=StoragePlugin.MCAP)
            writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
            writer.open()
            conns = {}
            for stamp, topic, msg in self.messages(result):
                if topic not in conns:
                    qos = [latched] if topic == "/tf_static" else []
                    conns[topic] = writer.add_connection(
                        topic, msg.__msgtype__, typestore=rm.STORE, offered_qos_profiles=qos
                    )
                writer.write(conns[topic], stamp, rm.serialize(msg))
                counts[topic] += 1
            writer.close()
            os.replace(bag / f"{path.stem}.mcap", path)
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
        return dict(counts)

    # ------------------------------------------------------------------ the parts
    def _static_transforms(self, result: PipelineResult) -> list:
        t0 = self.first
        tfs = [rm.transform(t0, DISPLAY_FRAME, WORLD_FRAME, (0, 0, 0), NED_IN_ENU)]
        bodies = [*result.results, *([TRUTH] if result.truth is not None and len(result.truth) else [])]
        for body in bodies:
            for sensor in self.metadata.sensors.values():
                if sensor.kind == "ground_truth":
                    continue
                T = sensor.T_BS
                q = Rotation.from_matrix(T[:3, :3]).as_quat()
                tfs.append(rm.transform(t0, f"{body}/base_link", f"{body}/{sensor.name}", T[:3, 3], q))
        return tfs

    def _trajectory_messages(self, name: str, traj: Trajectory, final: Trajectory, with_cov: bool) -> list:
        cfg = self.config
        out = []
        body = f"{name}/base_link"
        for i in thin(traj.stamps, 1e9 / cfg.pose_rate_hz):
            s, p, q = int(traj.stamps[i]), traj.positions[i], traj.orientations[i]
            if with_cov:
                cov = traj.position_cov[i] if traj.position_cov is not None else None
                out.append((s, f"/semslam/{name}/pose", rm.pose_with_covariance(s, WORLD_FRAME, p, q, cov)))
            else:
                out.append((s, f"/semslam/{name}/pose", rm.pose_stamped(s, WORLD_FRAME, p, q)))
            out.append((s, "/tf", rm.tf_message([rm.transform(s, WORLD_FRAME, body, p, q)])))
        spacing = cfg.path_spacing_s * 1e9
        along, along_final = thin(traj.stamps, spacing), thin(final.stamps, spacing)
        for t in path_stamps(self.first, self.last, cfg.path_period_s):
            src, idx = (final, along_final) if t == self.last else (traj, along)
            idx = idx[src.stamps[idx] <= t]
            path = rm.path(t, WORLD_FRAME, src.stamps[idx], src.positions[idx], src.orientations[idx])
            out.append((t, f"/semslam/{name}/path", path))
        return out

    def _map(self, stamp: int, landmarks: list[LandmarkEstimate]) -> list:
        return landmark_markers(stamp, WORLD_FRAME, landmarks, self.pipe_radius)

    def _scan_messages(self, result: PipelineResult) -> list:
        if not self.scans:
            return []
        placer = result.results.get(self.config.scan_estimator) or next(iter(result.results.values()))
        traj = placer.trajectory
        if len(traj) == 0:
            return []
        stamps = np.array([s.stamp for s in self.scans], np.int64)
        R_WB, t_WB = traj.poses_at(stamps)
        out = []
        for scan, R, t in zip(self.scans, R_WB, t_WB):
            T_BS = self.metadata.sensors[scan.sensor].T_BS if scan.sensor in self.metadata.sensors else np.eye(4)
            world = (scan.points @ T_BS[:3, :3].T + T_BS[:3, 3]) @ R.T + t
            msg = rm.point_cloud(scan.stamp, WORLD_FRAME, world, scan.rgb, scan.segment, scan.cls)
            out.append((scan.stamp, f"/semslam/scan/{scan.sensor}", msg))
        return out


def make_recorder(record: bool, metadata: MissionMetadata, scan_points: int | None = None) -> ReplayRecorder | None:
    """The recorder the commands' ``--record`` and ``--record-points`` ask for (None without ``record``)."""
    if not record:
        return None
    return ReplayRecorder(metadata, ReplayConfig() if scan_points is None else ReplayConfig(scan_points=scan_points))


def thin(stamps: np.ndarray, period_ns: float) -> np.ndarray:
    """Indices of ``stamps`` (sorted) kept when no two kept ones are closer than ``period_ns``:
    the first, then each one at least that long after the last kept."""
    keep, last = [], None
    for i, s in enumerate(np.asarray(stamps, np.int64)):
        if last is None or s - last >= period_ns:
            keep.append(i)
            last = s
    return np.array(keep, int)


def path_stamps(first: int, last: int, period_s: float) -> list[int]:
    """When the paths are published: every ``period_s`` after ``first``, and at ``last``."""
    step = int(period_s * 1e9)
    return [*range(first + step, last, step), last]


def _signature(landmarks: list[LandmarkEstimate]) -> tuple:
    """What a map update shows: per landmark (id, kind, class) and its geometry with its σ."""
    keys, geo = [], []
    for lm in sorted(landmarks, key=lambda lm: (lm.kind, lm.id)):
        post = lm.class_posterior or {}
        keys.append((lm.id, lm.kind, max(post, key=post.get) if post else None))
        if lm.kind == "pipe":
            g = [
                *np.ravel(lm.p if lm.p is not None else np.zeros(3)),
                *np.ravel(lm.q if lm.q is not None else np.zeros(3)),
            ]
        elif lm.kind == "structure" and lm.pose is not None:
            g = [*np.ravel(np.asarray(lm.pose)[:3, :4])]
        else:
            g = [*np.ravel(lm.position if lm.position is not None else np.zeros(3))]
        cov = lm.covariance
        if lm.kind != "pipe" and cov is not None:
            block = np.asarray(cov)[-3:, -3:]  # position, or a structure's translation
            g.append(float(np.sqrt(max(np.trace(block), 0.0))))
        else:
            g.append(-1.0)
        geo.append(g)
    return tuple(keys), geo


def _same(a: tuple, b: tuple, tol: float) -> bool:
    if a[0] != b[0]:
        return False
    return all(len(x) == len(y) and np.max(np.abs(np.subtract(x, y))) <= tol for x, y in zip(a[1], b[1]))


@functools.cache
def _structure_boxes() -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Bounding box (min, max corner in the model frame) of every known structure model."""
    from semslam.models.structures import structure_library

    return {name: (m.vertices.min(axis=0), m.vertices.max(axis=0)) for name, m in structure_library().items()}


def how_to_open(out_dir: str | Path) -> str:
    """What a command prints after writing a replay: where it is and how to open it."""
    out = Path(out_dir).resolve()
    return (
        f"replay: {out / REPLAY_FILE}\n"
        f"  Foxglove: open that file, then Layouts > Import from file: {out / LAYOUT_FILE}\n"
        f"  RViz: ros2 bag play {out / REPLAY_FILE} --clock  (Humble: add -s mcap; fixed frame: map)"
    )
