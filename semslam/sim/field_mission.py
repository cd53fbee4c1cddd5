"""``simulate_field``: the simulated sonar field mission (multibeam, DVL, AHRS, depth) with ground truth.

Sensor names / topics / message types of the field bag (the navigation sensors as in the tank):

================  ==========================  =============================
``dvl``           /sim/dvl                    cola2_msgs/msg/DVL
``ahrs``          /sim/imu                    sensor_msgs/msg/Imu
``depth``         /sim/pressure               sensor_msgs/msg/FluidPressure
``sonar``         /sim/sonar/scan             sensor_msgs/msg/LaserScan
``ground_truth``  /sim/ground_truth/odom      nav_msgs/msg/Odometry
================  ==========================  =============================
"""

from __future__ import annotations

from collections.abc import Collection
from pathlib import Path

import numpy as np

from semslam.mission.mission import Mission, MissionMetadata
from semslam.sim import sensors as S
from semslam.sim.drift import navigation_drift
from semslam.sim.field import KIND_NAMES, PIPE, SEABED, STRUCTURE, FieldScene, make_field
from semslam.sim.field_config import FieldSimConfig
from semslam.sim.lawnmower import Lawnmower
from semslam.sim.simulate import SENSORS as TANK_SENSORS
from semslam.sim.simulate import dvl_dropout_extras, nav_noise, sensor_infos, simulate_nav
from semslam.sim.sonar import beam_angles, simulate_sonar
from semslam.sim.streams import rng_stream
from semslam.sim.vary import ASPECTS

#: sensor name → (kind, topic, message type it is written as)
SENSORS = {
    **{k: v for k, v in TANK_SENSORS.items() if k != "laser"},
    "sonar": ("sonar", "/sim/sonar/scan", "sensor_msgs/msg/LaserScan"),
}

#: echo strength of each kind of surface (Lambertian intensity = reflectivity × |cos incidence|)
REFLECTIVITY = {SEABED: 0.35, STRUCTURE: 0.9, PIPE: 0.7}


def declared_noise(cfg: FieldSimConfig, duration_s: float) -> dict:
    """The sensor noise the simulator adds, in SI units, as estimators should assume it."""
    angles = beam_angles(cfg.sonar)
    return {
        **nav_noise(cfg.dvl, cfg.ahrs, cfg.depth, duration_s),
        "sonar": {
            "range_sigma_m": cfg.sonar.range_sigma_m,
            "rate_hz": cfg.sonar.rate_hz,
            "n_beams": cfg.sonar.n_beams,
            "angle_min_rad": float(angles[0]),
            "angle_increment_rad": float(angles[1] - angles[0]),
            "beam_width_modelled": False,
        },
        "ground_truth": {"rate_hz": cfg.ground_truth.rate_hz},
    }


def simulate_field(config: FieldSimConfig | None = None, *, progress: bool = False) -> Mission:
    """Simulate the sonar field mission in memory.

    The returned :class:`Mission` holds, in stamp order: ``DvlVelocity`` (sensor ``dvl``),
    ``Attitude`` (``ahrs``), ``Depth`` (``depth``), ``SonarSwath`` (``sonar``) and
    ``GroundTruthPose`` (``ground_truth``). Its metadata carries the sensors (kind, topic, message
    type, T_BS), the ground-truth map (three structures, two pipelines, the ids hit by at least one
    sonar beam; ``extras["pipeline_connections"]`` = {pipe id: [structure ids]}) and ``extras``:
    ``noise`` (:func:`declared_noise`), ``scene`` (area, seabed parameters, layout), ``trajectory``
    (lines), ``sonar`` (counts, raw cloud bytes), ``navigation_drift`` (:mod:`semslam.sim.drift`),
    ``dvl_dropouts`` and ``simulator`` (the resolved configuration). Same config → same bytes.
    """
    cfg = config or FieldSimConfig()
    field = make_field(cfg)
    scene = FieldScene(field)
    traj = Lawnmower(cfg.trajectory, cfg.seabed)
    start_ns = int(round(cfg.start_time_s * 1e9))
    T = traj.duration
    nav = simulate_nav(cfg, traj, scene, start_ns, T, lost_kinds=(), lost_cause="no bottom lock")
    st, t = S.sample_times(start_ns, cfg.sonar.rate_hz, T, first=1, offset_s=cfg.sonar.time_offset_s)
    sonar = simulate_sonar(
        cfg.sonar, traj, scene, st, t, rng_stream(cfg.seed, "sonar"), REFLECTIVITY, progress=progress
    )

    mounts = {
        "dvl": cfg.dvl.mount.matrix(),
        "ahrs": cfg.ahrs.mount.matrix(),
        "depth": cfg.depth.mount.matrix(),
        "sonar": cfg.sonar.mount.matrix(),
        "ground_truth": np.eye(4),
    }
    ground_truth = field.ground_truth(
        seen_structures=tuple(sorted(sonar.seen[STRUCTURE])), seen_pipes=tuple(sorted(sonar.seen[PIPE]))
    )
    half_n, half_e = np.array(cfg.seabed.area_m) / 2
    extras = {
        "simulator": {"name": "semslam.sim.field", "seed": cfg.seed, "config": cfg.model_dump(mode="json")},
        "noise": declared_noise(cfg, T),
        "scene": {
            "kind": "field",
            "area": {"north_m": [-half_n, half_n], "east_m": [-half_e, half_e]},
            "seabed": field.seabed.to_dict(),
            "layout": field.to_dict(),
            "geometry_kinds": list(KIND_NAMES),
        },
        "trajectory": {
            "kind": "lawnmower",
            "duration_s": T,
            "speed_m_s": cfg.trajectory.speed_m_s,
            "depth_m": traj.depth,
            "line_spacing_m": cfg.trajectory.line_spacing_m,
            "turn_length_m": traj.turn_length,
            "lines": traj.lines(),
        },
        "sonar": {
            "swaths": len(sonar.measurements),
            "points": sonar.n_points,
            "raw_cloud_bytes": sonar.n_points * 3 * 4,  # as x, y, z float32
        },
        "dvl_dropouts": dvl_dropout_extras(nav.dvl),
        "heading_bias_final_rad": float(nav.heading_bias[-1]) if len(nav.heading_bias) else 0.0,
        "gyro_bias_rad_s": [float(b) for b in nav.gyro_bias],
    }
    meta = MissionMetadata(
        name=cfg.mission_name, sensors=sensor_infos(SENSORS, mounts), ground_truth=ground_truth, extras=extras
    )
    mission = Mission.from_measurements(meta, [*nav.measurements(), *sonar.measurements])
    extras["navigation_drift"] = navigation_drift(mission)
    return mission


def simulate_field_to_bag(
    out: str | Path,
    *,
    seed: int = 0,
    vary: Collection[str] = ASPECTS,
    dvl_dropout_rate: float | None = None,
    preview: str | Path | None = None,
    config: str | Path | None = None,
    overwrite: bool = False,
    progress: bool = False,
) -> Mission:
    """What ``semslam simulate field`` does: resolve the configuration (defaults ← what ``seed`` draws
    for the ``vary`` aspects, :mod:`semslam.sim.vary` ← YAML ``config`` ← the options given), simulate,
    write the bag (+ sidecar) at ``out`` and, if asked, the preview PNG.
    ``dvl_dropout_rate`` → ``dvl.random_dropout_rate``. Returns the simulated mission."""
    from semslam.sim.scenarios import simulate_with_options

    return simulate_with_options(
        "field",
        out,
        seed=seed,
        vary=vary,
        config=config,
        preview=preview,
        overwrite=overwrite,
        progress=progress,
        dvl_dropout_rate=dvl_dropout_rate,
    )
