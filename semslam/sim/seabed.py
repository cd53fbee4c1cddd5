"""The seabed of the sonar field: a smooth seeded relief with levelled pads under the structures.

Depth (NED z, m, down) of the seabed at north n, east e::

    base(n, e) = depth_m + offset_m + gradient · (n, e) + Σ_k a_k exp(−|(n, e) − c_k|² / (2 σ_k²))
    z(n, e)    = base, then for each pad j in turn:  z ← z + w_j(ρ_j) · (pad_depth_j − z)

with ρ_j the horizontal distance to pad j's centre and w_j = 1 inside its ``radius``, falling to 0
over the next ``blend`` metres by a quintic smoothstep. The bumps (c_k, σ_k, a_k) and the gradient
are drawn from the seed, then scaled and offset so that over the surveyed area the relief has mean
0 and reaches ±``relief_m`` at its extreme (``depth_m`` is the mean seabed depth). Pads are the
levelled ground a structure stands on (site preparation), at the base depth of the structure's
centre. Everything needed to evaluate z is in :meth:`Seabed.to_dict` (the mission's
``extras["scene"]["seabed"]``); :meth:`Seabed.from_dict` and :func:`seabed_depth` rebuild it.

The ray-cast surface is a regular triangle grid over ``bounds`` at ``resolution_m`` (the surveyed
area plus a margin, so that turns and the outer beams still see the bottom); at 0.25 m it departs
from z(n, e) by well under a millimetre.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import open3d as o3d

from semslam.sim.trajectory import smoothstep


@dataclass(frozen=True)
class Pad:
    """Levelled ground under a structure: flat at ``depth`` (m) within ``radius`` of ``center``
    (north, east), blending back to the relief over the next ``blend`` metres."""

    center: tuple[float, float]
    radius: float
    blend: float
    depth: float


@dataclass
class Seabed:
    depth_m: float  # mean depth over the surveyed area
    offset_m: float  # makes the relief's mean 0 over the surveyed area
    gradient: tuple[float, float]  # dz/dn, dz/de of the planar slope
    bumps: np.ndarray  # K×4: centre north, centre east, sigma, amplitude (m; + = deeper)
    bounds: tuple[tuple[float, float], tuple[float, float]]  # (n_min, n_max), (e_min, e_max) of the mesh
    resolution_m: float
    pads: tuple[Pad, ...] = field(default_factory=tuple)

    def base_depth(self, n, e) -> np.ndarray:
        """Depth of the relief without the pads."""
        n, e = np.asarray(n, float), np.asarray(e, float)
        z = self.depth_m + self.offset_m + self.gradient[0] * n + self.gradient[1] * e
        for cn, ce, s, a in self.bumps:
            z = z + a * np.exp(-((n - cn) ** 2 + (e - ce) ** 2) / (2 * s * s))
        return z

    def depth(self, n, e) -> np.ndarray:
        """Depth (m, NED z) of the seabed at north ``n``, east ``e`` (arrays broadcast)."""
        n, e = np.asarray(n, float), np.asarray(e, float)
        z = self.base_depth(n, e)
        for p in self.pads:
            rho = np.hypot(n - p.center[0], e - p.center[1])
            w = 1.0 - smoothstep((rho - p.radius) / p.blend)[0]
            z = z + w * (p.depth - z)
        return z

    def with_pads(self, pads) -> Seabed:
        return Seabed(
            self.depth_m, self.offset_m, self.gradient, self.bumps, self.bounds, self.resolution_m, tuple(pads)
        )

    def grid(self, resolution_m: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """North and east coordinates of the mesh grid (1-D each)."""
        r = resolution_m or self.resolution_m
        (n0, n1), (e0, e1) = self.bounds
        return (np.linspace(n0, n1, int(round((n1 - n0) / r)) + 1), np.linspace(e0, e1, int(round((e1 - e0) / r)) + 1))

    def mesh(self) -> o3d.geometry.TriangleMesh:
        """The seabed as a triangle grid in {W} (normals up, towards −z)."""
        gn, ge = self.grid()
        N, E = np.meshgrid(gn, ge, indexing="ij")
        V = np.stack([N.ravel(), E.ravel(), self.depth(N, E).ravel()], 1)
        rows, cols = N.shape
        i = (np.arange(rows - 1)[:, None] * cols + np.arange(cols - 1)[None, :]).ravel()
        # (n, e, z) is right-handed with z down: e × n = −z, so (i, i+1, i+cols) faces up
        F = np.concatenate([np.stack([i, i + 1, i + cols], 1), np.stack([i + 1, i + cols + 1, i + cols], 1)])
        m = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(V), o3d.utility.Vector3iVector(F.astype(np.int32)))
        m.compute_triangle_normals()
        return m

    def to_dict(self) -> dict:
        """Plain JSON: everything :meth:`depth` needs, in metres."""
        return {
            "model": "mean depth + offset + planar gradient + gaussian bumps, levelled pads (semslam.sim.seabed)",
            "depth_m": float(self.depth_m),
            "offset_m": float(self.offset_m),
            "gradient": [float(g) for g in self.gradient],
            "bumps": [[float(x) for x in b] for b in self.bumps],
            "bumps_columns": ["north_m", "east_m", "sigma_m", "amplitude_m"],
            "pads": [
                {"center": [float(c) for c in p.center], "radius": p.radius, "blend": p.blend, "depth": p.depth}
                for p in self.pads
            ],
            "bounds": [[float(x) for x in b] for b in self.bounds],
            "resolution_m": float(self.resolution_m),
        }

    @classmethod
    def from_dict(cls, d: dict) -> Seabed:
        return cls(
            depth_m=float(d["depth_m"]),
            offset_m=float(d["offset_m"]),
            gradient=tuple(map(float, d["gradient"])),
            bumps=np.asarray(d["bumps"], float).reshape(-1, 4),
            bounds=tuple(tuple(map(float, b)) for b in d["bounds"]),
            resolution_m=float(d["resolution_m"]),
            pads=tuple(
                Pad(tuple(map(float, p["center"])), float(p["radius"]), float(p["blend"]), float(p["depth"]))
                for p in d.get("pads", ())
            ),
        )


def seabed_depth(params: dict, n, e) -> np.ndarray:
    """Seabed depth (m) at north ``n``, east ``e`` from a mission's ``extras["scene"]["seabed"]``."""
    return Seabed.from_dict(params).depth(n, e)


def random_seabed(
    rng: np.random.Generator,
    *,
    area: tuple[tuple[float, float], tuple[float, float]],
    margin_m: float,
    depth_m: float,
    relief_m: float,
    n_bumps: int,
    bump_sigma_m: tuple[float, float],
    slope_share: float,
    resolution_m: float,
) -> Seabed:
    """A seeded relief over ``area`` ((n_min, n_max), (e_min, e_max)): ``n_bumps`` gaussian bumps of
    widths in ``bump_sigma_m`` centred anywhere over the mesh, and a planar slope that makes up about
    ``slope_share`` of the relief; scaled so that its extreme over the area is ±``relief_m``."""
    (n0, n1), (e0, e1) = area
    bounds = ((n0 - margin_m, n1 + margin_m), (e0 - margin_m, e1 + margin_m))
    bumps = np.column_stack(
        [
            rng.uniform(*bounds[0], n_bumps),
            rng.uniform(*bounds[1], n_bumps),
            rng.uniform(*bump_sigma_m, n_bumps),
            rng.normal(0.0, 1.0, n_bumps),
        ]
    )
    heading = rng.uniform(0, 2 * np.pi)
    span = np.hypot(n1 - n0, e1 - e0)
    unit = Seabed(0.0, 0.0, (0.0, 0.0), bumps, bounds, resolution_m)
    gn, ge = np.linspace(n0, n1, 69), np.linspace(e0, e1, 101)
    N, E = np.meshgrid(gn, ge, indexing="ij")
    b = unit.base_depth(N, E)
    # the slope: a plane whose drop across the area's diagonal is slope_share × the bumps' range
    g = slope_share * (b.max() - b.min()) / max(1.0 - slope_share, 1e-9) / span
    gradient = (g * np.cos(heading), g * np.sin(heading))
    relief = b + gradient[0] * N + gradient[1] * E
    relief -= relief.mean()
    scale = relief_m / max(np.abs(relief).max(), 1e-12)
    bumps[:, 3] *= scale
    gradient = (gradient[0] * scale, gradient[1] * scale)
    shifted = Seabed(0.0, 0.0, gradient, bumps, bounds, resolution_m).base_depth(N, E)
    return Seabed(depth_m, float(-shifted.mean()), gradient, bumps, bounds, resolution_m)
