"""Simulated missions with ground truth: scenes, trajectories, sensor models.

Tank mission (laser, DVL, AHRS, depth)::

    from semslam.sim import TankSimConfig, simulate_tank, render_preview
    mission = simulate_tank(TankSimConfig(seed=0))

The public names are imported lazily, so ``import semslam.sim`` stays cheap (no open3d).
"""

from importlib import import_module

_EXPORTS = {
    "TankSimConfig": "semslam.sim.config",
    "load_tank_config": "semslam.sim.config",
    "simulate_tank": "semslam.sim.simulate",
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
