"""The odometry's translation covariance carries the laser's range noise, measured on the floor it
removes: the map's points carry that noise too, and it is shared by every scan point matched to the
same map surface, so it does not average out over the scan (issue 23, experiments/odometry/README.md,
stop 39). And the planes behind the covariance are the same whether fitted afresh or kept from the
re-solve's previous step."""

import numpy as np

from frontends.odometry import OdometryFrontend
from frontends.odometry.config import OdometryConfig
from frontends.odometry.information import FREE_ROTATION_SIGMA_RAD, translation_given_rotation, translation_only
from frontends.odometry.matcher import ScanMatcher, _MapPlanes

S = 1_000_000_000  # ns per s


def _scene(rng, sigma: float) -> np.ndarray:
    """A floor (y = 1.5 m in the sensor frame, 70 % of the points, ``sigma`` of noise across it) and
    three bars along x at 3–4 m: they fix y and z well, x only by their ends."""
    n_floor = 14000
    floor = np.c_[rng.uniform(-2, 2, n_floor), 1.5 + rng.normal(0, sigma, n_floor), rng.uniform(1.5, 6, n_floor)]
    bars = []
    for y, z in ((0.0, 3.0), (0.6, 3.5), (-0.5, 4.0)):
        m = 2000
        angle = rng.uniform(0, 2 * np.pi, m)
        bars.append(np.c_[rng.uniform(-1.2, 1.2, m), y + 0.06 * np.cos(angle), z + 0.06 * np.sin(angle)])
    return np.concatenate([floor, *bars])


def _registered(sigma: float, range_noise_scale: float):
    rng = np.random.default_rng(3)
    matcher = ScanMatcher(OdometryConfig.model_validate({"covariance": {"range_noise_scale": range_noise_scale}}))
    assert matcher.start(_scene(rng, sigma), np.eye(4), stamp=0)
    reg = matcher.register(_scene(rng, sigma), np.eye(4), stamp=2 * S, rotation_cov=np.eye(3) * 1e-12)
    assert reg.rejected is None
    return matcher, reg


def test_the_range_noise_is_measured_on_the_removed_floor():
    for sigma in (0.002, 0.008):
        matcher, _ = _registered(sigma, 0.0)
        assert 0.7 * sigma**2 < matcher.range_variance < 1.3 * sigma**2


def test_the_translation_covariance_follows_the_range_noise_along_the_weak_direction():
    covariances = {sigma: _registered(sigma, 0.08)[1].covariance[3:, 3:] for sigma in (0.002, 0.008)}
    ratio = np.trace(covariances[0.008]) / np.trace(covariances[0.002])
    assert 10 < ratio < 25  # ∝ σ_r² (16)
    _, vectors = np.linalg.eigh(covariances[0.008])
    assert abs(vectors[0, -1]) > 0.9  # largest along the bars (x), which fix it least


def test_planes_kept_between_steps_are_the_planes_fitted_afresh():
    rng = np.random.default_rng(5)
    map_points = _scene(rng, 0.003)
    source = _scene(rng, 0.003)
    pose = np.eye(4)
    pose[:3, 3] = [0.01, -0.005, 0.004]
    warm = _MapPlanes(map_points, source, 0.15, 8)
    t = warm.translation(source, pose, 0.15, 0.05)  # fits and keeps planes at every step
    pose[:3, 3] = t
    cold = _MapPlanes(map_points, source, 0.15, 8)
    for a, b in zip(warm.information(source, pose, 0.15), cold.information(source, pose, 0.15), strict=True):
        assert np.allclose(a, b, rtol=1e-12, atol=0)


def test_the_held_covariance_is_its_parts_and_the_tail_leaves_the_rotation_alone():
    """The covariance of a registration with the attitude held is the sum of its stated parts
    (a·σ²·H_tt⁻¹ + b·σ_r²·n·H_tt⁻¹ + f², the rotation's prior, and what the rotation moves
    the translation by), and the Student-t factor multiplies the translation's measured part alone: the
    held rotation is the navigation's, whatever ICP did (experiments/odometry/README.md, stop 40)."""
    a, b, f = 2.0, 0.1, 0.002
    covariance = {"held_residual_scale": a, "range_noise_scale": b, "held_floor_sigma_m": f}
    rng = np.random.default_rng(3)
    matcher = ScanMatcher(OdometryConfig.model_validate({"covariance": covariance}))
    assert matcher.start(_scene(rng, 0.004), np.eye(4), stamp=0)
    rotation_cov = np.diag([1.0, 2.0, 3.0]) * 1e-6
    reg = matcher.register(_scene(rng, 0.004), np.eye(4), stamp=2 * S, rotation_cov=rotation_cov)
    assert reg.rejected is None
    H_tt_inv = np.linalg.inv(reg.information[3:, 3:])
    K = -H_tt_inv @ reg.information[3:, :3]
    measured = (a * reg.residual_var + b * matcher.range_variance * reg.inliers) * H_tt_inv + f**2 * np.eye(3)
    assert np.allclose(reg.covariance[:3, :3], rotation_cov, rtol=1e-12, atol=0)
    assert np.allclose(reg.covariance[3:, :3], K @ rotation_cov, rtol=1e-9, atol=1e-18)
    assert np.allclose(reg.covariance[3:, 3:], measured + K @ rotation_cov @ K.T, rtol=1e-9, atol=1e-15)
    # the range part is there: the floor's noise, times the inliers, is most of the measured part here
    assert b * matcher.range_variance * reg.inliers > a * reg.residual_var

    frontend = OdometryFrontend.__new__(OdometryFrontend)  # the tail's factor alone, without a mission
    frontend._tail_factor = lambda *args: 5.0
    scaled = frontend._tail_scaled(reg, np.eye(6))
    assert np.array_equal(scaled[:3, :], reg.covariance[:3, :])  # the rotation and the cross terms: unchanged
    assert np.allclose(scaled[3:, 3:] - reg.covariance[3:, 3:], 4.0 * measured, rtol=1e-9, atol=1e-15)


def test_translation_only_keeps_the_translations_marginal_and_frees_the_rotation():
    rng = np.random.default_rng(0)
    a = rng.normal(size=(6, 6))
    cov = a @ a.T
    out = translation_only(cov)
    np.testing.assert_array_equal(out[3:, 3:], cov[3:, 3:])
    np.testing.assert_array_equal(out[:3, 3:], 0.0)
    np.testing.assert_array_equal(out[3:, :3], 0.0)
    np.testing.assert_array_equal(out[:3, :3], np.eye(3) * FREE_ROTATION_SIGMA_RAD**2)


def test_translation_given_rotation_keeps_the_translations_dependence_on_the_rotation_and_drops_its_own():
    # a held rotation Σ_θ and a translation that moves K per radian of its error, plus its measured part M
    rng = np.random.default_rng(1)
    S = np.diag([1e-6, 2e-6, 1.5e-6])
    K = rng.normal(scale=3.0, size=(3, 3))
    a = rng.normal(scale=1e-3, size=(3, 3))
    M = a @ a.T + np.eye(3) * 1e-6
    cov = np.block([[S, S @ K.T], [K @ S, M + K @ S @ K.T]])
    out = translation_given_rotation(cov)
    info = np.linalg.inv(out)
    # the information of t − K·θ (M⁻¹) is the factor's; of the rotation alone, FREE_ROTATION_SIGMA_RAD's
    J = np.hstack([-K, np.eye(3)])
    expected = J.T @ np.linalg.solve(M, J)
    expected[:3, :3] += np.eye(3) / FREE_ROTATION_SIGMA_RAD**2
    np.testing.assert_allclose(info, expected, rtol=1e-6, atol=1e-3)
    # given the rotation, the translation's covariance is M (translation_only leaves M + K·Σ_θ·Kᵀ's marginal)
    given = out[3:, 3:] - out[3:, :3] @ np.linalg.solve(out[:3, :3], out[:3, 3:])
    np.testing.assert_allclose(given, M, rtol=1e-6)
