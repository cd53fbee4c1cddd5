"""Comparison figures (matplotlib, Agg): what people would rather look at than read.

Each function takes results and returns a matplotlib Figure; the caller saves it. Axes follow
NED: top views plot east (y) to the right and north (x) up; side views plot depth (z) down.
"""

from __future__ import annotations

from collections.abc import Mapping

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.collections import LineCollection, PolyCollection  # noqa: E402
from matplotlib.ticker import FuncFormatter, NullFormatter  # noqa: E402

from semslam.estimation import EstimatorResult, Trajectory  # noqa: E402
from semslam.mission.ground_truth import GroundTruthMap  # noqa: E402

COLORS = {"truth": "k", "dr": "tab:red", "ekf": "tab:blue", "graph": "tab:green", "graph_online": "tab:olive"}


def _color(name: str) -> str:
    return COLORS.get(name, None)


def _lay_out(fig, left=0.9, right=0.25, bottom=0.6, top=0.45, wspace=0.85, hspace=0.9) -> None:
    """Margins and gaps between the axes of a grid, in inches (room for tick labels, axis labels and
    titles at the default font size): fixed, where ``tight_layout`` would measure every tick label
    first (about a third of the report's time) and leave a placeholder layout engine behind that makes
    ``savefig`` lay the figure out once more."""
    w, h = fig.get_size_inches()
    nrows, ncols = fig.axes[0].get_subplotspec().get_gridspec().get_geometry()
    inner_w, inner_h = w - left - right, h - bottom - top
    fig.subplots_adjust(
        left=left / w,
        right=1 - right / w,
        bottom=bottom / h,
        top=1 - top / h,
        wspace=wspace / ((inner_w - (ncols - 1) * wspace) / ncols),
        hspace=hspace / ((inner_h - (nrows - 1) * hspace) / nrows),
    )


def _band(ax, t: np.ndarray, lo: np.ndarray, hi: np.ndarray, color) -> None:
    """The ±2σ band between ``lo`` and ``hi`` over ``t``, the polygons ``ax.fill_between`` would draw
    (one per run of finite values, closed along ``hi``), made from plain arrays: fill_between slices
    masked arrays once per run, and poses without a covariance split a band into hundreds of runs."""
    t, lo, hi = np.broadcast_arrays(np.asarray(t, float), np.asarray(lo, float), np.asarray(hi, float))
    ok = np.isfinite(t) & np.isfinite(lo) & np.isfinite(hi)
    edges = np.flatnonzero(np.diff(np.concatenate([[False], ok, [False]]).astype(np.int8)))
    verts = []
    for i0, i1 in zip(edges[::2], edges[1::2]):
        n = i1 - i0
        pts = np.empty((2 * n + 2, 2))
        pts[0] = t[i0], hi[i0]
        pts[1 : n + 1, 0], pts[1 : n + 1, 1] = t[i0:i1], lo[i0:i1]
        pts[n + 1] = t[i1 - 1], hi[i1 - 1]
        pts[n + 2 :, 0], pts[n + 2 :, 1] = t[i0:i1][::-1], hi[i0:i1][::-1]
        verts.append(pts)
    ax.add_collection(PolyCollection(verts, color=color, alpha=0.15, lw=0))


def trajectories(truth: Trajectory | None, results: Mapping[str, EstimatorResult]):
    """Top (north/east) and side (north/depth) views of the trajectories."""
    fig, (top, side) = plt.subplots(1, 2, figsize=(13, 5.5))
    series = ([("truth", truth)] if truth is not None else []) + [(n, r.trajectory) for n, r in results.items()]
    for name, tr in series:
        kw = dict(color=_color(name), lw=1.6 if name == "truth" else 1.0, label=name)
        if name == "truth":
            kw["ls"] = "--"
        top.plot(tr.positions[:, 1], tr.positions[:, 0], **kw)
        side.plot(tr.positions[:, 0], tr.positions[:, 2], **kw)
    top.set(xlabel="east [m]", ylabel="north [m]", title="top view", aspect="equal")
    side.set(xlabel="north [m]", ylabel="depth [m]", title="side view")
    side.invert_yaxis()
    for ax in (top, side):
        ax.grid(alpha=0.3)
        ax.legend(loc="best", fontsize=8)
    _lay_out(fig)
    return fig


def maps(results: Mapping[str, EstimatorResult], truth: GroundTruthMap | None, observations=None):
    """Top views of each estimator's map over the true landmarks (the paper's Figure 10). Each layer
    (true pipes, true objects, and each map's pipes, objects and structures) is one artist: the dead
    reckoning map places thousands of observations, and an artist per landmark cost ~20 s."""
    names = list(results)
    fig, axes = plt.subplots(1, len(names), figsize=(5.5 * len(names), 5.2), squeeze=False)
    for ax, name in zip(axes[0], names):
        if truth is not None:
            if truth.pipes:
                ends = np.array([[p.p, p.q] for p in truth.pipes], float)
                ax.add_collection(LineCollection(ends[:, :, [1, 0]], colors="0.75", lw=4, capstyle="round"))
            if truth.objects:
                xy = truth.object_positions()
                ax.scatter(xy[:, 1], xy[:, 0], s=60, facecolors="none", edgecolors="0.4", label="true objects")
        color = _color(name) or "tab:blue"
        layers = map_layers(results[name].landmarks)
        if len(layers["pipes"]):
            ax.add_collection(LineCollection(layers["pipes"][:, :, [1, 0]], colors=color, lw=1.2))
        if len(layers["objects"]):
            ax.scatter(layers["objects"][:, 1], layers["objects"][:, 0], s=12, color=color)
        if len(layers["structures"]):
            ax.scatter(layers["structures"][:, 1], layers["structures"][:, 0], marker="s", s=40, color=color)
        ax.autoscale_view()
        ax.set(title=f"{name} map", xlabel="east [m]", ylabel="north [m]", aspect="equal")
        ax.grid(alpha=0.3)
    _lay_out(fig)
    return fig


def map_layers(landmarks) -> dict[str, np.ndarray]:
    """A map's geometry as arrays: pipe segments (P, 2, 3), object positions (O, 3) and structure
    origins (S, 3), in {W}; landmarks without that geometry are left out."""
    pipes = [(lm.p, lm.q) for lm in landmarks if lm.kind == "pipe" and lm.p is not None]
    objects = [lm.position for lm in landmarks if lm.kind == "object" and lm.position is not None]
    structures = [np.asarray(lm.pose)[:3, 3] for lm in landmarks if lm.kind == "structure" and lm.pose is not None]
    return {
        "pipes": np.asarray(pipes, float).reshape(-1, 2, 3),
        "objects": np.asarray(objects, float).reshape(-1, 3),
        "structures": np.asarray(structures, float).reshape(-1, 3),
    }


def _interp_truth(truth: Trajectory, stamps: np.ndarray) -> np.ndarray:
    t = truth.stamps.astype(float)
    return np.column_stack([np.interp(stamps.astype(float), t, truth.positions[:, k]) for k in range(3)])


def position_errors(truth: Trajectory, results: Mapping[str, EstimatorResult]):
    """Position error per axis over time with the estimator's ±2σ (the paper's Figures 13–14)."""
    fig, axes = plt.subplots(3, 1, figsize=(12, 8), sharex=True)
    t0 = truth.stamps[0]
    reach = np.zeros(3)  # per axis: the largest error worth showing
    for name, r in results.items():
        tr = r.trajectory
        if len(tr) == 0:
            continue
        err = tr.positions - _interp_truth(truth, tr.stamps)
        reach = np.maximum(reach, np.nanpercentile(np.abs(err), 99.5, axis=0))
        t = (tr.stamps - t0) * 1e-9
        for k, ax in enumerate(axes):
            ax.plot(t, err[:, k], color=_color(name), lw=0.9, label=name)
            if tr.position_cov is not None:
                s2 = 2 * np.sqrt(np.maximum(tr.position_cov[:, k, k], 0))
                _band(ax, t, -s2, s2, _color(name))
    for k, (ax, lab) in enumerate(zip(axes, ("north", "east", "depth"))):
        ax.set_ylabel(f"{lab} error [m]")
        ax.grid(alpha=0.3)
        # Scaled to the errors, not to the widest band (dead reckoning's σ would flatten the rest).
        if reach[k] > 0:
            ax.set_ylim(-2.5 * reach[k], 2.5 * reach[k])
    axes[0].legend(loc="upper left", fontsize=8, ncol=4)
    axes[0].set_title("position error and ±2σ (axes scaled to the errors: wider bands run off the plot)")
    axes[-1].set_xlabel("mission time [s]")
    _lay_out(fig, hspace=0.25)
    return fig


def velocities(results: Mapping[str, EstimatorResult]):
    """Body velocity estimates with ±2σ over time (None if no estimator reports velocities)."""
    have = {n: r for n, r in results.items() if r.trajectory.velocities is not None}
    if not have:
        return None
    fig, axes = plt.subplots(3, 1, figsize=(12, 7), sharex=True)
    t0 = min(r.trajectory.stamps[0] for r in have.values())
    for name, r in have.items():
        tr = r.trajectory
        t = (tr.stamps - t0) * 1e-9
        for k, ax in enumerate(axes):
            ax.plot(t, tr.velocities[:, k], color=_color(name), lw=0.8, label=name)
            if tr.velocity_cov is not None:
                s2 = 2 * np.sqrt(np.maximum(tr.velocity_cov[:, k, k], 0))
                _band(ax, t, tr.velocities[:, k] - s2, tr.velocities[:, k] + s2, _color(name))
    for ax, lab in zip(axes, ("u", "v", "w")):
        ax.set_ylabel(f"{lab} [m/s]")
        ax.grid(alpha=0.3)
    axes[0].legend(loc="upper left", fontsize=8)
    axes[0].set_title("body velocity and ±2σ")
    axes[-1].set_xlabel("mission time [s]")
    _lay_out(fig, hspace=0.25)
    return fig


def uncertainty_volumes(results: Mapping[str, EstimatorResult], t0: int | None = None):
    """Uncertainty volume (sum of log eigenvalues) of each landmark over time (Figures 11–12).
    Estimators that keep no landmark covariances (dead reckoning) are left out."""
    have = {
        n: r
        for n, r in results.items()
        if any(len(np.atleast_1d(st)) >= 2 for st, _ in (r.history.get("landmark_volume") or {}).values())
    }
    if not have:
        return None
    if t0 is None:
        t0 = min(int(np.min(st)) for r in have.values() for st, _ in r.history["landmark_volume"].values() if len(st))
    fig, axes = plt.subplots(len(have), 2, figsize=(12, 3.8 * len(have)), squeeze=False)
    cycle = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for row, (name, r) in zip(axes, have.items()):
        kinds = r.history.get("landmark_kind", {})
        curves: tuple[list, list] = ([], [])  # pipes, objects: one LineCollection each
        for lid, (stamps, vol) in r.history["landmark_volume"].items():
            t = (np.asarray(stamps) - t0) * 1e-9
            curves[0 if kinds.get(lid, "object") == "pipe" else 1].append(np.column_stack([t, np.asarray(vol, float)]))
        for ax, lines in zip(row, curves):
            if lines:  # each curve in the next colour of the cycle, as one plot call per curve would
                ax.add_collection(
                    LineCollection(lines, colors=[cycle[k % len(cycle)] for k in range(len(lines))], lw=0.8)
                )
                ax.autoscale_view()
        row[0].set(title=f"{name}: pipes", ylabel="Σ log λ", xlabel="mission time [s]")
        row[1].set(title=f"{name}: objects", ylabel="Σ log λ", xlabel="mission time [s]")
        for ax in row:
            ax.grid(alpha=0.3)
    _lay_out(fig)
    return fig


def update_cost(results: Mapping[str, EstimatorResult]):
    """Per-update wall time against the number of landmarks in the map, for the estimators that
    keep landmarks in their state (dead reckoning's map is placed observations: not shown)."""
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for name, r in results.items():
        if name == "dr":
            continue
        if len(r.update_times_s) and len(r.update_n_landmarks) == len(r.update_times_s):
            ax.scatter(
                r.update_n_landmarks, np.asarray(r.update_times_s) * 1e3, s=4, alpha=0.5, color=_color(name), label=name
            )
    ax.set(xlabel="landmarks in the map", ylabel="update time [ms]", yscale="log", title="per-update cost")
    # plain numbers on the log axis: its default 10^k labels go through mathtext, ~1 s of font set-up
    ax.yaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    ax.yaxis.set_minor_formatter(NullFormatter())
    ax.grid(alpha=0.3)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=8, markerscale=3)
    _lay_out(fig)
    return fig


def confusion_matrices(recognition: Mapping[str, dict], classes: list[str]):
    """One confusion matrix per recognition stage (rows: true class, columns: recognised)."""
    stages = [s for s in ("SYN", "DESC", "BAYS", "SEM") if s in recognition and recognition[s].get("confusion")]
    if not stages:
        return None
    fig, axes = plt.subplots(1, len(stages), figsize=(4.6 * len(stages), 4.4), squeeze=False)
    for ax, stage in zip(axes[0], stages):
        C = np.asarray(recognition[stage]["confusion"], float)
        Cn = C / np.maximum(C.sum(axis=1, keepdims=True), 1)
        ax.imshow(Cn, cmap="Blues", vmin=0, vmax=1)
        for (i, j), v in np.ndenumerate(C):
            if v:
                ax.text(
                    j,
                    i,
                    f"{int(v)}",
                    ha="center",
                    va="center",
                    fontsize=7,
                    color="white" if Cn[i, j] > 0.5 else "black",
                )
        ax.set_xticks(range(len(classes)), classes, rotation=60, ha="right", fontsize=7)
        ax.set_yticks(range(len(classes)), classes, fontsize=7)
        f1 = recognition[stage].get("f1")
        ax.set_title(f"{stage}" + (f" (F1 {f1:.2f})" if isinstance(f1, (int, float)) else ""))
    _lay_out(fig, left=0.95, bottom=0.95, wspace=1.0)  # class names at the rows and under the columns
    return fig
