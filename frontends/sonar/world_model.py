"""The semantic world model (Guerneve et al.): the registered CAD meshes, the pipelines as cylinders
and the bare seabed as a surface mesh at a chosen level of detail, written as a binary PLY.

The seabed surface is the map's median depth on a grid of ``seabed_cell_m`` where the map shows
seabed; under the registered structures and the pipelines (which their meshes replace) it is the
seabed level interpolated from around them, so the surface is continuous and the structures stand
on it. The grid mesh is simplified by quadric decimation as long as its vertical departure from
the grid stays below ``seabed_max_error_m``, and further if the whole model would exceed
``max_fraction`` of the raw cloud's bytes (raw cloud = points × 3 float32).
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np
import open3d as o3d

from frontends.sonar.config import WorldModelConfig
from frontends.sonar.grid import GridSpec

SEABED_COLOR = (0.62, 0.55, 0.42)
PIPE_COLOR = (0.25, 0.25, 0.28)


def heightfield_mesh(depth: np.ndarray, spec: GridSpec) -> o3d.geometry.TriangleMesh:
    """Triangle mesh through the cell centres of a depth grid (NaN cells left out), in {W}."""
    H, W = depth.shape
    N, E = spec.centres()
    ok = np.isfinite(depth)
    vid = -np.ones((H, W), np.int64)
    vid[ok] = np.arange(ok.sum())
    nn, ee = np.meshgrid(N, E, indexing="ij")
    V = np.column_stack([nn[ok], ee[ok], depth[ok]])
    a, b, c, d = vid[:-1, :-1], vid[1:, :-1], vid[:-1, 1:], vid[1:, 1:]
    tris = []
    # two triangles per quad, wound so that the normals point up (−z in NED)
    for t in ((a, c, b), (b, c, d)):
        m = (t[0] >= 0) & (t[1] >= 0) & (t[2] >= 0)
        tris.append(np.column_stack([t[0][m], t[1][m], t[2][m]]))
    F = np.vstack(tris) if tris else np.zeros((0, 3), np.int64)
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(V), o3d.utility.Vector3iVector(F))
    return mesh


def _vertical_error(simplified: o3d.geometry.TriangleMesh, points: np.ndarray) -> float:
    """Largest |Δz| between the grid points and the simplified surface under/over them."""
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(simplified))
    rays = np.zeros((len(points), 6), np.float32)
    rays[:, :2] = points[:, :2]
    rays[:, 2] = points[:, 2].min() - 50.0
    rays[:, 5] = 1.0
    t = scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()
    z = rays[:, 2] + t
    ok = np.isfinite(z)
    if not ok.any():
        return np.inf
    return float(np.percentile(np.abs(z[ok] - points[ok, 2]), 99))


def seabed_surface(depth: np.ndarray, spec: GridSpec, cfg: WorldModelConfig, max_triangles: int | None = None):
    """The seabed heightfield at ``spec`` simplified within ``cfg.seabed_max_error_m``; (mesh, error)."""
    full = heightfield_mesh(depth, spec)
    n = len(full.triangles)
    if n == 0:
        return full, 0.0
    pts = np.asarray(full.vertices)
    best, best_err = full, 0.0
    target = n // 2
    limit = max_triangles if max_triangles is not None else n
    while target >= 64:
        simp = best.simplify_quadric_decimation(target)  # from the last accepted: each step is cheaper
        err = _vertical_error(simp, pts)
        if err > cfg.seabed_max_error_m and len(best.triangles) <= limit:
            break
        best, best_err = simp, err
        if len(best.triangles) <= limit and err > 0.5 * cfg.seabed_max_error_m:
            break
        target //= 2
    return best, best_err


def ply_size(mesh: o3d.geometry.TriangleMesh) -> int:
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "m.ply"
        write_ply(mesh, p)
        return os.path.getsize(p)


def write_ply(mesh: o3d.geometry.TriangleMesh, path) -> None:
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    ok = o3d.io.write_triangle_mesh(
        str(path),
        mesh,
        write_ascii=False,
        compressed=False,
        write_vertex_normals=False,
        write_vertex_colors=True,
        write_triangle_uvs=False,
        print_progress=False,
    )
    if not ok:
        raise OSError(f"could not write {path}")


def _colour_by_depth(mesh: o3d.geometry.TriangleMesh) -> None:
    z = np.asarray(mesh.vertices)[:, 2]
    if len(z) == 0:
        return
    t = (z - z.min()) / max(np.ptp(z), 1e-6)
    base = np.array(SEABED_COLOR)
    col = base[None, :] * (1.15 - 0.45 * t[:, None])
    mesh.vertex_colors = o3d.utility.Vector3dVector(np.clip(col, 0, 1))


def pipe_mesh(p, q, radius: float, facets: int) -> o3d.geometry.TriangleMesh:
    p, q = np.asarray(p, float), np.asarray(q, float)
    L = float(np.linalg.norm(q - p))
    m = o3d.geometry.TriangleMesh.create_cylinder(radius=radius, height=L, resolution=facets, split=1)
    z = np.array([0.0, 0.0, 1.0])
    d = (q - p) / max(L, 1e-9)
    v = np.cross(z, d)
    s, c = np.linalg.norm(v), float(z @ d)
    if s < 1e-9:
        R = np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    else:
        K = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
        R = np.eye(3) + K + K @ K * ((1 - c) / s**2)
    m.rotate(R, center=np.zeros(3))
    m.translate(0.5 * (p + q))
    m.paint_uniform_color(PIPE_COLOR)
    return m


def build_world_model(
    structures, pipes, seabed_depth: np.ndarray, seabed_spec: GridSpec, cfg: WorldModelConfig, raw_bytes: int | None
) -> tuple[o3d.geometry.TriangleMesh, dict]:
    """(mesh, info) of the world model. ``structures``: (StructureModel, T_WM) pairs; ``pipes``:
    PipeSegments; ``seabed_depth``: the bare seabed's depth on ``seabed_spec``."""
    parts = []
    for model, T in structures:
        parts.append(model.transformed(T))
    for s in pipes:
        parts.append(pipe_mesh(s.p, s.q, s.radius, cfg.pipe_facets))
    fixed = o3d.geometry.TriangleMesh()
    for p in parts:
        if not p.has_vertex_colors():
            p.paint_uniform_color((0.7, 0.7, 0.7))
        fixed += p
    fixed_bytes = ply_size(fixed) if len(fixed.triangles) else 0
    budget = None if not raw_bytes else int(cfg.max_fraction * raw_bytes)
    max_tris = None
    seabed, err = seabed_surface(seabed_depth, seabed_spec, cfg)
    if budget is not None:
        # 13 bytes a triangle and ~15 a vertex (half as many vertices as triangles) in a binary PLY
        while len(seabed.triangles) > 64 and ply_size(fixed + _painted(seabed)) > budget:
            max_tris = len(seabed.triangles) // 2
            seabed = seabed.simplify_quadric_decimation(max_tris)
            err = _vertical_error(seabed, np.asarray(heightfield_mesh(seabed_depth, seabed_spec).vertices))
    _colour_by_depth(seabed)
    world = fixed + seabed
    info = {
        "seabed_cell_m": seabed_spec.cell,
        "seabed_triangles": len(seabed.triangles),
        "seabed_vertical_error_p99_m": err,
        "structure_triangles": int(sum(len(m.transformed(np.eye(4)).triangles) for m, _ in structures)),
        "pipes": len(pipes),
        "triangles": len(world.triangles),
        "vertices": len(world.vertices),
        "seabed": "bare: the structures' and pipes' footprints replaced by the seabed level around them",
    }
    info["bytes"] = ply_size(world)
    info["fixed_bytes"] = fixed_bytes
    info["budget_bytes"] = budget
    return world, info


def _painted(mesh):
    m = o3d.geometry.TriangleMesh(mesh)
    _colour_by_depth(m)
    return m
