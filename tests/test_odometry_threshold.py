"""kiss-icp's adaptive correspondence threshold over recent registrations only (``kiss_icp.threshold_window``):
kiss-icp's own keeps the RMS of every correction since the map started, so a descent's large corrections set
the threshold for the rest of the mission; the windowed one forgets them."""

import numpy as np
from kiss_icp.threshold import AdaptiveThreshold

from frontends.odometry.config import OdometryConfig
from frontends.odometry.matcher import ScanMatcher, WindowedThreshold, kiss_config


def _deviation(metres: float) -> np.ndarray:
    T = np.eye(4)
    T[0, 3] = metres
    return T


def test_the_windowed_threshold_forgets_old_corrections_where_kiss_icps_does_not():
    config = kiss_config(OdometryConfig())
    own, windowed = AdaptiveThreshold(config), WindowedThreshold(config, window=5)
    for metres in [0.15] * 10 + [0.02] * 5:  # a descent's 15 cm corrections, then five of 2 cm
        own.update_model_deviation(_deviation(metres))
        windowed.update_model_deviation(_deviation(metres))
    # kiss-icp's model over the last five alone (its initial threshold counts as one sample, as in its own)
    assert np.isclose(windowed.get_threshold(), np.sqrt((0.05**2 + 5 * 0.02**2) / 6))
    assert own.get_threshold() > 0.11  # √((0.05² + 10·0.15² + 5·0.02²)/16): the descent still rules


def test_the_windowed_threshold_is_kiss_icps_while_the_window_holds_every_correction():
    config = kiss_config(OdometryConfig())
    own, windowed = AdaptiveThreshold(config), WindowedThreshold(config, window=10)
    assert windowed.get_threshold() == own.get_threshold()  # the initial threshold before any
    for metres in (0.03, 0.005, 0.08, 0.04):  # 5 mm is below kiss-icp's min motion: not counted by either
        own.update_model_deviation(_deviation(metres))
        windowed.update_model_deviation(_deviation(metres))
        assert np.isclose(windowed.get_threshold(), own.get_threshold())


def test_the_matcher_takes_the_windowed_threshold_from_the_config_and_keeps_it_over_a_map_restart():
    assert isinstance(ScanMatcher(OdometryConfig()).kiss.adaptive_threshold, AdaptiveThreshold)
    matcher = ScanMatcher(OdometryConfig.model_validate({"kiss_icp": {"threshold_window": 15}}))
    assert isinstance(matcher.kiss.adaptive_threshold, WindowedThreshold)
    matcher.reset()
    assert matcher.kiss.adaptive_threshold.deviations.maxlen == 15
