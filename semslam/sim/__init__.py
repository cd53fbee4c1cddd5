"""Simulated missions with ground truth: scenes, trajectories, sensor models.

Tank mission (laser, DVL, AHRS, depth)::

    from semslam.sim import TankSimConfig, simulate_tank, render_preview
    mission = simulate_tank(TankSimConfig(seed=0))        # in memory
    render_preview(mission, "tank.png")

Sonar field mission (multibeam, DVL, AHRS, depth) over three CAD-known subsea structures::

    from semslam.sim import FieldSimConfig, simulate_field, render_field_preview
    from semslam.models.structures import structure_library
    mission = simulate_field(FieldSimConfig(seed=0))
    render_field_preview(mission, "field.png")
    structure_library()["manifold"].mesh                  # the model library (semslam.models), shared with the front-ends

``semslam.sim.simulate.simulate_tank_to_bag`` / ``semslam.sim.field_mission.simulate_field_to_bag``
are what ``semslam simulate tank`` / ``semslam simulate field`` run.

Conventions (see each module): world {W} NED with its origin at the surface above the tank centre
(field: above the centre of the surveyed area); body {B} x forward, y right, z down. Sensor frames
{S} (extrinsics T_BS in the mission metadata): DVL and AHRS with the body's axes; laser {S} x right,
y down, z along the view axis (the default mount looks forward and 35° down); multibeam {S} with the
body's axes, beam i along (0, sin a_i, cos a_i). Sensor names / topics / message types: ``dvl``
/sim/dvl cola2_msgs/msg/DVL, ``ahrs`` /sim/imu sensor_msgs/msg/Imu, ``depth`` /sim/pressure
sensor_msgs/msg/FluidPressure, ``laser`` /sim/laser/points sensor_msgs/msg/PointCloud2 (tank),
``sonar`` /sim/sonar/scan sensor_msgs/msg/LaserScan (field), ``ground_truth``
/sim/ground_truth/odom nav_msgs/msg/Odometry.

The public names are imported lazily, so ``import semslam.sim`` stays cheap (no open3d).
"""

from importlib import import_module

_EXPORTS = {
    "TankSimConfig": "semslam.sim.config",
    "load_tank_config": "semslam.sim.config",
    "simulate_tank": "semslam.sim.simulate",
    "simulate_tank_to_bag": "semslam.sim.simulate",
    "render_preview": "semslam.sim.preview",
    "FieldSimConfig": "semslam.sim.field_config",
    "load_field_config": "semslam.sim.field_config",
    "simulate_field": "semslam.sim.field_mission",
    "simulate_field_to_bag": "semslam.sim.field_mission",
    "render_field_preview": "semslam.sim.field_preview",
}

__all__ = list(_EXPORTS)


def __getattr__(name):
    if name in _EXPORTS:
        return getattr(import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module 'semslam.sim' has no attribute {name!r}")
