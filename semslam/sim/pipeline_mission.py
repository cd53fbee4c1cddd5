"""``simulate_pipeline``: the simulated pipeline mission (stereo camera, DVL, AHRS, depth) with ground truth.

A pipeline on a natural seabed (:mod:`semslam.sim.pipeline_scene`) seen by a down/forward-looking
stereo camera (:mod:`semslam.sim.stereo`) from a vehicle that inspects the main line there and
back (:class:`InspectionTrack`). Sensor names / topics / message types (the navigation sensors as in the tank):

================  ==========================  ==============================
``dvl``           /sim/dvl                    cola2_msgs/msg/DVL
``ahrs``          /sim/imu                    sensor_msgs/msg/Imu
``depth``         /sim/pressure               sensor_msgs/msg/FluidPressure
``stereo``        /sim/stereo/points          sensor_msgs/msg/PointCloud2 (organised, NaN where
                                              stereo fails, with rgb; sensor kind ``laser``)
``ground_truth``  /sim/ground_truth/odom      nav_msgs/msg/Odometry
================  ==========================  ==============================
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from semslam.mission.mission import Mission, MissionMetadata
from semslam.sim import sensors as S
from semslam.sim.pipeline_config import PipelineSimConfig, PipelineTrajectoryConfig
from semslam.sim.pipeline_scene import (
    KIND_NAMES,
    Line,
    PipelineScene,
    make_pipeline,
    make_rocks,
    make_seabed,
)
from semslam.sim.simulate import SENSORS as TANK_SENSORS
from semslam.sim.simulate import dvl_dropout_extras, nav_noise, sensor_infos, simulate_nav
from semslam.sim.stereo import depth_sigma, focal_px, simulate_stereo
from semslam.sim.trajectory import MotionModel

#: sensor name → (kind, topic, message type it is written as)
SENSORS = {
    **{k: v for k, v in TANK_SENSORS.items() if k != "laser"},
    "stereo": ("laser", "/sim/stereo/points", "sensor_msgs/msg/PointCloud2"),
}

# This scenario's own random streams (semslam.sim.streams holds the tank's and the field's): the
# ids are fixed forever, so that a mission is reproducible from its seed.
_STREAMS = {"pipeline_seabed": 101, "pipeline_layout": 102, "pipeline_rocks": 103, "stereo": 104, "scene": 105}


def _stream(seed: int, purpose: str) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence([seed, _STREAMS[purpose]]))


class InspectionTrack(MotionModel):
    """T_WB(t) of the inspection (:class:`~semslam.sim.pipeline_config.PipelineTrajectoryConfig`):
    along the main line there and back, swaying sideways, facing along it with a heading wobble.
    Position and velocity analytic."""

    def __init__(self, cfg: PipelineTrajectoryConfig, line: Line):
        self.cfg = cfg
        d = line.direction
        horizontal = np.hypot(d[0], d[1])
        self.u = np.array([d[0], d[1], 0.0]) / horizontal  # horizontal along the line
        self.w = np.array([-self.u[1], self.u[0], 0.0])
        self.slope = d[2] / horizontal  # dz per horizontal metre
        self.heading = float(np.arctan2(self.u[1], self.u[0]))
        self.half_span = 0.5 * horizontal * line.length + cfg.margin_m
        self.centre = line.origin + 0.5 * line.length * d - np.array([0.0, 0.0, cfg.altitude_m])
        self.centre = self.centre - cfg.view_lead_m * (self.u + self.slope * np.array([0.0, 0.0, 1.0]))
        self.pass_s = np.pi * self.half_span / cfg.speed_m_s  # top speed mid-pass
        self.T = cfg.duration_s if cfg.duration_s is not None else cfg.passes * self.pass_s

    @property
    def duration(self) -> float:
        return self.T

    def position_velocity(self, t) -> tuple[np.ndarray, np.ndarray]:
        t = np.atleast_1d(np.asarray(t, float))
        c = self.cfg
        w_s = np.pi / self.pass_s
        s, ds = -self.half_span * np.cos(w_s * t), self.half_span * w_s * np.sin(w_s * t)
        w_y = 2 * np.pi / c.sway_period_s
        y, dy = c.sway_amplitude_m * np.sin(w_y * t), c.sway_amplitude_m * w_y * np.cos(w_y * t)
        along = self.u + self.slope * np.array([0.0, 0.0, 1.0])
        return self.centre + np.outer(s, along) + np.outer(y, self.w), np.outer(ds, along) + np.outer(dy, self.w)

    def rotation(self, t) -> Rotation:
        t = np.atleast_1d(np.asarray(t, float))
        c = self.cfg
        yaw = self.heading + np.radians(c.yaw_amplitude_deg) * np.sin(2 * np.pi * t / c.yaw_period_s)
        A = np.deg2rad(c.roll_pitch_amplitude_deg)
        roll = A * np.sin(2 * np.pi * t / 7.3)
        pitch = A * np.sin(2 * np.pi * t / 11.1 + 0.7)
        return Rotation.from_euler("ZYX", np.stack([yaw, pitch, roll], 1))


def declared_noise(cfg: PipelineSimConfig, duration_s: float) -> dict:
    """The sensor noise the simulator adds, in SI units, as estimators should assume it."""
    st = cfg.stereo
    return {
        **nav_noise(cfg.dvl, cfg.ahrs, cfg.depth, duration_s),
        "stereo": {
            "model": "depth sigma_z = z^2 * disparity_sigma_px / (focal_px * baseline_m), along each pixel's ray",
            "disparity_sigma_px": st.disparity_sigma_px,
            "focal_px": focal_px(st),
            "baseline_m": st.baseline_m,
            "depth_sigma_at_1m_m": float(depth_sigma(st, 1.0)),
            "rate_hz": st.rate_hz,
            "organised": list(st.resolution),
        },
        "ground_truth": {"rate_hz": cfg.ground_truth.rate_hz},
    }


def simulate_pipeline(config: PipelineSimConfig | None = None, *, progress: bool = False) -> Mission:
    """Simulate the pipeline mission in memory.

    The returned :class:`Mission` holds, in stamp order: ``DvlVelocity`` (sensor ``dvl``),
    ``Attitude`` (``ahrs``), ``Depth`` (``depth``), ``PointCloud`` (``stereo``: organised,
    width × height points with NaN where stereo failed, and ``rgb``) and ``GroundTruthPose``
    (``ground_truth``). Its metadata carries the sensors (kind, topic, message type, T_BS), the
    ground-truth map (fittings as objects, straight pipe pieces as pipes, the ids seen by at least
    one valid point) and ``extras``: ``noise`` (:func:`declared_noise`), ``scene`` (seabed, lines,
    layout with each fitting's scale, rocks), ``scans`` (per cloud: the visible length of each pipe,
    the points on each fitting and on rocks), ``trajectory``, ``dvl_dropouts`` and ``simulator``
    (the resolved configuration). Same config → same bytes.
    """
    cfg = config or PipelineSimConfig()
    lay_rng = _stream(cfg.seed, "pipeline_layout")
    heading = float(lay_rng.uniform(0, 2 * np.pi))
    length = float(lay_rng.uniform(*cfg.layout.length_m))
    half_length = 0.5 * length + cfg.seabed.margin_m
    seabed = make_seabed(cfg.seabed, heading, half_length, _stream(cfg.seed, "pipeline_seabed"))
    layout = make_pipeline(cfg.layout, seabed, heading, length, lay_rng)
    rocks = make_rocks(cfg.seabed, seabed, layout, _stream(cfg.seed, "pipeline_rocks"))
    scene = PipelineScene(seabed, rocks, layout, cfg.seabed.roughness_m, _stream(cfg.seed, "scene"))
    traj = InspectionTrack(cfg.trajectory, layout.lines[0])
    start_ns = int(round(cfg.start_time_s * 1e9))
    T = traj.duration
    nav = simulate_nav(cfg, traj, scene, start_ns, T, lost_kinds=(), lost_cause="no bottom lock")
    st, t = S.sample_times(start_ns, cfg.stereo.rate_hz, T, first=1, offset_s=cfg.stereo.time_offset_s)
    stereo = simulate_stereo(cfg.stereo, traj, scene, st, t, _stream(cfg.seed, "stereo"), progress=progress)

    mounts = {
        "dvl": cfg.dvl.mount.matrix(),
        "ahrs": cfg.ahrs.mount.matrix(),
        "depth": cfg.depth.mount.matrix(),
        "stereo": cfg.stereo.mount.matrix(),
        "ground_truth": np.eye(4),
    }
    ground_truth = layout.ground_truth(
        seen_objects=tuple(sorted(stereo.seen_objects)), seen_pipes=tuple(sorted(stereo.seen_pipes))
    )
    extras = {
        "simulator": {"name": "semslam.sim.pipeline", "seed": cfg.seed, "config": cfg.model_dump(mode="json")},
        "noise": declared_noise(cfg, T),
        "scene": {
            "kind": "pipeline",
            "seabed": seabed.relief.to_dict()
            | {
                "ripple_amplitude_m": seabed.ripple_amplitude,
                "ripple_wavelength_m": seabed.ripple_wavelength,
                "note": "relief only: the ripples' slowly varying phase and amplitude are not stored",
            },
            "layout": layout.to_dict(),
            "rocks": [{"id": r.id, "center": r.center.tolist(), "radii": r.radii.tolist()} for r in rocks],
            "geometry_kinds": list(KIND_NAMES),
        },
        "scans": [s.to_dict() for s in stereo.scans],
        "trajectory": {"kind": "inspection", "duration_s": T, "passes": cfg.trajectory.passes},
        "dvl_dropouts": dvl_dropout_extras(nav.dvl),
        "heading_bias_final_rad": float(nav.heading_bias[-1]) if len(nav.heading_bias) else 0.0,
        "gyro_bias_rad_s": [float(b) for b in nav.gyro_bias],
    }
    meta = MissionMetadata(
        name=cfg.mission_name, sensors=sensor_infos(SENSORS, mounts), ground_truth=ground_truth, extras=extras
    )
    return Mission.from_measurements(meta, [*nav.measurements(), *stereo.measurements])
