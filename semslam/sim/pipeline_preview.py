"""Preview of a simulated pipeline mission: the pipeline, its fittings, the rocks and the inspection
track from above, and their depths along the line.

Drawn from the mission alone (ground-truth map, ``extras["scene"]`` and the ground-truth poses), so
it works on an in-memory simulation and on a bag read back with its sidecar.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure
from matplotlib.patches import Circle

from semslam.mission.measurements import GroundTruthPose, PointCloud
from semslam.mission.mission import Mission


def render_pipeline_preview(mission: Mission, png_path: str | Path) -> None:
    """Write a PNG with two panels: north/east from above (pipes, fittings by class, rocks, track
    with stereo views as dots) and depth against the distance along the first line."""
    meta = mission.metadata
    gt = meta.ground_truth
    scene = meta.extras.get("scene", {})
    poses = np.array([(m.stamp, *m.position) for m in mission.of_type(GroundTruthPose)], float).reshape(-1, 4)
    scan_stamps = np.array([m.stamp for m in mission.of_type(PointCloud)], float)
    lines = scene.get("layout", {}).get("lines", [])
    origin = np.asarray(lines[0]["origin"], float) if lines else np.zeros(3)
    direction = np.asarray(lines[0]["direction"], float) if lines else np.array([1.0, 0.0, 0.0])

    fig = Figure(figsize=(13, 9), dpi=100)
    ax_top, ax_side = fig.subplots(2, 1, gridspec_kw={"height_ratios": [1.6, 1]})
    fig.suptitle(
        f"{meta.name}: {len(gt.objects) if gt else 0} fittings, {len(gt.pipes) if gt else 0} pipe pieces, "
        f"{len(scene.get('rocks', []))} rocks, {len(scan_stamps)} stereo clouds",
        fontsize=12,
    )

    def along(P: np.ndarray) -> np.ndarray:
        return (np.asarray(P, float).reshape(-1, 3) - origin) @ direction

    for r in scene.get("rocks", []):
        ax_top.add_patch(Circle((r["center"][1], r["center"][0]), max(r["radii"][:2]), color="0.75", zorder=1))
    for p in gt.pipes if gt else ():
        P = np.array([p.p, p.q], float)
        ax_top.plot(P[:, 1], P[:, 0], color="0.3", lw=2, zorder=2)
        ax_side.plot(along(P), P[:, 2], color="0.3", lw=2)
    colours = {}  # one colour per class
    for o in gt.objects if gt else ():
        c = colours.setdefault(o.cls, f"C{len(colours)}")
        ax_top.plot(o.position[1], o.position[0], "o", ms=6, color=c, zorder=3, label=o.cls)
        ax_side.plot(along(o.position), o.position[2], "o", ms=6, color=c)
    if len(poses):
        ax_top.plot(poses[:, 2], poses[:, 1], color="tab:blue", lw=0.8, zorder=4, label="track")
        ax_side.plot(along(poses[:, 1:]), poses[:, 3], color="tab:blue", lw=0.8)
    if len(scan_stamps) and len(poses):
        at = np.column_stack([np.interp(scan_stamps, poses[:, 0], poses[:, k]) for k in (1, 2)])
        ax_top.plot(at[:, 1], at[:, 0], ".", color="tab:blue", ms=3, zorder=5)
    handles, labels = ax_top.get_legend_handles_labels()
    unique = dict(zip(labels, handles, strict=True))
    ax_top.legend(unique.values(), unique.keys(), fontsize=8, loc="best")
    ax_top.set(xlabel="east (m)", ylabel="north (m)", title="from above")
    ax_top.set_aspect("equal", adjustable="box")
    ax_side.set(xlabel="along the pipeline (m)", ylabel="depth (m, down)", title="depths along the line")
    ax_side.invert_yaxis()
    fig.tight_layout()
    fig.savefig(png_path)
