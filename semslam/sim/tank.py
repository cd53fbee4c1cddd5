"""The tank and its pipe structure: geometry, layout generation (from a seed or YAML), ray casting.

World {W} is NED with its origin at the surface above the tank centre; the flat floor lies at
z = ``tank.depth_m`` and four plane walls slope up from its edges to the surface.

The structure is a tree of straight PVC pipes laid along the edges of a small 3-D lattice standing
on the floor. Fittings sit at lattice nodes and are chosen by the pipe directions meeting there
(two orthogonal → Elbow, T-shaped three → R-Tee or 3-Way-Ball-Valve, two collinear → an in-line
part); in-line parts (Ball-Valve, Butterfly-Valve, R-Socket) may also sit mid-edge, and valves at
free pipe ends. Every object is the CAD mesh of :mod:`semslam.models.cad` placed so that its ports lie
on the pipe axes: a pipe's end point *is* the port position of the object it enters.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import open3d as o3d
import yaml
from scipy.spatial.transform import Rotation

from semslam.errors import ConfigError
from semslam.mission.ground_truth import GroundTruthMap, GtObject, GtPipe
from semslam.models import cad
from semslam.sim.config import StructureConfig, TankConfig
from semslam.sim.raycast import LabelledScene

UP = np.array([0.0, 0.0, -1.0])  # NED: up is -z
PORT_TOL_M = 0.01  # a pipe end within this distance of a port is connected to it

# geometry kinds in a TankScene
FLOOR, WALL, PIPE, OBJECT = 0, 1, 2, 3
KIND_NAMES = ("floor", "wall", "pipe", "object")


# ----------------------------------------------------------------------------------------------
# layout


@dataclass
class PlacedObject:
    """An object of the structure: class, CAD model name, pose T_WM (4×4) and attached pipe ids."""

    id: int
    cls: str
    model: str
    T_WM: np.ndarray
    pipes: tuple[int, ...] = ()

    @property
    def position(self) -> np.ndarray:
        return self.T_WM[:3, 3]

    def ports(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """The model's ports (position, outward direction) in {W}."""
        return cad.library()[self.model].ports_in(self.T_WM)


@dataclass
class Pipe:
    """A straight pipe: axis from ``p`` to ``q`` in {W} (m), outer radius (m)."""

    id: int
    p: np.ndarray
    q: np.ndarray
    radius: float

    @property
    def length(self) -> float:
        return float(np.linalg.norm(self.q - self.p))


@dataclass
class Layout:
    """The structure: placed objects and pipes, all in {W}."""

    objects: list[PlacedObject] = field(default_factory=list)
    pipes: list[Pipe] = field(default_factory=list)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Axis-aligned bounds (min, max corners, m) of every mesh of the structure."""
        lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
        for mesh in self.meshes().values():
            v = np.asarray(mesh.vertices)
            lo, hi = np.minimum(lo, v.min(0)), np.maximum(hi, v.max(0))
        return lo, hi

    def center(self) -> np.ndarray:
        lo, hi = self.bounds()
        return (lo + hi) / 2

    def meshes(self) -> dict[tuple[int, int], o3d.geometry.TriangleMesh]:
        """(kind, id) → mesh in {W} for every pipe (kind PIPE) and object (kind OBJECT)."""
        lib = cad.library()
        out = {}
        for p in self.pipes:
            out[(PIPE, p.id)] = cad.cylinder(p.p, p.q, p.radius)
        for o in self.objects:
            out[(OBJECT, o.id)] = lib[o.model].transformed(o.T_WM)
        return out

    def ground_truth(
        self, seen_objects: tuple[int, ...] | None = None, seen_pipes: tuple[int, ...] | None = None
    ) -> GroundTruthMap:
        objs = tuple(
            GtObject(
                id=o.id,
                cls=o.cls,
                position=tuple(map(float, o.T_WM[:3, 3])),
                orientation=tuple(map(float, Rotation.from_matrix(o.T_WM[:3, :3]).as_quat())),
                pipes=tuple(o.pipes),
                model=o.model,
            )
            for o in self.objects
        )
        pipes = tuple(GtPipe(p.id, tuple(map(float, p.p)), tuple(map(float, p.q)), float(p.radius)) for p in self.pipes)
        classes = tuple(dict.fromkeys(list(cad.CLASSES) + [o.cls for o in self.objects]))
        return GroundTruthMap(
            classes=classes,
            objects=objs,
            pipes=pipes,
            seen_objects=seen_objects,
            seen_pipes=seen_pipes,
            seen_structures=(),
        )

    # --- YAML ----------------------------------------------------------------------------------

    def to_dict(self) -> dict:
        """A plain description (lists of floats), the format :func:`layout_from_dict` reads."""
        return {
            "objects": [
                {
                    "id": o.id,
                    "cls": o.cls,
                    "model": o.model,
                    "position": [round(float(x), 9) for x in o.T_WM[:3, 3]],
                    "orientation": [round(float(x), 12) for x in Rotation.from_matrix(o.T_WM[:3, :3]).as_quat()],
                    "pipes": list(o.pipes),
                }
                for o in self.objects
            ],
            "pipes": [
                {
                    "id": p.id,
                    "p": [round(float(x), 9) for x in p.p],
                    "q": [round(float(x), 9) for x in p.q],
                    "radius": float(p.radius),
                }
                for p in self.pipes
            ],
        }

    def save_yaml(self, path: str | Path) -> None:
        Path(path).write_text(yaml.safe_dump(self.to_dict(), sort_keys=False))


def connections(layout: Layout, tol: float = PORT_TOL_M) -> dict[int, list[int]]:
    """Object id → pipes one of whose ends lies within ``tol`` of one of the object's ports, with the
    pipe leaving the port along the port's outward direction (within ~8°)."""
    out: dict[int, list[int]] = {}
    for o in layout.objects:
        hits = []
        for port, d in o.ports():
            for p in layout.pipes:
                for a, b in ((p.p, p.q), (p.q, p.p)):
                    axis = (b - a) / max(np.linalg.norm(b - a), 1e-12)
                    if np.linalg.norm(a - port) <= tol and axis @ d > 0.99:
                        hits.append(p.id)
        out[o.id] = sorted(set(hits))
    return out


def check_layout(layout: Layout, tol: float = PORT_TOL_M) -> list[str]:
    """Problems of a layout (empty when consistent): listed pipes must enter a port, ports must carry
    the pipes that enter them, no port takes two pipes, classes must be connected plausibly."""
    problems = []
    geo = connections(layout, tol)
    pipe_ids = {p.id for p in layout.pipes}
    for o in layout.objects:
        listed = sorted(o.pipes)
        for pid in listed:
            if pid not in pipe_ids:
                problems.append(f"object {o.id}: unknown pipe {pid}")
        if listed != geo[o.id]:
            problems.append(f"object {o.id} ({o.cls}): lists pipes {listed}, but pipes {geo[o.id]} meet its ports")
        if len(geo[o.id]) > len(o.ports()):
            problems.append(f"object {o.id} ({o.cls}): more pipes than ports")
    return problems


def _rotation_from_quat_or_rpy(entry: dict, where: str) -> np.ndarray:
    if "orientation" in entry:
        q = np.asarray(entry["orientation"], float)
        if q.shape != (4,) or not np.isfinite(q).all() or np.linalg.norm(q) < 1e-9:
            raise ConfigError(f"{where}.orientation: expected a quaternion [x, y, z, w]")
        return Rotation.from_quat(q).as_matrix()
    if "rpy_deg" in entry:
        r = np.asarray(entry["rpy_deg"], float)
        if r.shape != (3,):
            raise ConfigError(f"{where}.rpy_deg: expected [roll, pitch, yaw] in degrees")
        return Rotation.from_euler("ZYX", np.deg2rad(r[::-1])).as_matrix()
    return np.eye(3)


def _vec3(value, where: str) -> np.ndarray:
    v = np.asarray(value, float) if isinstance(value, (list, tuple)) else None
    if v is None or v.shape != (3,) or not np.isfinite(v).all():
        raise ConfigError(f"{where}: expected three numbers [x, y, z]")
    return v


def layout_from_dict(data: dict, source: str = "layout") -> Layout:
    """A layout from its plain description. Objects: ``cls``, optional ``model`` (default the class's
    built-in), ``position``, ``orientation`` [x,y,z,w] or ``rpy_deg``, optional ``pipes`` (inferred
    from the geometry when absent). Pipes: ``p``, ``q``, ``radius``. Ids default to list order.
    Positions in {W} (m). Example (an elbow joining two pipes at the floor)::

        objects:
          - {cls: Elbow, position: [0.0, 0.0, 4.8], rpy_deg: [0, 0, 0]}
        pipes:
          - {p: [0.084, 0.0, 4.8], q: [0.6, 0.0, 4.8], radius: 0.0315}
          - {p: [0.0, 0.084, 4.8], q: [0.0, 0.6, 4.8], radius: 0.0315}
    """
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: expected a mapping with 'objects' and 'pipes'")
    unknown = sorted(set(data) - {"objects", "pipes"})
    if unknown:
        raise ConfigError(f"{source}: unknown key {unknown[0]!r} in a layout (expected 'objects' and 'pipes')")
    if not data.get("objects"):
        raise ConfigError(f"{source}: a layout needs a non-empty 'objects' list")
    lib = cad.library()
    pipes = []
    for i, e in enumerate(data.get("pipes") or []):
        where = f"{source}: pipes[{i}]"
        if not isinstance(e, dict):
            raise ConfigError(f"{where}: expected a mapping")
        for k in ("p", "q"):
            if k not in e:
                raise ConfigError(f"{where}: missing key {k!r}")
        radius = float(e.get("radius", cad.PIPE_RADIUS_M))
        if not 0 < radius <= 0.5:
            raise ConfigError(f"{where}.radius: must be in (0, 0.5] m")
        pipes.append(Pipe(int(e.get("id", i)), _vec3(e["p"], f"{where}.p"), _vec3(e["q"], f"{where}.q"), radius))
    objects = []
    infer = False
    for i, e in enumerate(data.get("objects") or []):
        where = f"{source}: objects[{i}]"
        if not isinstance(e, dict) or "cls" not in e or "position" not in e:
            raise ConfigError(f"{where}: expected a mapping with 'cls' and 'position'")
        model = e.get("model") or e["cls"]
        if model not in lib:
            raise ConfigError(f"{where}.model: unknown CAD model {model!r} (known: {', '.join(sorted(lib))})")
        T = np.eye(4)
        T[:3, :3] = _rotation_from_quat_or_rpy(e, where)
        T[:3, 3] = _vec3(e["position"], f"{where}.position")
        infer |= "pipes" not in e
        objects.append(
            PlacedObject(int(e.get("id", i)), str(e["cls"]), model, T, tuple(int(p) for p in e.get("pipes", ())))
        )
    if len({o.id for o in objects}) != len(objects) or len({p.id for p in pipes}) != len(pipes):
        raise ConfigError(f"{source}: object and pipe ids must be unique")
    layout = Layout(objects, pipes)
    if infer:
        geo = connections(layout)
        for o in layout.objects:
            o.pipes = tuple(geo[o.id])
    problems = check_layout(layout)
    if problems:
        raise ConfigError(f"{source}: inconsistent layout: {problems[0]}")
    return layout


def load_layout_yaml(path: str | Path) -> Layout:
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"{path}: layout file not found")
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML ({str(exc).splitlines()[0]})") from exc
    return layout_from_dict(data, str(path))


# ----------------------------------------------------------------------------------------------
# generation from a seed

_DIRS = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]])  # lattice steps
_WDIRS = _DIRS * np.array([1.0, 1.0, -1.0])  # the same steps in {W}: lattice layers go up, NED z goes down
_INLINE = (cad.BALL_VALVE, cad.BUTTERFLY_VALVE, cad.R_SOCKET)
_END_VALVES = (cad.BALL_VALVE, cad.BUTTERFLY_VALVE)


class _Retry(Exception):
    pass


def _handle_dir(axis: np.ndarray, pos: np.ndarray, center: np.ndarray) -> np.ndarray:
    """Where a valve's handle should point: up, unless the pipe is vertical; then outward (axis-aligned)."""
    if abs(axis @ UP) < 0.5:
        return UP.copy()
    out = (pos - center)[:2]
    k = int(np.argmax(np.abs(out)))
    h = np.zeros(3)
    h[k] = 1.0 if out[k] >= 0 else -1.0
    return h


def _frame(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    R = np.column_stack([x, y, np.cross(x, y)])
    return np.round(R)  # the lattice is axis-aligned: exact ±1/0 entries keep ports on the pipes


def _grow_tree(cfg: StructureConfig, rng: np.random.Generator):
    shape = np.array(cfg.grid)
    start = tuple(int(rng.integers(0, n)) for n in shape[:2]) + (0,)  # start on the bottom layer
    dirs: dict[tuple, list[int]] = {start: []}
    edges = []
    for _ in range(cfg.n_edges):
        cands = []
        for u in sorted(dirs):
            du = dirs[u]
            if len(du) >= 3:
                continue
            for k, d in enumerate(_DIRS):
                v = tuple(np.add(u, d))
                if min(v) < 0 or np.any(np.array(v) >= shape) or v in dirs:
                    continue
                new = du + [k]
                if len(new) == 3 and not any((a ^ 1) in new for a in new):  # must be a T, never a corner of 3
                    continue
                # favour straight runs and tees over elbows, so that the six classes are balanced
                w = 1.0 if len(du) == 0 else 3.0 if len(du) == 2 else 4.0 if du[0] ^ 1 == k else 1.0
                cands.append((u, k, v, w))
        if not cands:
            raise _Retry
        w = np.array([c[3] for c in cands])
        u, k, v, _ = cands[int(rng.choice(len(cands), p=w / w.sum()))]
        dirs[u].append(k)
        dirs[v] = [k ^ 1]
        edges.append((u, v, k))
    return dirs, edges


def generate_layout(cfg: StructureConfig, tank: TankConfig, seed: int) -> Layout:
    """A consistent structure from a seed: ≥ ``min_objects`` objects covering the six classes,
    ≥ ``min_pipes`` pipes, every pipe ≥ ``min_pipe_length_m``. Deterministic in ``seed``."""
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0x5EED_1A70]))
    for _ in range(500):
        try:
            return _try_generate(cfg, tank, rng)
        except _Retry:
            continue
    raise ConfigError("structure: no layout satisfies min_objects/min_pipes/min_pipe_length_m on this grid; relax them")


def _try_generate(cfg: StructureConfig, tank: TankConfig, rng: np.random.Generator) -> Layout:
    dirs, edges = _grow_tree(cfg, rng)
    nx, ny, nz = cfg.grid
    sx, sy, sz = cfg.spacing_m
    cx, cy = cfg.center_xy_m
    z0 = tank.depth_m - cfg.floor_clearance_m

    def pos(n):
        return np.array([cx + (n[0] - (nx - 1) / 2) * sx, cy + (n[1] - (ny - 1) / 2) * sy, z0 - n[2] * sz])

    center = np.array([cx, cy, z0 - (nz - 1) * sz / 2])

    # --- fittings at nodes
    node_cls: dict[tuple, str] = {}
    tees, collinear, leaves = [], [], []
    for n in sorted(dirs):
        ks = sorted(dirs[n])
        if len(ks) == 3:
            tees.append(n)
        elif len(ks) == 2 and ks[0] ^ 1 == ks[1]:
            collinear.append(n)
        elif len(ks) == 2:
            node_cls[n] = cad.ELBOW
        else:
            leaves.append(n)
    if len(tees) < 2 or not node_cls:
        raise _Retry
    order = rng.permutation(len(tees))
    for i, j in enumerate(order):
        node_cls[tees[j]] = (
            (cad.R_TEE, cad.THREE_WAY_BALL_VALVE)[i]
            if i < 2
            else str(rng.choice([cad.R_TEE, cad.THREE_WAY_BALL_VALVE]))
        )

    # --- in-line slots: collinear nodes always carry a part; leaves and mid-edges optionally
    forced = len(node_cls) + len(collinear)
    optional = [("leaf", n) for n in leaves] + [("mid", e) for e in range(len(edges))]
    n_more = max(0, cfg.min_objects - forced, 3 - len(collinear))
    if n_more > len(optional):
        raise _Retry
    chosen = [optional[i] for i in sorted(rng.choice(len(optional), n_more, replace=False))]
    slots = [("node", n) for n in collinear] + chosen
    for _ in range(50):
        classes = [str(rng.choice(_END_VALVES if kind == "leaf" else _INLINE)) for kind, _ in slots]
        if set(_INLINE) <= set(classes):
            break
    else:
        raise _Retry
    for (kind, ref), c in zip(slots, classes):
        if kind in ("node", "leaf"):
            node_cls[ref] = c
    mid_cls = {ref: c for (kind, ref), c in zip(slots, classes) if kind == "mid"}

    # --- place node objects
    objects: list[PlacedObject] = []
    node_obj: dict[tuple, PlacedObject] = {}
    for n in sorted(node_cls):
        c = node_cls[n]
        ds = [_WDIRS[k] for k in sorted(dirs[n])]
        p = pos(n)
        if c == cad.ELBOW:
            R = _frame(ds[0], ds[1])
        elif c in (cad.R_TEE, cad.THREE_WAY_BALL_VALVE):
            run = next(d for d in ds if any(np.allclose(d, -e) for e in ds))
            branch = next(d for d in ds if not any(np.allclose(d, -e) or np.allclose(d, e) for e in (run, -run)))
            if c == cad.R_TEE:
                R = _frame(branch, run)  # model: +x branch, ±y run
            else:  # model: ±x run, +y branch, +z handle: pick the run sign that puts the handle up/out
                want = _handle_dir(branch, p, center) if abs(branch @ UP) > 0.5 else UP
                R = max((_frame(s * run, branch) for s in (1, -1)), key=lambda R: R[:, 2] @ want)
        else:  # in-line part at a collinear node or a leaf: model x along the pipe
            x = ds[0] if len(ds) == 2 else -ds[0]  # at a leaf, the -x port faces the neighbour
            z = _handle_dir(x, p, center)
            R = _frame(x, np.cross(z, x))
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R, p
        obj = PlacedObject(-1, c, c, T)
        objects.append(obj)
        node_obj[n] = obj

    # --- pipes along the edges, split by mid-edge parts
    lib = cad.library()
    pipes: list[Pipe] = []
    attach: list[tuple[PlacedObject, int]] = []

    def port_towards(obj: PlacedObject, e: np.ndarray) -> np.ndarray:
        R, t = obj.T_WM[:3, :3], obj.T_WM[:3, 3]
        for pm, dm in lib[obj.model].ports:
            if (R @ dm) @ e > 0.999:
                return R @ pm + t
        raise AssertionError(f"{obj.cls} has no port towards {e}")

    for ei, (u, v, k) in enumerate(edges):
        d = _WDIRS[k]
        ends = []  # sequence of (point, object or None) along the edge from u to v
        a = node_obj.get(u)
        ends.append((port_towards(a, d) if a else pos(u), a))
        if ei in mid_cls:
            c = mid_cls[ei]
            f = rng.uniform(0.4, 0.6)
            m = pos(u) + f * (pos(v) - pos(u))
            z = _handle_dir(d, m, center)
            T = np.eye(4)
            T[:3, :3], T[:3, 3] = _frame(d, np.cross(z, d)), m
            mo = PlacedObject(-1, c, c, T)
            objects.append(mo)
            ends.append((port_towards(mo, -d), mo))
            ends.append((port_towards(mo, d), mo))
        b = node_obj.get(v)
        ends.append((port_towards(b, -d) if b else pos(v), b))
        for (p0, o0), (p1, o1) in zip(ends[0::2], ends[1::2]):
            pid = len(pipes)
            pipes.append(Pipe(pid, p0, p1, cfg.pipe_radius_m))
            for o in (o0, o1):
                if o is not None:
                    attach.append((o, pid))
    if len(pipes) < cfg.min_pipes or min(p.length for p in pipes) < cfg.min_pipe_length_m:
        raise _Retry
    # ids in a stable spatial order (by x, y, z) so that the same seed gives the same ids
    objects.sort(key=lambda o: tuple(np.round(o.T_WM[:3, 3], 6)))
    for i, o in enumerate(objects):
        o.id = i
    for o, pid in attach:
        o.pipes = tuple(sorted(o.pipes + (pid,)))
    return Layout(objects, pipes)


def make_layout(cfg: StructureConfig, tank: TankConfig, seed: int) -> Layout:
    """The layout of a mission: from ``cfg.layout_yaml`` if given, else generated from the seed."""
    if cfg.layout_yaml is not None:
        return load_layout_yaml(cfg.layout_yaml)
    return generate_layout(cfg, tank, seed)


# ----------------------------------------------------------------------------------------------
# tank geometry and the ray-casting scene


def tank_meshes(tank: TankConfig) -> dict[str, o3d.geometry.TriangleMesh]:
    """The floor and the four sloped walls (one mesh) in {W}."""
    D, fx, fy = tank.depth_m, tank.floor_half_x_m, tank.floor_half_y_m
    off = D / np.tan(np.deg2rad(tank.wall_slope_deg))
    floor_c = np.array([[fx, fy, D], [-fx, fy, D], [-fx, -fy, D], [fx, -fy, D]])
    top_c = np.array(
        [[fx + off, fy + off, 0], [-fx - off, fy + off, 0], [-fx - off, -fy - off, 0], [fx + off, -fy - off, 0]]
    )
    floor = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(floor_c), o3d.utility.Vector3iVector(np.array([[0, 1, 2], [0, 2, 3]]))
    )
    V = np.vstack([floor_c, top_c])
    tris = []
    for i in range(4):
        j = (i + 1) % 4
        tris += [[i, j, 4 + j], [i, 4 + j, 4 + i]]
    walls = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(V), o3d.utility.Vector3iVector(np.array(tris)))
    return {"floor": floor, "walls": walls}


def tank_surface_corners(tank: TankConfig) -> np.ndarray:
    """The 4 corners (x, y) of the water surface rim, for drawing."""
    off = tank.depth_m / np.tan(np.deg2rad(tank.wall_slope_deg))
    a, b = tank.floor_half_x_m + off, tank.floor_half_y_m + off
    return np.array([[a, b], [-a, b], [-a, -b], [a, -b]])


class TankScene(LabelledScene):
    """Tank + structure in an open3d ``RaycastingScene``, each hit labelled by (kind, id).

    ``cast(origins, dirs)`` returns the hit distance along each unit direction (inf: no hit) and, per
    ray, the kind (FLOOR, WALL, PIPE, OBJECT or -1) and the pipe/object id (-1 otherwise).
    """

    def __init__(self, tank: TankConfig, layout: Layout):
        tm = tank_meshes(tank)
        parts = [(FLOOR, -1, tm["floor"]), (WALL, -1, tm["walls"])]
        parts += [(kind, ident, mesh) for (kind, ident), mesh in layout.meshes().items()]
        super().__init__(parts)
