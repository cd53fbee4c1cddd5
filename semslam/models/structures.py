"""CAD library of subsea structures for the sonar field: a manifold, a PLET and a wellhead.

The sonar front-end recognises these structures in multibeam elevation maps and registers their
meshes (Guerneve et al.), so the three differ in size and in their top-down height profile:

============  =====================  ==========  ====================================================
name          size x × y × h (m)     symmetry    what the sonar sees from above
============  =====================  ==========  ====================================================
``manifold``  6.4 × 3.8 × 2.5        2 (180°)    a wide flat roof of beams at 2.5 m over valve blocks
``plet``      3.0 × 2.0 × 1.5        1           a low mudmat and header, one actuator, a rear frame
``wellhead``  1.95 × 1.7 × 2.5       1           a narrow tree: a 2.5 m column on a small guide base
============  =====================  ==========  ====================================================

Model frame {M} (metres): origin at the centre of the base footprint, on the seabed; x and y
horizontal; z DOWN as in NED, so the structure stands at negative z (its top is at z = −height).
Placed in the world {W} (NED) by a pose T_WM that is a yaw about the vertical and a translation
(:func:`pose_matrix`): the base then rests on the seabed at the position's depth.

``symmetry`` is the order of the mesh's rotational symmetry about the vertical z axis: 1 = none
(a pose search covers yaw in [0°, 360°)), 2 = the mesh is unchanged by a 180° turn (yaw in
[0°, 180°)); ``yaw_period`` gives the interval. It is true of the meshes: rotated by
``yaw_period`` a model coincides with itself (:func:`symmetry_error`).

A ``Hub`` is where a pipeline attaches: ``position`` is the end point of the connected pipe's
axis (the mouth of the hub's clamp), ``direction`` the horizontal unit vector along which the pipe
leaves the structure, ``pipe_radius`` the radius of the pipe the hub takes. Hubs sit at axis height
pipe_radius + 1 cm, so that a connected pipe rests on the seabed (their clamps sink 3 cm into it:
``size`` includes that, ``height`` is the top above the base). The manifold has a large (0.25 m)
and a small (0.10 m) hub at each end, the PLET one large hub, the wellhead one small.

Meshes are light (1–1.5 k triangles: the world model of a mission embeds them) and built from
open3d primitives, deterministically: the same call gives the same vertices, byte for byte.
Library meshes are shared; never modify one in place (use :meth:`StructureModel.transformed`).

Public API::

    structure_library() -> dict[str, StructureModel]        # built-ins + registered (cached meshes)
    register_structure(path, name=None, *, symmetry=1, hubs=(), scale=1.0, z_up=False) -> StructureModel
    unregister_structure(name)
    pose_matrix(position, yaw) -> 4×4 T_WM
    symmetry_error(mesh, order) -> float (m)
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import open3d as o3d

from semslam.errors import SemslamError
from semslam.models import cad
from semslam.models.registry import ModelRegistry

MANIFOLD = "manifold"
PLET = "plet"
WELLHEAD = "wellhead"

#: The built-in structures, largest first (the order a recogniser should search them in).
STRUCTURES: tuple[str, ...] = (MANIFOLD, PLET, WELLHEAD)

#: RGB colours (0..1) for previews and figures.
STRUCTURE_COLORS: dict[str, tuple[float, float, float]] = {
    MANIFOLD: (0.90, 0.55, 0.10),
    PLET: (0.80, 0.20, 0.45),
    WELLHEAD: (0.20, 0.60, 0.30),
}

LARGE_PIPE_RADIUS_M = 0.25  # the flowline's radius, what the large hubs take
SMALL_PIPE_RADIUS_M = 0.10  # the jumper's radius, what the small hubs take


class StructureError(SemslamError):
    """A user structure model cannot be registered (missing file, unreadable mesh, wrong symmetry)."""


@dataclass(frozen=True, eq=False)
class Hub:
    """Where a pipeline attaches, in {M}: the pipe axis' end point, its outward horizontal unit
    direction, and the radius (m) of the pipe the hub takes."""

    position: np.ndarray
    direction: np.ndarray
    pipe_radius: float


@dataclass(eq=False)
class StructureModel:
    """One structure: its mesh in {M} (z down, origin at the base centre on the seabed) and what a
    recogniser needs to know about it.

    ``footprint_radius``: largest horizontal distance (m) of the mesh from the z axis;
    ``size``: axis-aligned extents (x, y, z) in metres; ``height``: top above the base (m).
    """

    name: str
    mesh: o3d.geometry.TriangleMesh
    symmetry: int
    hubs: tuple[Hub, ...]
    footprint_radius: float
    size: tuple[float, float, float]
    height: float
    description: str = ""
    source: str | None = None  # file of a user-registered model, None for a built-in

    @property
    def yaw_period(self) -> float:
        """The yaw interval (rad) a pose search must cover: 2π / symmetry."""
        return 2 * np.pi / self.symmetry

    @property
    def vertices(self) -> np.ndarray:
        return np.asarray(self.mesh.vertices)

    @property
    def triangles(self) -> np.ndarray:
        return np.asarray(self.mesh.triangles)

    def transformed(self, T_WM: np.ndarray) -> o3d.geometry.TriangleMesh:
        """A copy of the mesh placed by the 4×4 pose T_WM."""
        m = copy.deepcopy(self.mesh)
        m.transform(np.asarray(T_WM, dtype=float))
        return m

    def hubs_in(self, T_WM: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
        """Hubs (position, outward direction) in the frame of the 4×4 pose T_WM."""
        T = np.asarray(T_WM, dtype=float)
        return [(T[:3, :3] @ h.position + T[:3, 3], T[:3, :3] @ h.direction) for h in self.hubs]


def pose_matrix(position, yaw: float) -> np.ndarray:
    """T_WM of a structure standing upright: a yaw (rad, about the NED z axis, x towards y) and the
    position (m) of its base centre."""
    c, s = np.cos(yaw), np.sin(yaw)
    T = np.eye(4)
    T[:2, :2] = [[c, -s], [s, c]]
    T[:3, 3] = position
    return T


def symmetry_error(mesh: o3d.geometry.TriangleMesh, order: int) -> float:
    """How far (m) the mesh is from being unchanged by a turn of 2π/``order`` about the z axis: the
    symmetric Chamfer distance (mean of both directions) between the mesh and its turned copy,
    sampled at the vertices and triangle centroids. 0 for ``order`` 1."""
    if order <= 1:
        return 0.0
    V = np.asarray(mesh.vertices)
    F = np.asarray(mesh.triangles)
    samples = np.vstack([V, V[F].mean(1)])
    turned = pose_matrix((0, 0, 0), 2 * np.pi / order)[:3, :3]
    other = copy.deepcopy(mesh)
    other.rotate(turned, center=np.zeros(3))
    out = []
    for target, pts in ((mesh, samples @ turned.T), (other, samples)):
        scene = o3d.t.geometry.RaycastingScene()
        scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(target))
        out.append(float(scene.compute_distance(o3d.core.Tensor(pts.astype(np.float32))).numpy().mean()))
    return float(np.mean(out))


# ----------------------------------------------------------------------------------------------
# primitives in (x, y, height above the base): {M} has z = −height


def _box(x0, x1, y0, y1, h0, h1) -> o3d.geometry.TriangleMesh:
    return cad.box((x0, y0, -h1), (x1, y1, -h0))


def _cyl(a, b, r: float, res: int = 16) -> o3d.geometry.TriangleMesh:
    """Cylinder between (x, y, height) points a and b."""
    return cad.cylinder((a[0], a[1], -a[2]), (b[0], b[1], -b[2]), r, resolution=res)


def _hub_height(pipe_r: float) -> float:
    """Axis height of a hub: the pipe it takes rests 1 cm above the seabed there."""
    return pipe_r + 0.01


def _clamp(a, b, pipe_r: float):
    """A hub's clamp from a to b around a pipe of radius pipe_r (its bottom sinks 3 cm into the seabed)."""
    return _cyl(a, b, pipe_r + 0.04, 16)


def _hub_parts(x_spool, x_hub, y, h_from, pipe_r, spool_r, sign):
    """A spool down from a header at height ``h_from`` to the hub height, a stub out to the hub and
    the hub's clamp at the mouth; ``sign`` ±1 = the end of the structure."""
    h_hub = _hub_height(pipe_r)
    parts = [
        _cyl((x_spool, y, h_hub), (x_spool, y, h_from), spool_r, 12),
        _cyl((x_spool, y, h_hub), (x_hub, y, h_hub), pipe_r, 16),
        _clamp((x_hub - sign * 0.2, y, h_hub), (x_hub, y, h_hub), pipe_r),
    ]
    hub = Hub(np.array([x_hub, y, -h_hub]), np.array([float(sign), 0.0, 0.0]), pipe_r)
    return parts, hub


def _manifold():
    X, Y, w, H = 2.8, 1.9, 0.25, 2.5
    parts = []
    for s in (1, -1):  # every part comes with its 180° turned twin: (x, y) → (−x, −y)
        ey = (Y - w, Y) if s > 0 else (-Y, -Y + w)  # the frame's side beams, inside its edge
        ex = (X - w, X) if s > 0 else (-X, -X + w)  # and its end beams
        parts += [
            _box(-X, X, *ey, 0, w),  # base frame
            _box(*ex, -Y + w, Y - w, 0, w),
            _box(s * 0.9 - 0.125, s * 0.9 + 0.125, -Y + w, Y - w, 0, w),  # base cross beam
            _box(-X, X, *ey, H - 0.2, H),  # roof frame
            _box(*ex, -Y + w, Y - w, H - 0.2, H),
            _box(-w / 2, w / 2, s * (Y - w / 2) - w / 2, s * (Y - w / 2) + w / 2, w, H - 0.2),  # mid post
            _cyl((-2.3, s * 0.8, 0.8), (2.3, s * 0.8, 0.8), 0.2),  # header
        ]
        for sy in (1, -1):  # corner posts
            cx, cy = s * (X - w / 2), sy * (Y - w / 2)
            parts.append(_box(cx - w / 2, cx + w / 2, cy - w / 2, cy + w / 2, w, H - 0.2))
        for x in (0.4, 1.2, 2.0):  # protective roof beams across, with gaps the sonar sees through
            parts.append(_box(s * x - 0.1, s * x + 0.1, -Y + w, Y - w, H - 0.2, H - 0.02))
        for sy in (1, -1):  # header supports
            parts.append(_box(s * 1.8 - 0.1, s * 1.8 + 0.1, sy * 0.8 - 0.15, sy * 0.8 + 0.15, w, 0.62))
        for cx, cy in ((1.2, 0.8), (0.0, 0.8)):  # valve blocks with actuators; twins at (−cx, −cy)
            cx, cy = s * cx, s * cy
            parts += [
                _box(cx - 0.35, cx + 0.35, cy - 0.3, cy + 0.3, 0.6, 1.3),
                _cyl((cx, cy, 1.3), (cx, cy, 1.8), 0.15, 12),
            ]
    hubs = []
    for s in (1, -1):  # each end: a large hub on one header, a small one on the other
        for y, pipe_r, spool_r in ((0.8, LARGE_PIPE_RADIUS_M, 0.2), (-0.8, SMALL_PIPE_RADIUS_M, 0.12)):
            p, hub = _hub_parts(s * 2.45, s * 3.2, s * y, 0.8, pipe_r, spool_r, s)
            parts += p
            hubs.append(hub)
    return parts, hubs, 2, "manifold: beam frame with a protective roof, two headers, four valve blocks"


def _plet():
    r, h_hub = LARGE_PIPE_RADIUS_M, _hub_height(LARGE_PIPE_RADIUS_M)
    parts = [
        _box(-1.5, 1.2, -1.0, 1.0, 0.0, 0.12),  # mudmat
        _cyl((-1.45, 0, 0.37), (1.15, 0, 0.37), r),  # pipeline header on the mudmat ...
        _cyl((1.15, 0, 0.37), (1.3, 0, h_hub), r),  # ... stepping down off it to the hub
        _clamp((1.3, 0, h_hub), (1.5, 0, h_hub), r),
        _box(-0.35, 0.25, -0.35, 0.35, 0.3, 0.95),  # isolation valve ...
        _cyl((-0.05, 0, 0.95), (-0.05, 0, 1.5), 0.22),  # ... and its actuator, the highest point
        _box(-0.3, 0.2, 0.35, 0.45, 0.5, 0.9),  # ROV panel
        _cyl((0.6, 0, 0.37), (0.6, -0.75, 0.37), 0.12, 12),  # branch with a small valve
        _box(0.45, 0.75, -0.9, -0.6, 0.2, 0.7),
        _box(-1.45, -1.3, 0.75, 0.9, 0.12, 1.1),  # lifting frame at the rear end
        _box(-1.45, -1.3, -0.9, -0.75, 0.12, 1.1),
        _box(-1.45, -1.3, -0.9, 0.9, 1.0, 1.1),
    ]
    hubs = [Hub(np.array([1.5, 0.0, -h_hub]), np.array([1.0, 0.0, 0.0]), r)]
    return parts, hubs, 1, "PLET: mudmat, header with an actuated valve, a branch valve and a rear lifting frame"


def _wellhead():
    r, h_hub = SMALL_PIPE_RADIUS_M, _hub_height(SMALL_PIPE_RADIUS_M)
    parts = [
        _box(-0.85, 0.85, 0.65, 0.85, 0.0, 0.3),  # guide base
        _box(-0.85, 0.85, -0.85, -0.65, 0.0, 0.3),
        _box(0.65, 0.85, -0.65, 0.65, 0.0, 0.3),
        _box(-0.85, -0.65, -0.65, 0.65, 0.0, 0.3),
        _cyl((0, 0, 0.0), (0, 0, 0.9), 0.3),  # wellhead housing
        _box(-0.4, 0.4, -0.4, 0.4, 0.9, 1.9),  # tree body
        _cyl((0, 0, 1.9), (0, 0, 2.5), 0.25),  # tree cap
        _cyl((0.4, 0, 1.45), (0.85, 0, 1.45), 0.12, 12),  # production wing ...
        _box(0.5, 0.75, -0.15, 0.15, 1.57, 1.85),  # ... with its choke
        _cyl((0.85, 0, h_hub), (0.85, 0, 1.57), 0.1, 12),  # flowline spool down to the hub
        _cyl((0.85, 0, h_hub), (1.1, 0, h_hub), r, 12),
        _clamp((0.9, 0, h_hub), (1.1, 0, h_hub), r),
        _cyl((0, -0.4, 1.6), (0, -0.85, 1.6), 0.14, 12),  # valve actuator on the side
        _box(-0.55, -0.4, -0.3, 0.3, 0.9, 1.5),  # ROV panel
    ]
    for sx in (1, -1):
        for sy in (1, -1):
            parts.append(_cyl((sx * 0.75, sy * 0.75, 0.3), (sx * 0.75, sy * 0.75, 1.0), 0.06, 8))  # guide posts
    hubs = [Hub(np.array([1.1, 0.0, -h_hub]), np.array([1.0, 0.0, 0.0]), r)]
    return parts, hubs, 1, "wellhead: christmas tree on a guide base, production wing and flowline hub"


_BUILDERS = {MANIFOLD: _manifold, PLET: _plet, WELLHEAD: _wellhead}


def _model(name, mesh, symmetry, hubs, description="", source=None) -> StructureModel:
    mesh.compute_vertex_normals()
    mesh.compute_triangle_normals()
    v = np.asarray(mesh.vertices)
    return StructureModel(
        name=name,
        mesh=mesh,
        symmetry=int(symmetry),
        hubs=tuple(hubs),
        footprint_radius=float(np.linalg.norm(v[:, :2], axis=1).max()),
        size=tuple(map(float, v.max(0) - v.min(0))),
        height=float(max(-v[:, 2].min(), 0.0)),
        description=description,
        source=source,
    )


def _build(name: str) -> StructureModel:
    parts, hubs, symmetry, description = _BUILDERS[name]()
    mesh = cad.union(parts)
    mesh.remove_duplicated_vertices()
    mesh.paint_uniform_color(STRUCTURE_COLORS[name])
    return _model(name, mesh, symmetry, hubs, description)


_LIBRARY: ModelRegistry[StructureModel] = ModelRegistry(lambda: {n: _build(n) for n in STRUCTURES})


def structure_library() -> dict[str, StructureModel]:
    """Every known structure model by name: the built-ins (:data:`STRUCTURES`) and registered ones."""
    return _LIBRARY.all()


def register_structure(
    path: str | Path,
    name: str | None = None,
    *,
    symmetry: int = 1,
    hubs=(),
    scale: float = 1.0,
    z_up: bool = False,
    symmetry_tol_m: float = 0.05,
) -> StructureModel:
    """Register a user's mesh (STL/OBJ/PLY) as a structure model named ``name`` (default: the file
    stem), replacing an earlier user model of that name.

    The mesh must be in the model-frame convention ({M}: origin at the base centre on the seabed, z
    down); a file with z up (most CAD exports) is turned 180° about x with ``z_up=True``. ``scale``
    converts the file's units to metres (0.001 for mm). ``hubs`` are :class:`Hub` or
    ``(position, direction, pipe_radius)`` triples in {M} after scaling and turning. A declared
    ``symmetry`` > 1 is checked (:func:`symmetry_error` ≤ ``symmetry_tol_m``).
    """
    path = Path(path)
    if not path.is_file():
        raise StructureError(f"{path}: structure model file not found")
    if path.suffix.lower() not in (".stl", ".obj", ".ply"):
        raise StructureError(f"{path}: unsupported mesh format {path.suffix!r} (expected .stl, .obj or .ply)")
    if int(symmetry) != symmetry or symmetry < 1:
        raise StructureError(f"{path}: symmetry must be a whole number ≥ 1, got {symmetry!r}")
    name = name or path.stem
    if name in STRUCTURES:
        raise StructureError(f"{path}: {name!r} is a built-in structure; choose another name")
    mesh = o3d.io.read_triangle_mesh(str(path))
    if len(mesh.triangles) == 0:
        raise StructureError(f"{path}: no triangles could be read from the structure model")
    flip = np.diag([1.0, -1.0, -1.0]) if z_up else np.eye(3)
    mesh.vertices = o3d.utility.Vector3dVector(np.asarray(mesh.vertices) * scale @ flip.T)
    err = symmetry_error(mesh, int(symmetry))
    if err > symmetry_tol_m:
        raise StructureError(
            f"{path}: the mesh is not symmetric of order {symmetry} about its z axis "
            f"(turned copy {err:.3f} m away on average)"
        )
    hub_list = []
    for h in hubs:
        if not isinstance(h, Hub):
            p, d, r = h
            d = np.asarray(d, float)
            h = Hub(np.asarray(p, float), d / np.linalg.norm(d), float(r))
        hub_list.append(h)
    model = _model(name, mesh, symmetry, hub_list, f"user model from {path.name}", str(path))
    _LIBRARY.add(name, model)
    return model


def unregister_structure(name: str) -> None:
    """Forget a user-registered structure model (no-op if unknown)."""
    _LIBRARY.remove(name)
