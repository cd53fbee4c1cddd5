"""Figures of the laser front-end's stages for one scan (raw, planes removed, pipes, objects).

Each panel is a view of the scan in the sensor frame {S}, seen from the sensor's side (x right,
y down in the image, as the scanner looks along +z), points coloured by depth or by segment.
"""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from frontends.laser.frontend import ScanSegmentation  # noqa: E402


def _scatter(ax, pts, c, s=0.4, cmap="viridis", **kw):
    if isinstance(c, np.ndarray) and c.ndim == 1 and len(c) == len(pts):  # values to colour-map
        kw["cmap"] = cmap
    ax.scatter(pts[:, 0], pts[:, 1], c=c, s=s, linewidths=0, **kw)


def stage_figure(raw: np.ndarray, seg: ScanSegmentation, path, title: str = "", truth=None) -> None:
    """Write a 2×2 figure of the four stages to ``path``. ``truth`` (optional ScanTruth) adds the
    ground-truth pipe axes (dashed) and object positions (crosses) to the last two panels."""
    raw = np.asarray(raw, dtype=np.float64)
    fig, axes = plt.subplots(2, 2, figsize=(13, 12.5), constrained_layout=True)
    sub = np.random.default_rng(0).permutation(len(raw))[:60000]
    ax = axes[0, 0]
    _scatter(ax, raw[sub], raw[sub, 2])
    ax.set_title(f"raw scan: {len(raw)} points (colour = z, m)")

    pts = seg.pre.points
    ax = axes[0, 1]
    removed = ~seg.planes.structure
    _scatter(ax, pts[removed], "0.85")
    st = seg.structure_points
    _scatter(ax, st, st[:, 2], s=1.5, cmap="plasma")
    ax.set_title(
        f"planes removed: {removed.sum()} of {len(pts)} voxels on {len(seg.planes.planes)} planes (grey)\n"
        f"structure re-sampled finely: {len(st)} points (colour = z)"
    )

    ax = axes[1, 0]
    _scatter(ax, st, "0.75", s=1.0)
    colors = plt.cm.tab10(np.arange(max(len(seg.pipes), 1)) % 10)
    for i, p in enumerate(seg.pipes):
        _scatter(ax, st[p.inliers], [colors[i]], s=2.5)
        ax.plot([p.p[0], p.q[0]], [p.p[1], p.q[1]], "-", color="k", lw=1.2)
        ax.plot([p.p[0], p.q[0]], [p.p[1], p.q[1]], "o", color=colors[i], ms=5, mec="k")
        m = 0.5 * (p.p + p.q)
        ax.annotate(f"{i}: r={100 * p.radius:.1f} cm", m[:2], fontsize=8)
    if truth is not None:
        for p, q, _ in truth.pipes:
            ax.plot([p[0], q[0]], [p[1], q[1]], "--", color="r", lw=0.8)
    ax.set_title(f"pipes: {len(seg.pipes)} segments (axes, endpoints; truth dashed red)")

    ax = axes[1, 1]
    _scatter(ax, st, "0.85", s=1.0)
    for p in seg.pipes:
        ax.plot([p.p[0], p.q[0]], [p.p[1], p.q[1]], "-", color="0.5", lw=1)
    colors = plt.cm.tab10(np.arange(max(len(seg.objects), 1)) % 10)
    for i, o in enumerate(seg.objects):
        _scatter(ax, st[o.indices], [colors[i]], s=3)
        ax.plot(*o.position[:2], "k+", ms=12)
        for d in o.directions:
            e = o.position + 0.25 * np.asarray(d)
            ax.annotate("", e[:2], o.position[:2], arrowprops=dict(arrowstyle="->", color=colors[i]))
        ax.annotate(f"conf {o.configuration}", o.position[:2] + 0.06, fontsize=9)
    if truth is not None:
        for pos, _conf in truth.objects:
            ax.plot(pos[0], pos[1], "rx", ms=9)
    ax.set_title(f"objects: {len(seg.objects)} segments (+ estimate, x truth, arrows = pipes)")

    for ax in axes.ravel():
        ax.set_aspect("equal")
        ax.invert_yaxis()
        ax.set_xlabel("x (m, sensor)")
        ax.set_ylabel("y (m, sensor)")
    if title:
        fig.suptitle(title)
    fig.savefig(path, dpi=90)
    plt.close(fig)
