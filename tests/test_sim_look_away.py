"""The tank route option ``trajectory.look_away_s``: the vehicle keeps its path but turns its back
on the structure for the interval, and faces it again afterwards."""

import numpy as np

from semslam.sim.config import TrajectoryConfig
from semslam.sim.trajectory import Trajectory


def _off_facing_deg(traj: Trajectory, t: np.ndarray) -> np.ndarray:
    """How far (deg, wrapped) the heading is from facing the structure centre."""
    p, _ = traj.position_velocity(t)
    yaw = traj.rotation(t).as_euler("ZYX")[:, 0]
    facing = np.arctan2(traj.center[1] - p[:, 1], traj.center[0] - p[:, 0])
    return np.degrees(np.abs(np.angle(np.exp(1j * (yaw - facing)))))


def test_the_vehicle_turns_its_back_on_the_structure_inside_the_interval_only():
    centre = np.array([0.2, -0.1, 4.0])
    plain = Trajectory(TrajectoryConfig(loops=2), centre)
    away = Trajectory(TrajectoryConfig(loops=2, look_away_s=(200.0, 90.0), look_away_turn_s=10.0), centre)
    outside, inside = np.array([150.0, 199.0, 291.0, 320.0]), np.array([210.0, 250.0, 280.0])
    assert np.all(_off_facing_deg(away, outside) < 1e-6)
    assert np.all(_off_facing_deg(away, inside) > 179.9)
    t = np.linspace(0.0, away.duration, 2000)
    np.testing.assert_allclose(away.position_velocity(t)[0], plain.position_velocity(t)[0])  # the same path
    # the turns are smooth: a 180° turn over 10 s peaks at 1.875·π/10 rad/s (quintic smoothstep)
    rate = np.abs(away.angular_rate(np.linspace(195.0, 295.0, 1001))[:, 2])
    assert 0.5 < rate.max() < 0.7
