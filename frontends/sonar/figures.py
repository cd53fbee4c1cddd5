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
    from semslam.models.structures import STRUCTURE_COLORS

    plt = _plt()
    em: ElevationMap = fe.final["map"]
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    n_zoom = min(len(fe.structures), 4)
    e0, e1, n0, n1 = em.spec.extent()
    main_h = min(max(12.0 * (n1 - n0) / max(e1 - e0, 1e-6), 3.0), 12.0) + 1.0
    fig = plt.figure(figsize=(13.5, main_h + (4.2 if n_zoom else 0)), dpi=fe.config.figures.dpi, layout="constrained")
    gs = fig.add_gridspec(2 if n_zoom else 1, max(n_zoom, 1), height_ratios=[main_h, 4.2] if n_zoom else [1])
    ax = fig.add_subplot(gs[0, :])
    D = em.depth
    ext = em.spec.extent()
    shade = _hillshade(D, em.spec.cell)
    im = ax.imshow(
        D,
        origin="lower",
        extent=ext,
        cmap="viridis_r",
        interpolation="nearest",
        vmin=np.nanpercentile(D, 1),
        vmax=np.nanpercentile(D, 99.5),
    )
    ax.imshow(
        np.where(np.isfinite(D), shade, np.nan),
        origin="lower",
        extent=ext,
        cmap="gray",
        alpha=0.35,
        interpolation="nearest",
    )
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
        ax.annotate(
            f"{ks.model}\nscore {ks.detection.normalised:.2f}, median {med}",
            (T[1, 3], T[0, 3]),
            xytext=(0, fe.library[ks.model].footprint_radius * 9 + 14),
            textcoords="offset points",
            ha="center",
            fontsize=9,
            bbox=dict(boxstyle="round", fc="white", alpha=0.85),
        )
        handles.append(Line2D([], [], color=col, lw=2, label=f"{ks.model} (registered CAD outline)"))
    for s in fe.final["pipes"]:
        ax.plot([s.p[1], s.q[1]], [s.p[0], s.q[0]], "-", color="red", lw=2.2, alpha=0.9)
        mid = 0.5 * (s.p + s.q)
        conn = f" → {', '.join(s.connected)}" if s.connected else ""
        ax.annotate(
            f"pipe r {s.radius:.2f} m{conn}",
            (mid[1], mid[0]),
            fontsize=7,
            color="darkred",
            xytext=(8, -16),
            textcoords="offset points",
            bbox=dict(boxstyle="round,pad=0.2", fc="white", ec="none", alpha=0.75),
        )
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
    ax.set_title(
        f"Sonar elevation map ({100 * em.spec.cell:.0f} cm cells, median depth, final estimate; "
        f"white: no return): {len(fe.structures)} structures recognised, {len(fe.final['pipes'])} pipelines"
    )
    ax.legend(handles=handles, loc="upper left", fontsize=8, framealpha=0.9)
    # close-ups: each structure's returns (5 cm cells: the swaths are 4 cm apart, so every cell holds
    # some; height above the structure's base) under its CAD outline; cells without a return in pink
    pts = fe.final.get("pts_W")
    cmap = plt.get_cmap("bone").with_extremes(bad="#f2b6b6")
    for k, ks in enumerate(fe.structures[:n_zoom]):
        zax = fig.add_subplot(gs[1, k])
        reg = ks.final or ks.detection.registration
        T = reg.T if reg is not None else ks.T_WM
        R = fe.library[ks.model].footprint_radius + 0.8
        c = T[:2, 3]
        near = pts[(np.abs(pts[:, 0] - c[0]) < R) & (np.abs(pts[:, 1] - c[1]) < R)] if pts is not None else pts
        if near is None or not len(near):
            continue
        zm = ElevationMap.from_points(near, 0.05)
        h = T[2, 3] - zm.depth  # height above the structure's base
        im2 = zax.imshow(
            h,
            origin="lower",
            extent=zm.spec.extent(),
            cmap=cmap,
            vmin=-0.2,
            vmax=fe.library[ks.model].height,
            interpolation="nearest",
        )
        col = STRUCTURE_COLORS.get(ks.model, (1.0, 0.2, 0.2))
        _outline(zax, fe.recogniser.model_data[ks.model], T, "black", lw=2.8)
        _outline(zax, fe.recogniser.model_data[ks.model], T, col, lw=1.5)
        zax.set_aspect("equal")
        zax.set_xlim(c[1] - R, c[1] + R)
        zax.set_ylim(c[0] - R, c[0] + R)
        med = f"{100 * reg.median_m:.1f} cm" if reg is not None else "n/a"
        zax.set_title(f"{ks.model}: median point-to-model {med}\n(5 cm cells; pink: no return)", fontsize=9)
        zax.set_xlabel("east (m)", fontsize=8)
        zax.set_ylabel("north (m)", fontsize=8)
        zax.tick_params(labelsize=7)
        fig.colorbar(im2, ax=zax, shrink=0.8, pad=0.02).set_label("height above base (m)", fontsize=7)
    fig.savefig(path)
    plt.close(fig)


def _clip_box(tri: np.ndarray, lo, hi) -> list[np.ndarray]:
    """Triangles (n, 3, 3) clipped to lo ≤ x, y ≤ hi (Sutherland–Hodgman on the two horizontal
    axes; z interpolated on the facet's plane): the polygons that remain."""
    out = []
    for poly in tri:
        P = list(poly)
        for axis, bound, keep_less in ((0, lo[0], False), (0, hi[0], True), (1, lo[1], False), (1, hi[1], True)):
            if not P:
                break
            inside = [(p[axis] <= bound) if keep_less else (p[axis] >= bound) for p in P]
            Q = []
            for i in range(len(P)):
                a, b = P[i - 1], P[i]
                ia, ib = inside[i - 1], inside[i]
                if ib != ia:
                    t = (bound - a[axis]) / (b[axis] - a[axis])
                    Q.append(a + t * (b - a))
                if ib:
                    Q.append(b)
            P = Q
        if len(P) >= 3:
            out.append(np.array(P))
    return out


def _render(ax, polys, colors, light=np.array([-0.4, 0.5, 0.77])):
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    if not polys:
        return
    light = light / np.linalg.norm(light)
    shade = []
    for P in polys:
        n = np.cross(P[1] - P[0], P[2] - P[0])
        n /= max(np.linalg.norm(n), 1e-12)
        shade.append(0.45 + 0.55 * abs(n @ light))
    col = np.clip(np.asarray(colors) * np.asarray(shade)[:, None], 0, 1)
    # One array of equal-length polygons (each padded by repeating its last vertex, which draws
    # the same polygon): given ragged ones, matplotlib 3.11 pads them into np.empty and reads that
    # uninitialised padding when autoscaling and projecting (matplotlib#32272), which now and
    # then gave an infinite axis limit.
    n = max(len(P) for P in polys)
    faces = np.stack([np.concatenate([P, np.repeat(P[-1:], n - len(P), axis=0)]) for P in polys])
    # edges in the face colour hide the hairline seams between adjacent facets
    ax.add_collection3d(Poly3DCollection(faces, facecolors=col, edgecolors=col, linewidths=0.2))


def world_model_figure(fe, path) -> None:
    """The world model: the whole field (top) and a close-up of each registered structure on its
    surroundings (bottom); east, north, up with a true vertical scale unless stated."""
    from matplotlib.ticker import MaxNLocator

    plt = _plt()
    world = fe.final["world"]
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    V = np.asarray(world.vertices)
    F = np.asarray(world.triangles)
    C = np.asarray(world.vertex_colors) if world.has_vertex_colors() else np.full((len(V), 3), 0.7)
    # {W} is NED: plot east, north, up
    P = np.column_stack([V[:, 1], V[:, 0], -V[:, 2]])
    tri = P[F]
    col = C[F].mean(1)
    n_zoom = min(len(fe.structures), 4)
    fig = plt.figure(figsize=(14, 7 + (5 if n_zoom else 0)), dpi=fe.config.figures.dpi)
    gs = fig.add_gridspec(
        2 if n_zoom else 1,
        max(n_zoom, 1),
        height_ratios=[7, 5] if n_zoom else [1],
        hspace=0.0,
        wspace=0.05,
        left=0.01,
        right=0.97,
        top=0.96,
        bottom=0.01,
    )
    ax = fig.add_subplot(gs[0, :], projection="3d")
    _render(ax, list(tri), col)
    lo, hi = P.min(0), P.max(0)
    exag = 3.0  # the seabed's relief (about a metre over 60 m) would not show at a true scale
    span = hi - lo
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_zlim(lo[2], hi[2])
    ax.set_box_aspect((span[0], span[1], exag * span[2]))
    ax.view_init(elev=35, azim=-62)
    ax.set_xlabel("east (m)")
    ax.set_ylabel("north (m)")
    ax.set_zlabel("up (m)", labelpad=8)
    ax.zaxis.set_major_locator(MaxNLocator(4))
    info = fe_metrics_line(fe)
    ax.set_title(
        f"World model: registered CAD meshes, pipelines and the bare seabed (vertical scale ×{exag:.0f})\n{info}",
        fontsize=11,
    )
    for k, ks in enumerate(fe.structures[:n_zoom]):
        zax = fig.add_subplot(gs[1, k], projection="3d")
        reg = ks.final or ks.detection.registration
        T = reg.T if reg is not None else ks.T_WM
        R = fe.library[ks.model].footprint_radius + 1.0
        c = np.array([T[1, 3], T[0, 3]])
        near = np.any(np.all(np.abs(tri[:, :, :2] - c) < R + 1e-9, axis=2), axis=1)
        big = ~near & (tri[:, :, :2].min(1) < c + R).all(1) & (tri[:, :, :2].max(1) > c - R).all(1)
        polys, cols = [], []
        for i in np.flatnonzero(near | big):
            clipped = _clip_box(tri[i : i + 1], c - R, c + R)
            polys += clipped
            cols += [col[i]] * len(clipped)
        if not polys:
            continue
        _render(zax, polys, cols)
        allp = np.concatenate(polys)
        zlo, zhi = allp[:, 2].min(), allp[:, 2].max()
        zax.set_xlim(c[0] - R, c[0] + R)
        zax.set_ylim(c[1] - R, c[1] + R)
        zax.set_zlim(zlo, zhi)
        zax.set_box_aspect((2 * R, 2 * R, zhi - zlo))
        zax.view_init(elev=30, azim=-62)
        zax.set_axis_off()  # ticks on a small 3-D box are unreadable: the sizes are in the title
        med = f"{100 * reg.median_m:.1f} cm" if reg is not None else "n/a"
        sx, sy, sz = fe.library[ks.model].size
        zax.set_title(
            f"{ks.model}: {sx:.1f} × {sy:.1f} × {sz:.1f} m on a {2 * R:.1f} m square of seabed\n"
            f"(true scale), median point-to-model {med}",
            fontsize=9,
        )
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
    cell = 0.05  # as the metrics (summary.swath_disagreement)
    fig = plt.figure(figsize=(15, 9), dpi=fe.config.figures.dpi, layout="constrained")
    gs = fig.add_gridspec(2, 2, width_ratios=[2.6, 1])
    map_axes = [fig.add_subplot(gs[0, 0]), fig.add_subplot(gs[1, 0])]
    hax = fig.add_subplot(gs[:, 1])
    hists = []
    sc = None
    placements = (
        ("as navigated (each patch as placed when it closed)", lambda p: p.T_nav, fe.final.get("before")),
        ("re-placed with the final estimate", fe.place, fe.final.get("after")),
    )
    for ax, (label, pose_fn, stats) in zip(map_axes, placements):
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
            sc = ax.scatter(
                X[order, 1], X[order, 0], c=v[order], s=0.6, cmap="magma_r", vmin=0, vmax=0.10, marker="s", linewidths=0
            )
            hists.append((label.split(" (")[0], v))
            tex = (
                f"; on sloped cells (pipes, structures' edges) {100 * stats['textured_median_m']:.2f} cm"
                if stats and stats.get("textured_median_m") is not None
                else ""
            )
            ax.set_title(
                f"|Δ depth| between overlapping passes, {label}\nmedian {100 * np.median(v):.2f} cm, "
                f"90th percentile {100 * np.percentile(v, 90):.2f} cm{tex}",
                fontsize=10,
            )
        ax.set_aspect("equal")
        ax.set_xlabel("east (m)")
        ax.set_ylabel("north (m)")
    if sc is not None:
        fig.colorbar(sc, ax=map_axes, shrink=0.9, label="|Δ depth| (m), 5 cm cells")
    if hists:
        bins = np.linspace(0, 0.4, 81)
        for label, v in hists:
            hax.hist(v, bins=bins, histtype="step", lw=1.6, label=label, density=True)
        hax.set_yscale("log")
        hax.set_xlabel("|Δ depth| (m)")
        hax.set_ylabel("density")
        hax.legend()
        hax.set_title(
            f"{len(fe.swath_registrations)} swath registrations accepted,\n{len(fe.structures)} structures registered",
            fontsize=10,
        )
    fig.savefig(path)
    plt.close(fig)
