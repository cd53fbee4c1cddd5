"""The pipeline scene: a natural seabed (relief, sand ripples, rocks) and a pipeline lying on it.

World {W}: NED with its origin at the surface above the middle of the main line. The seabed is a
height field (:class:`NaturalSeabed`): the seeded relief of :mod:`semslam.sim.seabed` (a planar
slope and gaussian bumps) plus mounds and hollows of gravel (a smooth field of short wavelengths),
sand ripples (a sine across a drawn direction, its phase and
amplitude varying slowly over the area) and a fine roughness. Rocks are deformed ellipsoids sunk
into the sand, scattered at random and a few right against the pipes.

The pipeline (:func:`make_pipeline`): a straight main line of one radius (20-60 mm), laid along the
seabed's trend under it, resting on the crests of the sand and sunk into it by a drawn share of its
diameter (so it spans over troughs and is buried where the seabed rises); in-line fittings on it
(flanges, i.e. the CAD library's R-Socket, and ball or butterfly valves), optionally a tee junction
(R-Tee or 3-way ball valve) with a branch line ending free or at a valve, and optionally a second,
parallel line. Fittings are the CAD models of :mod:`semslam.models.cad` scaled by the line's radius
over the library's 31.5 mm, placed so that their ports lie on the pipe axes (as in the tank).

Colours (:meth:`PipelineScene.albedo`): sand with a mottled texture, rocks grey-brown and speckled,
each line a coating colour with patches of marine growth, fittings a darker shade of their line's.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import open3d as o3d
from scipy.spatial.transform import Rotation

from semslam.mission.ground_truth import GroundTruthMap, GtObject, GtPipe
from semslam.models import cad
from semslam.sim.pipeline_config import NaturalSeabedConfig, PipelineLayoutConfig
from semslam.sim.raycast import LabelledScene
from semslam.sim.seabed import Seabed, random_seabed

# geometry kinds in a PipelineScene
GROUND, ROCK, PIPE, OBJECT = 0, 1, 2, 3
KIND_NAMES = ("seabed", "rock", "pipe", "object")
UP = np.array([0.0, 0.0, -1.0])  # NED: up is −z

PIPE_RESOLUTION = 48  # segments around a pipe: facets within 0.13 mm of a 60 mm cylinder
PIPE_SPLIT_M = 0.25  # rings along a pipe (long sliver triangles make ray casting imprecise)
_COATINGS = ((0.85, 0.62, 0.12), (0.80, 0.30, 0.10), (0.20, 0.22, 0.24), (0.75, 0.75, 0.70))
_GROWTH = np.array([0.33, 0.38, 0.24])


def _smooth_field(rng: np.random.Generator, n_waves: int, wavelength: tuple[float, float]):
    """A random smooth field f(x, y) in about [−1, 1]: a sum of plane waves of random directions,
    wavelengths and phases (deterministic once drawn)."""
    ang = rng.uniform(0, 2 * np.pi, n_waves)
    k = 2 * np.pi / rng.uniform(*wavelength, n_waves)
    kx, ky, ph = k * np.cos(ang), k * np.sin(ang), rng.uniform(0, 2 * np.pi, n_waves)
    scale = np.sqrt(2.0 / n_waves)

    def f(x, y):
        x, y = np.asarray(x, float), np.asarray(y, float)
        return scale * sum(np.sin(kx[i] * x + ky[i] * y + ph[i]) for i in range(n_waves))

    return f


def _texture3(rng: np.random.Generator, n_waves: int, wavelength: tuple[float, float]):
    """A random smooth 3-D field (for colours on any surface): sum of plane waves, about [−1, 1]."""
    d = rng.normal(size=(n_waves, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    k = (2 * np.pi / rng.uniform(*wavelength, n_waves))[:, None] * d
    ph = rng.uniform(0, 2 * np.pi, n_waves)
    scale = np.sqrt(2.0 / n_waves)
    return lambda P: scale * np.sin(np.asarray(P, float) @ k.T + ph).sum(axis=1)


@dataclass
class NaturalSeabed:
    """Seabed depth z(n, e) = relief + ripples (+ roughness in the mesh only)."""

    relief: Seabed
    ripple_amplitude: float
    ripple_wavelength: float
    ripple_direction: float  # rad, of the wave vector (north → east)
    ripple_phase: object = field(repr=False)  # (n, e) → phase perturbation (rad)
    ripple_envelope: object = field(repr=False)  # (n, e) → amplitude factor in [0.3, 1]
    lumps: object = field(repr=False)  # (n, e) → depth of the mounds and hollows (m; + = deeper)
    # the meshed band: a rectangle about the origin, ``half_length`` along the heading (rad, from
    # north) and ``half_width`` across it (m)
    heading: float = 0.0
    half_length: float = 1.0
    half_width: float = 1.0

    def band_to_world(self, s, w) -> tuple[np.ndarray, np.ndarray]:
        """(north, east) of the band coordinates s (along the heading) and w (across, to the right)."""
        c, sn = np.cos(self.heading), np.sin(self.heading)
        s, w = np.asarray(s, float), np.asarray(w, float)
        return c * s - sn * w, sn * s + c * w

    @property
    def area(self) -> float:
        return 4.0 * self.half_length * self.half_width

    def depth(self, n, e) -> np.ndarray:
        """Seabed depth (m, NED z) at north ``n``, east ``e`` (without the mesh's fine roughness)."""
        n, e = np.asarray(n, float), np.asarray(e, float)
        k = 2 * np.pi / self.ripple_wavelength
        arg = k * (n * np.cos(self.ripple_direction) + e * np.sin(self.ripple_direction)) + self.ripple_phase(n, e)
        # sand ripples are asymmetric: a second harmonic sharpens the crests (crests are shallower: −z)
        wave = np.sin(arg) + 0.25 * np.sin(2 * arg + 0.8)
        ripples = self.ripple_amplitude * self.ripple_envelope(n, e) * wave
        return self.relief.depth(n, e) + self.lumps(n, e) - ripples

    def mesh(self, roughness: float, rng: np.random.Generator) -> o3d.geometry.TriangleMesh:
        """The seabed as a triangle grid over the band at the relief's resolution (normals up)."""
        r = self.relief.resolution_m
        gs = np.linspace(-self.half_length, self.half_length, int(round(2 * self.half_length / r)) + 1)
        gw = np.linspace(-self.half_width, self.half_width, int(round(2 * self.half_width / r)) + 1)
        N, E = self.band_to_world(*np.meshgrid(gs, gw, indexing="ij"))
        Z = self.depth(N, E) + rng.normal(0.0, roughness, N.shape)
        V = np.stack([N.ravel(), E.ravel(), Z.ravel()], 1)
        rows, cols = N.shape
        i = (np.arange(rows - 1)[:, None] * cols + np.arange(cols - 1)[None, :]).ravel()
        F = np.concatenate([np.stack([i, i + 1, i + cols], 1), np.stack([i + 1, i + cols + 1, i + cols], 1)])
        m = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(V), o3d.utility.Vector3iVector(F.astype(np.int32)))
        m.compute_triangle_normals()
        if np.asarray(m.triangle_normals)[:, 2].mean() > 0:  # (s, w) may be left-handed in (n, e): face up
            m.triangles = o3d.utility.Vector3iVector(F[:, ::-1].astype(np.int32))
            m.compute_triangle_normals()
        return m


def make_seabed(cfg: NaturalSeabedConfig, heading: float, half_length: float, rng: np.random.Generator):
    """The seabed under a band of ``half_length`` along ``heading`` (rad from north) and
    ``cfg.half_width_m`` across it, about the origin, drawn from ``rng``."""
    half = float(np.hypot(half_length, cfg.half_width_m))
    bounds = ((-half, half), (-half, half))
    relief = random_seabed(
        rng,
        area=bounds,
        margin_m=0.0,
        depth_m=cfg.depth_m,
        relief_m=cfg.relief_m,
        n_bumps=cfg.bumps,
        bump_sigma_m=cfg.bump_sigma_m,
        slope_share=cfg.slope_share,
        resolution_m=cfg.resolution_m,
    )
    phase = _smooth_field(rng, 4, (1.0, 4.0))
    env = _smooth_field(rng, 4, (1.5, 5.0))
    lumps = _smooth_field(rng, 12, cfg.lump_wavelength_m)
    return NaturalSeabed(
        relief=relief,
        ripple_amplitude=float(rng.uniform(*cfg.ripple_amplitude_m)),
        ripple_wavelength=float(rng.uniform(*cfg.ripple_wavelength_m)),
        ripple_direction=float(rng.uniform(0, np.pi)),
        ripple_phase=lambda n, e: 1.5 * phase(n, e),
        ripple_envelope=lambda n, e: 0.65 + 0.35 * np.clip(env(n, e), -1, 1),
        lumps=lambda n, e: cfg.lump_amplitude_m * lumps(n, e),
        heading=heading,
        half_length=half_length,
        half_width=cfg.half_width_m,
    )


# ----------------------------------------------------------------------------------------------
# rocks


@dataclass
class Rock:
    """A deformed ellipsoid: centre (m, {W}), semi-axes (m), rotation, shape seed, base colour."""

    id: int
    center: np.ndarray
    radii: np.ndarray
    R: np.ndarray
    shape_seed: int
    color: np.ndarray

    def mesh(self) -> o3d.geometry.TriangleMesh:
        m = o3d.geometry.TriangleMesh.create_sphere(radius=1.0, resolution=10)
        u = np.asarray(m.vertices)
        bumps = _texture3(np.random.default_rng(self.shape_seed), 5, (1.5, 4.0))(u)
        V = (u * (1.0 + 0.12 * bumps)[:, None] * self.radii) @ self.R.T + self.center
        m.vertices = o3d.utility.Vector3dVector(V)
        m.compute_triangle_normals()
        return m


def _rock(rid: int, n: float, e: float, radius: float, seabed: NaturalSeabed, burial: float, rng) -> Rock:
    radii = radius * np.array([1.0, rng.uniform(0.6, 1.0), rng.uniform(0.35, 0.7)])  # flattened: lying stones
    R = Rotation.from_euler("ZYX", [rng.uniform(0, 2 * np.pi), rng.normal(0, 0.15), rng.normal(0, 0.15)]).as_matrix()
    height = radii[2]
    z = float(seabed.depth(n, e)) + 2 * height * burial - height  # NED: the share ``burial`` of it below the sand
    grey = rng.uniform(0.28, 0.5)
    color = np.clip(grey + rng.normal(0, 0.04, 3) + np.array([0.03, 0.01, -0.03]), 0, 1)
    return Rock(rid, np.array([n, e, z]), radii, R, int(rng.integers(2**31)), color)


# ----------------------------------------------------------------------------------------------
# pipeline


@dataclass
class Line:
    """A straight line of the pipeline: its axis through ``origin`` along unit ``direction`` (from
    s = 0 to ``length``), the radius, and the coating colour of its pipes and fittings."""

    origin: np.ndarray
    direction: np.ndarray
    length: float
    radius: float
    color: np.ndarray

    def point(self, s) -> np.ndarray:
        return self.origin + np.multiply.outer(np.asarray(s, float), self.direction)


@dataclass
class Fitting:
    """A placed fitting: class, CAD model, rigid pose T_WM (4×4), scale of the model, attached pipes."""

    id: int
    cls: str
    model: str
    T_WM: np.ndarray
    scale: float
    color: np.ndarray
    pipes: tuple[int, ...] = ()

    @property
    def position(self) -> np.ndarray:
        return self.T_WM[:3, 3]

    def ports(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """The model's ports (position, outward unit direction) in {W}."""
        R, t = self.T_WM[:3, :3], self.T_WM[:3, 3]
        return [(R @ (self.scale * p) + t, R @ d) for p, d in cad.library()[self.model].ports]

    def mesh(self) -> o3d.geometry.TriangleMesh:
        T = self.T_WM.copy()
        T[:3, :3] *= self.scale
        m = cad.library()[self.model].transformed(T)
        m.compute_triangle_normals()
        return m


@dataclass
class PipePiece:
    """A straight pipe between two ports (or a port and a free end): axis ``p`` → ``q`` (m, {W})."""

    id: int
    p: np.ndarray
    q: np.ndarray
    radius: float
    color: np.ndarray

    @property
    def length(self) -> float:
        return float(np.linalg.norm(self.q - self.p))

    @property
    def axis(self) -> np.ndarray:
        return (self.q - self.p) / max(self.length, 1e-12)


@dataclass
class PipelineLayout:
    lines: list[Line] = field(default_factory=list)
    fittings: list[Fitting] = field(default_factory=list)
    pipes: list[PipePiece] = field(default_factory=list)

    def ground_truth(self, seen_objects=None, seen_pipes=None) -> GroundTruthMap:
        objs = tuple(
            GtObject(
                id=f.id,
                cls=f.cls,
                position=tuple(map(float, f.position)),
                orientation=tuple(map(float, Rotation.from_matrix(f.T_WM[:3, :3]).as_quat())),
                pipes=tuple(f.pipes),
                model=None,  # a scaled copy of the library's model (scale in the scene's extras)
            )
            for f in self.fittings
        )
        pipes = tuple(GtPipe(p.id, tuple(map(float, p.p)), tuple(map(float, p.q)), float(p.radius)) for p in self.pipes)
        classes = tuple(dict.fromkeys(list(cad.CLASSES) + [f.cls for f in self.fittings]))
        return GroundTruthMap(
            classes=classes, objects=objs, pipes=pipes, seen_objects=seen_objects, seen_pipes=seen_pipes
        )

    def to_dict(self) -> dict:
        return {
            "lines": [
                {
                    "origin": _rounded(ln.origin),
                    "direction": _rounded(ln.direction),
                    "length_m": ln.length,
                    "radius_m": ln.radius,
                }
                for ln in self.lines
            ],
            "objects": [
                {
                    "id": f.id,
                    "cls": f.cls,
                    "model": f.model,
                    "scale": f.scale,
                    "position": _rounded(f.position),
                    "orientation": _rounded(Rotation.from_matrix(f.T_WM[:3, :3]).as_quat()),
                    "pipes": list(f.pipes),
                }
                for f in self.fittings
            ],
            "pipes": [{"id": p.id, "p": _rounded(p.p), "q": _rounded(p.q), "radius": p.radius} for p in self.pipes],
        }


def _rounded(v) -> list[float]:
    return [round(float(x), 9) for x in v]


def _line_on_seabed(seabed: NaturalSeabed, start_h, u_h, length: float, radius: float, burial: float):
    """Where a straight line of ``radius`` from the horizontal point ``start_h`` (n, e) along the
    horizontal unit ``u_h`` comes to rest: on the seabed's trend under it, its bottom on the crests
    (the 10 % shallowest residuals about the trend), then sunk by ``burial`` × its diameter.
    Returns (origin (3,), unit direction (3,))."""
    s = np.arange(-0.3, length + 0.3, 0.01)
    w_h = np.array([-u_h[1], u_h[0]])
    zs = []
    for off in (-0.6 * radius, 0.0, 0.6 * radius):  # the pipe's footprint across
        xy = start_h + np.outer(s, u_h) + off * w_h
        zs.append(seabed.depth(xy[:, 0], xy[:, 1]))
    z = np.min(zs, axis=0)  # NED: the shallowest across the footprint carries the pipe
    A = np.column_stack([np.ones_like(s), s])
    (a, b), *_ = np.linalg.lstsq(A, z, rcond=None)
    crest = np.quantile(z - (a + b * s), 0.1)
    z0 = a + crest - radius + 2 * radius * burial  # axis depth at s = 0
    d = np.array([u_h[0], u_h[1], b])
    return np.array([start_h[0], start_h[1], z0]), d / np.linalg.norm(d)


def _fitting_frame(x: np.ndarray) -> np.ndarray:
    """Rotation with model x along ``x``, model z up (against gravity) as far as it can be."""
    z = UP - (UP @ x) * x
    z /= np.linalg.norm(z)
    return np.column_stack([x, np.cross(z, x), z])


def _spaced_positions(rng, lo: float, hi: float, n: int, gap: float) -> list[float]:
    """n sorted positions in [lo, hi], neighbours at least ``gap`` apart (fewer if they do not fit)."""
    for _ in range(200):
        s = np.sort(rng.uniform(lo, hi, n))
        if n <= 1 or np.diff(s).min() >= gap:
            return s.tolist()
    return _spaced_positions(rng, lo, hi, n - 1, gap) if n > 1 else []


def make_pipeline(cfg: PipelineLayoutConfig, seabed: NaturalSeabed, heading: float, length: float, rng):
    """The pipeline's lines, fittings and pipe pieces (see the module docstring)."""
    u_h = np.array([np.cos(heading), np.sin(heading)])
    w_h = np.array([-u_h[1], u_h[0]])
    colors = [np.array(_COATINGS[i]) for i in rng.permutation(len(_COATINGS))]
    lines: list[Line] = []
    r = float(rng.uniform(*cfg.radius_m))
    start = -0.5 * length * u_h
    o, d = _line_on_seabed(seabed, start, u_h, length, r, float(rng.uniform(*cfg.burial)))
    lines.append(Line(o, d, length, r, colors[0]))

    # in-line fittings and the tee on the main line: (position along it, class)
    n_inline = int(rng.integers(cfg.inline_fittings[0], cfg.inline_fittings[1] + 1))
    tee = rng.uniform() < cfg.tee_probability
    slots = _spaced_positions(rng, 0.7, length - 0.7, n_inline + int(tee), cfg.min_fitting_spacing_m)
    kinds = ["inline"] * len(slots)
    if tee and slots:
        kinds[int(rng.integers(len(slots)))] = "tee"
    inline = [k for k, kind in enumerate(kinds) if kind == "inline"]
    valves = {k for k in inline if rng.uniform() < cfg.valve_share}
    if inline and not valves:
        valves = {inline[int(rng.integers(len(inline)))]}
    side = 1.0 if rng.uniform() < 0.5 else -1.0  # the branch's side; the parallel line goes on the other

    fittings: list[Fitting] = []
    pipes: list[PipePiece] = []
    scale = r / cad.PIPE_RADIUS_M
    ends = [(lines[0].point(0.0), None)]  # ports along the main line, in order: (point, fitting)
    branch = None
    for k, (s, kind) in enumerate(zip(slots, kinds)):
        c = lines[0].point(s)
        if kind == "tee":
            cls = cad.R_TEE if rng.uniform() < 0.5 else cad.THREE_WAY_BALL_VALVE
            w = np.array([side * w_h[0], side * w_h[1], 0.0])  # horizontal, across the main line (⟂ d)
            v = np.cross(d, w)
            ahead = c[:2] + w[:2]
            slope = float(seabed.relief.depth(*ahead) - seabed.relief.depth(*c[:2]))
            d2 = w + (slope / v[2] if abs(v[2]) > 0.1 else 0.0) * v  # follows the seabed's fall across
            d2 /= np.linalg.norm(d2)
            if cls == cad.R_TEE:  # model: +x branch, ±y run
                R = np.column_stack([d2, d, np.cross(d2, d)])
            else:  # model: ±x run, +y branch, +z handle: the run's sign that puts the handle up
                R = max(
                    (np.column_stack([sx * d, d2, np.cross(sx * d, d2)]) for sx in (1.0, -1.0)),
                    key=lambda M: M[:, 2] @ UP,
                )
            branch = (len(fittings), d2)
        else:
            cls = (cad.BALL_VALVE if rng.uniform() < 0.5 else cad.BUTTERFLY_VALVE) if k in valves else cad.R_SOCKET
            R = _fitting_frame(d)
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R, c
        fit = Fitting(len(fittings), cls, cls, T, scale, colors[0] * 0.7)
        fittings.append(fit)
        ports = fit.ports()
        back = min(ports, key=lambda pd: pd[1] @ d)[0]  # the port facing the line's start
        front = max(ports, key=lambda pd: pd[1] @ d)[0]
        ends += [(back, fit), (front, fit)]
    ends.append((lines[0].point(length), None))

    def add_pipe(p, q, rad, color, at=()):
        pid = len(pipes)
        pipes.append(PipePiece(pid, np.asarray(p, float), np.asarray(q, float), rad, color))
        for f in at:
            if f is not None:
                f.pipes = tuple(sorted(f.pipes + (pid,)))

    for (p0, f0), (p1, f1) in zip(ends[0::2], ends[1::2]):
        add_pipe(p0, p1, r, colors[0], (f0, f1))

    if branch is not None:
        tee_fit, d2 = fittings[branch[0]], branch[1]
        port = max(tee_fit.ports(), key=lambda pd: pd[1] @ d2)[0]
        lb = float(rng.uniform(*cfg.branch_length_m))
        lines.append(Line(port, d2, lb, r, colors[0]))
        end = port + lb * d2
        end_fit = None
        if rng.uniform() < cfg.end_valve_probability:
            cls = cad.BALL_VALVE
            port_offset = cad.library()[cls].ports[0][0][0] * scale  # the −x port (negative)
            T = np.eye(4)
            T[:3, :3], T[:3, 3] = _fitting_frame(d2), end - port_offset * d2
            end_fit = Fitting(len(fittings), cls, cls, T, scale, colors[0] * 0.7)
            fittings.append(end_fit)
        add_pipe(port, end, r, colors[0], (tee_fit, end_fit))

    if rng.uniform() < cfg.parallel_probability:
        r2 = float(rng.uniform(*cfg.radius_m))
        off = -side * float(rng.uniform(*cfg.parallel_offset_m))
        lp = length * float(rng.uniform(0.7, 1.0))
        start2 = -0.5 * lp * u_h + off * w_h
        o2, d2 = _line_on_seabed(seabed, start2, u_h, lp, r2, float(rng.uniform(*cfg.burial)))
        lines.append(Line(o2, d2, lp, r2, colors[1]))
        add_pipe(o2, o2 + lp * d2, r2, colors[1])
    return PipelineLayout(lines, fittings, pipes)


def _distance_to_segments(P: np.ndarray, pipes: list[PipePiece]) -> np.ndarray:
    """Distance (m) from each point (K×3) to the nearest pipe axis segment, minus its radius."""
    out = np.full(len(P), np.inf)
    for pp in pipes:
        t = np.clip((P - pp.p) @ pp.axis, 0.0, pp.length)
        out = np.minimum(out, np.linalg.norm(P - (pp.p + t[:, None] * pp.axis), axis=1) - pp.radius)
    return out


def make_rocks(cfg: NaturalSeabedConfig, seabed: NaturalSeabed, layout: PipelineLayout, rng) -> list[Rock]:
    """Rocks at random over the seabed (clear of the pipes and fittings), and ``rocks_touching``
    right against the pipes' sides (clear of the fittings)."""
    lo, hi = np.log(cfg.rock_radius_m[0]), np.log(cfg.rock_radius_m[1])
    fit_pos = np.array([f.position for f in layout.fittings]).reshape(-1, 3)
    rocks: list[Rock] = []
    for _ in range(int(rng.poisson(cfg.rock_density_m2 * seabed.area))):
        n, e = seabed.band_to_world(rng.uniform(-1, 1) * seabed.half_length, rng.uniform(-1, 1) * seabed.half_width)
        rad = float(np.exp(rng.uniform(lo, hi)))
        rock = _rock(len(rocks), n, e, rad, seabed, float(rng.uniform(*cfg.rock_burial)), rng)
        clear = _distance_to_segments(rock.center[None], layout.pipes)[0] > 1.1 * rad
        if clear and (not len(fit_pos) or np.linalg.norm(fit_pos - rock.center, axis=1).min() > 0.3 + rad):
            rocks.append(rock)
    tries = 0
    placed = 0
    while placed < cfg.rocks_touching and layout.pipes and tries < 200:
        tries += 1
        pp = layout.pipes[int(rng.integers(len(layout.pipes)))]
        if pp.length < 0.5:
            continue
        c = pp.p + rng.uniform(0.2, pp.length - 0.2) * pp.axis
        if len(fit_pos) and np.linalg.norm(fit_pos - c, axis=1).min() < 0.35:
            continue
        rad = float(np.exp(rng.uniform(lo, np.log(min(cfg.rock_radius_m[1], 0.12)))))
        side = np.cross(pp.axis, UP)
        side /= np.linalg.norm(side)
        xy = c + (1 if rng.uniform() < 0.5 else -1) * side * (pp.radius + 0.9 * rad)
        rocks.append(_rock(len(rocks), xy[0], xy[1], rad, seabed, float(rng.uniform(*cfg.rock_burial)), rng))
        placed += 1
    return rocks


# ----------------------------------------------------------------------------------------------
# the scene


class PipelineScene(LabelledScene):
    """Seabed, rocks, pipes and fittings in an open3d ``RaycastingScene``, each hit labelled by
    (kind, id): GROUND, ROCK, PIPE or OBJECT (−1 for no hit) and the rock / pipe / fitting id."""

    def __init__(self, seabed: NaturalSeabed, rocks: list[Rock], layout: PipelineLayout, roughness: float, rng):
        self.seabed, self.rocks, self.layout = seabed, rocks, layout
        parts = [(GROUND, -1, seabed.mesh(roughness, rng))]
        parts += [(ROCK, rk.id, rk.mesh()) for rk in rocks]
        for pp in layout.pipes:
            split = max(1, int(np.ceil(pp.length / PIPE_SPLIT_M)))
            parts.append((PIPE, pp.id, cad.cylinder(pp.p, pp.q, pp.radius, resolution=PIPE_RESOLUTION, split=split)))
        parts += [(OBJECT, f.id, f.mesh()) for f in layout.fittings]
        super().__init__(parts)
        tex = np.random.default_rng(int(rng.integers(2**31)))
        self._sand = _texture3(tex, 6, (0.05, 0.6))
        self._speckle = _texture3(tex, 8, (0.01, 0.06))
        self._growth = _texture3(tex, 5, (0.08, 0.5))

    def albedo(self, kind: np.ndarray, ident: np.ndarray, P: np.ndarray) -> np.ndarray:
        """Surface colour (N×3 in [0, 1]) at the hit points ``P`` (N×3, {W}) of the given kinds and ids."""
        out = np.zeros((len(P), 3))
        sel = kind == GROUND
        if sel.any():
            t = 0.6 * self._sand(P[sel]) + 0.4 * self._speckle(P[sel])
            out[sel] = np.array([0.62, 0.55, 0.42]) * (1.0 + 0.12 * t)[:, None]
        sel = np.flatnonzero(kind == ROCK)
        if len(sel):
            base = np.array([rk.color for rk in self.rocks])[ident[sel]]
            out[sel] = base * (1.0 + 0.25 * self._speckle(P[sel] * 1.7))[:, None]
        for k, colors in (
            (PIPE, [p.color for p in self.layout.pipes]),
            (OBJECT, [f.color for f in self.layout.fittings]),
        ):
            sel = np.flatnonzero(kind == k)
            if not len(sel):
                continue
            base = np.array(colors)[ident[sel]]
            growth = np.clip((self._growth(P[sel]) - 0.5) * 3.0, 0.0, 1.0)[:, None]  # patches of marine growth
            out[sel] = (1 - growth) * base + growth * _GROWTH
            out[sel] *= (1.0 + 0.05 * self._speckle(P[sel]))[:, None]
        return np.clip(out, 0.0, 1.0)
