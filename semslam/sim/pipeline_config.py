"""Configuration of the simulated pipeline mission: every default is documented in its Field.

The scenario (issue 22): a pipeline (pipes of 20–60 mm radius with flanges, valves and a tee
junction) lying on, and partly buried in, a natural seabed (slope, gentle relief, sand ripples,
rocks), inspected by an AUV that weaves across it at ~1.2 m altitude with a down/forward-looking
stereo camera. The camera gives organised clouds (NaN where stereo fails) with RGB, ~40k valid points
each, with a stereo noise model (depth σ ∝ z²), holes, edge artefacts, outliers and turbidity; each
view holds a few tenths of a metre of pipe. The navigation sensors are the tank's (DVL, AHRS,
depth; :mod:`semslam.sim.config`).

Frames as in :mod:`semslam.sim.config`: world {W} NED with its origin at the surface above the
middle of the pipeline (north = x, east = y, depth = z); body {B} x forward / y right / z down;
camera {S} x right, y down, z along the optical axis (the left camera; the right one sits
``baseline_m`` along +x).
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


class NaturalSeabedConfig(_Section):
    """The seabed: a seeded relief (slope + gaussian bumps), mounds and hollows, sand ripples and rocks."""

    depth_m: float = Field(15.0, gt=2, description="mean seabed depth under the pipeline (m)")
    relief_m: float = Field(0.25, ge=0, le=2, description="the relief reaches ±this about the mean over the area (m)")
    bumps: int = Field(8, ge=0, le=50, description="gaussian bumps of the relief")
    bump_sigma_m: tuple[float, float] = Field((0.8, 3.0), description="min, max width (σ) of a bump (m)")
    slope_share: float = Field(
        0.6, ge=0, lt=1, description="share of the relief made by a planar slope (0.6: slopes of ~3-6°)"
    )
    ripple_amplitude_m: tuple[float, float] = Field(
        (0.004, 0.015), description="min, max amplitude of the sand ripples (m), drawn per mission"
    )
    ripple_wavelength_m: tuple[float, float] = Field(
        (0.08, 0.20), description="min, max wavelength of the sand ripples (m), drawn per mission"
    )
    lump_amplitude_m: float = Field(
        0.015, ge=0, description="σ of the gravel mounds and hollows (a smooth field of short wavelengths, m)"
    )
    lump_wavelength_m: tuple[float, float] = Field(
        (0.25, 1.2), description="min, max wavelength of the mounds and hollows (m)"
    )
    roughness_m: float = Field(0.002, ge=0, description="σ of the fine roughness of the sand (m)")
    resolution_m: float = Field(
        0.02, gt=0.005, le=0.2, description="spacing of the seabed triangle grid (m; ripples need ≤ 1/4 wavelength)"
    )
    margin_m: float = Field(3.0, ge=0, description="the seabed extends this far beyond the pipeline's ends (m)")
    half_width_m: float = Field(3.0, gt=0, description="the seabed extends this far either side of the pipeline (m)")
    rock_density_m2: float = Field(12.0, ge=0, description="rocks per square metre of seabed")
    rock_radius_m: tuple[float, float] = Field(
        (0.025, 0.25), description="min, max rock radius (m), drawn log-uniformly (many small, few large)"
    )
    rocks_touching: int = Field(
        6, ge=0, description="rocks placed right against the pipes (touching their sides), besides the random ones"
    )
    rock_burial: tuple[float, float] = Field((0.2, 0.6), description="min, max share of a rock's height below the sand")


class PipelineLayoutConfig(_Section):
    """The pipeline: one straight main line with in-line fittings, optionally a tee and a parallel line."""

    length_m: tuple[float, float] = Field((8.0, 11.0), description="min, max length of the main line (m)")
    radius_m: tuple[float, float] = Field((0.02, 0.06), description="min, max pipe radius (m), drawn per line")
    inline_fittings: tuple[int, int] = Field(
        (2, 4), description="min, max in-line fittings on the main line (flanges and valves; at least one valve)"
    )
    valve_share: float = Field(0.5, ge=0, le=1, description="share of the in-line fittings that are valves")
    min_fitting_spacing_m: float = Field(1.2, gt=0, description="between neighbouring fittings on a line (m)")
    tee_probability: float = Field(
        0.7, ge=0, le=1, description="probability of a tee junction with a branch line leaving the main line"
    )
    branch_length_m: tuple[float, float] = Field((1.5, 2.5), description="min, max length of the branch (m)")
    end_valve_probability: float = Field(0.5, ge=0, le=1, description="probability of a valve at the branch's end")
    parallel_probability: float = Field(0.4, ge=0, le=1, description="probability of a second, parallel line")
    parallel_offset_m: tuple[float, float] = Field(
        (0.5, 0.9), description="min, max distance between the main line and the parallel one (m)"
    )
    burial: tuple[float, float] = Field(
        (0.0, 0.35), description="min, max share of a line's diameter sunk below the crests of the seabed it rests on"
    )


class StereoConfig(_Section):
    """Stereo camera (left camera = {S}): a pinhole grid of rays, depth from disparity.

    Depth noise: σ_z = z² · ``disparity_sigma_px`` / (f · ``baseline_m``), f the focal length in
    pixels; a share of it spatially correlated (stereo matching windows). Points are NaN where stereo
    fails: pixels the right camera does not see (occlusion), low-texture patches, beyond the range
    that turbidity allows (dropouts growing with range). Edge artefacts: foreground fattening and
    mixed depths next to depth jumps. Outliers: mismatches (wrong depth) and marine snow (points near
    the camera). RGB: lamp-lit colours attenuated towards the water colour with range.
    """

    rate_hz: float = Field(2.0, gt=0, description="stereo clouds per second")
    time_offset_s: float = Field(0.0, ge=0, lt=1, description="first cloud one period plus this after the start")
    resolution: tuple[int, int] = Field(
        (240, 180), description="pixels across and down (organised cloud of width × height points)"
    )
    fov_deg: tuple[float, float] = Field((20.0, 15.0), description="horizontal and vertical field of view (deg)")
    baseline_m: float = Field(0.12, gt=0, description="distance between the two cameras (m)")
    disparity_sigma_px: float = Field(
        0.15,
        ge=0,
        description="disparity noise (px): with the default optics σ_z ≈ 4 mm at 1.2 m, 11 mm at 2 m, 25 mm at 3 m",
    )
    correlated_share: float = Field(
        0.5, ge=0, le=1, description="share of the disparity noise variance that is spatially correlated"
    )
    correlation_px: float = Field(2.0, gt=0, description="σ (px) of the correlated noise's smoothing")
    min_range_m: float = Field(0.3, ge=0, description="closer surfaces give no depth (m)")
    max_range_m: float = Field(4.0, gt=0, description="farther surfaces give no depth (m)")
    dropout_range_m: float = Field(
        3.0, gt=0, description="turbidity: a pixel at range r fails with probability 1 − exp(−(r/this)⁴)"
    )
    hole_share: float = Field(0.05, ge=0, lt=0.5, description="share of the image lost to low-texture holes")
    hole_size_px: float = Field(6.0, gt=0, description="typical size (σ of the smoothing, px) of those holes")
    edge_px: int = Field(2, ge=0, description="pixels next to a depth jump on the far side that are affected")
    edge_jump: float = Field(0.04, gt=0, description="a depth jump: neighbours' depths differ by this share")
    mismatch_share: float = Field(0.004, ge=0, lt=0.1, description="share of valid pixels with a wrong depth")
    snow_share: float = Field(0.002, ge=0, lt=0.1, description="share of pixels returning from marine snow (0.3-1 m)")
    turbidity_per_m: float = Field(
        0.35, ge=0, description="attenuation of the colours per metre of path (there and back)"
    )
    water_rgb: tuple[int, int, int] = Field((20, 70, 80), description="colour of the water veil (backscatter)")
    rgb_noise: float = Field(6.0, ge=0, description="σ of the colour noise (0-255 scale)")
    mount: Mount = Field(
        default_factory=lambda: Mount(xyz=(0.5, 0.0, 0.3), rpy_deg=(35.0, 0.0, 90.0)),
        description="under the bow, looking forward and 55° down (sensor z = body x pitched down): at 1.4 m "
        "above a pipe its view holds ~0.55 m of it along the track and ~0.6 m across",
    )


class PipelineTrajectoryConfig(_Section):
    """The vehicle (a hovering AUV) inspects the main line there and back, facing along it: its
    position along the line goes from before the start to past the end and back (s = centre −
    half span · cos(π t / pass time)), with a slow sideways sway and a heading wobble that vary
    the views, at constant altitude above the line's axis (following its slope)."""

    passes: int = Field(2, ge=1, description="passes along the line (2: there and back; the return sees it again)")
    speed_m_s: float = Field(0.17, gt=0, le=2, description="top speed along the line, mid-pass (m/s)")
    altitude_m: float = Field(1.4, gt=0.3, description="height of the body origin above the line's axis (m)")
    margin_m: float = Field(0.3, ge=0, description="the view reaches this far beyond the line's ends (m)")
    view_lead_m: float = Field(
        1.5,
        description="the camera's view lies this far ahead of the body origin (the default mount at 1.4 m: 0.5 m "
        "forward, then 1 m to where its axis meets the seabed); the passes are centred on the view, not the body",
    )
    sway_amplitude_m: float = Field(0.15, ge=0, description="amplitude of the sideways sway (m)")
    sway_period_s: float = Field(23.0, gt=0, description="period of the sideways sway (s)")
    yaw_amplitude_deg: float = Field(
        8.0, ge=0, description="amplitude of the heading wobble about the line's direction (deg)"
    )
    yaw_period_s: float = Field(17.0, gt=0, description="period of the heading wobble (s)")
    roll_pitch_amplitude_deg: float = Field(1.0, ge=0, description="amplitude of the roll/pitch wobble (deg)")
    duration_s: float | None = Field(
        None, gt=0, description="mission length (s); default all the passes (a shorter one ends mid-pass)"
    )


def _pipeline_dvl() -> DvlConfig:
    return DvlConfig(random_dropout_rate=0.03, burst_s=(1.0, 4.0), mount=Mount(xyz=(-0.25, 0.0, 0.30)))


def _pipeline_ahrs() -> AhrsConfig:
    return AhrsConfig(heading_bias_drift_deg=0.75)


def _pipeline_ground_truth() -> GroundTruthConfig:
    return GroundTruthConfig(rate_hz=20.0)


class PipelineSimConfig(_Section):
    """Everything that defines a simulated pipeline mission. Same config (incl. seed) → same bytes.

    The DVL, AHRS and depth sections are the tank's (:mod:`semslam.sim.config`); over the seabed the
    DVL has no walls to lose (``wall_beams_lost`` has no effect) and short random dropouts (3 % of the
    time, 1-4 s bursts); the heading bias drifts at the tank's rate (0.75° over the ~3 minutes).
    """

    seed: int = Field(0, ge=0, description="random seed of the seabed, the pipeline and every sensor's noise")
    name: str | None = Field(None, description="mission name (default pipeline-seed<N>)")
    start_time_s: float = Field(1.7e9, ge=0, description="stamp of the first sample (s since the epoch)")
    seabed: NaturalSeabedConfig = Field(default_factory=NaturalSeabedConfig)
    layout: PipelineLayoutConfig = Field(default_factory=PipelineLayoutConfig)
    trajectory: PipelineTrajectoryConfig = Field(default_factory=PipelineTrajectoryConfig)
    stereo: StereoConfig = Field(default_factory=StereoConfig)
    dvl: DvlConfig = Field(default_factory=_pipeline_dvl)
    ahrs: AhrsConfig = Field(default_factory=_pipeline_ahrs)
    depth: DepthConfig = Field(default_factory=DepthConfig)
    ground_truth: GroundTruthConfig = Field(default_factory=_pipeline_ground_truth)

    @model_validator(mode="after")
    def _check(self):
        for key, (lo, hi) in (
            ("dvl.burst_s", self.dvl.burst_s),
            ("seabed.bump_sigma_m", self.seabed.bump_sigma_m),
            ("seabed.ripple_amplitude_m", self.seabed.ripple_amplitude_m),
            ("seabed.ripple_wavelength_m", self.seabed.ripple_wavelength_m),
            ("seabed.lump_wavelength_m", self.seabed.lump_wavelength_m),
            ("seabed.rock_radius_m", self.seabed.rock_radius_m),
            ("seabed.rock_burial", self.seabed.rock_burial),
            ("layout.length_m", self.layout.length_m),
            ("layout.radius_m", self.layout.radius_m),
            ("layout.inline_fittings", self.layout.inline_fittings),
            ("layout.branch_length_m", self.layout.branch_length_m),
            ("layout.parallel_offset_m", self.layout.parallel_offset_m),
            ("layout.burial", self.layout.burial),
        ):
            if lo > hi:
                raise ValueError(f"{key}: the minimum exceeds the maximum")
        if self.layout.radius_m[0] <= 0:
            raise ValueError("layout.radius_m: radii must be positive")
        if self.trajectory.altitude_m + 1.0 >= self.seabed.depth_m:
            raise ValueError("trajectory.altitude_m: the vehicle would be above the surface")
        return self

    @property
    def mission_name(self) -> str:
        return self.name or f"pipeline-seed{self.seed}"


def load_pipeline_config(path: str | Path | None = None, **overrides) -> PipelineSimConfig:
    """The defaults, overridden by a YAML file (if given) and then by ``overrides`` given as dotted keys
    with ``__`` separators, e.g. ``load_pipeline_config(None, seed=3, trajectory__duration_s=20)``."""
    return load_sim_config(PipelineSimConfig, path, **overrides)
