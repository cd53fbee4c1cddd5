"""What the fault tests run: the `semslam` command as a user starts it, on a short simulated mission."""

from __future__ import annotations

import sys
from pathlib import Path


def semslam_command() -> list[str]:
    """The installed `semslam` script beside this interpreter (else the module)."""
    script = Path(sys.executable).with_name("semslam")
    return [str(script)] if script.exists() else [sys.executable, "-m", "semslam.cli"]


def short_tank(seconds: float = 16.0):
    """A simulated tank mission of ``seconds``: DVL, AHRS, depth, ground truth and laser scans of
    ~1000 rays (0.5 Hz), enough for the oracle front-end, which only needs their stamps."""
    from semslam.sim.config import TankSimConfig
    from semslam.sim.simulate import simulate_tank

    return simulate_tank(TankSimConfig(trajectory={"duration_s": seconds}, laser={"resolution": (34, 30)}))


def short_tank_mission(path: Path, seconds: float = 16.0) -> Path:
    """:func:`short_tank` as a ROS 1 bag at ``path`` (a few MB, simulated in seconds)."""
    from semslam.mission.bag import write_mission

    write_mission(short_tank(seconds), path)
    return path
