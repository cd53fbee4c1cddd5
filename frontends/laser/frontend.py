"""The laser front-end: a scan in, pipe (line) and object (point) observations out, in {S}.

``segment_scan`` runs the stages (pre-processing, plane removal, pipes, objects) and keeps every
intermediate result for evaluation and figures; ``LaserFrontend`` wraps it behind the front-end
protocol of ``semslam.registry``.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from typing import Any, ClassVar, Protocol

import numpy as np
from scipy.spatial.transform import Rotation

from frontends.laser.config import LaserConfig, PipeConfig
from frontends.laser.grid import VoxelGrid, adjacency_of, stable_order
from frontends.laser.ground import GroundModel, fit_ground
from frontends.laser.noise import NoiseModel, measure_noise
from frontends.laser.objects import SegmentedObject, segment_objects
from frontends.laser.pipe_shape import Seabed, axis_height, lies_on_ground
from frontends.laser.pipes import Pipe, Rays, detect_pipes, over_a_line
from frontends.laser.planes import PlaneResult, remove_planes
from frontends.laser.preprocess import Preprocessed, hop_covariance_parts, preprocess, shape_of_parts
from semslam.errors import validated
from semslam.mission.measurements import Attitude, PointCloud
from semslam.observations import Connectivity, LineObservation, Observation, PointObservation
from semslam.registry import FrontendSummary

UP_NED = np.array([0.0, 0.0, -1.0])  # against gravity in the world frame (NED: z down)


# One line on stderr (logging's last-resort handler) unless the application configures logging.
log = logging.getLogger(__name__)
_RANGE_SAMPLE = 2000  # points of a cloud whose ranges are checked (evenly strided)


_FAR_FACTOR = 2.0  # a cloud whose median range exceeds max_range this many times over is not a far background


def range_problem(points: np.ndarray, min_range: float, max_range: float) -> str | None:
    """What is wrong with a cloud most of whose finite points lie outside [min_range, max_range]
    (m, from the sensor) for a likely cause: its median range in range once divided by 1000 (a cloud
    in millimetres), or beyond ``_FAR_FACTOR`` × max_range (a cloud in the world frame, or another
    sensor's). None otherwise: a scene mostly beyond max_range (the tank's far walls at 8-9 m, a view
    into open water) is a scene, not a wrong cloud."""
    pts = np.asarray(points, dtype=np.float64)
    pts = pts[:: max(len(pts) // _RANGE_SAMPLE, 1)]
    r = np.sqrt(np.einsum("ij,ij->i", pts, pts))
    r = r[np.isfinite(r)]
    if len(r) < 10:
        return None
    inside = float(np.mean((r >= min_range) & (r <= max_range)))
    med = float(np.median(r))
    if inside >= 0.5 or med <= _FAR_FACTOR * max_range:
        return None
    if min_range <= med / 1000.0 <= max_range:
        cause = "a cloud in millimetres? (points must be in metres)"
    else:
        cause = "a cloud in the world frame, or another sensor's? (points must be in the sensor's frame, metres)"
    return (
        f"{100 * (1 - inside):.0f}% of the points lie outside preprocess.min_range..max_range "
        f"({min_range:g}-{max_range:g} m; median range {med:.4g} m): {cause} They are dropped."
    )


class Recognizer(Protocol):
    """Object recognition hook: class likelihoods P(Z | X) of a segmented cloud (sensor frame)."""

    def classify(self, cloud: np.ndarray, connectivity: Connectivity) -> dict[str, float]: ...


@dataclass
class ScanSegmentation:
    """Everything one scan went through, in {S}.

    ``pre`` is the coarse cloud of the plane segmentation and ``planes`` its result; ``structure``
    indexes the coarse voxels kept. ``ground`` models the ground under the scan (a height field;
    ``on_ground`` marks the structure points on it: they seed no pipe and join no object). ``structure_points`` is the structure re-sampled finely from the
    raw points (``raw_to_structure`` maps every raw point to its fine voxel, −1 if not structure),
    with ``normals``; pipe inliers and object indices index ``structure_points``.
    """

    pre: Preprocessed
    planes: PlaneResult
    structure: np.ndarray
    structure_points: np.ndarray
    raw_to_structure: np.ndarray
    normals: np.ndarray
    pipes: list[Pipe]
    objects: list[SegmentedObject]
    up: np.ndarray
    timings: dict[str, float] = field(default_factory=dict)
    noise: NoiseModel | None = None  # the scan's measured noise
    ground: GroundModel | None = None  # the ground under the scan (None: not modelled)
    on_ground: np.ndarray | None = None  # (M,) structure points on the ground
    pipe_config: PipeConfig | None = None  # the pipe stage's configuration, scaled to this scan's noise

    def raw_indices(self, structure_indices: np.ndarray) -> np.ndarray:
        """Raw scan points that fell in the given fine structure voxels (sorted)."""
        if not hasattr(self, "_raw_index"):
            self._raw_index = RawIndex(self.raw_to_structure, len(self.structure_points))
        return self._raw_index(structure_indices)


class RawIndex:
    """The raw points of fine structure voxels: ``raw_to_structure`` (N,) each raw point's voxel
    (−1: none), ``n`` voxels. The raw points are grouped by voxel once (not a pass over the raw scan
    per query), on the first query (a scan without colour never asks): voxel v's raw points are
    order[start[v]:start[v + 1]]."""

    def __init__(self, raw_to_structure: np.ndarray, n: int):
        self._raw_to_structure, self._n = raw_to_structure, n
        self._built: tuple[np.ndarray, np.ndarray] | None = None

    @property
    def order(self) -> np.ndarray:
        return self._tables()[0]

    @property
    def start(self) -> np.ndarray:
        return self._tables()[1]

    def _tables(self) -> tuple[np.ndarray, np.ndarray]:
        if self._built is None:
            r2s = self._raw_to_structure
            inside = np.flatnonzero(r2s >= 0)
            order = inside[stable_order(r2s[inside])]
            self._built = order, np.r_[0, np.cumsum(np.bincount(r2s[inside], minlength=self._n))]
        return self._built

    def __call__(self, structure_indices: np.ndarray) -> np.ndarray:
        """Raw scan points that fell in the given voxels (sorted)."""
        start = self.start
        v = np.unique(structure_indices)
        counts = start[v + 1] - start[v]
        offsets = np.repeat(start[v] - np.r_[0, np.cumsum(counts)[:-1]], counts)
        return np.sort(self.order[np.arange(counts.sum()) + offsets])


def structure_cloud(raw: np.ndarray, pre: Preprocessed, planes: PlaneResult, cfg: LaserConfig):
    """The structure at fine resolution: raw points of the kept coarse voxels, re-voxelised.

    Returns (grid :class:`VoxelGrid` or None when empty, raw_to_structure (N,), normals M×3); the
    grid's ``points`` (M×3) are the structure points.
    """
    raw_to_structure = np.full(len(raw), -1, np.int64)
    kept_voxel = np.append(planes.structure, False)  # v = −1 (cropped, outlier) → the False slot
    keep = np.flatnonzero(kept_voxel[pre.raw_to_voxel])
    if len(keep) == 0:
        return None, raw_to_structure, np.zeros((0, 3))
    grid = VoxelGrid(raw.take(keep, axis=0), cfg.preprocess.structure_voxel_size)  # (np.take: faster than raw[keep])
    raw_to_structure[keep] = grid.inverse
    A = adjacency_of(grid.neighbours(1))
    normals, _, _ = shape_of_parts(hop_covariance_parts(grid.points, A, cfg.pipes.normal_hops), grid.points)
    return grid, raw_to_structure, normals


class _StageClock:
    """Wall and process-CPU time of consecutive stages: ``timings[name]`` (wall, s) and
    ``timings["cpu_" + name]`` (CPU of the whole process: both cores when a library threads; on a
    shared machine the wall time also counts waiting for a core, the CPU time does not)."""

    def __init__(self, timings: dict[str, float]):
        self.timings = timings
        self.w0 = self.w = time.perf_counter()
        self.c0 = self.c = time.process_time()

    def lap(self, name: str) -> None:
        w, c = time.perf_counter(), time.process_time()
        self.timings[name] = self.timings.get(name, 0.0) + w - self.w
        self.timings["cpu_" + name] = self.timings.get("cpu_" + name, 0.0) + c - self.c
        self.w, self.c = w, c

    def total(self, name: str = "total") -> None:
        self.timings[name] = time.perf_counter() - self.w0
        self.timings["cpu_" + name] = time.process_time() - self.c0


def scan_pipe_config(cfg: PipeConfig, noise: NoiseModel | None, points: np.ndarray) -> PipeConfig:
    """The pipe stage's configuration for one scan: the inlier tolerance at least ``distance_sigmas``
    × the scan's noise σ at the median range of ``points`` (the structure that may hold pipes)."""
    if noise is None or not len(points) or cfg.distance_sigmas <= 0:
        return cfg
    sigma = float(noise.at(np.median(np.sqrt(np.einsum("ij,ij->i", points, points)))))
    tol = max(cfg.distance_tolerance, cfg.distance_sigmas * sigma)
    return cfg if tol == cfg.distance_tolerance else cfg.model_copy(update={"distance_tolerance": tol})


def _lying(pipes: list[Pipe], ground, pcfg: PipeConfig) -> np.ndarray:
    """Per pipe segment: whether it lies on the ground (none without a ground model)."""
    if ground is None:
        return np.zeros(len(pipes), bool)
    heights = [axis_height(p, ground) for p in pipes]
    return np.array([h is not None and lies_on_ground(h, p.radius, pcfg) for h, p in zip(heights, pipes)], bool)


def _objects(
    spts, pipes: list[Pipe], up, cfg: LaserConfig, pcfg: PipeConfig, on_ground, ground, rays: Rays, lying: np.ndarray
):
    """The objects at the pipes' ends (:func:`segment_objects`). On the seabed, a segment lying on
    the ground and shorter than ``min_partial_length`` (not reported: a valve's lever or body, a
    stone's flank fitted as a pipe) connects no object: its points go to the objects instead (in the
    tank, where no pipe lies on the ground, the short pipes between fittings do connect them). A
    segment that only serves the objects (``objects_only``) counts as lying."""
    if ground is None:
        return segment_objects(spts, pipes, up, cfg.objects, on_ground, None, None, rays.seen_at)
    # a short held run (held_short_objects: it may be a stone's top) is judged as lying on the seabed
    # wherever the ground model puts it: a fitting at its end must rise over it
    lying = lying | np.array([p.objects_only for p in pipes], bool)
    arms = [k for k, p in enumerate(pipes) if not (lying[k] and p.length < pcfg.min_partial_length)]
    objects = segment_objects(
        spts, [pipes[k] for k in arms], up, cfg.objects, on_ground, ground, lying[arms], rays.seen_at
    )
    for o in objects:  # the attached pipes' indices into the scan's pipe list
        o.pipes = tuple(arms[k] for k in o.pipes)
    return objects


def segment_scan(
    points: np.ndarray, cfg: LaserConfig, up: np.ndarray | None = None, rgb: np.ndarray | None = None
) -> ScanSegmentation:
    """Run all stages on a raw scan (N×3, {S}; NaN points are dropped). ``up`` is the unit up
    direction in {S} (from the AHRS); when None the direction towards the sensor is used (the
    scanner looks down at the structure) and the ground is not modelled. ``rgb`` (N×3 uint8, or
    None): the points' colours, an optional cue of the pipe test on a natural seabed."""
    tm: dict[str, float] = {}
    clock = _StageClock(tm)
    raw = np.asarray(points, dtype=np.float64)
    pre = preprocess(raw, cfg.preprocess, cfg.planes)
    noise = measure_noise(raw, pre)
    clock.lap("preprocess")
    planes = remove_planes(pre, cfg.planes, cfg.preprocess.voxel_size)
    structure = np.flatnonzero(planes.structure)
    clock.lap("planes")
    ground = None
    if up is not None and cfg.ground.enabled:
        sigma = float(noise.at(noise.range_ref)) if noise is not None else 0.0
        ground = fit_ground(pre.points, pre.counts, up, cfg.ground, sigma)
    clock.lap("ground")
    grid, raw_to_s, normals = structure_cloud(raw, pre, planes, cfg)
    spts = grid.points if grid is not None else np.zeros((0, 3))
    on_ground = ground.is_ground(spts) if ground is not None else np.zeros(len(spts), bool)
    clock.lap("structure")
    if up is None:
        up = -spts.mean(axis=0) if len(spts) else -UP_NED
        up = up / max(np.linalg.norm(up), 1e-12)
    pipes: list[Pipe] = []
    pcfg = scan_pipe_config(cfg.pipes, noise, spts[~on_ground])
    rays = Rays(raw)
    if int((~on_ground).sum()) >= cfg.pipes.min_points:
        seabed = None
        if ground is not None:
            seabed = Seabed(ground, spts, pcfg, raw, rgb, RawIndex(raw_to_s, len(spts)))
        pipes = detect_pipes(spts, normals, grid, pcfg, rays, ~on_ground, ~on_ground, seabed)
    clock.lap("pipes")
    lying = _lying(pipes, ground, pcfg)
    if lying.any():  # a fitting's part standing over a line lying on the seabed is no pipe
        keep = ~over_a_line(pipes, lying, up, pcfg)
        pipes, lying = [p for p, k in zip(pipes, keep) if k], lying[keep]
    for pipe in (p for p, lies in zip(pipes, lying) if lies):
        # on the seabed a run between two "fittings" may be a stone's top between two stones, and a
        # short segment lying there connects no object (_objects): only its length reports it
        pipe.between_fittings = False
    objects = _objects(spts, pipes, up, cfg, pcfg, on_ground, ground, rays, lying)
    clock.lap("objects")
    clock.total()
    return ScanSegmentation(
        pre, planes, structure, spts, raw_to_s, normals, pipes, objects, up, tm, noise, ground, on_ground, pcfg
    )


class LaserFrontend:
    """Laser scanner front-end (``frontends.laser`` section validated by :class:`LaserConfig`).

    Consumes :class:`PointCloud` scans; returns one :class:`LineObservation` per pipe segment at least
    ``pipes.min_length`` long and one :class:`PointObservation` per object (class likelihoods filled
    only when a ``recognizer`` is set: pass one to the constructor or assign ``frontend.recognizer``).
    When the pipes' radius is known (the tank's 31.5 mm PVC), give it as ``pipes.radius_prior``.
    """

    config_model: ClassVar[type] = LaserConfig  # its section of the configuration, frontends.<name>
    name: ClassVar[str] = "laser"
    # The AHRS gives "up" (roll and pitch), so the front-end never reads the estimate and may run in
    # a process of its own, ahead of the estimators (semslam.frontend_process).
    consumes: ClassVar[tuple[type, ...]] = (PointCloud, Attitude)
    uses_view: ClassVar[bool] = False
    # A scan's result depends only on the scan and the latest AHRS reading (the RANSAC and ESF
    # generators are seeded per call): replicas in several worker processes may share the scans.
    parallel_consumes: ClassVar[tuple[type, ...]] = (PointCloud,)

    def __init__(self, metadata: Any, config: dict | None = None, recognizer: Recognizer | None = None):
        self.config = validated(LaserConfig, config, "frontends.laser")
        self.metadata = metadata
        self._recognizer = recognizer
        self._latest_attitude: Attitude | None = None  # the latest AHRS reading (R_WB computed from it per scan)
        self.last: ScanSegmentation | None = None  # the latest scan's stages, for inspection
        self._warned: set[str] = set()  # sensors whose clouds were found out of range (warned once each)

    @property
    def recognizer(self) -> Recognizer | None:
        """The configured recogniser, built on first use: the view database is rendered once and
        cached on disk, so a run that never segments an object never pays for it."""
        if self._recognizer is None and self.config.recognition.enabled:
            from frontends.laser.recognition.config import recognizer_from_config

            self._recognizer = recognizer_from_config(self.config.recognition, progress=True)
        return self._recognizer

    @recognizer.setter
    def recognizer(self, value: Recognizer | None) -> None:
        self._recognizer = value

    def _extrinsic(self, sensor: str) -> np.ndarray | None:
        info = getattr(self.metadata, "sensors", {}).get(sensor) if self.metadata is not None else None
        return None if info is None else np.asarray(info.T_BS)[:3, :3]

    def _up(self, sensor: str) -> np.ndarray | None:
        """Up (against gravity) in {S}: R_WSᵀ·up_W, with R_WB from the latest AHRS reading (its
        heading bias does not change "up"), or level (the extrinsic alone) before the first."""
        R_BS = self._extrinsic(sensor)
        if R_BS is None:
            return None
        R_WB = self._R_WB(self._latest_attitude) if self._latest_attitude is not None else np.eye(3)
        return (R_WB @ R_BS).T @ UP_NED

    def _R_WB(self, m: Attitude) -> np.ndarray:
        """The vehicle's attitude R_WB from an AHRS reading."""
        R_BA = self._extrinsic(m.sensor)
        R_WA = Rotation.from_quat(np.asarray(m.orientation, float)).as_matrix()
        return R_WA @ (R_BA.T if R_BA is not None else np.eye(3))

    def process(self, measurement: PointCloud | Attitude, view=None) -> list[Observation]:
        if isinstance(measurement, Attitude):
            # Only the latest reading before a scan is used: kept as is, converted at the scan
            # (~40 AHRS readings a scan in the tank mission; the conversion was most of their cost).
            self._latest_attitude = measurement
            return []
        self._check_range(measurement)
        seg = segment_scan(measurement.points, self.config, self._up(measurement.sensor), measurement.rgb)
        self.last = seg
        stamp, sensor = measurement.stamp, measurement.sensor
        obs: list[Observation] = [
            LineObservation(stamp, sensor, p=pp.p, q=pp.q, covariance=pp.covariance, radius=pp.radius)
            for pp in seg.pipes
            if pp.reported(seg.pipe_config)
        ]
        spts = seg.structure_points
        conns, clouds = [], []
        for o in seg.objects:
            conns.append(
                Connectivity(len(o.directions), o.configuration, tuple(tuple(map(float, d)) for d in o.directions))
            )
            if self.config.full_resolution_clouds:
                cloud = np.asarray(measurement.points)[seg.raw_indices(o.indices)]
            else:
                cloud = spts[o.indices]
            clouds.append(np.asarray(cloud, dtype=np.float32))
        likelihoods = self._classify(clouds, conns) if seg.objects else []
        for o, conn, cloud, likelihood in zip(seg.objects, conns, clouds, likelihoods):
            obs.append(
                PointObservation(
                    stamp,
                    sensor,
                    position=o.position,
                    covariance=o.covariance,
                    cloud=cloud,
                    class_likelihood=likelihood,
                    connectivity=conn,
                )
            )
        return obs

    def _check_range(self, m: PointCloud) -> None:
        """Warn once per sensor (one line on stderr, through ``logging``) when most of a cloud lies
        outside the configured range: a cloud in millimetres, or in the world frame, would otherwise
        give nothing, silently. (Once per front-end: with replicas in several worker processes,
        once per worker that meets such a cloud.)"""
        if m.sensor in self._warned:
            return
        message = range_problem(m.points, self.config.preprocess.min_range, self.config.preprocess.max_range)
        if message is not None:
            self._warned.add(m.sensor)
            log.warning("semslam: warning: laser front-end, sensor %r: %s", m.sensor, message)

    def _classify(self, clouds: list[np.ndarray], conns: list[Connectivity]) -> list[dict[str, float] | None]:
        """Class likelihoods of a scan's object clouds (None without a recogniser): all at once
        when the recogniser can (``classify_many``: the default one describes them together)."""
        rec = self.recognizer
        if rec is None:
            return [None] * len(clouds)
        if hasattr(rec, "classify_many"):
            return rec.classify_many(clouds, conns)
        return [rec.classify(c, k) for c, k in zip(clouds, conns)]

    def finish(self, view=None) -> FrontendSummary:
        """The recogniser's SYN stage (its confusion on held-out synthetic views, the P(Z | X) it
        used) for metrics.json's "recognition" block; nothing when no object was ever recognised
        or the confusion is the generic assumption rather than a measurement."""
        rec = self._recognizer
        if rec is None or not getattr(rec, "confusion_measured", False):
            return FrontendSummary()
        from semslam.semantics.metrics import classification_metrics

        return FrontendSummary(
            section="recognition", metrics={"SYN": classification_metrics(rec.confusion, rec.classes)}
        )
