"""Figures of the sonar front-end: the elevation map with the recognised structures and pipelines,
the world model rendered, and the swaths' disagreement before / after registration."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from frontends.sonar.grid import ElevationMap, GridSpec
from frontends.sonar.patches import transform


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _hillshade(depth: np.ndarray, cell: float, az_deg: float = 315.0, alt_deg: float = 45.0) -> np.ndarray:
    z = -np.nan_to_num(depth, nan=np.nanmedian(depth) if np.isfinite(depth).any() else 0.0)
    gy, gx = np.gradient(z, cell)  # rows = north, columns = east
    slope = np.arctan(np.hypot(gx, gy))
    aspect = np.arctan2(-gx, gy)
    az, alt = np.radians(az_deg), np.radians(alt_deg)
    shade = np.sin(alt) * np.cos(slope) + np.cos(alt) * np.sin(slope) * np.cos(az - aspect)
    return np.clip(shade, 0, 1)


def _outline(ax, md, T, color, lw=1.6):
    """The model's top-view footprint (its occupancy contour) placed by T_WM, in (east, north) axes."""
    occ = md.occupancy.astype(float)
    k = md.k
    g = (np.arange(occ.shape[0]) - k) * md.cell
    X, Y = np.meshgrid(g, g, indexing="ij")  # model x (rows), y (columns)
    n = T[0, 0] * X + T[0, 1] * Y + T[0, 3]
    e = T[1, 0] * X + T[1, 1] * Y + T[1, 3]
    ax.contour(e, n, occ, levels=[0.5], colors=[color], linewidths=lw)


def elevation_figure(fe, path) -> None:
    from semslam.sim.structures import STRUCTURE_COLORS

    plt = _plt()
    em: ElevationMap = fe.final["map"]
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    n_zoom = min(len(fe.structures), 4)
    e0, e1, n0, n1 = em.spec.extent()
    main_h = min(max(12.0 * (n1 - n0) / max(e1 - e0, 1e-6), 3.0), 12.0) + 1.0
    fig = plt.figure(figsize=(13.5, main_h + (4.2 if n_zoom else 0)), dpi=fe.config.figures.dpi,
                     layout="constrained")
    gs = fig.add_gridspec(2 if n_zoom else 1, max(n_zoom, 1), height_ratios=[main_h, 4.2] if n_zoom else [1])
    ax = fig.add_subplot(gs[0, :])
    D = em.depth
    ext = em.spec.extent()
    shade = _hillshade(D, em.spec.cell)
    im = ax.imshow(D, origin="lower", extent=ext, cmap="viridis_r", interpolation="nearest",
                   vmin=np.nanpercentile(D, 1), vmax=np.nanpercentile(D, 99.5))
    ax.imshow(np.where(np.isfinite(D), shade, np.nan), origin="lower", extent=ext, cmap="gray", alpha=0.35,
              interpolation="nearest")
    cb = fig.colorbar(im, ax=ax, shrink=0.9, pad=0.01, fraction=0.03)
    cb.set_label("depth (m, NED)")
    handles = []
    from matplotlib.lines import Line2D

    for ks in fe.structures:
        reg = ks.final or ks.detection.registration
        T = reg.T if reg is not None else ks.T_WM
        col = STRUCTURE_COLORS.get(ks.model, (1.0, 0.2, 0.2))
        _outline(ax, fe.recogniser.model_data[ks.model], T, "white", lw=3.2)
        _outline(ax, fe.recogniser.model_data[ks.model], T, col, lw=1.8)
        med = f"{100 * reg.median_m:.1f} cm" if reg is not None else "n/a"
        ax.annotate(f"{ks.model}\nscore {ks.detection.normalised:.2f}, median {med}", (T[1, 3], T[0, 3]),
                    xytext=(0, fe.library[ks.model].footprint_radius * 9 + 14), textcoords="offset points",
                    ha="center", fontsize=9, bbox=dict(boxstyle="round", fc="white", alpha=0.85))
        handles.append(Line2D([], [], color=col, lw=2, label=f"{ks.model} (registered CAD outline)"))
    for s in fe.final["pipes"]:
        ax.plot([s.p[1], s.q[1]], [s.p[0], s.q[0]], "-", color="red", lw=2.2, alpha=0.9)
        mid = 0.5 * (s.p + s.q)
        conn = f" → {', '.join(s.connected)}" if s.connected else ""
        ax.annotate(f"pipe r {s.radius:.2f} m{conn}", (mid[1], mid[0]), fontsize=7, color="darkred",
                    xytext=(8, -16), textcoords="offset points",
                    bbox=dict(boxstyle="round,pad=0.2", fc="white", ec="none", alpha=0.75))
    if fe.final["pipes"]:
        handles.append(Line2D([], [], color="red", lw=2, label="pipeline (detected axis)"))
    # the track as finally estimated
    anchors = np.array([fe.place(p)[:3, 3] for p in fe.patches if fe.place(p) is not None])
    if len(anchors):
        ax.plot(anchors[:, 1], anchors[:, 0], "-", color="k", lw=0.6, alpha=0.6)
        handles.append(Line2D([], [], color="k", lw=0.8, label="track (final estimate)"))
    ax.set_xlabel("east (m)")
    ax.set_ylabel("north (m)")
    ax.set_aspect("equal")
    ax.set_title(f"Sonar elevation map ({100 * em.spec.cell:.0f} cm cells, median depth, final estimate): "
                 f"{len(fe.structures)} structures recognised, {len(fe.final['pipes'])} pipelines")
    ax.legend(handles=handles, loc="upper left", fontsize=8, framealpha=0.9)
    # close-ups: each structure's returns (4 cm cells, height above the seabed) under its CAD outline
    pts = fe.final.get("pts_W")
    for k, ks in enumerate(fe.structures[:n_zoom]):
        zax = fig.add_subplot(gs[1, k])
        reg = ks.final or ks.detection.registration
        T = reg.T if reg is not None else ks.T_WM
        R = fe.library[ks.model].footprint_radius + 0.8
        c = T[:2, 3]
        near = pts[(np.abs(pts[:, 0] - c[0]) < R) & (np.abs(pts[:, 1] - c[1]) < R)] if pts is not None else pts
        if near is None or not len(near):
            continue
        zm = ElevationMap.from_points(near, 0.04)
        h = T[2, 3] - zm.depth  # height above the structure's base
        im2 = zax.imshow(h, origin="lower", extent=zm.spec.extent(), cmap="viridis", vmin=-0.2,
                         vmax=fe.library[ks.model].height, interpolation="nearest")
        col = STRUCTURE_COLORS.get(ks.model, (1.0, 0.2, 0.2))
        _outline(zax, fe.recogniser.model_data[ks.model], T, "white", lw=2.6)
        _outline(zax, fe.recogniser.model_data[ks.model], T, col, lw=1.4)
        zax.set_aspect("equal")
        zax.set_xlim(c[1] - R, c[1] + R)
        zax.set_ylim(c[0] - R, c[0] + R)
        med = f"{100 * reg.median_m:.1f} cm" if reg is not None else "n/a"
        zax.set_title(f"{ks.model}: median point-to-model {med}", fontsize=9)
        zax.tick_params(labelsize=7)
        fig.colorbar(im2, ax=zax, shrink=0.8, pad=0.02).set_label("height above base (m)", fontsize=7)
    fig.savefig(path)
    plt.close(fig)


def world_model_figure(fe, path) -> None:
    plt = _plt()
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    world = fe.final["world"]
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    V = np.asarray(world.vertices)
    F = np.asarray(world.triangles)
    C = np.asarray(world.vertex_colors) if world.has_vertex_colors() else np.full((len(V), 3), 0.7)
    # {W} is NED: plot east, north, up
    P = np.column_stack([V[:, 1], V[:, 0], -V[:, 2]])
    tri = P[F]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    light = np.array([-0.4, 0.5, 0.77])
    light /= np.linalg.norm(light)
    shade = 0.45 + 0.55 * np.abs(n @ light)
    col = np.clip(C[F].mean(1) * shade[:, None], 0, 1)
    fig = plt.figure(figsize=(13, 8), dpi=fe.config.figures.dpi)
    ax = fig.add_subplot(111, projection="3d")
    ax.add_collection3d(Poly3DCollection(tri, facecolors=col, edgecolors="none", linewidths=0))
    lo, hi = P.min(0), P.max(0)
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_zlim(lo[2], lo[2] + 0.35 * max(hi[0] - lo[0], hi[1] - lo[1]) * 0.3)
    ax.set_box_aspect((hi[0] - lo[0], hi[1] - lo[1], 0.35 * max(hi[0] - lo[0], hi[1] - lo[1]) * 0.3))
    ax.view_init(elev=38, azim=-60)
    ax.set_xlabel("east (m)")
    ax.set_ylabel("north (m)")
    ax.set_zlabel("up (m)")
    m = fe.final.get("world_info") or {}
    info = fe_metrics_line(fe)
    ax.set_title(f"World model: registered CAD meshes, pipelines and the bare seabed\n{info}", fontsize=10)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def fe_metrics_line(fe) -> str:
    w = fe.final.get("world_info") or {}
    if not w:
        return ""
    raw = fe.final.get("raw_bytes")
    frac = f" = {100 * w['bytes'] / raw:.2f} % of the raw cloud ({raw / 1e6:.1f} MB)" if raw else ""
    return f"{w['triangles']} triangles, {w['bytes'] / 1e3:.0f} kB{frac}"


def disagreement_figure(fe, path) -> None:
    """Depth difference between overlapping passes, as navigated and after the final estimate."""
    plt = _plt()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    pairs = fe.final["pairs"]
    cell = 0.1
    fig = plt.figure(figsize=(15, 8.5), dpi=fe.config.figures.dpi)
    gs = fig.add_gridspec(2, 2, width_ratios=[2.6, 1], hspace=0.35, wspace=0.15)
    map_axes = [fig.add_subplot(gs[0, 0]), fig.add_subplot(gs[1, 0])]
    hax = fig.add_subplot(gs[:, 1])
    hists = []
    sc = None
    placements = (("as navigated (each patch as placed when it closed)", lambda p: p.T_nav),
                  ("re-placed with the final estimate", fe.place))
    for ax, (label, pose_fn) in zip(map_axes, placements):
        pts, vals = [], []
        for a, b in pairs:
            A = transform(pose_fn(fe.patches[a]), fe.patches[a].points)
            B = transform(pose_fn(fe.patches[b]), fe.patches[b].points)
            lo = np.maximum(A[:, :2].min(0), B[:, :2].min(0))
            hi = np.minimum(A[:, :2].max(0), B[:, :2].max(0))
            if np.any(hi - lo <= cell):
                continue
            spec = GridSpec.around(lo, hi, cell)
            ea = ElevationMap.from_points(A, spec=spec)
            eb = ElevationMap.from_points(B, spec=spec)
            both = ea.filled & eb.filled
            N, E = spec.centres()
            nn, ee = np.meshgrid(N, E, indexing="ij")
            pts.append(np.column_stack([nn[both], ee[both]]))
            vals.append(np.abs(ea.depth[both] - eb.depth[both]))
        if pts:
            X = np.concatenate(pts)
            v = np.concatenate(vals)
            order = np.argsort(v)  # large differences drawn last, on top
            sc = ax.scatter(X[order, 1], X[order, 0], c=v[order], s=1.5, cmap="magma_r", vmin=0, vmax=0.10,
                            marker="s", linewidths=0)
            hists.append((label.split(" (")[0], v))
            ax.set_title(f"|Δ depth| between overlapping passes, {label}: median {100 * np.median(v):.2f} cm, "
                         f"90th percentile {100 * np.percentile(v, 90):.2f} cm", fontsize=10)
        ax.set_aspect("equal")
        ax.set_xlabel("east (m)")
        ax.set_ylabel("north (m)")
    if sc is not None:
        fig.colorbar(sc, ax=map_axes, shrink=0.9, pad=0.01, label="|Δ depth| (m), 10 cm cells")
    if hists:
        bins = np.linspace(0, 0.4, 81)
        for label, v in hists:
            hax.hist(v, bins=bins, histtype="step", lw=1.6, label=label, density=True)
        hax.set_yscale("log")
        hax.set_xlabel("|Δ depth| (m)")
        hax.set_ylabel("density")
        hax.legend()
        hax.set_title(f"{len(fe.swath_registrations)} swath registrations accepted, "
                      f"{len(fe.structures)} structures registered", fontsize=10)
    fig.savefig(path, bbox_inches="tight")
    plt.close(fig)
