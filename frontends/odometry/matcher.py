"""Scan-to-map registration with kiss-icp's library (voxel hash map, adaptive threshold, robust
point-to-point ICP), seeded by the navigation prior and judged before the map takes the scan.

kiss-icp's own ``KissICP.register_frame`` predicts with a constant-velocity model and always
inserts the scan into its map; here the prediction is the navigation sensors' and a registration
that the gate rejects never reaches the map (a shifted or featureless scan would corrupt it). So
the same components are called one by one: preprocess (range crop), voxelise, align, judge, update.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np
from kiss_icp.config import KISSConfig
from kiss_icp.kiss_icp import KissICP
from kiss_icp.threshold import AdaptiveThreshold
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from frontends.odometry.config import CovarianceSettings, OdometryConfig
from frontends.odometry.information import (
    VERTICAL,
    fitted_planes,
    mahalanobis2,
    plane_information,
    rotation_angle,
    twist_angle,
)

PLANE_NOISE_SCANS = 50  # scans over which the range noise's median is taken
PLANE_NOISE_POINTS = 50  # fewest plane points for a scan's range noise
# Without a removed plane the range noise is taken from the registration's point-to-plane residuals,
# which carry the scan's noise and the map's (the same sensor's): half of their variance each
RESIDUAL_NOISE_SHARE = 0.5
TRANSLATION_ITERATIONS = 10


@dataclass(frozen=True)
class Registration:
    """One scan's registration against the local map, in the map frame {O}."""

    pose: np.ndarray  # T_OS after ICP (4×4)
    correction: np.ndarray  # T_pred⁻¹ · T_OS: what ICP changed in the navigation prior
    covariance: np.ndarray  # 6×6 of T_OS (right perturbation, rotation then translation)
    information: np.ndarray  # point-to-plane Σ JᵀJ (6×6, per unit residual variance) behind it
    residual_var: float  # the point-to-plane residuals' variance (m²)
    inliers: int
    points: int
    rejected: str | None  # why it is not trusted, or None
    # the part of ``covariance`` that grows with ICP's disagreement with the prior (the front-end's Student-t
    # factor multiplies it): all of it, or with the attitude held the translation's measured part alone
    tail_part: np.ndarray | None = None


@contextmanager
def open3d_on_one_thread() -> Iterator[None]:
    """Inside the block, Open3D works on one thread (its previous limit is restored after). Open3D 0.20's
    RANSAC (``segment_plane``) runs its iterations in parallel, each drawing its sample from the one seeded
    generator: which iteration gets which draw depends on the threads' timing, so on several threads the
    same scan gave other planes from one call to the next, and the registrations after it other poses
    (experiments/odometry/README.md, stop 44). A run pins every library already
    (:func:`semslam.determinism.one_thread_per_library`); this pin holds wherever the front-end is called
    from (tests, experiments), so that the same input gives the same output to the bit."""
    import open3d as o3d

    before = o3d.utility.get_max_threads()
    o3d.utility.set_max_threads(1)
    try:
        yield
    finally:
        o3d.utility.set_max_threads(before)


def large_planes(points: np.ndarray, cfg) -> list[tuple[np.ndarray, float]]:
    """(unit normal, offset) of up to ``cfg.max_planes`` planes, each holding at least
    ``cfg.min_fraction`` of ``points`` (RANSAC, largest first; seeded and on one thread: the same scan gives
    the same planes)."""
    import open3d as o3d

    planes, rest = [], points
    for _ in range(cfg.max_planes):
        if len(rest) < 3:
            break
        pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(rest))
        o3d.utility.random.seed(0)
        with open3d_on_one_thread():
            model, inliers = pcd.segment_plane(cfg.distance_m, 3, 200)
        if len(inliers) < cfg.min_fraction * len(points):
            break
        normal = np.asarray(model[:3], float)
        norm = np.linalg.norm(normal)
        planes.append((normal / norm, float(model[3]) / norm))
        rest = np.delete(rest, inliers, axis=0)
    return planes


def kiss_config(cfg: OdometryConfig) -> KISSConfig:
    k = cfg.kiss_icp
    return KISSConfig(
        data={"max_range": k.max_range_m, "min_range": k.min_range_m, "deskew": False},
        mapping={"voxel_size": k.voxel_size_m, "max_points_per_voxel": k.max_points_per_voxel},
        registration={
            "max_num_iterations": k.max_iterations,
            "convergence_criterion": k.convergence,
            "max_num_threads": 1,
        },
        adaptive_threshold={
            "initial_threshold": k.initial_threshold_m,
            "min_motion_th": k.min_motion_m,
            "fixed_threshold": k.fixed_threshold_m,
        },
    )


def held_covariance(
    info: np.ndarray,
    residual_var: float,
    range_var: float | None,
    n: int,
    rotation_cov: np.ndarray,
    c: CovarianceSettings,
) -> tuple[np.ndarray, np.ndarray]:
    """Covariance (6×6, sensor frame) of a pose whose rotation is held to the navigation's and whose
    translation is solved given it, from its parts: the rotation's is the prior's ``rotation_cov``; the
    translation's measured part is a·σ²·H_tt⁻¹ + b·σ_r²·n·H_tt⁻¹ + f²·I (σ² the point-to-plane residuals' variance, σ_r² the laser's
    range noise across a surface — shared by the scan points matched to the same map surface, so not
    divided by their number n —, a, b, f the coefficients ``held_residual_scale``, ``range_noise_scale``,
    ``held_floor_sigma_m``), plus what the held rotation's error moves it by (K = −H_tt⁻¹·H_tr per
    radian: the scan's points are metres from the sensor). Returns (the covariance, its translation's
    measured part alone, 6×6): infinite where the geometry fixes nothing."""
    inf = np.full((6, 6), np.inf)
    if n < 6 or not np.isfinite(residual_var):
        return inf, inf
    try:
        H_tt_inv = np.linalg.inv(info[3:, 3:])
    except np.linalg.LinAlgError:
        return inf, inf
    K = -H_tt_inv @ info[3:, :3]  # translation error per rotation error
    measured = c.held_residual_scale * residual_var * H_tt_inv + np.eye(3) * c.held_floor_sigma_m**2
    if c.range_noise_scale > 0 and range_var is not None:  # until a plane is seen: without it
        measured = measured + c.range_noise_scale * range_var * n * H_tt_inv
    cov = np.zeros((6, 6))
    cov[:3, :3] = rotation_cov
    cov[3:, :3] = K @ rotation_cov
    cov[:3, 3:] = cov[3:, :3].T
    cov[3:, 3:] = measured + K @ rotation_cov @ K.T
    part = np.zeros((6, 6))
    part[3:, 3:] = measured
    return cov, part


class WindowedThreshold:
    """kiss-icp's adaptive correspondence σ over the last ``window`` registrations' model deviations only:
    kiss-icp's ``AdaptiveThreshold`` (its model error per deviation, its min-motion rule, its initial σ)
    rebuilt from the window at each update, where kiss-icp's own keeps a running sum from the map's start."""

    def __init__(self, config: KISSConfig, window: int):
        self.config = config
        self.deviations: deque[np.ndarray] = deque(maxlen=window)
        self._threshold = AdaptiveThreshold(config)

    def get_threshold(self) -> float:
        return self._threshold.get_threshold()

    def update_model_deviation(self, model_deviation: np.ndarray) -> None:
        self.deviations.append(np.array(model_deviation, dtype=np.float64))
        self._threshold = AdaptiveThreshold(self.config)
        for deviation in self.deviations:
            self._threshold.update_model_deviation(deviation)


class ScanMatcher:
    """Registers scans to a kiss-icp local map of the scans accepted in the last ``map_window_s``;
    ``reset()`` starts a new map.

    kiss-icp forgets map points only by distance (``max_range``), and a vehicle circling a structure
    never leaves that range: its map would keep every scan of the mission, each placed with the drift
    of its time, and a scan registered to points mapped a loop earlier takes that drift into its
    relative pose (the errors grew with the map's age, experiments/odometry/README.md). So the map
    is rebuilt from the recent scans alone, as they age out."""

    def __init__(self, cfg: OdometryConfig):
        self.cfg = cfg
        # the mean squared distance of the largest removed plane's points to it, per scan: the laser's
        # range noise across a flat floor (kept across maps: it is the sensor's)
        self._plane_var: deque[float] = deque(maxlen=PLANE_NOISE_SCANS)
        self.reset()

    @property
    def range_variance(self) -> float | None:
        """The laser's range noise (m², across the surface), the median over the last scans with a large
        plane; None before any."""
        return float(np.median(self._plane_var)) if self._plane_var else None

    def reset(self) -> None:
        self.kiss = KissICP(kiss_config(self.cfg))
        k = self.cfg.kiss_icp
        if k.threshold_window is not None and k.fixed_threshold_m is None:
            self.kiss.adaptive_threshold = WindowedThreshold(self.kiss.config, k.threshold_window)
        self._scans: deque[tuple[int, np.ndarray]] = deque()  # (stamp, map-frame points) in the map

    def _add(self, stamp: int, down: np.ndarray, pose: np.ndarray) -> None:
        """Adds a scan's points (placed at ``pose``) and drops the scans older than the window."""
        world = down @ pose[:3, :3].T + pose[:3, 3]
        self._scans.append((stamp, world))
        horizon = stamp - int(self.cfg.map_window_s * 1e9)
        if self._scans[0][0] >= horizon - int(self.cfg.map_window_slack_s * 1e9):
            self.kiss.local_map.update(down, pose)
            return
        while self._scans[0][0] < horizon:
            self._scans.popleft()
        self.kiss.local_map.clear()
        for _, points in self._scans:
            self.kiss.local_map.add_points(points)

    @property
    def empty(self) -> bool:
        return self.kiss.local_map.empty()

    def _prepared(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(source points for ICP, finer points for the map): range-cropped, voxelised, without
        their large planes."""
        frame = np.asarray(points, dtype=np.float64)
        frame = self.kiss.preprocessor.preprocess(frame, np.zeros(0), np.eye(4))
        source, down = self.kiss.voxelize(frame)
        planes = large_planes(source, self.cfg.planes)  # the coarser points: 5× fewer
        if planes:
            d = source @ planes[0][0] + planes[0][1]
            d = d[np.abs(d) <= self.cfg.planes.distance_m]
            if len(d) >= PLANE_NOISE_POINTS:
                self._plane_var.append(float(d @ d) / len(d))
        for normal, offset in planes:
            source = source[np.abs(source @ normal + offset) > self.cfg.planes.distance_m]
            down = down[np.abs(down @ normal + offset) > self.cfg.planes.distance_m]
        return source, down

    def start(self, points: np.ndarray, pose: np.ndarray, stamp: int) -> bool:
        """A new map from this scan, placed at ``pose`` (T_OS); False (and no map) if the scan has
        too few points to register others against."""
        self.reset()
        source, down = self._prepared(points)
        if len(source) < self.cfg.gate.min_inliers:
            return False
        self._add(stamp, down, pose)
        return True

    def register(
        self,
        points: np.ndarray,
        predicted: np.ndarray,
        stamp: int,
        rotation_cov: np.ndarray | None = None,
        translation_cov: np.ndarray | None = None,
    ) -> Registration:
        """Align ``points`` (sensor frame, taken at ``stamp``) to the map starting from ``predicted``
        (T_OS, in a map frame whose z axis is the vertical); the map takes the scan only if the
        registration passes the gate. ``rotation_cov``: the navigation prior's covariance (3×3, sensor
        frame) of the scan's rotation relative to the map's, used where the attitude is held to it
        (``attitude``); ``translation_cov``: the prior's covariance (3×3, sensor frame) of the translation, for
        the gate's ``max_prior_distance``."""
        source, down = self._prepared(points)
        gate = self.cfg.gate
        if len(source) < gate.min_inliers:
            nan = np.full((6, 6), np.nan)
            return Registration(predicted, np.eye(4), nan, nan, np.nan, 0, len(source), "too few points")
        sigma = self.kiss.adaptive_threshold.get_threshold()
        pose = self.kiss.registration.align_points_to_map(source, self.kiss.local_map, predicted, 3 * sigma, sigma)
        icp_correction = np.linalg.inv(predicted) @ pose
        world = source @ pose[:3, :3].T + pose[:3, 3]
        planes = _MapPlanes(np.asarray(self.kiss.local_map.point_cloud()), world, 3 * sigma, self.cfg.normal_neighbours)
        walks = [icp_correction[:3, 3]]  # the translations the gate judges (as corrections to the prior)
        held = self.cfg.attitude != "registration" and rotation_cov is not None
        bound = self.cfg.held_max_distance_m
        wide_only = bound is None or bound >= 3 * sigma
        cov = tail_part = None
        if not held or self.cfg.attitude == "roll_pitch" or not wide_only:
            # kiss-icp's pose's own covariance: emitted (attitude 'registration'), its heading's variance
            # ('roll_pitch'), the overlap at its threshold (tight bound); with the whole attitude held and
            # only the wide re-solve, the pose, covariance and overlap are all the re-solve's
            info, n_in, residual_var = planes.information(source, pose, 3 * sigma)
            cov = self._covariance(info, residual_var, n_in)
            overlap = n_in  # judged at kiss-icp's threshold where the re-solve's bound is tighter
            held = held and np.isfinite(cov).all()
        if held:
            pose[:3, :3] = self._held_rotation(pose[:3, :3], predicted[:3, :3])
            wide = pose.copy()
            wide[:3, 3] = planes.translation(source, pose, 3 * sigma, sigma / 3)
            walks.append((np.linalg.inv(predicted) @ wide)[:3, 3])
            if wide_only:
                pose = wide
                info, n_in, residual_var = planes.information(source, pose, 3 * sigma)
                overlap = n_in
            else:  # the wide re-solve is kept for the gate alone: a wrong minimum of ICP does not hold in it
                pose[:3, 3] = planes.translation(source, pose, bound, sigma / 3)
                info, n_in, residual_var = planes.information(source, pose, bound)
            cov, tail_part = self._held_covariance(info, residual_var, n_in, cov, rotation_cov, pose[:3, :3])
        correction = np.linalg.inv(predicted) @ pose
        walks.append(correction[:3, 3])
        # kiss-icp's rotation is judged, and the farthest translation: ICP's, the re-solves' at its threshold
        # and at the tight bound (a wrong minimum of ICP, kept in place by the tight bound, walks off in the wide one)
        judged = icp_correction.copy()
        judged[:3, 3] = max(walks, key=np.linalg.norm)
        rejected = self._judge(judged, cov, overlap, len(source), translation_cov)
        if rejected is None:
            self.kiss.adaptive_threshold.update_model_deviation(correction)
            self._add(stamp, down, pose)
        tail_part = cov if tail_part is None else tail_part
        return Registration(pose, correction, cov, info, residual_var, overlap, len(source), rejected, tail_part)

    def _held_rotation(self, R_icp: np.ndarray, R_pred: np.ndarray) -> np.ndarray:
        """The scan's rotation with the navigation's attitude: the prior's whole (``navigation``), or
        the prior's tilt turned about the vertical by kiss-icp's heading correction (``roll_pitch``)."""
        if self.cfg.attitude == "navigation":
            return R_pred.copy()
        heading = twist_angle(R_icp @ R_pred.T, VERTICAL)
        return Rotation.from_rotvec(heading * VERTICAL).as_matrix() @ R_pred

    def _held_covariance(self, info, residual_var, n, icp_cov, rotation_cov, R_OS) -> tuple[np.ndarray, np.ndarray]:
        """Covariance of the pose whose rotation is held and whose translation is solved given it, and its
        measured part (:func:`held_covariance`); with ``roll_pitch``, the rotation's heading variance is kiss-icp's."""
        cov_rot = rotation_cov
        if self.cfg.attitude == "roll_pitch":
            up = R_OS.T @ VERTICAL  # the vertical in the sensor frame
            tilt = np.eye(3) - np.outer(up, up)
            cov_rot = tilt @ rotation_cov @ tilt + (up @ icp_cov[:3, :3] @ up) * np.outer(up, up)
        range_var = self.range_variance
        if range_var is None:  # no plane to measure it on (a seabed under a stereo camera): from the residuals
            range_var = RESIDUAL_NOISE_SHARE * residual_var
        return held_covariance(info, residual_var, range_var, n, cov_rot, self.cfg.covariance)

    def _covariance(self, info: np.ndarray, residual_var: float, n: int) -> np.ndarray:
        c = self.cfg.covariance
        if n < 6 or not np.isfinite(residual_var):
            return np.full((6, 6), np.inf)
        try:
            cov = c.scale * residual_var * np.linalg.inv(info)
        except np.linalg.LinAlgError:
            return np.full((6, 6), np.inf)
        floor = np.array([c.floor_sigma_rad] * 3 + [c.floor_sigma_m] * 3) ** 2
        return cov + np.diag(floor)

    def _judge(
        self, correction: np.ndarray, cov: np.ndarray, inliers: int, points: int, translation_cov: np.ndarray | None
    ) -> str | None:
        g = self.cfg.gate
        if inliers < g.min_inliers or inliers < g.min_inlier_fraction * points:
            return "overlap"
        if not np.isfinite(cov).all():
            return "degenerate"
        if (
            np.linalg.eigvalsh(cov[3:, 3:]).max() > g.max_sigma_m**2
            or np.linalg.eigvalsh(cov[:3, :3]).max() > g.max_sigma_rad**2
        ):
            return "degenerate"
        if rotation_angle(correction[:3, :3]) > g.max_rotation_correction_rad:
            return "rotation_correction"
        if np.linalg.norm(correction[:3, 3]) > g.max_translation_correction_m:
            return "translation_correction"
        if g.max_prior_distance is not None and translation_cov is not None:
            d2 = mahalanobis2(correction[:3, 3], translation_cov)
            if d2 is not None and d2 > g.max_prior_distance**2:
                return "prior_distance"
        return None


class _MapPlanes:
    """The local map's points near one scan, with the plane of each scan point's map neighbours: the
    point-to-plane residuals behind the covariance, and the translation solved with the rotation held.

    One instance serves one scan (``n_source`` points, always queried whole and in the same order): a
    point's plane is fitted again only when its neighbours (their indices, in distance order) change
    between queries, as the translation re-solve moves the scan by millimetres between its steps (the
    same neighbours give the same plane, bit for bit)."""

    def __init__(self, map_points: np.ndarray, world: np.ndarray, max_distance: float, neighbours: int):
        reach = 2 * max_distance  # the map beyond the scan's box by more than the queries' bound is never a neighbour
        box = np.all((map_points >= world.min(axis=0) - reach) & (map_points <= world.max(axis=0) + reach), axis=1)
        self.points = map_points[box]
        self.k = neighbours
        self.tree = cKDTree(self.points) if len(self.points) >= neighbours else None
        n = len(world)
        self._neighbours = np.full((n, neighbours), -1)  # per scan point: the map indices of its last plane
        self._normals = np.zeros((n, 3))
        self._centroids = np.zeros((n, 3))

    def _match(self, world: np.ndarray, max_distance: float):
        """(scan points with a map neighbour within ``max_distance``, the unit normals and centroids of the
        planes fitted to their neighbours)."""
        if self.tree is None:
            return np.zeros(len(world), bool), np.zeros((0, 3)), np.zeros((0, 3))
        dist, idx = self.tree.query(world, k=self.k, distance_upper_bound=max_distance * 2)
        near = np.isfinite(dist[:, 0]) & (dist[:, 0] <= max_distance) & np.isfinite(dist).all(axis=1)
        rows, idx = np.flatnonzero(near), idx[near]
        changed = ~np.all(self._neighbours[rows] == idx, axis=1)
        if changed.any():
            new = rows[changed]
            self._neighbours[new] = idx[changed]
            self._normals[new], self._centroids[new] = fitted_planes(self.points[self._neighbours[new]])
        return near, self._normals[rows], self._centroids[rows]

    def information(self, source: np.ndarray, pose: np.ndarray, max_distance: float):
        """Point-to-plane information of the scan at ``pose`` against the map (6×6, per unit residual
        variance), its inlier count and the residuals' variance. Point-to-plane, not the
        point-to-point cost ICP minimised: its Hessian is n·I in translation whatever the geometry,
        while the plane residuals see that a flat floor fixes nothing along itself."""
        world = source @ pose[:3, :3].T + pose[:3, 3]
        near, normals, centroids = self._match(world, max_distance)
        if near.sum() < 6:
            return np.zeros((6, 6)), int(near.sum()), np.inf
        return plane_information(source[near], world[near], normals, centroids, pose[:3, :3])

    def translation(self, source: np.ndarray, pose: np.ndarray, max_distance: float, kernel: float) -> np.ndarray:
        """The translation that minimises the robust (Geman-McClure, kiss-icp's kernel) point-to-plane
        residuals with the rotation held at ``pose``'s: given R each step is closed-form (3×3 normal
        equations); a direction the planes do not fix keeps its start."""
        R, t = pose[:3, :3], pose[:3, 3].copy()
        rotated = source @ R.T
        for _ in range(TRANSLATION_ITERATIONS):
            near, normals, centroids = self._match(rotated + t, max_distance)
            if near.sum() < 6:
                break
            r = np.einsum("ni,ni->n", normals, rotated[near] + t - centroids)
            w = kernel**2 / (kernel + r**2) ** 2
            H = (normals * w[:, None]).T @ normals
            step = -np.linalg.lstsq(H, normals.T @ (w * r), rcond=1e-6)[0]
            t += step
            if np.linalg.norm(step) < 1e-5:
                break
        return t
