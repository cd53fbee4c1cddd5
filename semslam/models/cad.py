"""CAD library of the six object classes of the reference tank experiment (Vallicrosa et al. 2021).

Each built-in model is a procedural open3d triangle mesh made of primitives (cylinders, spheres,
boxes) whose shape differs the way the real PVC parts differ: sockets/union nuts where pipes
attach (the *ports*), a lever or T-handle where the real valve has one, a wafer disc for the
butterfly valve.

Model frame {M} (metres), common to every built-in model:
- origin at the junction of the pipe axes (the centre of the part);
- x along the main run (in-line parts have their two ports at ±x);
- z along the valve stem, towards the handle (handles are at +z);
- y completes a right-handed frame (a tee's branch and a 3-way valve's third port are at +y ...
  except the Elbow and R-Tee, whose layouts are given below).

A port is ``(position (3,), outward unit direction (3,))`` in {M}: the position is the centre of
the socket mouth, i.e. where the end of a connected pipe's axis lies, and the direction points out
of the part along the pipe.

Sizes from the paper, mm, and how they map to the model axes (x × y × z):
    Ball-Valve        198 × 120 × 160   ports ±x, lever handle +z
    Elbow             122.5 × 122.5 × 77  ports +x, +y
    R-Tee             122.5 × 168 × 77  ports ±y (run), +x (branch)
    R-Socket          88 × 75 × 75      ports ±x
    Butterfly-Valve   121 × 243 × 287.5 ports ±x, neck + gear head + lever at +z
    3-Way-Ball-Valve  240 × 160 × 172   ports ±x (run), +y (branch), T-handle +z
Each mesh is scaled at the end so that its axis-aligned bounding box matches these sizes exactly
(the ports are scaled with it, so they stay on the socket mouths).

Everything here is deterministic: the same call gives the same vertices, byte for byte.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import open3d as o3d

from semslam.errors import SemslamError
from semslam.models.registry import ModelRegistry

BALL_VALVE = "Ball-Valve"
ELBOW = "Elbow"
R_TEE = "R-Tee"
R_SOCKET = "R-Socket"
BUTTERFLY_VALVE = "Butterfly-Valve"
THREE_WAY_BALL_VALVE = "3-Way-Ball-Valve"

#: The six object classes of the reference paper, in the order of its confusion matrices.
CLASSES: tuple[str, ...] = (BALL_VALVE, ELBOW, R_TEE, R_SOCKET, BUTTERFLY_VALVE, THREE_WAY_BALL_VALVE)

#: Bounding-box size (x, y, z) in metres of each built-in model in its model frame.
SIZES_M: dict[str, tuple[float, float, float]] = {
    BALL_VALVE: (0.198, 0.120, 0.160),
    ELBOW: (0.1225, 0.1225, 0.077),
    R_TEE: (0.1225, 0.168, 0.077),
    R_SOCKET: (0.088, 0.075, 0.075),
    BUTTERFLY_VALVE: (0.121, 0.243, 0.2875),
    THREE_WAY_BALL_VALVE: (0.240, 0.160, 0.172),
}

#: RGB colours (0..1) used by previews and figures, one per class.
CLASS_COLORS: dict[str, tuple[float, float, float]] = {
    BALL_VALVE: (0.85, 0.15, 0.15),
    ELBOW: (0.15, 0.55, 0.90),
    R_TEE: (0.20, 0.70, 0.25),
    R_SOCKET: (0.95, 0.65, 0.10),
    BUTTERFLY_VALVE: (0.60, 0.25, 0.75),
    THREE_WAY_BALL_VALVE: (0.10, 0.75, 0.75),
}

#: Outer radius (m) of the PVC pipes the built-in fittings are sized for (63 mm OD pipe).
PIPE_RADIUS_M = 0.0315

_RES = 24  # angular resolution of the round primitives: smooth enough for 5 mm laser noise


class CadError(SemslamError):
    """A user CAD model cannot be registered (missing file, unreadable or empty mesh)."""


@dataclass
class CadModel:
    """One CAD model: its mesh and ports in the model frame {M} (metres).

    ``mesh`` is shared by every caller of :func:`library`; do not modify it in place, use
    :meth:`transformed` to obtain a placed copy.
    """

    name: str
    cls: str
    mesh: o3d.geometry.TriangleMesh
    ports: list[tuple[np.ndarray, np.ndarray]] = field(default_factory=list)
    size: tuple[float, float, float] = (0.0, 0.0, 0.0)  # axis-aligned bounding-box extents (m)
    source: str | None = None  # file of a user-registered model, None for a built-in

    def transformed(self, T_WM: np.ndarray) -> o3d.geometry.TriangleMesh:
        """A copy of the mesh placed in the world by the 4×4 pose T_WM."""
        m = copy.deepcopy(self.mesh)
        m.transform(np.asarray(T_WM, dtype=float))
        return m

    def ports_in(self, T_WM: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
        """Ports (position, outward direction) expressed in the frame of the 4×4 pose T_WM."""
        T = np.asarray(T_WM, dtype=float)
        return [(T[:3, :3] @ p + T[:3, 3], T[:3, :3] @ d) for p, d in self.ports]

    @property
    def vertices(self) -> np.ndarray:
        return np.asarray(self.mesh.vertices)

    @property
    def triangles(self) -> np.ndarray:
        return np.asarray(self.mesh.triangles)


# ----------------------------------------------------------------------------------------------
# primitives


def _rot_z_to(d: np.ndarray) -> np.ndarray:
    """Rotation taking +z to the unit vector d (exact for ±z, Rodrigues otherwise)."""
    d = np.asarray(d, float) / np.linalg.norm(d)
    z = np.array([0.0, 0.0, 1.0])
    c = float(z @ d)
    if c > 1 - 1e-12:
        return np.eye(3)
    if c < -1 + 1e-12:
        return np.diag([1.0, -1.0, -1.0])
    v = np.cross(z, d)
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + vx + vx @ vx * (1.0 / (1.0 + c))


def cylinder(p0, p1, r: float, resolution: int = _RES, split: int = 1) -> o3d.geometry.TriangleMesh:
    """Closed cylinder of radius r from point p0 to point p1, ``resolution`` segments around and
    ``split`` along ((2 + 2 × split) × resolution triangles)."""
    p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
    axis = p1 - p0
    m = o3d.geometry.TriangleMesh.create_cylinder(
        radius=r, height=float(np.linalg.norm(axis)), resolution=resolution, split=split
    )
    m.rotate(_rot_z_to(axis), center=np.zeros(3))
    m.translate((p0 + p1) / 2)
    return m


def _sphere(c, r: float) -> o3d.geometry.TriangleMesh:
    m = o3d.geometry.TriangleMesh.create_sphere(radius=r, resolution=_RES // 2)
    m.translate(np.asarray(c, float))
    return m


def box(lo, hi) -> o3d.geometry.TriangleMesh:
    """Axis-aligned box between corners lo and hi."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    m = o3d.geometry.TriangleMesh.create_box(*(hi - lo))
    m.translate(lo)
    return m


def union(parts) -> o3d.geometry.TriangleMesh:
    out = o3d.geometry.TriangleMesh()
    for p in parts:
        out += p
    return out


def _port(x, y, z, dx, dy, dz):
    return (np.array([x, y, z], float), np.array([dx, dy, dz], float))


# ----------------------------------------------------------------------------------------------
# the six parts (dimensions in metres; sockets 77 mm OD for a 63 mm pipe)

_SOCK = 0.0385  # socket outer radius
_BODY = 0.034  # fitting body radius between sockets


def _ball_valve():
    x_port = 0.099
    parts = [
        _sphere((0, 0, 0), 0.056),  # ball housing
        cylinder((-0.085, 0, 0), (0.085, 0, 0), 0.045),  # body
        cylinder((-0.085, 0, 0), (-0.045, 0, 0), 0.060),  # union nuts: the widest part (120 mm)
        cylinder((0.045, 0, 0), (0.085, 0, 0), 0.060),
        cylinder((-x_port, 0, 0), (-0.085, 0, 0), 0.041),  # pipe tails
        cylinder((0.085, 0, 0), (x_port, 0, 0), 0.041),
        cylinder((0, 0, 0.04), (0, 0, 0.085), 0.013),  # stem
        box((-0.035, -0.016, 0.085), (0.095, 0.016, 0.100)),  # lever along the pipe (open)
    ]
    return union(parts), [_port(-x_port, 0, 0, -1, 0, 0), _port(x_port, 0, 0, 1, 0, 0)]


def _elbow():
    L = 0.084  # junction → socket mouth
    parts = [
        _sphere((0, 0, 0), _BODY),  # the bend
        cylinder((0, 0, 0), (0.044, 0, 0), _BODY),
        cylinder((0, 0, 0), (0, 0.044, 0), _BODY),
        cylinder((0.044, 0, 0), (L, 0, 0), _SOCK),  # sockets
        cylinder((0, 0.044, 0), (0, L, 0), _SOCK),
    ]
    return union(parts), [_port(L, 0, 0, 1, 0, 0), _port(0, L, 0, 0, 1, 0)]


def _r_tee():
    L = 0.084
    parts = [
        cylinder((0, -0.044, 0), (0, 0.044, 0), _BODY),  # run body
        cylinder((0, -L, 0), (0, -0.044, 0), _SOCK),
        cylinder((0, 0.044, 0), (0, L, 0), _SOCK),
        cylinder((0, 0, 0), (0.050, 0, 0), _BODY * 0.9),  # branch (reduced body, hence "R-")
        cylinder((0.050, 0, 0), (L, 0, 0), _SOCK * 0.95),
        _sphere((0, 0, 0), _BODY),
    ]
    return union(parts), [_port(0, -L, 0, 0, -1, 0), _port(0, L, 0, 0, 1, 0), _port(L, 0, 0, 1, 0, 0)]


def _r_socket():
    L = 0.044
    parts = [
        cylinder((-L, 0, 0), (-0.006, 0, 0), 0.0375),  # the larger half
        cylinder((-0.006, 0, 0), (0.006, 0, 0), 0.0345),  # reducing step / central stop
        cylinder((0.006, 0, 0), (L, 0, 0), 0.0360),  # the reduced half
    ]
    return union(parts), [_port(-L, 0, 0, -1, 0, 0), _port(L, 0, 0, 1, 0, 0)]


def _butterfly_valve():
    x_port = 0.0605
    parts = [
        cylinder((-0.025, 0, 0), (0.025, 0, 0), 0.0875),  # wafer body holding the disc
        cylinder((-x_port, 0, 0), (-0.025, 0, 0), 0.046),  # flange stubs
        cylinder((0.025, 0, 0), (x_port, 0, 0), 0.046),
        box((-0.018, -0.018, -0.092), (0.018, 0.018, -0.080)),  # bottom lug
        cylinder((0, 0, 0.080), (0, 0, 0.165), 0.021),  # neck
        box((-0.035, -0.035, 0.165), (0.035, 0.035, 0.190)),  # gear/lock head
        box((-0.016, -0.075, 0.190), (0.016, 0.1555, 0.1955)),  # long lever across the pipe
    ]
    return union(parts), [_port(-x_port, 0, 0, -1, 0, 0), _port(x_port, 0, 0, 1, 0, 0)]


def _three_way_ball_valve():
    x_port, y_port = 0.120, 0.100
    parts = [
        _sphere((0, 0, 0), 0.060),  # ball housing
        cylinder((-0.095, 0, 0), (0.095, 0, 0), 0.045),
        cylinder((-0.095, 0, 0), (-0.055, 0, 0), 0.055),  # union nuts
        cylinder((0.055, 0, 0), (0.095, 0, 0), 0.055),
        cylinder((0, 0.040, 0), (0, 0.085, 0), 0.055),
        cylinder((-x_port, 0, 0), (-0.095, 0, 0), 0.041),  # tails
        cylinder((0.095, 0, 0), (x_port, 0, 0), 0.041),
        cylinder((0, 0.085, 0), (0, y_port, 0), 0.041),
        cylinder((0, 0, 0.045), (0, 0, 0.095), 0.013),  # stem
        box((-0.070, -0.015, 0.095), (0.070, 0.015, 0.112)),  # T-handle: bar along the run ...
        box((-0.015, 0.0, 0.095), (0.015, 0.075, 0.112)),  # ... and a stub towards the branch
    ]
    return union(parts), [
        _port(-x_port, 0, 0, -1, 0, 0),
        _port(x_port, 0, 0, 1, 0, 0),
        _port(0, y_port, 0, 0, 1, 0),
    ]


_BUILDERS = {
    BALL_VALVE: _ball_valve,
    ELBOW: _elbow,
    R_TEE: _r_tee,
    R_SOCKET: _r_socket,
    BUTTERFLY_VALVE: _butterfly_valve,
    THREE_WAY_BALL_VALVE: _three_way_ball_valve,
}


def _build(cls: str) -> CadModel:
    mesh, ports = _BUILDERS[cls]()
    target = np.array(SIZES_M[cls])
    v = np.asarray(mesh.vertices)
    # Per-axis scale (all within a few % of 1) so the bounding box matches the paper's size exactly.
    s = target / (v.max(0) - v.min(0))
    mesh.vertices = o3d.utility.Vector3dVector(v * s)
    mesh.remove_duplicated_vertices()
    mesh.compute_vertex_normals()
    mesh.compute_triangle_normals()
    mesh.paint_uniform_color(CLASS_COLORS[cls])
    ports = [(p * s, d / np.linalg.norm(d)) for p, d in ports]
    return CadModel(name=cls, cls=cls, mesh=mesh, ports=ports, size=tuple(map(float, target)))


_LIBRARY: ModelRegistry[CadModel] = ModelRegistry(lambda: {c: _build(c) for c in CLASSES})


def library() -> dict[str, CadModel]:
    """Every known model by name: the six built-ins (named after their class) and registered ones."""
    return _LIBRARY.all()


def builtin(cls: str) -> CadModel:
    """The built-in model of a class."""
    return _LIBRARY.builtin(cls)


def register_model(
    path: str | Path,
    cls: str,
    name: str | None = None,
    *,
    scale: float = 1.0,
    ports: list[tuple] | None = None,
) -> CadModel:
    """Register a user's mesh (STL/OBJ/PLY) as a model of class ``cls``.

    ``scale`` converts the file's units to metres (0.001 for a file in mm). ``ports`` are
    ``(position, direction)`` pairs in the model frame (metres), if known. The model is named
    ``name`` (default: the file stem) and replaces an earlier user model of that name.
    """
    path = Path(path)
    if not cls or not isinstance(cls, str):
        raise CadError(f"{path}: a class name is required to register a CAD model")
    if not path.is_file():
        raise CadError(f"{path}: CAD model file not found")
    if path.suffix.lower() not in (".stl", ".obj", ".ply"):
        raise CadError(f"{path}: unsupported CAD format {path.suffix!r} (expected .stl, .obj or .ply)")
    mesh = o3d.io.read_triangle_mesh(str(path))
    if len(mesh.triangles) == 0:
        raise CadError(f"{path}: no triangles could be read from the CAD model")
    if scale != 1.0:
        mesh.scale(scale, center=np.zeros(3))
    mesh.compute_vertex_normals()
    mesh.compute_triangle_normals()
    v = np.asarray(mesh.vertices)
    norm_ports = []
    for p, d in ports or []:
        d = np.asarray(d, float)
        norm_ports.append((np.asarray(p, float), d / np.linalg.norm(d)))
    model = CadModel(
        name=name or path.stem,
        cls=cls,
        mesh=mesh,
        ports=norm_ports,
        size=tuple(map(float, v.max(0) - v.min(0))),
        source=str(path),
    )
    if model.name in CLASSES:
        raise CadError(f"{path}: model name {model.name!r} is a built-in model; choose another name")
    _LIBRARY.add(model.name, model)
    return model


def unregister_model(name: str) -> None:
    """Forget a user-registered model (no-op if unknown)."""
    _LIBRARY.remove(name)
