"""Each sensor's physical bound (``reader.plausible``): finite nonsense is named, ordinary readings
and a DVL's own dropouts pass."""

import numpy as np
import pytest

from semslam.mission import Attitude, Depth, DvlVelocity, GpsFix, GroundTruthPose, SonarSwath
from semslam.mission.config import PlausibleBounds
from semslam.mission.plausible import implausible

BOUNDS = PlausibleBounds()
Q = np.array([0.0, 0.0, 0.0, 1.0])


@pytest.mark.parametrize(
    "m, why",
    [
        (DvlVelocity(0, "dvl", velocity=(1e188, 0, 0)), "velocity beyond 10 m/s"),
        (DvlVelocity(0, "dvl", velocity=(6.0, 6.0, 6.0)), "velocity beyond 10 m/s"),  # the magnitude
        (DvlVelocity(0, "dvl", velocity=(1.0, 0, 0), altitude=-3e4), "altitude beyond 12000 m"),
        (Depth(0, "pressure", depth=-1.3e4), "depth beyond ±12000 m"),
        (Attitude(0, "ahrs", orientation=Q, angular_rate=(0, 0, 1e9)), "angular_rate beyond 50 rad/s"),
        (GpsFix(0, "gps", position=(3e7, 0, 0)), "position beyond 2.1e+07 m"),
        (GroundTruthPose(0, "truth", position=(0, 0, 1e300), orientation=Q), "position beyond 2.1e+07 m"),
        (SonarSwath(0, "sonar", angles=(0.0, 0.1), ranges=(5.0, 1e6)), "ranges beyond 20000 m"),
    ],
)
def test_a_reading_beyond_its_sensors_bound_is_named(m, why):
    assert implausible(m, BOUNDS) == why


@pytest.mark.parametrize(
    "m",
    [
        DvlVelocity(0, "dvl", velocity=(2.0, -0.5, 0.1), altitude=30.0),
        DvlVelocity(0, "dvl", velocity=(1e188, 0, 0), valid=False),  # a dropout carries no velocity
        Depth(0, "pressure", depth=10_900.0),  # the Challenger Deep
        Depth(0, "pressure", depth=-0.4),  # at the surface, a wave
        Attitude(0, "ahrs", orientation=Q, angular_rate=(0.3, 0, 2.0)),
        Attitude(0, "ahrs", orientation=Q),
        GpsFix(0, "gps", position=(1.2e5, -3e4, 0.0)),
        SonarSwath(0, "sonar", angles=(0.0,), ranges=(120.0,)),
        SonarSwath(0, "sonar"),  # no return
    ],
)
def test_ordinary_readings_pass(m):
    assert implausible(m, BOUNDS) is None


def test_the_bounds_are_configuration():
    fast = DvlVelocity(0, "dvl", velocity=(12.0, 0, 0))
    assert implausible(fast, BOUNDS) is not None
    assert implausible(fast, PlausibleBounds(speed_m_s=15.0)) is None
    with pytest.raises(ValueError):
        PlausibleBounds(speed_m_s=0.0)
