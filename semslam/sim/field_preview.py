"""Preview of a simulated sonar field mission: the field from above, the pipeline profile, a side view.

Drawn from the mission alone (ground-truth map, ``extras["scene"]``, the ground-truth poses and the
swaths), so it works on an in-memory simulation and on a bag read back with its sidecar.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib import colormaps
from matplotlib.cm import ScalarMappable
from matplotlib.collections import PolyCollection
from matplotlib.colors import LightSource, Normalize
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch, Rectangle
from scipy.spatial.transform import Rotation

from semslam.mission.measurements import GroundTruthPose, SonarSwath
from semslam.mission.mission import Mission
from semslam.models import cad
from semslam.models.structures import STRUCTURE_COLORS, structure_library
from semslam.sim.seabed import Seabed

PIPE_COLOR = (0.25, 0.25, 0.25)
TRACK_COLOR = (0.05, 0.25, 0.75)


def _structure_mesh(s, lib):
    """(vertices in {W}, triangles) of a ground-truth structure, or None if its model is unknown."""
    if s.model not in lib:
        return None
    m = lib[s.model]
    return m.vertices @ Rotation.from_quat(s.orientation).as_matrix().T + np.asarray(s.position), m.triangles


def _silhouette(ax, V, F, i_h, i_v, color, z, edge=None):
    ax.add_collection(
        PolyCollection(V[:, [i_h, i_v]][F], facecolors=[color], edgecolors=edge or "none", linewidths=0.2, zorder=z)
    )


def _swath_edges(mission: Mission, poses: dict[int, np.ndarray], every: int = 4) -> np.ndarray:
    """World (north, east) of the outermost returns, port and starboard, of every ``every``-th swath."""
    info = next((s for s in mission.metadata.sensors.values() if s.kind == "sonar"), None)
    T_BS = info.T_BS if info is not None else np.eye(4)
    out = []
    for k, m in enumerate(mission.of_type(SonarSwath)):
        if k % every or m.stamp not in poses or len(m.ranges) < 2:
            continue
        T_WS = poses[m.stamp] @ T_BS
        P = m.points()[[0, -1]]
        out.append((P @ T_WS[:3, :3].T + T_WS[:3, 3])[:, :2])
    return np.array(out).reshape(-1, 2, 2)


def render_field_preview(mission: Mission, png_path: str | Path) -> None:
    """Write a PNG: (top) the field from above — seabed depth shaded, structures as their models'
    silhouettes with ids, pipelines, the vehicle's track and the outer edges of the sonar swaths;
    (bottom left) the profile along the pipelines: seabed, pipes (buried where they dip under it),
    hubs; (bottom right) everything seen from the south: seabed envelope, structures, pipes, track."""
    meta = mission.metadata
    gt = meta.ground_truth
    scene = meta.extras.get("scene", {})
    poses: dict[int, np.ndarray] = {}
    track = []
    n_swaths = 0
    for m in mission:
        if isinstance(m, GroundTruthPose):
            poses[m.stamp] = m.matrix()
            track.append((m.stamp, *m.position))
        elif isinstance(m, SonarSwath):
            n_swaths += 1
    P = np.array(track, float).reshape(-1, 4)
    lib = structure_library()
    seabed = Seabed.from_dict(scene["seabed"]) if "seabed" in scene else None
    area = scene.get("area")
    structures = gt.structures if gt else ()
    pipes = gt.pipes if gt else ()

    fig = Figure(figsize=(14, 13.5), dpi=100, layout="constrained")
    gs = fig.add_gridspec(2, 2, height_ratios=[1.55, 1])
    ax_top = fig.add_subplot(gs[0, :])
    ax_prof = fig.add_subplot(gs[1, 0])
    ax_side = fig.add_subplot(gs[1, 1])
    duration = (P[-1, 0] - P[0, 0]) * 1e-9 if len(P) > 1 else 0.0
    drift = meta.extras.get("navigation_drift", {})
    sonar = meta.extras.get("sonar", {})
    title = f"{meta.name}: {len(structures)} structures, {len(pipes)} pipelines, {n_swaths} sonar swaths"
    if sonar.get("points"):
        title += f" ({sonar['points'] / 1e6:.1f} M points)"
    title += f", {duration / 60:.1f} min"
    if "between_lines_median_m" in drift:
        title += (
            f"\ndead reckoning: between-line drift median {100 * drift['between_lines_median_m']:.0f} cm, "
            f"max {100 * drift['between_lines_max_m']:.0f} cm; final error {drift['final_m']:.2f} m"
        )
    fig.suptitle(title, fontsize=13)

    # --- top view: east to the right, north up
    if seabed is not None:
        gn, ge = seabed.grid(0.25)
        Z = seabed.depth(*np.meshgrid(gn, ge, indexing="ij"))
        cmap, lo, hi = colormaps["YlGnBu"], float(Z.min()), float(Z.max())
        # hill-shaded heights (−depth) so that the relief reads at a glance; the colours are depths
        rgb = LightSource(azdeg=315, altdeg=35).shade(
            -Z, cmap=cmap.reversed(), vert_exag=4, blend_mode="soft", dx=0.25, dy=0.25, vmin=-hi, vmax=-lo
        )
        ax_top.imshow(rgb, origin="lower", extent=(ge[0], ge[-1], gn[0], gn[-1]), zorder=0, interpolation="bilinear")
        cb = fig.colorbar(ScalarMappable(Normalize(lo, hi), cmap), ax=ax_top, fraction=0.025, pad=0.01)
        cb.set_label("seabed depth [m]")
        cb.ax.invert_yaxis()
    if area:
        (n0, n1), (e0, e1) = area["north_m"], area["east_m"]
        ax_top.add_patch(Rectangle((e0, n0), e1 - e0, n1 - n0, fill=False, ls="--", lw=1.2, ec="k", zorder=2))
    edges = _swath_edges(mission, poses)
    if len(edges):
        for side in (0, 1):
            ax_top.plot(edges[:, side, 1], edges[:, side, 0], ls="", marker=".", ms=0.8, color="w", alpha=0.9, zorder=3)
    if len(P):
        ax_top.plot(P[:, 2], P[:, 1], color=TRACK_COLOR, lw=1.4, zorder=4)
        ax_top.scatter([P[0, 2]], [P[0, 1]], marker="^", s=80, color="lime", edgecolors="k", zorder=6)
    for p in pipes:
        V, F = _cyl(p)
        _silhouette(ax_top, V, F, 1, 0, PIPE_COLOR, 5)
    for s in structures:
        mesh = _structure_mesh(s, lib)
        color = STRUCTURE_COLORS.get(s.model, (0.5, 0.5, 0.5))
        if mesh is not None:
            _silhouette(ax_top, *mesh, 1, 0, color, 5, edge=tuple(0.5 * c for c in color))
        seen = gt.seen_structures is None or s.id in gt.seen_structures
        away = _away_from_pipes(s, gt)  # label on the side without pipelines
        ax_top.annotate(
            f"{s.id}: {s.model}" + ("" if seen else " (unseen)"),
            (s.position[1], s.position[0]),
            xytext=(34 * away[1], 34 * away[0]),
            textcoords="offset points",
            ha="center",
            va="center",
            fontsize=10,
            weight="bold",
            color="k",
            zorder=7,
            bbox=dict(boxstyle="round,pad=0.2", fc="w", ec="none", alpha=0.8),
        )
    for p in pipes:
        a, b = np.asarray(p.p), np.asarray(p.q)
        mid = (a + b) / 2
        side = np.array([-(b - a)[1], (b - a)[0]]) / max(np.linalg.norm((b - a)[:2]), 1e-9)  # across the pipe
        side = side if side[0] >= 0 else -side  # on its northern side
        ax_top.annotate(
            f"pipe {p.id}, r {p.radius:.2f} m",
            (mid[1], mid[0]),
            xytext=(18 * side[1], 18 * side[0]),
            textcoords="offset points",
            ha="center",
            va="center",
            fontsize=9,
            zorder=7,
            bbox=dict(boxstyle="round,pad=0.2", fc="w", ec="none", alpha=0.8),
        )
    ax_top.set(
        title="top view (NED): seabed, structures, pipelines, track, outer swath edges",
        xlabel="east y [m]",
        ylabel="north x [m]",
    )
    ax_top.set_aspect("equal")
    if seabed is not None:
        (bn0, bn1), (be0, be1) = seabed.bounds
        ax_top.set_xlim(be0, be1)
        ax_top.set_ylim(bn0, bn1)
    handles = [Patch(color=c, label=n) for n, c in STRUCTURE_COLORS.items()]
    handles += [
        Line2D([], [], color=PIPE_COLOR, lw=4, label="pipeline"),
        Line2D([], [], color=TRACK_COLOR, lw=1.5, label="track"),
        Line2D([], [], color="w", marker=".", ls="", markeredgecolor="0.4", label="swath edges"),
        Line2D([], [], color="k", ls="--", label="surveyed area"),
        Line2D([], [], marker="^", color="lime", markeredgecolor="k", ls="", label="start"),
    ]
    ax_top.legend(handles=handles, fontsize=9, loc="upper right", bbox_to_anchor=(-0.06, 1.0))

    _pipeline_profile(ax_prof, gt, seabed, lib)
    _side_view(ax_side, gt, seabed, lib, P)
    fig.savefig(str(png_path))


def _away_from_pipes(s, gt) -> np.ndarray:
    """Unit (north, east) pointing away from the pipelines that leave structure ``s`` (north if none)."""
    c = np.asarray(s.position[:2])
    v = np.zeros(2)
    for p in gt.pipes:
        ids = gt.extras.get("pipeline_connections", {}).get(str(p.id), ())
        if s.id in ids:
            far = np.asarray((p.q if ids[0] == s.id else p.p)[:2])
            v -= (far - c) / max(np.linalg.norm(far - c), 1e-9)
    n = np.linalg.norm(v)
    return v / n if n > 0.3 else np.array([1.0, 0.0])


def _cyl(p):
    m = cad.cylinder(p.p, p.q, p.radius, resolution=16)
    return np.asarray(m.vertices), np.asarray(m.triangles)


def _pipeline_profile(ax, gt, seabed, lib) -> None:
    """Depth along the pipelines, end to end: pipe 0 from its first hub, then pipe 1 (the gap between
    them is the way across the structure they share), with the hubs marked."""
    ax.set(
        title="along the pipelines: seabed and pipe (bottom under the seabed = buried)",
        xlabel="distance along the route [m]",
        ylabel="depth z [m]",
    )
    if not gt or not gt.pipes or seabed is None:
        return
    x0, notes, hubs = 0.0, [], []
    conns = gt.extras.get("pipeline_connections", {})
    for p in gt.pipes:
        a, b = np.asarray(p.p), np.asarray(p.q)
        L = float(np.linalg.norm((b - a)[:2]))
        u = np.linspace(0.0, 1.0, max(int(L / 0.05), 2))
        X = a + u[:, None] * (b - a)
        d = x0 + u * L
        z_sb = seabed.depth(X[:, 0], X[:, 1])
        ax.fill_between(d, z_sb, z_sb + 0.5, color=(0.80, 0.70, 0.50), zorder=2.5, lw=0)  # hides what is buried
        ax.fill_between(d, X[:, 2] - p.radius, X[:, 2] + p.radius, color=PIPE_COLOR, alpha=0.85, zorder=2, lw=0)
        ax.plot(d, z_sb, color=(0.45, 0.35, 0.2), lw=1.2, zorder=3)
        burial = X[:, 2] + p.radius - z_sb
        notes.append(
            f"pipe {p.id}: r {p.radius:.2f} m, {L:.1f} m; resting {100 * (burial > -0.01).mean():.0f} % of it, "
            f"buried ≤ {100 * max(burial.max(), 0):.0f} cm, span ≤ {100 * max(-burial.min(), 0):.0f} cm"
        )
        for xe, sid in zip((x0, x0 + L), conns.get(str(p.id), ())):
            hubs.append((xe, sid))
        x0 += L + 2.0
    for sid in dict.fromkeys(sid for _, sid in hubs):
        s = next((s for s in gt.structures if s.id == sid), None)
        if s is None:
            continue
        xs = [xe for xe, k in hubs if k == sid]
        for xe in xs:
            ax.axvline(xe, color=STRUCTURE_COLORS.get(s.model, (0.5, 0.5, 0.5)), lw=2, zorder=0)
        ax.annotate(
            f"{sid}: {s.model}",
            (float(np.mean(xs)), 1.0),
            xycoords=("data", "axes fraction"),
            xytext=(0, -12),
            textcoords="offset points",
            ha="center",
            fontsize=9,
            bbox=dict(boxstyle="round,pad=0.2", fc="w", ec="none", alpha=0.8),
        )
    ax.text(
        0.02,
        0.04,
        "\n".join(notes),
        transform=ax.transAxes,
        fontsize=8.5,
        va="bottom",
        bbox=dict(boxstyle="round,pad=0.3", fc="w", ec="0.7", alpha=0.9),
        zorder=5,
    )
    lo, hi = ax.get_ylim()
    ax.set_ylim(hi + 0.9, lo - 0.4)  # depth down, room for the notes
    ax.grid(alpha=0.3)


def _side_view(ax, gt, seabed, lib, P) -> None:
    """Seen from the south: east to the right, depth down."""
    ax.set(title="side view from the south", xlabel="east y [m]", ylabel="depth z [m]")
    if seabed is not None:
        gn, ge = seabed.grid(0.5)
        Z = seabed.depth(*np.meshgrid(gn, ge, indexing="ij"))
        ax.fill_between(ge, Z.min(0), Z.max(0), color=(0.80, 0.70, 0.50), lw=0, zorder=1, label="seabed (all norths)")
    if gt:
        for p in gt.pipes:
            _silhouette(ax, *_cyl(p), 1, 2, PIPE_COLOR, 3)
        for s in gt.structures:
            mesh = _structure_mesh(s, lib)
            if mesh is not None:
                _silhouette(ax, *mesh, 1, 2, STRUCTURE_COLORS.get(s.model, (0.5, 0.5, 0.5)), 4)
    if len(P):
        ax.plot(P[:, 2], P[:, 3], color=TRACK_COLOR, lw=1.5, zorder=5, label="track")
        if seabed is not None:
            alt = seabed.depth(P[:, 1], P[:, 2]) - P[:, 3]
            ax.text(
                0.02,
                0.85,
                f"track altitude over the seabed {alt.min():.1f}–{alt.max():.1f} m (over the structures: less)",
                transform=ax.transAxes,
                ha="left",
                va="top",
                fontsize=8.5,
                bbox=dict(boxstyle="round,pad=0.3", fc="w", ec="0.7", alpha=0.9),
            )
    ax.invert_yaxis()
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="upper right")
