"""A scan decimated for the replay, each point labelled with what the front-end made of it.

The front-ends hand over observations, not per-point labels: a point is labelled from the
observations drawn from its scan — an object's when it lies within ``tolerance_m`` of the object's
segmented cloud, a pipe's when within the pipe's radius (+ tolerance) of its segment, a structure's
when inside the CAD model's bounding box (+ tolerance) where the front-end placed it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from semslam.eval.replay_scene import PIPE_RGB, STRUCTURE_RGB, UNKNOWN_RGB, class_index, class_rgb, map_class
from semslam.mission.measurements import PointCloud, SonarSwath
from semslam.observations import LineObservation, Observation, PointObservation, StructureObservation

SEGMENT_NONE, SEGMENT_PIPE, SEGMENT_OBJECT, SEGMENT_STRUCTURE = 0, 1, 2, 3
SCAN_TYPES = (PointCloud, SonarSwath)
DEFAULT_PIPE_RADIUS_M = 0.03


@dataclass
class SegmentedScan:
    """Points (N, 3) in the sensor frame with their segment (SEGMENT_*), class index and colour."""

    stamp: int
    sensor: str
    points: np.ndarray
    segment: np.ndarray
    cls: np.ndarray
    rgb: np.ndarray


# A scan is first cut to this many times the points the replay keeps, at random: thinning and
# labelling all of a 100k-point laser scan would cost ~0.1 s a scan on the driver's thread.
OVERSAMPLE = 8


def scan_points(measurement, max_points: int, voxel_m: float, seed: int) -> np.ndarray:
    """Points of a laser scan or a multibeam swath (sensor frame) for the replay: at most
    OVERSAMPLE × ``max_points`` of them drawn at random (seeded: the same scan gives the same
    points), then one per ``voxel_m`` cube so that near surfaces do not crowd out far ones."""
    pts = measurement.points() if isinstance(measurement, SonarSwath) else measurement.points
    pts = np.asarray(pts).reshape(-1, 3)
    if len(pts) > OVERSAMPLE * max_points:
        pick = np.random.default_rng(seed).choice(len(pts), OVERSAMPLE * max_points, replace=False)
        pts = pts[np.sort(pick)]
    pts = pts.astype(float)
    return voxel_thin(pts[np.all(np.isfinite(pts), axis=1)], voxel_m)


def voxel_thin(points: np.ndarray, voxel_m: float) -> np.ndarray:
    """One point per ``voxel_m`` cube (the first one met), in scan order."""
    if len(points) == 0 or voxel_m <= 0:
        return points
    cells = np.floor((points - points.min(axis=0)) / voxel_m).astype(np.int64)
    span = cells.max(axis=0) + 1
    key = (cells[:, 0] * span[1] + cells[:, 1]) * span[2] + cells[:, 2]
    _, first = np.unique(key, return_index=True)
    return points[np.sort(first)]


def keep_at_most(scan: SegmentedScan, max_points: int, seed: int) -> SegmentedScan:
    """At most ``max_points`` of the scan, the labelled ones first (what the front-end made of the
    scan is what a viewer looks for), the rest drawn at random (seeded: the same scan always
    gives the same points)."""
    if len(scan.points) <= max_points:
        return scan
    rng = np.random.default_rng(seed)
    labelled = np.flatnonzero(scan.segment != SEGMENT_NONE)
    other = np.flatnonzero(scan.segment == SEGMENT_NONE)
    if len(labelled) >= max_points:
        pick = rng.choice(labelled, max_points, replace=False)
    else:
        pick = np.concatenate([labelled, rng.choice(other, max_points - len(labelled), replace=False)])
    pick = np.sort(pick)
    return SegmentedScan(scan.stamp, scan.sensor, scan.points[pick], scan.segment[pick], scan.cls[pick], scan.rgb[pick])


def _rgb8(rgb) -> np.ndarray:
    return np.round(np.asarray(rgb, float) * 255).astype(np.uint8)


def _on_pipes(points: np.ndarray, pipes: list[LineObservation], tolerance_m: float) -> np.ndarray:
    """Which points lie within a pipe's radius (+ tolerance) of its segment: all pipes at once."""
    p = np.array([o.p for o in pipes])  # (P, 3)
    d = np.array([o.q for o in pipes]) - p
    r = np.array([o.radius if o.radius is not None else DEFAULT_PIPE_RADIUS_M for o in pipes])
    v = points[None, :, :] - p[:, None, :]  # (P, N, 3)
    t = np.clip(np.einsum("pnc,pc->pn", v, d) / np.maximum(np.einsum("pc,pc->p", d, d), 1e-12)[:, None], 0, 1)
    dist = np.linalg.norm(v - t[..., None] * d[:, None, :], axis=2)
    return np.any(dist <= (r + tolerance_m)[:, None], axis=0)


def _nearest_object(points: np.ndarray, objects: list[PointObservation], tolerance_m: float) -> np.ndarray:
    """Per point, the index of the object whose segmented cloud has a point within ``tolerance_m``
    of it (the nearest one), or -1: one KD-tree over every cloud of the scan, one query."""
    clouds = [np.asarray(o.cloud, float).reshape(-1, 3) for o in objects]
    owner = np.repeat(np.arange(len(clouds)), [len(c) for c in clouds])
    dist, idx = cKDTree(np.vstack(clouds)).query(points, distance_upper_bound=tolerance_m)
    found = np.isfinite(dist)
    out = np.full(len(points), -1)
    out[found] = owner[idx[found]]
    return out


def segment(
    stamp: int,
    sensor: str,
    points: np.ndarray,
    observations: Sequence[Observation],
    tolerance_m: float,
    structure_boxes: dict[str, tuple[np.ndarray, np.ndarray]] | None = None,
) -> SegmentedScan:
    """Label ``points`` (sensor frame) from the observations drawn from their scan. Objects win
    over pipes (an object's cloud includes the pipe stubs it sits on), pipes over structures."""
    n = len(points)
    seg = np.full(n, SEGMENT_NONE, np.uint8)
    cls = np.full(n, 255, np.uint8)
    rgb = np.tile(_rgb8(UNKNOWN_RGB), (n, 1))
    if n == 0:
        return SegmentedScan(stamp, sensor, points.astype(np.float32), seg, cls, rgb)
    for o in observations:  # lowest priority first: later labels overwrite
        if isinstance(o, StructureObservation) and structure_boxes and o.model in structure_boxes:
            lo, hi = structure_boxes[o.model]
            local = (points - o.pose[:3, 3]) @ o.pose[:3, :3]  # into the model frame
            inside = np.all((local >= lo - tolerance_m) & (local <= hi + tolerance_m), axis=1)
            seg[inside], rgb[inside] = SEGMENT_STRUCTURE, _rgb8(STRUCTURE_RGB)
    pipes = [o for o in observations if isinstance(o, LineObservation)]
    if pipes:
        on = _on_pipes(points, pipes, tolerance_m)
        seg[on], cls[on], rgb[on] = SEGMENT_PIPE, 255, _rgb8(PIPE_RGB)
    objects = [o for o in observations if isinstance(o, PointObservation) and o.cloud is not None and len(o.cloud)]
    if objects:
        owner = _nearest_object(points, objects, tolerance_m)
        for k, o in enumerate(objects):
            on = owner == k
            name, _ = map_class(o.class_likelihood)
            seg[on], cls[on], rgb[on] = SEGMENT_OBJECT, class_index(name), _rgb8(class_rgb(name))
    return SegmentedScan(stamp, sensor, points.astype(np.float32), seg, cls, rgb)
