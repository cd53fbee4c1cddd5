"""Ray casting into a scene of labelled triangle meshes (open3d ``RaycastingScene``).

Every mesh of a scene carries a label (kind, id): the tank labels floor / wall / pipe / object, the
sonar field seabed / structure / pipe. A cast returns, per ray, the hit distance and the label of
the mesh it hit, so that a sensor model can tell what it saw without a Python loop per ray.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
import open3d as o3d

NO_HIT = -1  # kind and id of a ray that hits nothing


class LabelledScene:
    """Meshes in {W}, each labelled (kind, id); ``cast`` / ``distance`` work on float32 rays and points."""

    def __init__(self, parts: Iterable[tuple[int, int, o3d.geometry.TriangleMesh]]):
        self.scene = o3d.t.geometry.RaycastingScene()
        labels = []
        for kind, ident, mesh in parts:
            gid = self.scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
            labels.append((gid, kind, ident))
        n = max((g for g, _, _ in labels), default=-1) + 2
        self._kind = np.full(n, NO_HIT, np.int32)
        self._ident = np.full(n, NO_HIT, np.int32)
        for gid, kind, ident in labels:
            self._kind[gid], self._ident[gid] = kind, ident

    def _cast(self, origins: np.ndarray, dirs: np.ndarray) -> dict:
        dirs = np.asarray(dirs, np.float32).reshape(-1, 3)
        rays = np.empty((len(dirs), 6), np.float32)
        rays[:, :3] = np.asarray(origins, np.float32).reshape(-1, 3)  # one origin broadcasts to all rays
        rays[:, 3:] = dirs
        return self.scene.cast_rays(o3d.core.Tensor(rays))

    def _labels(self, ans: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        t = ans["t_hit"].numpy()
        gid = ans["geometry_ids"].numpy().astype(np.int64)
        gid = np.where(np.isfinite(t), gid, len(self._kind) - 1)  # INVALID_ID → the trailing "no hit" label
        return t, self._kind[gid], self._ident[gid]

    def cast(self, origins: np.ndarray, dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Cast rays from ``origins`` (N×3, or one 3-vector for all) along unit ``dirs`` (N×3), in {W}:
        hit distance (inf: no hit), kind and id of the mesh hit (``NO_HIT`` when none)."""
        return self._labels(self._cast(origins, dirs))

    def cast_with_normals(self, origins: np.ndarray, dirs: np.ndarray):
        """As :meth:`cast`, plus the unit normal (N×3, {W}) of the triangle hit (NaN-free; zero for no hit)."""
        ans = self._cast(origins, dirs)
        return (*self._labels(ans), ans["primitive_normals"].numpy())

    def distance(self, points: np.ndarray) -> np.ndarray:
        """Unsigned distance (m) from each point to the nearest surface of the scene."""
        return self.scene.compute_distance(o3d.core.Tensor(np.asarray(points, np.float32))).numpy()
