"""The report's figures with fixed margins: every label, tick label and title inside the figure and
no two axes overlapping; each landmark's uncertainty-volume curve drawn, one collection per panel."""

import itertools

import numpy as np
from matplotlib.collections import LineCollection

from semslam.estimation import EstimatorResult, LandmarkEstimate, Trajectory
from semslam.eval import figures


def _result(name: str, n: int, rng, scale: float) -> EstimatorResult:
    stamps = (np.arange(n) * 5e7).astype(np.int64) + 10**18  # absolute ns, as a bag's
    pos = np.cumsum(rng.normal(0, 0.05, (n, 3)), axis=0) * scale
    traj = Trajectory(
        stamps,
        pos,
        np.tile([0.0, 0.0, 0.0, 1.0], (n, 1)),
        position_cov=np.tile(np.eye(3) * 1e-4, (n, 1, 1)),
        velocities=rng.normal(0, 0.2, (n, 3)),
        velocity_cov=np.tile(np.eye(3) * 1e-4, (n, 1, 1)),
    )
    lms = [LandmarkEstimate(i, "object", position=rng.uniform(-500, 500, 3) * scale) for i in range(7)]
    lms += [LandmarkEstimate(100 + i, "pipe", p=np.zeros(3), q=np.ones(3) * scale) for i in range(3)]
    volume = {lm.id: (stamps[:: 10 + lm.id % 7], -30.0 - np.arange(len(stamps[:: 10 + lm.id % 7]))) for lm in lms}
    history = {"landmark_volume": volume, "landmark_kind": {lm.id: lm.kind for lm in lms}}
    return EstimatorResult(
        name,
        traj,
        lms,
        update_times_s=list(rng.uniform(1e-3, 2.0, 50)),
        update_n_landmarks=list(range(50)),
        history=history,
    )


def _inside(fig) -> None:
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    W, H = fig.bbox.width, fig.bbox.height
    for ax in fig.axes:
        b = ax.get_tightbbox(renderer)
        assert b.x0 >= -1 and b.y0 >= -1 and b.x1 <= W + 1 and b.y1 <= H + 1, (ax.get_title(), b, (W, H))
    for a, b in itertools.combinations(fig.axes, 2):  # the axes' frames apart, their labels too
        assert not a.get_window_extent().overlaps(b.get_window_extent())
        ta, tb = a.get_tightbbox(renderer), b.get_tightbbox(renderer)
        assert not (ta.x0 < tb.x1 - 1 and tb.x0 < ta.x1 - 1 and ta.y0 < tb.y1 - 1 and tb.y0 < ta.y1 - 1)


def test_every_figure_fits_with_large_and_small_numbers():
    rng = np.random.default_rng(0)
    for scale in (1e-3, 300.0):  # tick labels from "0.0005" to "−150000"
        results = {n: _result(n, 400, rng, scale) for n in ("dr", "ekf", "graph")}
        truth = results["dr"].trajectory
        recognition = {
            s: {"confusion": rng.integers(0, 2000, (6, 6)).tolist(), "f1": 0.8} for s in ("SYN", "DESC", "BAYS", "SEM")
        }
        classes = ["Ball-Valve", "Elbow", "R-Tee", "R-Socket", "Butterfly-Valve", "3-Way-Ball-Valve"]
        for fig in (
            figures.trajectories(truth, results),
            figures.maps(results, None),
            figures.position_errors(truth, results),
            figures.velocities(results),
            figures.uncertainty_volumes(results),
            figures.update_cost(results),
            figures.confusion_matrices(recognition, classes),
        ):
            _inside(fig)


def test_uncertainty_volumes_draw_every_curve_in_its_panel():
    rng = np.random.default_rng(1)
    r = _result("graph", 500, rng, 1.0)
    fig = figures.uncertainty_volumes({"graph": r})
    pipes, objects = fig.axes
    t0 = min(int(np.min(st)) for st, _ in r.history["landmark_volume"].values())
    for ax, kind in ((pipes, "pipe"), (objects, "object")):
        (coll,) = [c for c in ax.collections if isinstance(c, LineCollection)]
        mine = [lid for lid, k in r.history["landmark_kind"].items() if k == kind]
        segs = coll.get_segments()
        assert len(segs) == len(mine)
        for seg, lid in zip(segs, mine):
            st, vol = r.history["landmark_volume"][lid]
            assert np.allclose(seg, np.column_stack([(st - t0) * 1e-9, vol]))
        assert len({tuple(c) for c in coll.get_colors()}) == min(len(mine), 10)  # told apart by colour
