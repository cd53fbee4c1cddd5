"""A measurement whose covariance cannot be one is unusable, like one with NaN: the reader drops and
counts it (a damaged recording's finite nonsense would otherwise reach the filters as NaN)."""

import numpy as np
import pytest

from semslam.mission.measurements import Attitude, DvlVelocity


def _attitude(cov):
    return Attitude(0, "ahrs", orientation=np.array([0.0, 0.0, 0.0, 1.0]), covariance=np.asarray(cov, float))


def test_a_covariance_is_usable_when_symmetric_with_variances_and_correlations_in_range():
    assert _attitude(np.diag([1e-4, 1e-4, 4e-4])).nonfinite_field() is None
    c = np.array([[4.0, 1.9, 0.0], [1.9, 1.0, 0.0], [0.0, 0.0, 0.0]]) * 1e-4  # correlation 0.95, one zero
    assert _attitude(c).nonfinite_field() is None
    assert _attitude(np.zeros((3, 3))).nonfinite_field() is None  # "unknown" as some drivers write it


@pytest.mark.parametrize(
    "cov",
    [
        [[1e-4, 0, -1.27e188], [0, 1e-4, 0], [0, 0, 1e-4]],  # damaged bytes (seen in a fault test)
        [[1e-4, 2e-4, 0], [2e-4, 1e-4, 0], [0, 0, 1e-4]],  # correlation 2
        [[-1e-4, 0, 0], [0, 1e-4, 0], [0, 0, 1e-4]],  # a negative variance
        [[1e-4, 1e-5, 0], [0, 1e-4, 0], [0, 0, 1e-4]],  # not symmetric
    ],
)
def test_a_covariance_that_cannot_be_one_makes_the_measurement_unusable(cov):
    assert _attitude(cov).nonfinite_field() == "covariance"
    assert not _attitude(cov).is_finite()
    dvl = DvlVelocity(0, "dvl", velocity=np.zeros(3), covariance=np.asarray(cov, float))
    assert dvl.nonfinite_field() == "covariance"
