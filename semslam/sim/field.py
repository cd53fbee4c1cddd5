"""The sonar field: seabed, three structures joined by two pipelines, and its ray-casting scene.

World {W}: NED with its origin at the surface above the centre of the surveyed area (north x,
east y, depth z). The surveyed area is ``seabed.area_m`` (north × east, default 34 × 50 m).

Layout (seeded, :func:`make_field`): structure B (``layout.chain[1]``, the manifold) stands at a
random position with a random yaw; each pipeline leaves one of B's hubs of its size within
``max_hub_angle_deg`` of the hub's direction, runs ``pipe_length_m`` horizontally, and ends at the
hub of A (pipeline 0) or C (pipeline 1), whose yaw turns that hub towards B within the same angle.
A draw is kept only if every footprint lies ``edge_margin_m`` inside the surveyed area, footprints
and pipelines keep ``min_gap_m`` clear of each other, and the pipelines neither span more than
``max_span_gap_m`` above the seabed nor sink below half their diameter (``max_burial``).

Every structure stands upright on a levelled pad (:class:`semslam.sim.seabed.Pad`) at the relief's
depth under its centre. A pipeline is a straight cylinder from hub to hub: its ends are exactly the
hubs' points; between them it rests where the seabed meets it, spans where the seabed falls away,
and is partly buried where the seabed rises (the seabed mesh simply cuts through it; ray casting
sees the part above). Ids: structures 0, 1, 2 = A, B, C; pipeline 0 = A→B (p at A's hub, q at
B's), pipeline 1 = B→C.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import open3d as o3d
from scipy.spatial.transform import Rotation

from semslam.errors import ConfigError
from semslam.mission.ground_truth import GroundTruthMap, GtPipe, GtStructure
from semslam.models import cad
from semslam.models.structures import StructureModel, pose_matrix, structure_library
from semslam.sim.field_config import FieldSimConfig
from semslam.sim.raycast import LabelledScene
from semslam.sim.seabed import Pad, Seabed, random_seabed
from semslam.sim.streams import rng_stream

# geometry kinds in a FieldScene
SEABED, STRUCTURE, PIPE = 0, 1, 2
KIND_NAMES = ("seabed", "structure", "pipe")

PIPE_RESOLUTION = 48  # segments around a pipeline: the facets depart < 0.6 mm from the 0.25 m cylinder
PIPE_SPLIT_M = 0.5  # and rings along it every 0.5 m: long sliver triangles make distance queries imprecise
MAX_DRAWS = 20000


@dataclass
class PlacedStructure:
    """A structure of the field: its model name and pose T_WM (upright: yaw + translation)."""

    id: int
    model: str
    T_WM: np.ndarray
    yaw: float

    @property
    def position(self) -> np.ndarray:
        return self.T_WM[:3, 3]

    def hubs(self) -> list[tuple[np.ndarray, np.ndarray]]:
        return structure_library()[self.model].hubs_in(self.T_WM)


@dataclass
class Pipeline:
    """A straight pipeline: axis from ``p`` (at hub ``ends[0]``) to ``q`` (at hub ``ends[1]``), in {W};
    ``ends`` are (structure id, hub index); ``max_burial_m`` / ``max_span_gap_m`` tell how deep its
    bottom sinks below the seabed and how high it spans above it at worst."""

    id: int
    p: np.ndarray
    q: np.ndarray
    radius: float
    ends: tuple[tuple[int, int], tuple[int, int]]
    max_burial_m: float = 0.0
    max_span_gap_m: float = 0.0

    @property
    def length(self) -> float:
        return float(np.linalg.norm(self.q - self.p))


@dataclass
class Field:
    """The seabed (with the structures' pads), the placed structures and the pipelines."""

    seabed: Seabed
    structures: list[PlacedStructure]
    pipes: list[Pipeline]

    def meshes(self) -> list[tuple[int, int, o3d.geometry.TriangleMesh]]:
        """(kind, id, mesh in {W}) for the seabed, every structure and every pipeline."""
        lib = structure_library()
        out = [(SEABED, -1, self.seabed.mesh())]
        out += [(STRUCTURE, s.id, lib[s.model].transformed(s.T_WM)) for s in self.structures]
        out += [(PIPE, p.id, pipe_mesh(p.p, p.q, p.radius)) for p in self.pipes]
        return out

    def connections(self) -> dict[str, list[int]]:
        """Pipeline id (as a string: a JSON key) → the two structure ids it joins."""
        return {str(p.id): [p.ends[0][0], p.ends[1][0]] for p in self.pipes}

    def ground_truth(self, seen_structures=None, seen_pipes=None) -> GroundTruthMap:
        structures = tuple(
            GtStructure(
                s.id,
                s.model,
                tuple(map(float, s.position)),
                tuple(map(float, Rotation.from_matrix(s.T_WM[:3, :3]).as_quat())),
            )
            for s in self.structures
        )
        pipes = tuple(GtPipe(p.id, tuple(map(float, p.p)), tuple(map(float, p.q)), float(p.radius)) for p in self.pipes)
        return GroundTruthMap(
            structures=structures,
            pipes=pipes,
            seen_objects=(),
            seen_pipes=seen_pipes,
            seen_structures=seen_structures,
            extras={
                "pipeline_connections": self.connections(),
                "pipeline_hubs": {str(p.id): [list(e) for e in p.ends] for p in self.pipes},
            },
        )

    def to_dict(self) -> dict:
        """A plain description (JSON) of the structures and pipelines."""
        lib = structure_library()
        return {
            "structures": [
                {
                    "id": s.id,
                    "model": s.model,
                    "position": [float(x) for x in s.position],
                    "orientation": [float(x) for x in Rotation.from_matrix(s.T_WM[:3, :3]).as_quat()],
                    "yaw_deg": float(np.degrees(s.yaw)),
                    "footprint_radius_m": lib[s.model].footprint_radius,
                    "symmetry": lib[s.model].symmetry,
                }
                for s in self.structures
            ],
            "pipes": [
                {
                    "id": p.id,
                    "p": [float(x) for x in p.p],
                    "q": [float(x) for x in p.q],
                    "radius": float(p.radius),
                    "structures": [p.ends[0][0], p.ends[1][0]],
                    "hubs": [list(e) for e in p.ends],
                    "length_m": p.length,
                    "max_burial_m": p.max_burial_m,
                    "max_span_gap_m": p.max_span_gap_m,
                }
                for p in self.pipes
            ],
        }


def pipe_mesh(p, q, radius: float) -> o3d.geometry.TriangleMesh:
    """A pipeline's cylinder from axis point p to q, as the scene ray-casts it."""
    split = max(1, int(np.ceil(np.linalg.norm(np.subtract(q, p)) / PIPE_SPLIT_M)))
    return cad.cylinder(p, q, radius, resolution=PIPE_RESOLUTION, split=split)


# ----------------------------------------------------------------------------------------------
# generation


def _hubs_of_size(model: StructureModel, radius: float, role: str) -> list[int]:
    idx = [i for i, h in enumerate(model.hubs) if abs(h.pipe_radius - radius) < 1e-6]
    if not idx:
        raise ConfigError(f"layout.chain: structure {role} ({model.name!r}) has no hub for a pipe of radius {radius} m")
    return idx


def _segment_distance(a0, a1, b0, b1, n: int = 64) -> float:
    """Horizontal distance between two segments (sampled: good to a few cm at field scale)."""
    u = np.linspace(0.0, 1.0, n)[:, None]
    A = a0[:2] + u * (a1[:2] - a0[:2])
    B = b0[:2] + u * (b1[:2] - b0[:2])
    return float(np.min(np.linalg.norm(A[:, None] - B[None], axis=2)))


def _point_segment_distance(c, a, b) -> float:
    ab = b[:2] - a[:2]
    u = np.clip((c[:2] - a[:2]) @ ab / max(ab @ ab, 1e-12), 0.0, 1.0)
    return float(np.linalg.norm(a[:2] + u * ab - c[:2]))


def pipe_clearance(seabed: Seabed, p: np.ndarray, q: np.ndarray, radius: float, step_m: float = 0.1):
    """(deepest burial of the pipe's bottom below the seabed, highest gap under it) in metres, ≥ 0."""
    n = max(int(np.ceil(np.linalg.norm(q - p) / step_m)), 1) + 1
    X = p + np.linspace(0.0, 1.0, n)[:, None] * (q - p)
    below = X[:, 2] + radius - seabed.depth(X[:, 0], X[:, 1])  # > 0: the bottom is under the seabed
    return float(max(below.max(), 0.0)), float(max(-below.min(), 0.0))


def make_field(cfg: FieldSimConfig) -> Field:
    """The seabed and layout of a mission, from its seed (deterministic)."""
    sb = cfg.seabed
    half_n, half_e = sb.area_m[0] / 2, sb.area_m[1] / 2
    base = random_seabed(
        rng_stream(cfg.seed, "seabed"),
        area=((-half_n, half_n), (-half_e, half_e)),
        margin_m=sb.margin_m,
        depth_m=sb.depth_m,
        relief_m=sb.relief_m,
        n_bumps=sb.bumps,
        bump_sigma_m=sb.bump_sigma_m,
        slope_share=sb.slope_share,
        resolution_m=sb.resolution_m,
    )
    lib = structure_library()
    lay = cfg.layout
    for name in lay.chain:
        if name not in lib:
            raise ConfigError(f"layout.chain: unknown structure model {name!r} (known: {', '.join(sorted(lib))})")
    models = [lib[n] for n in lay.chain]
    r01, r12 = lay.pipe_radii_m
    hubs_a = _hubs_of_size(models[0], r01, "A")
    hubs_b01 = _hubs_of_size(models[1], r01, "B")
    hubs_b12 = _hubs_of_size(models[1], r12, "B")
    hubs_c = _hubs_of_size(models[2], r12, "C")
    room = min(cfg.seabed.area_m) - 2 * lay.edge_margin_m
    if max(2 * m.footprint_radius for m in models) >= room:
        raise ConfigError(
            f"seabed.area_m: {list(cfg.seabed.area_m)} m leaves no room for the structures "
            f"with layout.edge_margin_m {lay.edge_margin_m} m"
        )
    rng = rng_stream(cfg.seed, "field_layout")
    alpha = np.deg2rad(lay.max_hub_angle_deg)
    for _ in range(MAX_DRAWS):
        field = _draw(base, models, (hubs_a, hubs_b01, hubs_b12, hubs_c), (r01, r12), alpha, cfg, rng)
        if field is not None:
            return field
    raise ConfigError(
        "layout: no placement of the structures satisfies the layout constraints in "
        f"{MAX_DRAWS} draws; relax pipe_length_m, min_gap_m, edge_margin_m, max_span_gap_m or max_burial"
    )


def _draw(base: Seabed, models, hubs, radii, alpha, cfg: FieldSimConfig, rng) -> Field | None:
    """One random layout, or None if it breaks a constraint."""
    lay, sb = cfg.layout, cfg.seabed
    half = np.array(sb.area_m) / 2
    hubs_a, hubs_b01, hubs_b12, hubs_c = hubs
    mB = models[1]
    inner = half - mB.footprint_radius - lay.edge_margin_m
    if (inner <= 0).any():
        return None
    yaw_b = rng.uniform(0.0, 2 * np.pi)
    xy_b = rng.uniform(-inner, inner)
    T = {1: pose_matrix((*xy_b, float(base.base_depth(*xy_b))), yaw_b)}
    yaws = {1: yaw_b}
    ends = {}
    for sid, hubs_b, hubs_x, _radius in ((0, hubs_b01, hubs_a, radii[0]), (2, hubs_b12, hubs_c, radii[1])):
        ib = int(rng.choice(hubs_b))
        hub_b, dir_b = mB.hubs_in(T[1])[ib]
        heading = np.arctan2(dir_b[1], dir_b[0]) + rng.uniform(-alpha, alpha)
        length = rng.uniform(*lay.pipe_length_m)
        end_xy = hub_b[:2] + length * np.array([np.cos(heading), np.sin(heading)])
        mx = models[sid]
        ix = int(rng.choice(hubs_x))
        h = mx.hubs[ix]
        # turn X so that its hub faces back along the pipeline, within ±alpha
        yaw = heading + np.pi + rng.uniform(-alpha, alpha) - np.arctan2(h.direction[1], h.direction[0])
        c, s = np.cos(yaw), np.sin(yaw)
        origin_xy = end_xy - np.array([[c, -s], [s, c]]) @ h.position[:2]
        T[sid] = pose_matrix((*origin_xy, float(base.base_depth(*origin_xy))), yaw)
        yaws[sid] = yaw
        ends[sid] = (ib, ix)

    # footprints inside the area and apart
    centers = {k: T[k][:3, 3] for k in T}
    for k, m in enumerate(models):
        if (np.abs(centers[k][:2]) + m.footprint_radius > half - lay.edge_margin_m).any():
            return None
    for i, j in ((0, 1), (1, 2), (0, 2)):
        gap = np.linalg.norm(centers[i][:2] - centers[j][:2]) - models[i].footprint_radius - models[j].footprint_radius
        if gap < lay.min_gap_m:
            return None

    structures = [PlacedStructure(k, models[k].name, T[k], float(np.mod(yaws[k], 2 * np.pi))) for k in (0, 1, 2)]
    hub_w = {k: models[k].hubs_in(T[k]) for k in (0, 1, 2)}
    ib0, ia = ends[0]
    ib1, ic = ends[2]
    pipes = [
        Pipeline(0, hub_w[0][ia][0], hub_w[1][ib0][0], radii[0], ((0, ia), (1, ib0))),
        Pipeline(1, hub_w[1][ib1][0], hub_w[2][ic][0], radii[1], ((1, ib1), (2, ic))),
    ]
    # pipelines clear of the structure they do not join, and of each other
    if _point_segment_distance(centers[2], pipes[0].p, pipes[0].q) < models[2].footprint_radius + lay.min_gap_m:
        return None
    if _point_segment_distance(centers[0], pipes[1].p, pipes[1].q) < models[0].footprint_radius + lay.min_gap_m:
        return None
    if _segment_distance(pipes[0].p, pipes[0].q, pipes[1].p, pipes[1].q) < radii[0] + radii[1] + 0.5:
        return None

    pads = [
        Pad((float(c[0]), float(c[1])), models[k].footprint_radius + sb.pad_margin_m, sb.pad_blend_m, float(c[2]))
        for k, c in sorted(centers.items())
    ]
    seabed = base.with_pads(pads)
    for p in pipes:
        p.max_burial_m, p.max_span_gap_m = pipe_clearance(seabed, p.p, p.q, p.radius)
        if p.max_burial_m > lay.max_burial * 2 * p.radius + 1e-9 or p.max_span_gap_m > lay.max_span_gap_m:
            return None
    return Field(seabed, structures, pipes)


class FieldScene(LabelledScene):
    """The field in an open3d ``RaycastingScene``; hits are labelled (SEABED | STRUCTURE | PIPE, id)."""

    def __init__(self, field: Field):
        super().__init__(field.meshes())
