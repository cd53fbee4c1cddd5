"""Small ray-cast test scenes for the laser front-end (tests and experiments, not the mission simulator).

A scene is a floor, a wall, pipes (cylinders) and objects (a body box, optionally a handle box on
top, like a valve), built from open3d primitives and ray-cast from a sensor with
``o3d.t.geometry.RaycastingScene``. Everything is in the sensor frame {S}: the sensor sits at the
origin looking along +z, which is also "down" (the floor is the plane z = ``floor_z``), so "up" is −z.
Each returned point carries the id of the geometry it hit, for ground-truth labelling.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
import open3d as o3d

UP = np.array([0.0, 0.0, -1.0])  # in {S}: the sensor looks down


@dataclass(frozen=True)
class SynthPipe:
    p: tuple[float, float, float]
    q: tuple[float, float, float]
    radius: float = 0.05


@dataclass(frozen=True)
class SynthObject:
    """A box body centred at ``center`` (its position), long side along ``axis`` (horizontal)."""

    center: tuple[float, float, float]
    size: tuple[float, float, float] = (0.2, 0.16, 0.16)  # along axis, across, up
    axis: tuple[float, float, float] = (1.0, 0.0, 0.0)
    handle: bool = False  # a thin handle box above the body (a valve)
    pipes: tuple[int, ...] = ()  # indices of the pipes connected to it
    configuration: int | None = None


@dataclass
class SynthScene:
    floor_z: float = 2.0
    wall_x: float | None = 1.6  # a wall x = wall_x, facing the sensor
    pipes: list[SynthPipe] = field(default_factory=list)
    objects: list[SynthObject] = field(default_factory=list)


@dataclass
class SynthScan:
    """A ray-cast scan: points (N×3 float32, {S}) and for each point what it hit.

    ``kind`` is 0 floor, 1 wall, 2 pipe, 3 object; ``index`` the pipe / object index (−1 for planes).
    """

    points: np.ndarray
    kind: np.ndarray
    index: np.ndarray
    scene: SynthScene

    FLOOR, WALL, PIPE, OBJECT = 0, 1, 2, 3


def _box(size, center, R) -> o3d.geometry.TriangleMesh:
    m = o3d.geometry.TriangleMesh.create_box(*size)
    m.translate(-np.asarray(size) / 2.0)
    m.rotate(R, center=np.zeros(3))
    m.translate(center)
    return m


def _frame(axis) -> np.ndarray:
    """Rotation whose columns are (axis, across, up) with up = UP made orthogonal to the axis."""
    x = np.asarray(axis, float)
    x = x / np.linalg.norm(x)
    z = UP - (UP @ x) * x
    z /= np.linalg.norm(z)
    return np.column_stack([x, np.cross(z, x), z])


def _cylinder(p, q, r) -> o3d.geometry.TriangleMesh:
    p, q = np.asarray(p, float), np.asarray(q, float)
    d = q - p
    length = np.linalg.norm(d)
    m = o3d.geometry.TriangleMesh.create_cylinder(radius=r, height=length, resolution=48, split=4)
    z = d / length
    x = np.cross(z, [1.0, 0, 0]) if abs(z[0]) < 0.9 else np.cross(z, [0, 1.0, 0])
    x /= np.linalg.norm(x)
    R = np.column_stack([x, np.cross(z, x), z])
    m.rotate(R, center=np.zeros(3))
    m.translate((p + q) / 2)
    return m


def default_scene() -> SynthScene:
    """A mock-up like the paper's tank structure, 2 m below the sensor.

    A valve between two collinear pipes (configuration 2), an elbow (3), a tee (4), two pipe ends
    with single-connection objects (1), and one pipe resting directly on the floor with a free end
    (coplanar-with-floor case).
    """
    fz = 2.0
    h = fz - 0.10  # pipe axes 10 cm above the floor (objects 16-20 cm tall standing on it)
    pipes = [
        SynthPipe((-1.0, -0.6, h), (-0.1, -0.6, h)),  # 0: end object A -> valve B
        SynthPipe((0.1, -0.6, h), (0.9, -0.6, h)),  # 1: valve B -> elbow C
        SynthPipe((1.0, -0.5, h), (1.0, 0.4, h)),  # 2: elbow C -> tee D
        SynthPipe((0.9, 0.5, h), (0.1, 0.5, h)),  # 3: tee D -> end object E
        SynthPipe((1.0, 0.6, h), (1.0, 1.2, h), radius=0.04),  # 4: tee D -> free end (thin pipe)
        SynthPipe((-1.2, 0.2, fz - 0.05), (-0.4, 0.9, fz - 0.05)),  # 5: on the floor, free ends
    ]
    objects = [
        SynthObject((-1.1, -0.6, h), (0.2, 0.18, 0.2), pipes=(0,), configuration=1),
        SynthObject((0.0, -0.6, h), (0.2, 0.16, 0.16), handle=True, pipes=(0, 1), configuration=2),
        SynthObject((1.0, -0.6, h), (0.2, 0.2, 0.18), pipes=(1, 2), configuration=3),
        SynthObject((1.0, 0.5, h), (0.2, 0.2, 0.18), axis=(0, 1.0, 0), pipes=(2, 3, 4), configuration=4),
        SynthObject((0.0, 0.5, h), (0.2, 0.16, 0.16), handle=True, pipes=(3,), configuration=1),
    ]
    return SynthScene(floor_z=fz, wall_x=1.35, pipes=pipes, objects=objects)


def raycast(
    scene: SynthScene,
    n_rays: int = 100_000,
    fov_deg: float = 80.0,
    range_sigma: float = 0.005,
    T_scene: np.ndarray | None = None,
    seed: int = 0,
) -> SynthScan:
    """Ray-cast ``scene`` from the origin over a square field of view along +z.

    ``T_scene`` (4×4) moves the whole scene before casting (a different viewpoint). Ranges get
    Gaussian noise ``range_sigma`` (m) along the ray.
    """
    meshes, kinds, indices = [], [], []
    span = 8.0
    floor = _box((span, span, 0.02), (0, 0, scene.floor_z + 0.01), np.eye(3))
    meshes.append(floor), kinds.append(SynthScan.FLOOR), indices.append(-1)
    if scene.wall_x is not None:
        wall = _box((0.02, span, 3.0), (scene.wall_x + 0.01, 0, scene.floor_z - 1.5), np.eye(3))
        meshes.append(wall), kinds.append(SynthScan.WALL), indices.append(-1)
    for i, p in enumerate(scene.pipes):
        meshes.append(_cylinder(p.p, p.q, p.radius)), kinds.append(SynthScan.PIPE), indices.append(i)
    for i, o in enumerate(scene.objects):
        R = _frame(o.axis)
        body = _box(o.size, o.center, R)
        if o.handle:
            hs = (0.04, 0.04, 0.10)  # stem
            stem_c = np.asarray(o.center) + R[:, 2] * (o.size[2] / 2 + hs[2] / 2)
            wheel = (0.16, 0.16, 0.025)
            wheel_c = np.asarray(o.center) + R[:, 2] * (o.size[2] / 2 + hs[2] + wheel[2] / 2)
            body = body + _box(hs, stem_c, R) + _box(wheel, wheel_c, R)
        meshes.append(body), kinds.append(SynthScan.OBJECT), indices.append(i)

    rc = o3d.t.geometry.RaycastingScene()
    for m in meshes:
        if T_scene is not None:
            m = o3d.geometry.TriangleMesh(m).transform(T_scene)
        rc.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(m))

    side = int(round(np.sqrt(n_rays)))
    t = np.tan(np.radians(fov_deg / 2))
    u, v = np.meshgrid(np.linspace(-t, t, side), np.linspace(-t, t, side))
    d = np.stack([u.ravel(), v.ravel(), np.ones(u.size)], axis=1)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    rays = np.hstack([np.zeros_like(d), d]).astype(np.float32)
    ans = rc.cast_rays(o3d.core.Tensor(rays))
    r = ans["t_hit"].numpy()
    gid = ans["geometry_ids"].numpy().astype(np.int64)
    hit = np.isfinite(r)
    rng = np.random.default_rng(seed)
    r = r[hit] + rng.normal(0.0, range_sigma, hit.sum())
    pts = (d[hit] * r[:, None]).astype(np.float32)
    gid = gid[hit]
    return SynthScan(pts, np.asarray(kinds)[gid], np.asarray(indices)[gid], scene)


def truth_of(scan: SynthScan, T_scene: np.ndarray | None = None):
    """The ground truth of a scan for :mod:`frontends.laser.evaluation`, in {S}."""
    from frontends.laser.evaluation import OBJECT, PIPE, PLANE, ScanTruth

    T = np.eye(4) if T_scene is None else np.asarray(T_scene)

    def tf(x):
        return T[:3, :3] @ np.asarray(x, float) + T[:3, 3]

    kind = np.select([scan.kind <= SynthScan.WALL, scan.kind == SynthScan.PIPE], [PLANE, PIPE], OBJECT)
    pipes = [(tf(p.p), tf(p.q), p.radius) for p in scan.scene.pipes]
    objects = [(tf(o.center), o.configuration) for o in scan.scene.objects]
    return ScanTruth(kind, scan.index.copy(), pipes, objects)


def viewpoint(yaw_deg: float = 0.0, shift=(0.0, 0.0), tilt_deg: float = 0.0, height: float = 0.0) -> np.ndarray:
    """A scene transform T_scene: the scene turned by ``yaw`` about the sensor's view axis (z),
    shifted in x, y, tilted about x, and moved ``height`` closer to the sensor."""
    from scipy.spatial.transform import Rotation

    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("xz", [tilt_deg, yaw_deg], degrees=True).as_matrix()
    T[:3, 3] = [shift[0], shift[1], -height]
    # rotate about the point under the sensor on the floor, so the structure stays in view
    c = np.array([0.0, 0.0, default_scene().floor_z])
    T[:3, 3] += c - T[:3, :3] @ c
    return T


@lru_cache(maxsize=4)
def cached_scan(n_rays: int = 60_000, seed: int = 0) -> SynthScan:
    """The default scene from the default viewpoint, cast once per process (tests share it)."""
    return raycast(default_scene(), n_rays=n_rays, seed=seed)
