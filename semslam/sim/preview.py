"""Preview of a simulated mission: top and side views of the tank, the structure and the trajectory.

Drawn from the mission alone (ground-truth map, ``extras["scene"]`` and the ground-truth poses), so
it works on an in-memory simulation and on a bag read back with its sidecar.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.collections import PolyCollection
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from scipy.spatial.transform import Rotation

from semslam.mission.measurements import DvlVelocity, GroundTruthPose, PointCloud
from semslam.mission.mission import Mission
from semslam.models import cad


def _object_mesh(o, lib):
    """(vertices in {W}, triangles) of a ground-truth object, or None if its model is unknown."""
    if o.model not in lib:
        return None
    m = lib[o.model]
    return m.vertices @ Rotation.from_quat(o.orientation).as_matrix().T + np.asarray(o.position), m.triangles


def _pipe_mesh(p):
    m = cad.cylinder(p.p, p.q, p.radius)
    return np.asarray(m.vertices), np.asarray(m.triangles)


def _draw_mesh(ax, V, F, i_h, i_v, color, z):
    """Silhouette of a mesh projected on the (i_h, i_v) plane, as filled triangles."""
    poly = V[:, [i_h, i_v]][F]
    ax.add_collection(PolyCollection(poly, facecolors=[color], edgecolors="none", zorder=z))


def render_preview(mission: Mission, png_path: str | Path) -> None:
    """Write a PNG with four panels: the whole tank seen from above and from the side (east face),
    and close-ups of the structure from above and from the side; pipes in grey, objects coloured by
    class, the trajectory with DVL dropouts in red and laser scan positions as dots."""
    meta = mission.metadata
    gt = meta.ground_truth
    scene = meta.extras.get("scene", {})
    t0 = None
    poses, scans, dvl = [], [], []
    for m in mission:
        if t0 is None:
            t0 = m.stamp
        if isinstance(m, GroundTruthPose):
            poses.append((m.stamp, *m.position))
        elif isinstance(m, PointCloud):
            scans.append(m.stamp)
        elif isinstance(m, DvlVelocity):
            dvl.append((m.stamp, m.valid))
    P = np.array(poses, float).reshape(-1, 4)
    lib = cad.library()

    fig = Figure(figsize=(15, 11), dpi=110)
    axes = fig.subplots(2, 2, gridspec_kw={"height_ratios": [1.15, 1]})
    (ax_top, ax_side), (ax_ztop, ax_zside) = axes
    duration = (P[-1, 0] - P[0, 0]) * 1e-9 if len(P) > 1 else 0.0
    fig.suptitle(
        f"{meta.name}: {len(gt.objects) if gt else 0} objects, {len(gt.pipes) if gt else 0} pipes, "
        f"{len(scans)} laser scans, {duration:.0f} s"
        + (f", DVL invalid {100 * (1 - np.mean([v for _, v in dvl])):.0f} %" if dvl else ""),
        fontsize=13,
    )

    # --- tank outline
    tank = scene.get("tank")
    if tank:
        D, fx, fy = tank["depth_m"], tank["floor_half_x_m"], tank["floor_half_y_m"]
        off = D / np.tan(np.deg2rad(tank["wall_slope_deg"]))
        for hx, hy, style, label in ((fx, fy, "--", "floor edge"), (fx + off, fy + off, "-", "surface rim")):
            ax_top.plot([-hy, hy, hy, -hy, -hy], [hx, hx, -hx, -hx, hx], style, color="0.45", lw=1, label=label)
        ax_side.fill(
            [-(fx + off), -fx, fx, fx + off], [0, D, D, 0], facecolor=(0.85, 0.92, 1.0), edgecolor="0.45", lw=1
        )
        ax_side.plot([-(fx + off), fx + off], [0, 0], color=(0.3, 0.5, 0.9), lw=1)

    # --- structure: pipes and objects
    def draw_structure(ax, i_h, i_v, close):
        if not gt:
            return
        for p in gt.pipes:
            if close:
                _draw_mesh(ax, *_pipe_mesh(p), i_h, i_v, (0.55, 0.55, 0.55), 2)
            else:
                ax.plot([p.p[i_h], p.q[i_h]], [p.p[i_v], p.q[i_v]], color="0.35", lw=1.5, zorder=2)
        for o in gt.objects:
            col = cad.CLASS_COLORS.get(o.cls, (0.3, 0.3, 0.3))
            mesh = _object_mesh(o, lib) if close else None
            if mesh is not None:
                _draw_mesh(ax, *mesh, i_h, i_v, col, 3)
            else:
                ax.scatter(
                    [o.position[i_h]], [o.position[i_v]], s=14, color=col, zorder=3, edgecolors="k", linewidths=0.3
                )
            if close:
                seen = gt.seen_objects is None or o.id in gt.seen_objects
                ax.annotate(
                    str(o.id) + ("" if seen else "*"),
                    (o.position[i_h], o.position[i_v]),
                    fontsize=7,
                    xytext=(5, 5),
                    textcoords="offset points",
                    zorder=4,
                )

    # top views: east to the right, north up; side views: north to the right, depth down
    draw_structure(ax_top, 1, 0, False)
    draw_structure(ax_side, 0, 2, False)
    draw_structure(ax_ztop, 1, 0, True)
    draw_structure(ax_zside, 0, 2, True)

    # --- trajectory, DVL dropouts, scan positions
    if len(P):
        ax_top.plot(P[:, 2], P[:, 1], color=(0.1, 0.3, 0.8), lw=3, label="trajectory", zorder=1)
        ax_side.plot(P[:, 1], P[:, 3], color=(0.1, 0.3, 0.8), lw=1, zorder=1)
        for ax, ih, iv in ((ax_top, 2, 1), (ax_side, 1, 3)):
            ax.scatter(
                [P[0, ih]], [P[0, iv]], marker="^", s=60, color="g", zorder=5, label="start" if ax is ax_top else None
            )
        if dvl:
            st = np.array([s for s, _ in dvl])
            bad = ~np.array([v for _, v in dvl])
            idx = np.searchsorted(P[:, 0], st[bad]).clip(0, len(P) - 1)
            ax_top.scatter(P[idx, 2], P[idx, 1], s=4, color="r", zorder=4, label="DVL invalid")
            ax_side.scatter(P[idx, 1], P[idx, 3], s=4, color="r", zorder=4)
        if scans:
            idx = np.searchsorted(P[:, 0], np.array(scans)).clip(0, len(P) - 1)
            ax_top.scatter(P[idx, 2], P[idx, 1], s=2, color="0.1", zorder=3, label="laser scan")

    ax_top.set(title="top view (NED)", xlabel="east y [m]", ylabel="north x [m]")
    ax_side.set(title="side view from the east", xlabel="north x [m]", ylabel="depth z [m]")
    ax_side.invert_yaxis()
    ax_ztop.set(
        title="structure from above (ids; * = never hit by the laser)", xlabel="east y [m]", ylabel="north x [m]"
    )
    ax_zside.set(title="structure from the east", xlabel="north x [m]", ylabel="depth z [m]")
    ax_zside.invert_yaxis()
    if "structure_bounds" in scene:
        lo, hi = (np.asarray(b) for b in scene["structure_bounds"])
        pad = 0.15
        ax_ztop.set_xlim(lo[1] - pad, hi[1] + pad)
        ax_ztop.set_ylim(lo[0] - pad, hi[0] + pad)
        ax_zside.set_xlim(lo[0] - pad, hi[0] + pad)
        ax_zside.set_ylim(hi[2] + pad, lo[2] - pad)
        if tank:
            ax_zside.axhline(tank["depth_m"], color="0.45", lw=1)
    for ax in axes.flat:
        ax.set_aspect("equal", adjustable="datalim" if ax in (ax_top, ax_side) else "box")
        ax.grid(alpha=0.3)
    handles = [Line2D([], [], marker="o", ls="", color=c, label=k) for k, c in cad.CLASS_COLORS.items()]
    handles.append(Line2D([], [], color="0.35", lw=3, label="pipe"))
    ax_ztop.legend(handles=handles, fontsize=8, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    ax_top.legend(fontsize=8, loc="upper right")
    fig.tight_layout()
    fig.savefig(str(png_path))
