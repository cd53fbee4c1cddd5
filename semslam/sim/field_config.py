"""Configuration of the simulated sonar field mission: every default is documented in its Field.

The field (issue 8): a 34 m (north) × 50 m (east) surveyed area of seabed at ~20 m with a smooth
relief (±0.8 m), three CAD-known structures (PLET, manifold, wellhead; :mod:`semslam.models.structures`)
joined by two pipelines (radius 0.25 m PLET → manifold, 0.10 m manifold → wellhead). The vehicle
flies six east–west lines 5.5 m apart at 5 m altitude and 0.5 m/s (≈ 11.5 minutes), with a
downward multibeam of 512 beams over 80° every 4 cm along track (12.5 Hz), a DVL (5 Hz), an AHRS
(20 Hz) and a depth sensor (8 Hz); their noise is the tank's (issue 3), the heading bias drifting
1.5° over the mission.

Frames as in :mod:`semslam.sim.config`: world {W} NED with its origin at the surface above the
centre of the surveyed area (north = x, east = y, depth = z); body {B} x forward / y right / z down;
mounts T_BS by translation and roll/pitch/yaw in degrees.
"""

from __future__ import annotations

from pathlib import Path

from pydantic import Field, model_validator

from semslam.sim.config import (
    AhrsConfig,
    DepthConfig,
    DvlConfig,
    GroundTruthConfig,
    Mount,
    _Section,
    load_sim_config,
)


class SeabedConfig(_Section):
    """The seabed: mean depth, seeded relief (gaussian bumps + a gentle slope), the ray-cast grid."""

    area_m: tuple[float, float] = Field(
        (34.0, 50.0), description="surveyed area, north × east extents (m), centred under the world origin"
    )
    depth_m: float = Field(20.0, gt=0, description="mean seabed depth over the surveyed area (m)")
    relief_m: float = Field(0.8, ge=0, le=5, description="the relief reaches ±this about the mean depth (m)")
    bumps: int = Field(6, ge=0, le=50, description="gaussian bumps of the relief")
    bump_sigma_m: tuple[float, float] = Field((5.0, 12.0), description="min, max width (σ) of a bump (m)")
    slope_share: float = Field(0.3, ge=0, lt=1, description="share of the relief made by a planar slope")
    resolution_m: float = Field(0.25, gt=0.02, le=2, description="spacing of the seabed triangle grid (m)")
    margin_m: float = Field(
        8.0, ge=0, description="the seabed extends this far beyond the surveyed area (turns, outer beams) (m)"
    )
    pad_margin_m: float = Field(
        0.3, ge=0, description="a structure stands on a levelled pad this much wider than its footprint (m)"
    )
    pad_blend_m: float = Field(2.0, gt=0, description="the pad blends back into the relief over this distance (m)")


class FieldLayoutConfig(_Section):
    """Where the three structures stand and how the two pipelines join them (seeded)."""

    chain: tuple[str, str, str] = Field(
        ("plet", "manifold", "wellhead"),
        description="structure models A, B, C (ids 0, 1, 2): pipeline 0 joins A–B, pipeline 1 B–C",
    )
    pipe_radii_m: tuple[float, float] = Field(
        (0.25, 0.10), description="radius of pipeline 0 (A–B) and pipeline 1 (B–C); each joins hubs of that size (m)"
    )
    pipe_length_m: tuple[float, float] = Field((7.0, 14.0), description="min, max horizontal hub-to-hub length (m)")
    max_hub_angle_deg: float = Field(
        25.0, ge=0, le=90, description="a pipeline leaves each hub within this angle of the hub's direction (deg)"
    )
    edge_margin_m: float = Field(3.0, ge=0, description="footprints stay this far inside the surveyed area (m)")
    min_gap_m: float = Field(
        3.0, ge=0, description="clearance between footprints, and between a pipeline and a structure it misses (m)"
    )
    max_span_gap_m: float = Field(0.6, gt=0, description="largest gap under a pipeline where the seabed falls (m)")
    max_burial: float = Field(
        0.5, ge=0, le=1, description="largest buried share of a pipeline's diameter where the seabed rises"
    )


class FieldTrajectoryConfig(_Section):
    """East–west lawnmower at constant depth: lines step north, joined by smooth half-turns."""

    lines: int = Field(6, ge=1, description="survey lines (the first at the south, heading east)")
    line_spacing_m: float = Field(
        5.5, gt=0, description="between neighbouring lines (m); 5.5 m: ~30 % swath overlap on a flat seabed"
    )
    line_length_m: float | None = Field(None, gt=0, description="length of a line (m); default the area's east extent")
    center_m: tuple[float, float] | None = Field(
        None, description="centre (north, east) of the pattern (m); default the centre of the surveyed area"
    )
    speed_m_s: float = Field(0.5, gt=0, le=3, description="speed over ground, constant (m/s)")
    altitude_m: float = Field(5.0, gt=0, description="the vehicle keeps depth = mean seabed depth − this (m)")
    roll_pitch_amplitude_deg: float = Field(0.5, ge=0, description="amplitude of the roll/pitch wobble (deg)")
    duration_s: float | None = Field(
        None, gt=0, description="mission length (s); default the whole pattern (beyond it, the last line continues)"
    )


class SonarConfig(_Section):
    """Downward multibeam: one ray per beam across track; beam i along (0, sin a_i, cos a_i) in {S}.

    The beams' widths (along and across track) are not modelled: each beam is one ray on its axis.
    """

    rate_hz: float = Field(12.5, gt=0, description="swaths per second (12.5 Hz at 0.5 m/s: one every 4 cm)")
    time_offset_s: float = Field(0.0, ge=0, lt=1, description="first swath one period plus this after the start")
    n_beams: int = Field(512, ge=2, le=4096, description="beams per swath, evenly spaced across the fan")
    swath_deg: float = Field(80.0, gt=0, lt=180, description="across-track opening of the fan (deg)")
    range_sigma_m: float = Field(0.015, gt=0, description="white range noise along each beam (m)")
    min_range_m: float = Field(0.5, ge=0, description="closer returns are dropped (m)")
    max_range_m: float = Field(30.0, gt=0, description="farther returns are dropped (m)")
    mount: Mount = Field(
        default_factory=lambda: Mount(xyz=(0.45, 0.0, 0.30)),
        description="under the bow, axes as {B}: z looks down, positive beam angles to starboard",
    )


class GpsConfig(_Section):
    """GPS receiver on a mast: fixes of its antenna in {W}, only while the vehicle is at the surface.

    The fixes are written as ``sensor_msgs/NavSatFix`` about the datum below, their declared
    covariance exactly the noise added. Noise is drawn for every sample, at the surface or not, so
    that the depth profile does not reshuffle it.
    """

    rate_hz: float = Field(1.0, gt=0, description="fixes per second while at the surface")
    time_offset_s: float = Field(0.37, ge=0, lt=1, description="first fix this long after the mission start")
    horizontal_sigma_m: float = Field(0.5, gt=0, description="white noise of north and east (m): an SBAS-class fix")
    vertical_sigma_m: float = Field(1.0, gt=0, description="white noise of the antenna's height (m)")
    surface_depth_m: float = Field(
        0.2, ge=0, description="a fix only while the body origin is shallower than this (the antenna above water) (m)"
    )
    datum_deg: tuple[float, float] = Field(
        (41.9876, 3.2131), description="latitude, longitude (WGS84, deg) of the world origin, height 0"
    )
    mount: Mount = Field(
        default_factory=lambda: Mount(xyz=(-0.4, 0.0, -0.6)), description="antenna 0.4 m aft, 0.6 m above the origin"
    )


# The field's own defaults live in its sections' classes: a section given in part (a YAML file, a
# seed's draws of some aspects) is built from its class's defaults, not from a default instance.
class FieldDvlConfig(DvlConfig):
    """The tank's DVL with occasional short dropouts: 2 % of the time, 1–4 s bursts."""

    random_dropout_rate: float = Field(
        0.02, ge=0, lt=0.9, description="fraction of the mission lost to random dropout bursts"
    )
    burst_s: tuple[float, float] = Field((1.0, 4.0), description="min and max duration of a dropout burst (s)")


class FieldAhrsConfig(AhrsConfig):
    """The tank's AHRS with the heading bias drifting 1.5° over the mission."""

    heading_bias_drift_deg: float = Field(
        1.5, ge=0, description="the heading bias drifts linearly by this much over the mission (sign from the seed)"
    )


class FieldGroundTruthConfig(GroundTruthConfig):
    """True body poses at 25 Hz, a multiple of the sonar's 12.5 Hz (it keeps the bag small)."""

    rate_hz: float = Field(25.0, ge=20, description="rate of the true body poses (Hz)")


class FieldSimConfig(_Section):
    """Everything that defines a simulated sonar field mission. Same config (incl. seed) → same bytes.

    The DVL, AHRS and depth sections are the tank's (:mod:`semslam.sim.config`); in the field the DVL
    has occasional short dropouts (2 % of the time, 1–4 s bursts) and no walls (``wall_beams_lost``
    has no effect), the heading bias drifts 1.5° over the mission, and the ground truth is written
    at 25 Hz (a multiple of the sonar's 12.5 Hz; it keeps the bag small).
    """

    seed: int = Field(0, ge=0, description="random seed of the seabed, the layout and every sensor's noise")
    name: str | None = Field(None, description="mission name (default field-seed<N>)")
    start_time_s: float = Field(1.7e9, ge=0, description="stamp of the first sample (s since the epoch)")
    seabed: SeabedConfig = Field(default_factory=SeabedConfig)
    layout: FieldLayoutConfig = Field(default_factory=FieldLayoutConfig)
    trajectory: FieldTrajectoryConfig = Field(default_factory=FieldTrajectoryConfig)
    dvl: FieldDvlConfig = Field(default_factory=FieldDvlConfig)
    ahrs: FieldAhrsConfig = Field(default_factory=FieldAhrsConfig)
    depth: DepthConfig = Field(default_factory=DepthConfig)
    sonar: SonarConfig = Field(default_factory=SonarConfig)
    ground_truth: FieldGroundTruthConfig = Field(
        default_factory=FieldGroundTruthConfig, description="25 Hz: every swath stamp is a ground-truth stamp"
    )

    @model_validator(mode="after")
    def _check(self):
        for key, (lo, hi) in (
            ("dvl.burst_s", self.dvl.burst_s),
            ("seabed.bump_sigma_m", self.seabed.bump_sigma_m),
            ("layout.pipe_length_m", self.layout.pipe_length_m),
        ):
            if lo > hi:
                raise ValueError(f"{key}: the minimum exceeds the maximum")
        if min(self.seabed.area_m) <= 0:
            raise ValueError("seabed.area_m: extents must be positive")
        if self.trajectory.altitude_m >= self.seabed.depth_m:
            raise ValueError("trajectory.altitude_m: the vehicle would be above the surface")
        return self

    @property
    def mission_name(self) -> str:
        return self.name or f"field-seed{self.seed}"


def load_field_config(path: str | Path | None = None, **overrides) -> FieldSimConfig:
    """The defaults, overridden by a YAML file (if given) and then by ``overrides`` given as dotted keys
    with ``__`` separators, e.g. ``load_field_config(None, seed=3, trajectory__lines=2)``."""
    return load_sim_config(FieldSimConfig, path, **overrides)
