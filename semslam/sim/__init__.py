"""Simulated missions with ground truth: scenes, trajectories, sensor models.

Tank mission (laser, DVL, AHRS, depth)::

    from semslam.sim import TankSimConfig, simulate_tank, render_preview
    mission = simulate_tank(TankSimConfig(seed=0))        # in memory
    render_preview(mission, "tank.png")

``semslam.sim.simulate.simulate_tank_to_bag`` is what ``semslam simulate tank`` runs.

Conventions (see each module): world {W} NED with its origin at the surface above the tank centre;
body {B} x forward, y right, z down. Sensor frames {S} (extrinsics T_BS in the mission metadata):
DVL and AHRS with the body's axes; laser {S} x right, y down, z along the view axis (the default
mount looks forward and 35° down). Sensor names / topics / message types: ``dvl`` /sim/dvl
cola2_msgs/msg/DVL, ``ahrs`` /sim/imu sensor_msgs/msg/Imu, ``depth`` /sim/pressure
sensor_msgs/msg/FluidPressure, ``laser`` /sim/laser/points sensor_msgs/msg/PointCloud2,
``ground_truth`` /sim/ground_truth/odom nav_msgs/msg/Odometry.

The public names are imported lazily, so ``import semslam.sim`` stays cheap (no open3d).
"""

from importlib import import_module

_EXPORTS = {
    "TankSimConfig": "semslam.sim.config",
    "load_tank_config": "semslam.sim.config",
    "simulate_tank": "semslam.sim.simulate",
    "simulate_tank_to_bag": "semslam.sim.simulate",
    "render_preview": "semslam.sim.preview",
    "library": "semslam.sim.cad",
    "register_model": "semslam.sim.cad",
    "CadModel": "semslam.sim.cad",
    "CLASSES": "semslam.sim.cad",
}

__all__ = list(_EXPORTS)


def __getattr__(name):
    if name in _EXPORTS:
        return getattr(import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module 'semslam.sim' has no attribute {name!r}")
