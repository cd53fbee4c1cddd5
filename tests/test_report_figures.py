"""The report's map figure: every landmark drawn where it is, each layer as one artist (the dead
reckoning map places thousands of observations)."""

import numpy as np
from matplotlib.collections import LineCollection, PathCollection

from semslam.estimation import EstimatorResult, LandmarkEstimate, Trajectory
from semslam.eval import figures
from semslam.mission import GroundTruthMap, GtObject, GtPipe

TRUTH = GroundTruthMap(
    classes=("Elbow",),
    objects=(GtObject(7, "Elbow", (1.0, 2.0, 3.0)),),
    pipes=(GtPipe(20, (0.0, 0.0, 3.0), (0.0, 5.0, 3.0), 0.03), GtPipe(21, (1.0, 0.0, 3.0), (1.0, 5.0, 3.0), 0.03)),
)


def _landmarks(n: int, rng) -> list[LandmarkEstimate]:
    out = []
    for i in range(n):
        kind = ("object", "pipe", "structure")[i % 3]
        x = rng.uniform(-5, 5, 3)
        if kind == "object":
            out.append(LandmarkEstimate(i, kind, position=x))
        elif kind == "pipe":
            out.append(LandmarkEstimate(i, kind, p=x, q=x + rng.uniform(-1, 1, 3)))
        else:
            pose = np.eye(4)
            pose[:3, 3] = x
            out.append(LandmarkEstimate(i, kind, pose=pose, position=x))
    return out


def test_each_map_layer_is_one_artist_with_every_landmark_where_it_is():
    rng = np.random.default_rng(0)
    lms = _landmarks(3000, rng)
    traj = Trajectory(np.arange(3, dtype=np.int64), np.zeros((3, 3)), np.tile([0.0, 0, 0, 1], (3, 1)))
    fig = figures.maps({"dr": EstimatorResult("dr", traj, lms)}, TRUTH)
    ax = fig.axes[0]
    lines = [c for c in ax.collections if isinstance(c, LineCollection)]
    points = [c for c in ax.collections if isinstance(c, PathCollection)]
    assert len(lines) == 2 and len(points) == 3 and not ax.lines  # truth pipes, map pipes; truth, objects, structures
    segs = np.array(lines[1].get_segments())
    pipes = [lm for lm in lms if lm.kind == "pipe"]
    assert np.allclose(segs, [[[lm.p[1], lm.p[0]], [lm.q[1], lm.q[0]]] for lm in pipes])  # east right, north up
    objects = np.array([lm.position for lm in lms if lm.kind == "object"])
    assert np.allclose(points[1].get_offsets(), objects[:, [1, 0]])
    structures = np.array([lm.pose[:3, 3] for lm in lms if lm.kind == "structure"])
    assert np.allclose(points[2].get_offsets(), structures[:, [1, 0]])
    x0, x1 = ax.get_xlim()
    y0, y1 = ax.get_ylim()
    ends = segs.reshape(-1, 2)
    assert x0 <= ends[:, 0].min() and ends[:, 0].max() <= x1 and y0 <= ends[:, 1].min() and ends[:, 1].max() <= y1


def test_band_draws_the_polygons_of_fill_between():
    """The ±2σ band's polygons equal fill_between's, runs split by missing covariances included."""
    import matplotlib.pyplot as plt

    from semslam.eval.figures import _band

    rng = np.random.default_rng(3)
    t = np.arange(40.0)
    lo, hi = -rng.uniform(0.1, 1, 40), rng.uniform(0.1, 1, 40)
    lo[[0, 7, 8, 20, 39]] = np.nan  # poses without a covariance: runs of one, several, at both ends
    hi[[7, 8, 21, 33]] = np.nan
    fig, (a, b) = plt.subplots(1, 2)
    want = [p.vertices for p in a.fill_between(t, lo, hi, color="r", alpha=0.15, lw=0).get_paths()]
    _band(b, t, lo, hi, "r")
    got = [p.vertices for p in b.collections[0].get_paths()]
    assert len(got) == len(want) == 4
    for g, w in zip(got, want):
        np.testing.assert_array_equal(g, w)
    assert a.dataLim.bounds == b.dataLim.bounds
    plt.close(fig)
