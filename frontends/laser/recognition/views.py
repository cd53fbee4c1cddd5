"""The view database: partial views of CAD models rendered by a virtual laser scanner, described
once and cached on disk.

As in the papers, each model is seen from many viewpoints (Fibonacci sphere, ``n_views`` ≥ 12
directions, each at a few distances because ESF depends on the point density) by a virtual scanner — a ray grid with the laser's angular resolution, cast with Open3D's
``RaycastingScene`` — with Gaussian range noise along each ray (σ 5 mm, the scanner's). Every view
keeps its ESF, VFH and CVFH descriptors and the camera pose T_CM (model frame {M} → camera frame
{C}; {C}: z along the view axis, x right, y down, the scanner at its origin), which seeds the ICP
pose of a recognised object.

Cache: ``<cache_dir>/views/<model>-<key>.npz``, ``key`` the SHA-256 of the model's content (the
file's bytes, or the mesh's vertices and triangles for an in-memory mesh) together with the
rendering parameters and the descriptor version, so that editing a model file or a parameter
re-renders it and nothing else. ``cache_dir`` defaults to ``$SEMSLAM_CACHE_DIR``, else
``$XDG_CACHE_HOME/semslam``, else ``~/.cache/semslam``.

User models: :func:`add_model` registers an STL/OBJ/PLY file under a class name (recorded in
``<cache_dir>/models.json``) and renders its views at once, so that the next
:func:`load_database` includes it.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import open3d as o3d

from frontends.laser.recognition.cvfh import cvfh
from frontends.laser.recognition.esf import esf
from frontends.laser.recognition.matching import principal_extents
from frontends.laser.recognition.vfh import vfh
from semslam.errors import SemslamError

DESCRIPTOR_VERSION = (
    "3"  # bump when a descriptor's definition changes: invalidates the cache (3: ESF bins rounded as PCL)
)
CAD_SUFFIXES = (".stl", ".obj", ".ply")


class RecognitionError(SemslamError):
    """A user error in object recognition: an unreadable CAD model, a bad class name, a corrupt cache."""


@dataclass(frozen=True)
class ViewParams:
    """How the views of a model are rendered (distances in metres, angles in radians)."""

    n_views: int = 24  # viewing directions; each is rendered at every distance below
    distances_m: tuple[float, ...] = (1.0, 1.6, 2.4, 3.6)  # ESF depends on point density: cover the working range
    angular_resolution_rad: float = float(np.deg2rad(0.15))  # the simulated laser's (50°/336, 45°/300 rays)
    range_sigma_m: float = 0.005
    min_points: int = 30  # views with fewer points (grazing, tiny) are dropped
    seed: int = 0

    def __post_init__(self):
        if (
            self.n_views < 1
            or not self.distances_m
            or min(self.distances_m) <= 0
            or self.angular_resolution_rad <= 0
            or self.range_sigma_m < 0
        ):
            raise RecognitionError(f"invalid view parameters: {self}")


def default_cache_dir() -> Path:
    if os.environ.get("SEMSLAM_CACHE_DIR"):
        return Path(os.environ["SEMSLAM_CACHE_DIR"])
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "semslam"


# ----------------------------------------------------------------------------------------------
# rendering


def fibonacci_directions(n: int) -> np.ndarray:
    """``n`` unit vectors spread evenly over the sphere (n×3)."""
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    r = np.sqrt(1.0 - z**2)
    phi = np.pi * (1.0 + 5**0.5) * i
    return np.c_[r * np.cos(phi), r * np.sin(phi), z]


def random_directions(n: int, rng: np.random.Generator) -> np.ndarray:
    d = rng.normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def look_at(eye: np.ndarray, target: np.ndarray, roll_rad: float = 0.0) -> np.ndarray:
    """T_MC (4×4): a camera at ``eye`` looking at ``target`` (both in {M}), rolled about its axis."""
    z = target - eye
    z = z / np.linalg.norm(z)
    up = np.array([0.0, 0.0, 1.0]) if abs(z[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    c, s = np.cos(roll_rad), np.sin(roll_rad)
    x, y = c * x + s * y, -s * x + c * y
    T = np.eye(4)
    T[:3, :3] = np.c_[x, y, z]
    T[:3, 3] = eye
    return T


class VirtualScanner:
    """Ray-casts a mesh (model frame {M}) from camera poses; returns clouds in the camera frame."""

    def __init__(self, mesh: o3d.geometry.TriangleMesh):
        if len(mesh.triangles) == 0:
            raise RecognitionError("cannot render a mesh without triangles")
        self.scene = o3d.t.geometry.RaycastingScene()
        self.scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
        v = np.asarray(mesh.vertices)
        lo, hi = v.min(axis=0), v.max(axis=0)
        self.center = 0.5 * (lo + hi)
        self.radius = 0.5 * float(np.linalg.norm(hi - lo))

    def scan(
        self, T_MC: np.ndarray, angular_resolution_rad: float, range_sigma_m: float, rng: np.random.Generator
    ) -> np.ndarray:
        """Points (N×3, float64, camera frame) hit by an equal-angle ray grid that just covers the
        model, with Gaussian noise of ``range_sigma_m`` along each ray."""
        dist = np.linalg.norm(T_MC[:3, 3] - self.center)
        half = np.arcsin(min(1.0, self.radius / dist)) * 1.05 if dist > self.radius else np.deg2rad(60.0)
        n = int(np.ceil(2 * half / angular_resolution_rad)) + 1
        a = (np.arange(n) - (n - 1) / 2) * angular_resolution_rad
        ax, ay = np.meshgrid(a, a)
        d_c = np.stack([np.sin(ax) * np.cos(ay), np.sin(ay), np.cos(ax) * np.cos(ay)], -1).reshape(-1, 3)
        d_m = d_c @ T_MC[:3, :3].T
        rays = np.hstack([np.broadcast_to(T_MC[:3, 3], d_m.shape), d_m]).astype(np.float32)
        t = self.scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy().astype(np.float64)
        hit = np.isfinite(t)
        r = t[hit] + rng.normal(scale=range_sigma_m, size=int(hit.sum())) if range_sigma_m > 0 else t[hit]
        return d_c[hit] * r[:, None]


def render_views(
    mesh: o3d.geometry.TriangleMesh,
    directions: np.ndarray,
    *,
    distance_m: float | np.ndarray,
    angular_resolution_rad: float,
    range_sigma_m: float,
    rng: np.random.Generator,
    rolls_rad: np.ndarray | None = None,
) -> tuple[list[np.ndarray], np.ndarray]:
    """One cloud (camera frame) per viewing direction (unit, {M}, from the model's centre towards
    the camera) and the camera poses T_CM (V×4×4)."""
    scanner = VirtualScanner(mesh)
    dist = np.broadcast_to(np.asarray(distance_m, dtype=np.float64), (len(directions),))
    rolls = np.zeros(len(directions)) if rolls_rad is None else rolls_rad
    clouds, poses = [], []
    for d, r, roll in zip(directions, dist, rolls):
        T_MC = look_at(scanner.center + r * d, scanner.center, roll)
        clouds.append(scanner.scan(T_MC, angular_resolution_rad, range_sigma_m, rng))
        poses.append(np.linalg.inv(T_MC))
    return clouds, np.array(poses).reshape(-1, 4, 4)


# ----------------------------------------------------------------------------------------------
# descriptors of views


@dataclass
class Descriptors:
    """Descriptors of V views: ESF (V×640), VFH (V×308), CVFH (list of R_i×308) and the
    principal extents (V×3, metres)."""

    esf: np.ndarray
    vfh: np.ndarray
    cvfh: list[np.ndarray]
    extent: np.ndarray


def describe(clouds: Sequence[np.ndarray], seed: int = 0) -> Descriptors:
    """ESF, VFH and CVFH of clouds in their sensor frame (viewpoint at the origin)."""
    e = np.array([esf(c, seed=seed + i) for i, c in enumerate(clouds)]).reshape(-1, 640)
    v = np.array([vfh(c) for c in clouds]).reshape(-1, 308)
    cv = [cvfh(c) for c in clouds]
    x = np.array([principal_extents(c) for c in clouds]).reshape(-1, 3)
    return Descriptors(e, v, cv, x)


@dataclass
class ModelViews:
    """The described views of one model."""

    name: str
    cls: str
    key: str
    T_CM: np.ndarray  # V×4×4
    n_points: np.ndarray  # V
    descriptors: Descriptors
    ports: list[tuple[np.ndarray, np.ndarray]] = field(default_factory=list)

    def save(self, path: Path) -> None:
        d = self.descriptors
        offsets = np.cumsum([0] + [len(c) for c in d.cvfh])
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f".{path.stem}.{os.getpid()}.tmp.npz")
        np.savez_compressed(
            tmp,
            meta=np.array(json.dumps({"name": self.name, "cls": self.cls, "key": self.key})),
            T_CM=self.T_CM,
            n_points=self.n_points,
            esf=d.esf,
            vfh=d.vfh,
            cvfh=np.concatenate(d.cvfh) if d.cvfh else np.empty((0, 308)),
            cvfh_offsets=offsets,
            extent=d.extent,
            ports=np.array([np.r_[p, q] for p, q in self.ports]).reshape(-1, 6),
        )
        tmp.replace(path)  # atomic: a concurrent reader never sees half a file

    @classmethod
    def load(cls, path: Path) -> ModelViews:
        try:
            with np.load(path) as z:
                meta = json.loads(str(z["meta"]))
                off = z["cvfh_offsets"]
                flat = z["cvfh"]
                desc = Descriptors(
                    z["esf"], z["vfh"], [flat[off[i] : off[i + 1]] for i in range(len(off) - 1)], z["extent"]
                )
                ports = [(p[:3], p[3:]) for p in z["ports"]]
                return cls(meta["name"], meta["cls"], meta["key"], z["T_CM"], z["n_points"], desc, ports)
        except Exception as exc:  # noqa: BLE001 - any unreadable cache file is the same user-facing problem
            raise RecognitionError(f"{path}: corrupt view cache ({exc}); delete it to rebuild") from exc


def mesh_key(mesh: o3d.geometry.TriangleMesh, params: ViewParams, file_bytes: bytes | None = None) -> str:
    """Content hash of a model (its file's bytes if it has one, else its geometry) and parameters."""
    h = hashlib.sha256()
    if file_bytes is not None:
        h.update(file_bytes)
    else:
        h.update(np.ascontiguousarray(np.asarray(mesh.vertices, dtype=np.float64)).tobytes())
        h.update(np.ascontiguousarray(np.asarray(mesh.triangles, dtype=np.int64)).tobytes())
    h.update(json.dumps(dataclasses.asdict(params), sort_keys=True).encode())
    h.update(DESCRIPTOR_VERSION.encode())
    return h.hexdigest()


def build_model_views(
    name: str,
    cls: str,
    mesh: o3d.geometry.TriangleMesh,
    params: ViewParams = ViewParams(),
    *,
    ports: Sequence[tuple[np.ndarray, np.ndarray]] = (),
    file_bytes: bytes | None = None,
    cache_dir: str | Path | None = None,
    use_cache: bool = True,
) -> ModelViews:
    """Render and describe ``params.n_views`` views of a mesh (model frame, metres), or load them
    from the cache when the model's content and the parameters are unchanged."""
    key = mesh_key(mesh, params, file_bytes)
    safe = "".join(ch if ch.isalnum() or ch in "-_" else "_" for ch in name)
    path = Path(cache_dir or default_cache_dir()) / "views" / f"{safe}-{key[:16]}.npz"
    if use_cache and path.is_file():
        mv = ModelViews.load(path)
        if mv.key == key:
            mv.cls = cls
            return mv
    rng = np.random.default_rng(params.seed)
    dirs = fibonacci_directions(params.n_views)
    clouds, T_CM = render_views(
        mesh,
        np.tile(dirs, (len(params.distances_m), 1)),
        distance_m=np.repeat(np.asarray(params.distances_m, dtype=np.float64), len(dirs)),
        angular_resolution_rad=params.angular_resolution_rad,
        range_sigma_m=params.range_sigma_m,
        rng=rng,
    )
    keep = [i for i, c in enumerate(clouds) if len(c) >= params.min_points]
    if not keep:
        raise RecognitionError(f"model {name!r}: no view has {params.min_points} points; is it in metres?")
    clouds = [clouds[i] for i in keep]
    mv = ModelViews(
        name, cls, key, T_CM[keep], np.array([len(c) for c in clouds]), describe(clouds, params.seed),
        [(np.asarray(p, float), np.asarray(d, float)) for p, d in ports],
    )  # fmt: skip
    if use_cache:
        mv.save(path)
    return mv


# ----------------------------------------------------------------------------------------------
# the database


@dataclass
class ViewDatabase:
    """Every described view of every model, stacked for matching; ``meshes`` (model name → mesh,
    model frame) when known, for the ICP pose."""

    models: list[ModelViews]
    meshes: dict[str, o3d.geometry.TriangleMesh] = field(default_factory=dict)

    @property
    def classes(self) -> list[str]:
        """The distinct classes, in first-seen order."""
        return list(dict.fromkeys(m.cls for m in self.models))

    @property
    def labels(self) -> np.ndarray:
        return np.concatenate([[m.cls] * len(m.T_CM) for m in self.models])

    @property
    def view_model(self) -> np.ndarray:
        """Index of the model of every view."""
        return np.concatenate([[i] * len(m.T_CM) for i, m in enumerate(self.models)]).astype(int)

    @property
    def T_CM(self) -> np.ndarray:
        return np.concatenate([m.T_CM for m in self.models])

    def features(self, kind: str) -> np.ndarray | list[np.ndarray]:
        if kind == "esf":
            return np.concatenate([m.descriptors.esf for m in self.models])
        if kind == "vfh":
            return np.concatenate([m.descriptors.vfh for m in self.models])
        if kind == "cvfh":
            return [c for m in self.models for c in m.descriptors.cvfh]
        if kind == "extent":
            return np.concatenate([m.descriptors.extent for m in self.models])
        raise RecognitionError(f"unknown descriptor {kind!r} (esf, vfh, cvfh or extent)")

    def model(self, name: str) -> ModelViews:
        for m in self.models:
            if m.name == name:
                return m
        raise KeyError(name)


def _read_mesh(path: Path, scale: float = 1.0) -> o3d.geometry.TriangleMesh:
    if not path.is_file():
        raise RecognitionError(f"{path}: CAD model file not found")
    if path.suffix.lower() not in CAD_SUFFIXES:
        raise RecognitionError(f"{path}: unsupported CAD format {path.suffix!r} (expected .stl, .obj or .ply)")
    mesh = o3d.io.read_triangle_mesh(str(path))
    if len(mesh.triangles) == 0:
        raise RecognitionError(f"{path}: no triangles could be read from the CAD model")
    if scale != 1.0:
        mesh.scale(scale, center=np.zeros(3))
    return mesh


def builtin_models() -> dict[str, tuple[str, o3d.geometry.TriangleMesh, list]]:
    """The simulator's CAD library: name → (class, mesh, ports). Empty if it is unavailable."""
    try:
        from semslam.models.cad import library
    except ImportError:  # the simulator's CAD library is not installed in this build
        return {}
    return {name: (m.cls, m.mesh, list(m.ports)) for name, m in library().items() if m.source is None}


def _registry_path(cache_dir: str | Path | None) -> Path:
    return Path(cache_dir or default_cache_dir()) / "models.json"


def write_atomic(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` via a temporary file and a rename (no half-written file)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(text)
    tmp.replace(path)


def registered_models(cache_dir: str | Path | None = None) -> dict[str, dict]:
    """The user models added with :func:`add_model`: name → {path, cls, scale, sha256, ports}."""
    path = _registry_path(cache_dir)
    if not path.is_file():
        return {}
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise RecognitionError(f"{path}: corrupt model registry ({exc.msg}); fix or delete it") from exc


def add_model(
    path: str | Path,
    cls: str,
    *,
    name: str | None = None,
    scale: float = 1.0,
    ports: Sequence[tuple[Sequence[float], Sequence[float]]] = (),
    params: ViewParams = ViewParams(),
    cache_dir: str | Path | None = None,
) -> ModelViews:
    """Make a user's CAD model (STL/OBJ/PLY; ``scale`` converts its units to metres) recognisable
    as class ``cls``: register it and render and describe its views now (cached by content).
    ``ports`` (position, outward direction) in the model frame, if known, give its connectivity.
    Returns its views."""
    path = Path(path).expanduser().resolve()
    if not cls or not cls.strip():
        raise RecognitionError(f"{path}: a class name is required (--class NAME)")
    if scale <= 0:
        raise RecognitionError(f"{path}: scale must be positive, got {scale}")
    mesh = _read_mesh(path, scale)
    data = path.read_bytes()
    name = name or path.stem
    mv = build_model_views(
        name, cls, mesh, params, ports=[(np.asarray(p, float), np.asarray(d, float)) for p, d in ports],
        file_bytes=data + repr(scale).encode(), cache_dir=cache_dir,
    )  # fmt: skip
    reg = registered_models(cache_dir)
    reg[name] = {
        "path": str(path),
        "cls": cls,
        "scale": scale,
        "sha256": hashlib.sha256(data).hexdigest(),
        "ports": [[list(map(float, p)), list(map(float, d))] for p, d in ports],
    }
    write_atomic(_registry_path(cache_dir), json.dumps(reg, indent=2))
    return mv


def remove_model(name: str, cache_dir: str | Path | None = None) -> bool:
    """Forget a user model (its cached views stay until the cache is cleared). True if it existed."""
    reg = registered_models(cache_dir)
    if name not in reg:
        return False
    del reg[name]
    write_atomic(_registry_path(cache_dir), json.dumps(reg, indent=2))
    return True


def load_database(
    models: Mapping[str, tuple[str, o3d.geometry.TriangleMesh, list]] | None = None,
    params: ViewParams = ViewParams(),
    *,
    cache_dir: str | Path | None = None,
    include_user_models: bool = True,
    progress: bool = False,
) -> ViewDatabase:
    """The view database of ``models`` (name → (class, mesh, ports); default: the simulator's
    built-in library) plus, unless disabled, every user model registered with :func:`add_model`.
    ``progress`` shows a progress bar (rendering a model's views takes seconds; cached ones load
    at once)."""
    models = builtin_models() if models is None else models
    meshes = {name: mesh for name, (_cls, mesh, _ports) in models.items()}
    items = list(models.items())
    if progress:
        from tqdm import tqdm

        items = tqdm(items, desc="CAD model views", unit="model")
    views = [
        build_model_views(name, cls, mesh, params, ports=ports, cache_dir=cache_dir)
        for name, (cls, mesh, ports) in items
    ]
    if include_user_models:
        for name, entry in registered_models(cache_dir).items():
            path = Path(entry["path"])
            mesh = _read_mesh(path, entry.get("scale", 1.0))
            meshes[name] = mesh
            ports = [(np.asarray(p, float), np.asarray(d, float)) for p, d in entry.get("ports", [])]
            views.append(
                build_model_views(
                    name,
                    entry["cls"],
                    mesh,
                    params,
                    ports=ports,
                    file_bytes=path.read_bytes() + repr(entry.get("scale", 1.0)).encode(),
                    cache_dir=cache_dir,
                )  # fmt: skip
            )
    if not views:
        raise RecognitionError("the view database is empty: no CAD model available (add one with `semslam models add`)")
    return ViewDatabase(views, meshes)
