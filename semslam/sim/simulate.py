"""``simulate_tank``: the simulated tank mission (laser scanner, DVL, AHRS, depth) with ground truth.

Also what every simulated mission shares (the sonar field's too): the navigation sensors and ground
truth (:func:`simulate_nav`), their declared noise (:func:`nav_noise`), the sensor table.
"""

from __future__ import annotations

from collections.abc import Collection
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from semslam.mission.measurements import Attitude, Depth, GroundTruthPose
from semslam.mission.mission import Mission, MissionMetadata, SensorInfo
from semslam.sim import sensors as S
from semslam.sim.config import AhrsConfig, DepthConfig, DvlConfig, TankSimConfig
from semslam.sim.raycast import LabelledScene
from semslam.sim.streams import rng_stream
from semslam.sim.tank import TankScene, make_layout, tank_surface_corners
from semslam.sim.trajectory import MotionModel, Trajectory
from semslam.sim.vary import ASPECTS

#: sensor name → (kind, topic, message type it is written as)
SENSORS = {
    "dvl": ("dvl", "/sim/dvl", "cola2_msgs/msg/DVL"),
    "ahrs": ("ahrs", "/sim/imu", "sensor_msgs/msg/Imu"),
    "depth": ("depth", "/sim/pressure", "sensor_msgs/msg/FluidPressure"),
    "laser": ("laser", "/sim/laser/points", "sensor_msgs/msg/PointCloud2"),
    "ground_truth": ("ground_truth", "/sim/ground_truth/odom", "nav_msgs/msg/Odometry"),
}


def _rng(seed: int, purpose: str) -> np.random.Generator:
    return rng_stream(seed, purpose)


def nav_noise(dvl: DvlConfig, ahrs: AhrsConfig, depth: DepthConfig, duration_s: float) -> dict:
    """The noise of the navigation sensors (DVL, AHRS, depth), in SI units, as estimators should
    assume it; the heading bias drifts by ``heading_bias_drift_rad`` over ``duration_s``."""
    d2r = np.pi / 180
    return {
        "dvl": {
            "velocity_sigma_m_s": dvl.sigma_m_s,
            "rate_hz": dvl.rate_hz,
            "random_dropout_rate": dvl.random_dropout_rate,
        },
        "ahrs": {
            "roll_sigma_rad": ahrs.roll_pitch_sigma_deg * d2r,
            "pitch_sigma_rad": ahrs.roll_pitch_sigma_deg * d2r,
            "heading_sigma_rad": ahrs.heading_sigma_deg * d2r,
            "heading_bias_drift_rad": ahrs.heading_bias_drift_deg * d2r,
            "heading_bias_drift_over_s": duration_s,
            # The bias starts at 0: the AHRS's heading at the start defines the world's yaw.
            "heading_bias_initial_sigma_rad": 0.0,
            "angular_rate_sigma_rad_s": ahrs.angular_rate_sigma_rad_s,
            "gyro_bias_sigma_rad_s": ahrs.gyro_bias_sigma_rad_s,
            "gyro_bias_walk_rad_s_per_sqrt_s": 0.0,  # constant over the mission
            "rate_hz": ahrs.rate_hz,
        },
        "depth": {"sigma_m": depth.sigma_m, "rate_hz": depth.rate_hz},
    }


def declared_noise(cfg: TankSimConfig) -> dict:
    """The sensor noise the simulator adds, in SI units, as estimators should assume it."""
    return {
        **nav_noise(cfg.dvl, cfg.ahrs, cfg.depth, cfg.trajectory.duration_s),
        "laser": {"range_sigma_m": cfg.laser.range_sigma_m, "rate_hz": cfg.laser.rate_hz},
        "ground_truth": {"rate_hz": cfg.ground_truth.rate_hz},
    }


@dataclass
class NavStreams:
    """What the navigation sensors and the ground truth of a simulated mission recorded."""

    dvl: S.DvlResult
    ahrs: list[Attitude]
    depth: list[Depth]
    ground_truth: list[GroundTruthPose]
    heading_bias: np.ndarray  # rad, at the AHRS samples
    gyro_bias: np.ndarray  # rad/s, the AHRS's sensor axes (constant)

    def measurements(self) -> list:
        return [*self.dvl.measurements, *self.ahrs, *self.depth, *self.ground_truth]


def simulate_nav(
    cfg,
    traj: MotionModel,
    scene: LabelledScene,
    start_ns: int,
    duration_s: float,
    **dvl_options,
) -> NavStreams:
    """DVL, AHRS, depth and ground truth over the mission, each at its rate and offset and from its
    own random stream; ``cfg`` is any simulator configuration with ``seed``, ``dvl``, ``ahrs``,
    ``depth`` and ``ground_truth`` sections; ``dvl_options`` go to :func:`sensors.simulate_dvl`."""
    seed, T = cfg.seed, duration_s
    st, t = S.sample_times(start_ns, cfg.dvl.rate_hz, T, offset_s=cfg.dvl.time_offset_s)
    dvl = S.simulate_dvl(cfg.dvl, traj, scene, st, t, _rng(seed, "dvl_noise"), _rng(seed, "dvl_dropout"), **dvl_options)
    st, t = S.sample_times(start_ns, cfg.ahrs.rate_hz, T, offset_s=cfg.ahrs.time_offset_s)
    bias = S.heading_bias(cfg.ahrs, t, T, _rng(seed, "heading_bias"))
    # its own stream: every other stream (and so every mission without a gyro bias) stays as it was
    gyro_bias = _rng(seed, "gyro_bias").normal(0.0, cfg.ahrs.gyro_bias_sigma_rad_s, 3)
    ahrs = S.simulate_ahrs(cfg.ahrs, traj, st, t, _rng(seed, "ahrs"), bias, gyro_bias)
    st, t = S.sample_times(start_ns, cfg.depth.rate_hz, T, offset_s=cfg.depth.time_offset_s)
    depth = S.simulate_depth(cfg.depth, traj, st, t, _rng(seed, "depth"))
    st, t = S.sample_times(start_ns, cfg.ground_truth.rate_hz, T)
    gt = S.ground_truth_poses(traj, st, t)
    return NavStreams(dvl, ahrs, depth, gt, bias, gyro_bias)


def sensor_infos(table: dict[str, tuple[str, str, str]], mounts: dict[str, np.ndarray]) -> dict[str, SensorInfo]:
    """``SensorInfo`` per sensor from a name → (kind, topic, message type) table and the T_BS mounts."""
    return {
        name: SensorInfo(name=name, kind=kind, topic=topic, msgtype=msgtype, T_BS=mounts[name])
        for name, (kind, topic, msgtype) in table.items()
    }


def dvl_dropout_extras(dvl: S.DvlResult) -> dict:
    return {"intervals_s": [[s, e, c] for s, e, c in dvl.intervals], "invalid_fraction": dvl.invalid_fraction}


def simulate_tank(config: TankSimConfig | None = None, *, progress: bool = False) -> Mission:
    """Simulate the tank mission in memory.

    The returned :class:`Mission` holds, in stamp order: ``DvlVelocity`` (sensor ``dvl``),
    ``Attitude`` (``ahrs``), ``Depth`` (``depth``), ``PointCloud`` (``laser``) and ``GroundTruthPose``
    (``ground_truth``). Its metadata carries the sensors (kind, topic, message type, T_BS), the
    ground-truth map (objects, pipes, and the ids hit by at least one laser ray) and ``extras``:
    ``noise`` (:func:`declared_noise`), ``scene`` (tank, layout, structure bounds), ``trajectory``,
    ``dvl_dropouts`` and ``simulator`` (the resolved configuration). Same config → same bytes.
    """
    cfg = config or TankSimConfig()
    layout = make_layout(cfg.structure, cfg.tank, cfg.seed)
    scene = TankScene(cfg.tank, layout)
    lo, hi = layout.bounds()
    center = np.array([*cfg.structure.center_xy_m, (lo[2] + hi[2]) / 2])
    traj = Trajectory(cfg.trajectory, center)
    start_ns = int(round(cfg.start_time_s * 1e9))
    T = cfg.trajectory.duration_s
    nav = simulate_nav(cfg, traj, scene, start_ns, T)
    st, t = S.sample_times(start_ns, cfg.laser.rate_hz, T, first=1)  # the first scan after one period
    laser = S.simulate_laser(cfg.laser, traj, scene, st, t, _rng(cfg.seed, "laser"), progress=progress)

    mounts = {
        "dvl": cfg.dvl.mount.matrix(),
        "ahrs": cfg.ahrs.mount.matrix(),
        "depth": cfg.depth.mount.matrix(),
        "laser": cfg.laser.mount.matrix(),
        "ground_truth": np.eye(4),
    }
    sensors = sensor_infos(SENSORS, mounts)
    ground_truth = layout.ground_truth(
        seen_objects=tuple(sorted(laser.seen_objects)), seen_pipes=tuple(sorted(laser.seen_pipes))
    )
    extras = {
        "simulator": {"name": "semslam.sim.tank", "seed": cfg.seed, "config": cfg.model_dump(mode="json")},
        "noise": declared_noise(cfg),
        "scene": {
            "kind": "tank",
            "tank": cfg.tank.model_dump(mode="json"),
            "surface_corners_xy": tank_surface_corners(cfg.tank).tolist(),
            "structure_bounds": [lo.tolist(), hi.tolist()],
            "structure_center": center.tolist(),
            "layout": layout.to_dict(),
        },
        "trajectory": {"center": center.tolist(), "duration_s": T, "loops": cfg.trajectory.loops},
        "dvl_dropouts": dvl_dropout_extras(nav.dvl),
        "heading_bias_final_rad": float(nav.heading_bias[-1]) if len(nav.heading_bias) else 0.0,
        "gyro_bias_rad_s": [float(b) for b in nav.gyro_bias],
    }
    meta = MissionMetadata(name=cfg.mission_name, sensors=sensors, ground_truth=ground_truth, extras=extras)
    return Mission.from_measurements(meta, [*nav.measurements(), *laser.measurements])


def simulate_tank_to_bag(
    out: str | Path,
    *,
    seed: int = 0,
    vary: Collection[str] = ASPECTS,
    dvl_dropout_rate: float | None = None,
    loops: float | None = None,
    preview: str | Path | None = None,
    config: str | Path | None = None,
    layout: str | Path | None = None,
    overwrite: bool = False,
    progress: bool = False,
) -> Mission:
    """What ``semslam simulate tank`` does: resolve the configuration (defaults ← what ``seed`` draws
    for the ``vary`` aspects, :mod:`semslam.sim.vary` ← YAML ``config`` ← the options given), simulate,
    write the bag (+ sidecar) at ``out`` and, if asked, the preview PNG.

    Options map to: ``seed`` → ``seed``; ``dvl_dropout_rate`` → ``dvl.random_dropout_rate``;
    ``loops`` → ``trajectory.loops`` (the duration follows unless ``trajectory.duration_s`` is set);
    ``layout`` → ``structure.layout_yaml``. Returns the simulated mission.
    """
    from semslam.sim.scenarios import simulate_with_options

    return simulate_with_options(
        "tank",
        out,
        seed=seed,
        vary=vary,
        config=config,
        preview=preview,
        overwrite=overwrite,
        progress=progress,
        dvl_dropout_rate=dvl_dropout_rate,
        loops=loops,
        layout=layout,
    )
