"""``simulate_dive``: a field dive with surface GPS before and after (DVL, AHRS, depth, GPS, ground truth).

The vehicle follows the field's east–west lawnmower (:mod:`semslam.sim.lawnmower`, seven lines) from
the first second to the last, at its speed; only its depth changes: ``surface_start_s`` at the
surface (GPS fixes), a descent to the working depth over ``descent_s`` (quintic smoothstep), the
pattern submerged, an ascent over ``ascent_s`` and ``surface_end_s`` at the surface again. The DVL has its
random dropouts (5 % of the time in 2–8 s bursts by default) and the AHRS heading bias drifts 3°:
what a navigation-only run has to bridge between the fixes. No sonar is simulated (``dive.sonar``
adds it). Sensor names, topics and message types as in the field, plus:

================  ==========================  =============================
``gps``           /sim/gps/fix                sensor_msgs/msg/NavSatFix
================  ==========================  =============================
"""

from __future__ import annotations

import numpy as np
from pydantic import Field
from scipy.spatial.transform import Rotation

from semslam.errors import ConfigError
from semslam.mission.geodesy import Geodetic
from semslam.mission.mission import Mission, MissionMetadata
from semslam.sim import sensors as S
from semslam.sim.config import _Section
from semslam.sim.field import PIPE, STRUCTURE, FieldScene, make_field
from semslam.sim.field_config import (
    FieldAhrsConfig,
    FieldDvlConfig,
    FieldSimConfig,
    FieldTrajectoryConfig,
    GpsConfig,
)
from semslam.sim.field_mission import REFLECTIVITY
from semslam.sim.field_mission import SENSORS as FIELD_SENSORS
from semslam.sim.field_mission import declared_noise as field_noise
from semslam.sim.lawnmower import Lawnmower
from semslam.sim.simulate import dvl_dropout_extras, sensor_infos, simulate_nav
from semslam.sim.sonar import simulate_sonar
from semslam.sim.streams import rng_stream
from semslam.sim.trajectory import MotionModel, smoothstep

GPS_SENSOR = ("gps", "/sim/gps/fix", "sensor_msgs/msg/NavSatFix")


class DiveProfileConfig(_Section):
    """The depth profile of the dive, within the survey pattern (``trajectory``): the vehicle follows
    the pattern at the surface too, before the descent and after the ascent."""

    surface_start_s: float = Field(45.0, ge=0, description="time at the surface before diving (s)")
    descent_s: float = Field(60.0, gt=0, description="from the surface to the working depth (s)")
    ascent_s: float = Field(60.0, gt=0, description="from the working depth back to the surface (s)")
    surface_end_s: float = Field(45.0, ge=0, description="time at the surface after resurfacing (s)")
    sonar: bool = Field(False, description="also simulate the multibeam (slow: a navigation dive needs none)")


# The dive's own defaults live in its sections' classes: a section given in part (a YAML file, a
# seed's draws) is built from its class's defaults, not from the parent's default instance.
class DiveTrajectoryConfig(FieldTrajectoryConfig):
    """The field's lawnmower, seven lines by default (≈ 13.5 min at 0.5 m/s)."""

    lines: int = Field(7, ge=1, description="survey lines (the first at the south, heading east)")


class DiveDvlConfig(FieldDvlConfig):
    """The field's DVL with dropouts 5 % of the time, in 2–8 s bursts."""

    random_dropout_rate: float = Field(
        0.05, ge=0, lt=0.9, description="fraction of the mission lost to random dropout bursts"
    )
    burst_s: tuple[float, float] = Field((2.0, 8.0), description="min, max length of a random dropout burst (s)")


class DiveAhrsConfig(FieldAhrsConfig):
    """A magnetic heading: its bias drifts 3° over the mission."""

    heading_bias_drift_deg: float = Field(
        3.0, ge=0, description="the heading bias drifts linearly by this much over the mission (sign from the seed)"
    )


class DiveSimConfig(FieldSimConfig):
    """A field mission (:class:`FieldSimConfig`) as a dive from and back to the surface, with a GPS:
    seven survey lines (≈ 13.5 min, ≈ 11.5 min of it submerged by default)."""

    name: str | None = Field(None, description="mission name (default dive-seed<N>)")
    trajectory: DiveTrajectoryConfig = Field(default_factory=DiveTrajectoryConfig)
    dvl: DiveDvlConfig = Field(default_factory=DiveDvlConfig)
    ahrs: DiveAhrsConfig = Field(default_factory=DiveAhrsConfig)
    dive: DiveProfileConfig = Field(default_factory=DiveProfileConfig)
    gps: GpsConfig = Field(default_factory=GpsConfig)

    @property
    def mission_name(self) -> str:
        return self.name or f"dive-seed{self.seed}"


class DiveTrajectory(MotionModel):
    """T_WB(t) of the dive: the lawnmower's horizontal path and attitude over the whole mission, the
    dive's depth profile (surface, descent, working depth, ascent, surface) within it."""

    def __init__(self, cfg: DiveSimConfig):
        p = cfg.dive
        self.path = Lawnmower(cfg.trajectory, cfg.seabed)
        self.depth = self.path.depth
        self.T = self.path.duration
        self.t_down = p.surface_start_s
        self.t_up = self.T - p.surface_end_s - p.ascent_s
        self.descent_s, self.ascent_s = p.descent_s, p.ascent_s
        if self.t_up < self.t_down + p.descent_s:
            raise ConfigError(
                f"dive: the mission ({self.T:.0f} s) is shorter than its surface, descent and ascent times"
            )

    @property
    def duration(self) -> float:
        return self.T

    def depth_profile(self, t) -> tuple[np.ndarray, np.ndarray]:
        """Depth of the body origin (m) and its rate (m/s) at times t."""
        t = np.atleast_1d(np.asarray(t, float))
        down, d_down, _ = smoothstep((t - self.t_down) / self.descent_s)
        up, d_up, _ = smoothstep((t - self.t_up) / self.ascent_s)
        return self.depth * (down - up), self.depth * (d_down / self.descent_s - d_up / self.ascent_s)

    def position_velocity(self, t) -> tuple[np.ndarray, np.ndarray]:
        p, v = self.path.position_velocity(t)
        p[:, 2], v[:, 2] = self.depth_profile(t)
        return p, v

    def rotation(self, t) -> Rotation:
        return self.path.rotation(t)

    def submerged_s(self, surface_depth_m: float) -> float:
        """Time spent deeper than ``surface_depth_m`` (no GPS fix), on a 0.1 s grid."""
        t = np.arange(0.0, self.T, 0.1)
        return float(np.sum(self.depth_profile(t)[0] > surface_depth_m) * 0.1)


def simulate_dive(config: DiveSimConfig | None = None, *, progress: bool = False) -> Mission:
    """Simulate the dive in memory: ``DvlVelocity`` (``dvl``), ``Attitude`` (``ahrs``), ``Depth``
    (``depth``), ``GpsFix`` (``gps``, at the surface only), ``GroundTruthPose`` (``ground_truth``)
    and, with ``dive.sonar``, ``SonarSwath`` (``sonar``). Metadata as the field's, plus the datum,
    ``extras["noise"]["gps"]`` and ``extras["dive"]`` (its phases and the time submerged)."""
    cfg = config or DiveSimConfig()
    field = make_field(cfg)
    scene = FieldScene(field)
    traj = DiveTrajectory(cfg)
    start_ns = int(round(cfg.start_time_s * 1e9))
    T = traj.duration
    nav = simulate_nav(cfg, traj, scene, start_ns, T, lost_kinds=(), lost_cause="no bottom lock")
    st, t = S.sample_times(start_ns, cfg.gps.rate_hz, T, offset_s=cfg.gps.time_offset_s)
    gps = S.simulate_gps(cfg.gps, traj, st, t, rng_stream(cfg.seed, "gps"))
    table = {**{k: v for k, v in FIELD_SENSORS.items() if k != "sonar"}, "gps": GPS_SENSOR}
    mounts = {
        "dvl": cfg.dvl.mount.matrix(),
        "ahrs": cfg.ahrs.mount.matrix(),
        "depth": cfg.depth.mount.matrix(),
        "gps": cfg.gps.mount.matrix(),
        "ground_truth": np.eye(4),
    }
    scans: list = []
    seen: tuple = ((), ())
    if cfg.dive.sonar:
        st, t = S.sample_times(start_ns, cfg.sonar.rate_hz, T, first=1, offset_s=cfg.sonar.time_offset_s)
        sonar = simulate_sonar(
            cfg.sonar, traj, scene, st, t, rng_stream(cfg.seed, "sonar"), REFLECTIVITY, progress=progress
        )
        scans, seen = sonar.measurements, (sorted(sonar.seen[STRUCTURE]), sorted(sonar.seen[PIPE]))
        table["sonar"], mounts["sonar"] = FIELD_SENSORS["sonar"], cfg.sonar.mount.matrix()
    noise = {k: v for k, v in field_noise(cfg, T).items() if k in table}
    noise["gps"] = {
        "horizontal_sigma_m": cfg.gps.horizontal_sigma_m,
        "vertical_sigma_m": cfg.gps.vertical_sigma_m,
        "rate_hz": cfg.gps.rate_hz,
    }
    extras = {
        "simulator": {"name": "semslam.sim.dive", "seed": cfg.seed, "config": cfg.model_dump(mode="json")},
        "noise": noise,
        "scene": {"kind": "field", "seabed": field.seabed.to_dict(), "layout": field.to_dict()},
        "trajectory": {"kind": "dive", "duration_s": T, "speed_m_s": cfg.trajectory.speed_m_s, "depth_m": traj.depth},
        "dive": {
            "surface_until_s": traj.t_down,
            "ascent_from_s": traj.t_up,
            "submerged_s": traj.submerged_s(cfg.gps.surface_depth_m),
            "gps_fixes": len(gps),
        },
        "dvl_dropouts": dvl_dropout_extras(nav.dvl),
        "heading_bias_final_rad": float(nav.heading_bias[-1]) if len(nav.heading_bias) else 0.0,
        "gyro_bias_rad_s": [float(b) for b in nav.gyro_bias],
    }
    meta = MissionMetadata(
        name=cfg.mission_name,
        sensors=sensor_infos(table, mounts),
        ground_truth=field.ground_truth(seen_structures=tuple(seen[0]), seen_pipes=tuple(seen[1])),
        extras=extras,
        datum=Geodetic(*cfg.gps.datum_deg, 0.0),
    )
    return Mission.from_measurements(meta, [*nav.measurements(), *gps, *scans])


def describe(mission: Mission) -> str:
    """One line for ``semslam simulate dive``."""
    d = mission.metadata.extras["dive"]
    return f"{d['submerged_s'] / 60:.1f} min submerged, {d['gps_fixes']} surface GPS fixes"


def render_preview(mission: Mission, png) -> None:
    """The true track (north–east) with the GPS fixes, and the depth over time."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from semslam.mission.measurements import GpsFix, GroundTruthPose

    truth = np.array([[m.stamp, *m.position] for m in mission.of_type(GroundTruthPose)])
    fixes = np.array([m.position for m in mission.of_type(GpsFix)]).reshape(-1, 3)
    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4.5))
    a.plot(truth[:, 2], truth[:, 1], lw=0.8, label="true track")
    a.plot(fixes[:, 1], fixes[:, 0], ".", ms=3, label="GPS fixes")
    a.set(xlabel="east (m)", ylabel="north (m)", aspect="equal", title=mission.metadata.name)
    a.legend()
    b.plot((truth[:, 0] - truth[0, 0]) * 1e-9, truth[:, 3], lw=0.8)
    b.set(xlabel="t (s)", ylabel="depth (m)", title="depth")
    b.invert_yaxis()
    fig.tight_layout()
    fig.savefig(png, dpi=100)
    plt.close(fig)
