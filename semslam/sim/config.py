"""Configuration of the simulated tank mission: every default is documented in its Field.

The sensor defaults are those fixed by the project (issue 3) so that no estimator can be favoured
by tuning the world: DVL 5 Hz σ 0.01 m/s with 10–20 % dropouts, pressure 8 Hz σ 0.02 m, AHRS
20 Hz σ 0.1° roll/pitch and 0.5° heading plus a heading bias drifting ~2° over the mission, laser
0.5 Hz σ 5 mm with ~100k points per scan, ~245 scans over ~8 minutes.

Frames: world {W} NED (z = depth, down), body {B} x forward / y right / z down. A sensor mount is
the extrinsic T_BS given as a translation (m, in {B}) and roll/pitch/yaw in degrees (intrinsic
Z-Y-X, i.e. R_BS = Rz(yaw)·Ry(pitch)·Rx(roll)).
"""

from __future__ import annotations

import copy
from pathlib import Path
from typing import TypeVar

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from semslam.config import read_yaml_mapping
from semslam.errors import ConfigError
from semslam.sim.vary import merge_into

Vec3 = tuple[float, float, float]


class _Section(BaseModel):
    model_config = ConfigDict(extra="forbid")


_M = TypeVar("_M", bound=BaseModel)


class Mount(_Section):
    """Extrinsic T_BS of a sensor on the vehicle."""

    xyz: Vec3 = Field((0.0, 0.0, 0.0), description="sensor origin in {B} (m)")
    rpy_deg: Vec3 = Field((0.0, 0.0, 0.0), description="roll, pitch, yaw of {S} in {B} (deg, Z-Y-X)")

    def matrix(self) -> np.ndarray:
        """T_BS as a 4×4 homogeneous matrix."""
        from scipy.spatial.transform import Rotation

        T = np.eye(4)
        r, p, y = np.deg2rad(self.rpy_deg)
        T[:3, :3] = Rotation.from_euler("ZYX", [y, p, r]).as_matrix()
        T[:3, 3] = self.xyz
        return T


class TankConfig(_Section):
    """The tank: flat rectangular floor at ``depth_m``, four plane walls sloping up to the surface."""

    depth_m: float = Field(5.0, gt=0, description="floor depth below the surface (m)")
    floor_half_x_m: float = Field(4.2, gt=0, description="half length of the flat floor along north (m)")
    floor_half_y_m: float = Field(4.6, gt=0, description="half width of the flat floor along east (m)")
    wall_slope_deg: float = Field(
        55.0, gt=5, le=90, description="angle of the side walls above the horizontal (90 = vertical)"
    )


class StructureConfig(_Section):
    """The pipe structure standing on the tank floor (generated from the seed unless ``layout_yaml``)."""

    layout_yaml: Path | None = Field(None, description="load the layout from this YAML instead of generating it")
    center_xy_m: tuple[float, float] = Field((0.0, 0.0), description="horizontal centre of the structure (m, NED)")
    grid: tuple[int, int, int] = Field((3, 3, 3), description="lattice nodes along x, y, z where fittings may sit")
    spacing_m: Vec3 = Field((0.6, 0.6, 0.5), description="lattice spacing along x, y, z (m)")
    floor_clearance_m: float = Field(0.12, ge=0, description="height of the lowest pipe axis above the floor (m)")
    pipe_radius_m: float = Field(0.0315, gt=0, le=0.064, description="outer radius of the PVC pipes (m)")
    min_objects: int = Field(20, ge=6, description="at least this many objects (all six classes appear)")
    min_pipes: int = Field(12, ge=1, description="at least this many straight pipes")
    n_edges: int = Field(20, ge=6, description="lattice edges in the generated pipe tree")
    min_pipe_length_m: float = Field(0.12, gt=0, description="no generated pipe is shorter than this (m)")


class TrajectoryConfig(_Section):
    """The vehicle starts at rest on the surface, descends and circles the structure facing it."""

    loops: float = Field(3.0, gt=0, description="loops around the structure")
    duration_s: float | None = Field(
        None,
        gt=0,
        description="mission length (s); default rest_s + ramp_s/2 + loops × loop_period_s (490 s, 245 scans)",
    )
    loop_period_s: float = Field(
        156.6667, gt=0, description="time per loop at cruise speed (s), when duration_s is unset"
    )
    rest_s: float = Field(5.0, ge=0, description="time at rest on the surface before moving (s)")
    ramp_s: float = Field(30.0, gt=0, description="time to reach cruise speed and working depth (s)")
    semi_axes_m: tuple[float, float] = Field(
        (3.3, 2.3), description="semi-axes (north, east) of the elliptic path around the structure centre (m)"
    )
    start_angle_deg: float = Field(90.0, description="bearing of the start point from the structure centre (deg)")
    start_depth_m: float = Field(0.0, description="depth of the body origin at the start (on the surface)")
    work_depth_m: float = Field(2.9, gt=0, description="mean working depth (m)")
    depth_swing_m: float = Field(0.25, ge=0, description="depth oscillation amplitude, twice per loop (m)")
    roll_pitch_amplitude_deg: float = Field(1.0, ge=0, description="amplitude of the roll/pitch wobble (deg)")
    look_away_s: tuple[float, float] | None = Field(
        None,
        description="(start, length) in s from the mission start: the vehicle keeps its path but turns its back on "
        "the structure (heading +180°, e.g. to inspect the tank wall), so that the laser loses the rack; null: "
        "it always faces it",
    )
    look_away_turn_s: float = Field(10.0, gt=0, description="time to turn away and to turn back (s)")

    @model_validator(mode="after")
    def _duration(self):
        if self.duration_s is None:
            self.duration_s = round(self.rest_s + self.ramp_s / 2 + self.loops * self.loop_period_s, 3)
        return self


class DvlConfig(_Section):
    """Doppler velocity log: 4 Janus beams; velocity of the DVL head over ground in {S}."""

    rate_hz: float = Field(5.0, gt=0, description="DVL readings per second")
    time_offset_s: float = Field(
        0.011,
        ge=0,
        lt=1,
        description="first reading this long after the mission start (the sensors are not synchronised)",
    )
    sigma_m_s: float = Field(0.01, gt=0, description="white noise per axis (m/s); also the message covariance")
    beam_angle_deg: float = Field(30.0, gt=0, lt=80, description="beam tilt from the DVL z axis (deg)")
    beam_azimuths_deg: tuple[float, ...] = Field((45.0, 135.0, 225.0, 315.0), description="beam azimuths in {S}")
    min_range_m: float = Field(0.3, ge=0, description="beams closer than this give no return (m)")
    max_range_m: float = Field(30.0, gt=0, description="beams further than this give no return (m)")
    wall_beams_lost: bool = Field(
        True, description="beams hitting the sloped walls give no return (False: they track the wall like the floor)"
    )
    min_valid_beams: int = Field(3, ge=1, le=4, description="fewer valid beams → the reading is invalid")
    relock_s: float = Field(1.0, ge=0, description="after losing bottom lock, time to re-acquire it (s)")
    random_dropout_rate: float = Field(
        0.07,
        ge=0,
        lt=0.9,
        description="fraction of the mission lost to random dropout bursts (placed ≥ 1 s clear of the wall dropouts)",
    )
    burst_s: tuple[float, float] = Field((2.0, 10.0), description="min and max duration of a dropout burst (s)")
    outage_s: tuple[float, float] | None = Field(
        None,
        description="one long loss of bottom lock, [start, length] in mission seconds (e.g. [60, 90]: working near "
        "the structure); none by default",
    )
    mount: Mount = Field(
        default_factory=lambda: Mount(xyz=(-0.25, 0.0, 0.30)),
        description="behind and below the body origin, axes as {B}",
    )


class AhrsConfig(_Section):
    """Attitude and heading reference system; orientation R_WS with additive roll/pitch/yaw noise."""

    rate_hz: float = Field(20.0, gt=0, description="AHRS readings per second")
    time_offset_s: float = Field(
        0.003,
        ge=0,
        lt=1,
        description="first reading this long after the mission start (the sensors are not synchronised)",
    )
    roll_pitch_sigma_deg: float = Field(0.1, gt=0, description="white noise of roll and pitch (deg)")
    heading_sigma_deg: float = Field(0.5, gt=0, description="white noise of the heading (deg)")
    heading_bias_drift_deg: float = Field(
        2.0, ge=0, description="the heading bias drifts linearly by this much over the mission (sign from the seed)"
    )
    angular_rate_sigma_rad_s: float = Field(0.002, gt=0, description="white noise of the angular rate (rad/s)")
    gyro_bias_sigma_rad_s: float = Field(
        5e-5,
        ge=0,
        description="the angular rate's constant bias, drawn per axis from N(0, σ²) for each mission (rad/s; "
        "5e-5 ≈ 10°/h, a good MEMS gyro after its own calibration)",
    )
    mount: Mount = Field(default_factory=Mount, description="at the body origin, axes as {B}")


class DepthConfig(_Section):
    """Pressure sensor, reported as depth of the sensor (m, down)."""

    rate_hz: float = Field(8.0, gt=0, description="pressure readings per second")
    time_offset_s: float = Field(
        0.007,
        ge=0,
        lt=1,
        description="first reading this long after the mission start (the sensors are not synchronised)",
    )
    sigma_m: float = Field(0.02, gt=0, description="white noise of the depth (m); also the message variance")
    mount: Mount = Field(
        default_factory=lambda: Mount(xyz=(0.0, 0.0, -0.20)), description="20 cm above the body origin"
    )


class LaserConfig(_Section):
    """Scanning laser, simulated as a ray-cast grid; sensor frame x right, y down, z along the view axis."""

    rate_hz: float = Field(0.5, gt=0, description="laser scans per second (each an instantaneous snapshot)")
    range_sigma_m: float = Field(0.005, gt=0, description="white range noise along each ray (m)")
    fov_deg: tuple[float, float] = Field((50.0, 45.0), description="horizontal and vertical field of view (deg)")
    resolution: tuple[int, int] = Field((336, 300), description="rays across and along (≈100k per scan)")
    min_range_m: float = Field(0.3, ge=0, description="closer returns are dropped (m)")
    max_range_m: float = Field(9.0, gt=0, description="farther returns are dropped (m)")
    mount: Mount = Field(
        default_factory=lambda: Mount(xyz=(0.55, 0.0, 0.25), rpy_deg=(55.0, 0.0, 90.0)),
        description="default: looking forward and 35° down (sensor z = body x pitched down)",
    )


class GroundTruthConfig(_Section):
    """True body poses T_WB, written as nav_msgs/Odometry."""

    rate_hz: float = Field(50.0, ge=20, description="rate of the true body poses (Hz)")


class TankSimConfig(_Section):
    """Everything that defines a simulated tank mission. Same config (incl. seed) → same bytes."""

    seed: int = Field(0, ge=0, description="random seed; seed 0 is the default, fixed layout")
    name: str | None = Field(None, description="mission name (default tank-seed<N>)")
    start_time_s: float = Field(1.7e9, ge=0, description="stamp of the first sample (s since the epoch)")
    tank: TankConfig = Field(default_factory=TankConfig)
    structure: StructureConfig = Field(default_factory=StructureConfig)
    trajectory: TrajectoryConfig = Field(default_factory=TrajectoryConfig)
    dvl: DvlConfig = Field(default_factory=DvlConfig)
    ahrs: AhrsConfig = Field(default_factory=AhrsConfig)
    depth: DepthConfig = Field(default_factory=DepthConfig)
    laser: LaserConfig = Field(default_factory=LaserConfig)
    ground_truth: GroundTruthConfig = Field(default_factory=GroundTruthConfig)

    @model_validator(mode="after")
    def _check(self):
        if self.dvl.burst_s[0] > self.dvl.burst_s[1]:
            raise ValueError("dvl.burst_s: the minimum exceeds the maximum")
        return self

    @property
    def mission_name(self) -> str:
        return self.name or f"tank-seed{self.seed}"


def load_tank_config(path: str | Path | None = None, **overrides) -> TankSimConfig:
    """The defaults, overridden by a YAML file (if given) and then by ``overrides`` given as dotted keys
    with ``__`` separators, e.g. ``load_tank_config(None, seed=3, trajectory__loops=2)``."""
    return load_sim_config(TankSimConfig, path, **overrides)


def load_sim_config(model: type[_M], path: str | Path | None = None, base: dict | None = None, **overrides) -> _M:
    """A simulator configuration of type ``model``: its defaults, overridden by ``base`` (e.g. what a
    seed draws, :func:`semslam.sim.vary.draws`), then by a YAML file (if given) and then by
    ``overrides`` (dotted keys with ``__`` separators). Every problem is a one-line
    :class:`ConfigError` naming the file and the key."""
    data = read_yaml_mapping(path, "simulation configuration") if path is not None else {}
    return build_sim_config(model, data, source=None if path is None else str(path), base=base, **overrides)


def build_sim_config(
    model: type[_M], data: dict, *, source: str | None = None, base: dict | None = None, **overrides
) -> _M:
    """``model`` from its defaults ← ``base`` ← ``data`` (a YAML file's mapping, named ``source`` in
    errors) ← ``overrides`` (dotted keys with ``__`` separators)."""
    where = source or "simulation config"
    data = merge_into(copy.deepcopy(base or {}), copy.deepcopy(data))
    for key, value in overrides.items():
        d = data
        *parents, leaf = key.split("__")
        for k in parents:
            d = d.setdefault(k, {})
            if not isinstance(d, dict):
                raise ConfigError(f"{where}: {k}: expected a mapping")
        d[leaf] = value
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        err = exc.errors()[0]
        key = ".".join(str(x) for x in err["loc"])
        msg = err["msg"].removeprefix("Value error, ")
        raise ConfigError(f"{where}: {key + ': ' if key else ''}{msg}") from exc
