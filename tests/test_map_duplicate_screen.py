"""The duplicate test's screen (semslam.mapping.builder): a pair of objects is skipped without its χ² when
|Δ|² ≥ gate · (spread_a + spread_b)², which is exact only if every estimator's ``gating_spread`` bounds the
covariance its ``difference_nis`` uses: ν'S⁻¹ν ≥ |ν|² / (spread_a + spread_b)² for every pair."""

import itertools

import numpy as np
import pytest

from semslam.backend.graph import GraphEstimator
from semslam.config import SemslamConfig
from semslam.ekf import EkfEstimator
from semslam.mapping.tracks import Track, TrackView
from semslam.mission.measurements import Attitude
from semslam.observations import PointObservation
from tests.support.ekf_mission import seen_from_truth, simulate_circling
from tests.support.replay import Scanner

# objects 0.2–1.5 m apart around a hover circle of 1 m, seen with 5 mm noise every 2 s
OBJECTS = [np.array(p) for p in ([1.0, 0.0, 4.5], [-0.6, 0.7, 4.2], [0.2, -0.9, 4.4], [0.4, -0.9, 4.4])]


@pytest.fixture(scope="module", params=["ekf", "graph"])
def mapped(request):
    sim = simulate_circling(seed=4, duration_s=30.0, dropouts=(), with_features=False, radius_m=1.0, speed_m_s=0.1)
    rng = np.random.default_rng(4)

    def scan(m):
        if m.stamp % 2_000_000_000 or m.stamp == 0:
            return []
        return seen_from_truth(sim, m.stamp, [], OBJECTS, rng, 0.002, 0.005)

    make = EkfEstimator if request.param == "ekf" else GraphEstimator
    est = make(sim.metadata, SemslamConfig())
    sim.run([est], [Scanner((Attitude,), scan)], observations=False)
    return est


def _bound_holds(state, ids, pos):
    spread = state.gating_spread(ids)
    assert np.all(np.isfinite(spread)) and np.all(spread > 0)
    ratios = []
    for a, b in itertools.combinations(range(len(ids)), 2):
        nis = state.difference_nis(ids[a], ids[b])
        bound = float(np.sum((pos[a] - pos[b]) ** 2)) / (spread[a] + spread[b]) ** 2
        assert nis >= bound * (1 - 1e-9), (ids[a], ids[b], nis, bound)
        ratios.append(nis / bound)
    return ratios


def test_the_spread_bounds_the_difference_test_of_every_mapped_pair(mapped):
    ids, pos = mapped.map.objects()
    assert len(ids) == len(OBJECTS)
    ratios = _bound_holds(mapped.map, ids, pos)
    if isinstance(mapped, GraphEstimator):  # its gating covariances are uncorrelated: the bound is near the χ²
        assert max(ratios) < 50


def test_the_bound_holds_for_a_twin_with_a_wide_covariance_beside_a_sure_object():
    """A freshly promoted twin (one view's covariance, correlated with the vehicle) next to an object
    seen for a while: the filter's cross-covariances count in its χ² and must stay inside the bound."""
    sim = simulate_circling(seed=4, duration_s=20.0, dropouts=(), with_features=False, radius_m=1.0, speed_m_s=0.1)
    rng = np.random.default_rng(5)

    def scan(m):
        if m.stamp % 2_000_000_000 or m.stamp == 0:
            return []
        return seen_from_truth(sim, m.stamp, [], OBJECTS[:2], rng, 0.002, 0.005)

    est = EkfEstimator(sim.metadata, SemslamConfig())
    sim.run([est], [Scanner((Attitude,), scan)], observations=False)
    for offset, sigma in ((0.01, 0.02), (0.05, 0.001), (0.3, 0.05)):
        est.map.begin()
        T_WS = est.map.sensor_pose("laser")
        R, t = T_WS[:3, :3], T_WS[:3, 3]
        z = PointObservation(
            0, "laser", position=(OBJECTS[0] + [offset, 0, 0] - t) @ R, covariance=np.eye(3) * sigma**2
        )
        world, cov, prepared, *drift = est.map.place(z)
        est.map.promote(Track(-1, "object", views=[TrackView(0, z, world, cov, prepared, *drift)]))
    ids, pos = est.map.objects()
    assert len(ids) == 5
    _bound_holds(est.map, ids, pos)
