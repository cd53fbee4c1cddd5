"""Configuration of the laser odometry front-end (section ``frontends.odometry``).

kiss-icp's defaults are made for driving LiDARs (100 m range, voxels of range/100, a 2 m initial
correspondence threshold, deskewing). Underwater scans are short-range (1–10 m), sparse and seen
from a vehicle moving a few decimetres between scans, so these of its parameters change here:
``max_range_m`` / ``min_range_m`` (the sensor's useful range, not a car's), ``voxel_size_m`` (a few
centimetres: pipes are 4–13 cm across), ``max_points_per_voxel`` (8: a voxel of 5 cm holds a
few map points per surface, more only slow the neighbour search), ``initial_threshold_m`` (the navigation prior is good to
centimetres, not metres), ``max_iterations`` (30: the prior starts ICP close) and no deskewing
(ours are snapshots without per-point times). kiss-icp runs single-threaded: the front-end has a
process of its own beside the others. The gate is BUGWRIGHT2 D4.2's: a registration that corrects the navigation prior by
more than 0.05 rad or 0.35 m is rejected; and one that corrects it by more than ten of the prior's own σ.
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field


class KissIcpSettings(BaseModel):
    """What is handed to kiss-icp's ``KISSConfig`` (the rest stays kiss-icp's default)."""

    model_config = ConfigDict(extra="forbid")
    max_range_m: float = Field(10.0, gt=0, description="points farther from the sensor are ignored (m)")
    min_range_m: float = Field(0.3, ge=0, description="points nearer than this are ignored (m)")
    voxel_size_m: float = Field(0.05, gt=0, description="voxel of kiss-icp's local map (m)")
    max_points_per_voxel: int = Field(
        8,
        ge=1,
        description="points kept per voxel of the local map (kiss-icp's 20 costs a quarter more CPU per scan "
        "for the same registrations: experiments/odometry/README.md)",
    )
    initial_threshold_m: float = Field(
        0.05, gt=0, description="correspondence σ before kiss-icp has adapted it (m; ICP pairs points within 3σ)"
    )
    min_motion_m: float = Field(0.01, ge=0, description="kiss-icp adapts its threshold only past this motion (m)")
    fixed_threshold_m: float | None = Field(
        None, gt=0, description="a fixed correspondence σ (m) instead of kiss-icp's adaptive one (ICP uses 3σ)"
    )
    threshold_window: int | None = Field(
        None,
        ge=1,
        description="kiss-icp's adaptive correspondence σ over the last this many accepted registrations only "
        "(kiss-icp's own model error per registration; null: kiss-icp's, the RMS over every registration since the "
        "map started, which never forgets a descent's or an outage's large corrections)",
    )
    max_iterations: int = Field(30, ge=1, description="ICP iterations per registration")
    convergence: float = Field(
        1e-4,
        gt=0,
        description="ICP stops when its update (rad and m, one norm) is below this (a looser one is cheaper but narrows "
        "the gate's margin on a wrong minimum: experiments/odometry/README.md, stop 39)",
    )


class PlaneSettings(BaseModel):
    """Large planes (a tank floor, a wall, flat sand) are removed before registration: they fix
    nothing along themselves, and their points, sampled in a pattern that moves with the sensor,
    pull point-to-point ICP back towards the previous pose (on the tank: 87% of a scan's points are
    floor, and with them ICP finds 2–4 cm per 2 s scan where the structure alone gives ~1 cm)."""

    model_config = ConfigDict(extra="forbid")
    max_planes: int = Field(2, ge=0, description="at most this many planes removed per scan (0: keep every point)")
    min_fraction: float = Field(
        0.15, gt=0, le=1, description="a plane is removed only if it holds this fraction of the scan's points"
    )
    distance_m: float = Field(0.03, gt=0, description="a point this close to a plane belongs to it (m)")


class GateSettings(BaseModel):
    """When a registration is not trusted (it is then dropped and counted, never emitted)."""

    model_config = ConfigDict(extra="forbid")
    max_rotation_correction_rad: float = Field(
        0.05, gt=0, description="largest rotation the registration may apply to the navigation prior (rad)"
    )
    max_translation_correction_m: float = Field(
        0.35, gt=0, description="largest translation it may apply to the navigation prior (m)"
    )
    max_prior_distance: float | None = Field(
        10.0,
        gt=0,
        description="largest translation correction in units of the navigation prior's σ over the interval "
        "(Mahalanobis distance; null: no such bound). The prior's σ grows while a DVL reading is held, so in a "
        "dropout the absolute bound above decides",
    )
    min_inliers: int = Field(200, ge=6, description="fewest scan points matched to the map within the threshold")
    min_inlier_fraction: float = Field(
        0.3, gt=0, le=1, description="fewest scan points matched to the map, as a fraction of the scan's"
    )
    max_sigma_m: float = Field(
        0.05,
        gt=0,
        description="largest translation σ (m, any direction) of the registration: a scan that cannot fix "
        "a direction (a flat floor: along it) is not an odometry measurement",
    )
    max_sigma_rad: float = Field(0.02, gt=0, description="largest rotation σ (rad, about any axis)")


class CovarianceSettings(BaseModel):
    """The registration's covariance: σ²·H⁻¹ of the point-to-plane residuals at the solution (σ² from
    them), scaled and floored, then scaled by how far ICP moved from the navigation prior against the
    prior's own covariance (a Student-t error: most registrations are good to a centimetre, a few
    converge wrong, and those are the ones that disagree with the prior). Shape tuned on tank seeds
    0–5 (150 s); scale and floors recalibrated (× 0.833) on whole missions of tuning seeds 0–1 with
    the windowed map (experiments/odometry_covariance.py; experiments/odometry/README.md). With the
    attitude held (the default) the covariance is made of the parts ``held_*`` and ``range_noise_scale``
    name, and the Student-t factor multiplies the translation's measured part alone
    (``frontends.odometry.matcher.held_covariance``; coefficients fitted by likelihood, stop 40)."""

    model_config = ConfigDict(extra="forbid")
    scale: float = Field(
        8.2,
        gt=0,
        description="multiplies σ²·H⁻¹ of the 6-DoF registration (attitude 'registration', and the heading's with "
        "'roll_pitch'; the held translation's is held_residual_scale): neighbouring residuals of a voxelised map "
        "are not independent, so the raw Hessian bound is overconfident (experiments/odometry_eval.py measures the NEES)",
    )
    floor_sigma_m: float = Field(
        0.0035, ge=0, description="least translation σ per axis (m) of the 6-DoF registration: ICP's sampling bias"
    )
    floor_sigma_rad: float = Field(
        0.0024, ge=0, description="least rotation σ per axis (rad) of the 6-DoF registration (not the held rotation)"
    )
    tail_dof: float = Field(
        34.0,
        ge=0,
        description="ν of the Student-t scaling: the covariance (with the attitude held, the translation's measured "
        "part alone) is multiplied by (ν + d²)/(ν + 6), d² the squared Mahalanobis distance of ICP's correction "
        "under the prior's covariance (0: no scaling)",
    )
    hold_walk_m_s: float = Field(
        0.02,
        ge=0,
        description="the prior's covariance: σ of the body velocity's random walk while a DVL reading is held "
        "(m/s per √s)",
    )

    held_residual_scale: float = Field(
        2.449,
        ge=0,
        description="with the attitude held (attitude 'navigation' or 'roll_pitch'), the translation's measured "
        "covariance is this times σ²·H_tt⁻¹ (σ² the point-to-plane residuals' variance) plus range_noise_scale's "
        "part plus held_floor_sigma_m² per axis (fitted by likelihood on tuning seeds: experiments/odometry/README.md)",
    )
    range_noise_scale: float = Field(
        0.0911,
        ge=0,
        description="with the attitude held, adds this times σ_r²·n·H_tt⁻¹ to the translation's measured covariance: "
        "σ_r² the laser's range noise across a surface (the largest removed plane's points' mean squared distance to "
        "it, median over the last scans), n the inliers; the map's noise is shared by the scan points matched to it "
        "and does not average out over them. Where no plane is removed (none seen yet, or `planes.max_planes` 0): half the "
        "registration's residual variance (they carry the scan's noise and the map's)",
    )
    held_floor_sigma_m: float = Field(
        0.0, ge=0, description="with the attitude held, the translation's least σ per axis (m)"
    )
    gyro_sigma_rad_s: float | None = Field(
        None,
        gt=0,
        description="white noise of the AHRS's angular rate per reading (rad/s; the messages carry none; null: "
        "estimated from the readings' second differences): the rotation between two scans, integrated from it, "
        "has σ²·dt·T (dt the readings' interval, T the scans')",
    )


class OdometryConfig(BaseModel):
    """Laser odometry from kiss-icp, seeded and gated by the navigation prior (DVL + AHRS + depth)."""

    model_config = ConfigDict(extra="forbid")
    kiss_icp: KissIcpSettings = Field(default_factory=KissIcpSettings)
    planes: PlaneSettings = Field(default_factory=PlaneSettings)
    gate: GateSettings = Field(default_factory=GateSettings)
    covariance: CovarianceSettings = Field(default_factory=CovarianceSettings)
    map_window_s: float = Field(
        30.0,
        gt=0,
        description="the local map holds the scans accepted in the last this many seconds (kiss-icp forgets only "
        "by distance, and a vehicle circling a structure stays within range: a map a loop old holds that loop's drift)",
    )
    map_window_slack_s: float = Field(
        0.0,
        ge=0,
        description="the map is rebuilt (from the scans of the last map_window_s) only once its oldest scan is older "
        "than map_window_s plus this: it then holds up to this much more, and is rebuilt once per this many seconds "
        "instead of at every scan (a rebuild re-adds every scan of the window)",
    )
    attitude: Literal["registration", "roll_pitch", "navigation"] = Field(
        "navigation",
        description="where the scan's rotation comes from: 'navigation' (the AHRS's angular rate integrated since "
        "the last scan, or its attitude readings without rates), 'roll_pitch' (the AHRS's tilt, kiss-icp's heading) "
        "or 'registration' (kiss-icp's 6 DoF); with the first two the translation is re-solved with that rotation "
        "held, and the relative pose's rotation covariance is the navigation prior's",
    )
    held_max_distance_m: float | None = Field(
        None,
        gt=0,
        description="with the attitude held, re-solve the translation (and take its covariance) from the scan points "
        "within min(kiss-icp's 3σ threshold, this) of the map; the overlap is judged at kiss-icp's threshold, and the "
        "gate's translation bound also on a second re-solve at that threshold (a wrong minimum of ICP that the tight "
        "bound holds in place walks off in it). null: kiss-icp's 3σ for all. An experiment's setting: it needs its own "
        "held_residual_scale (experiments/odometry/README.md, stops 36–37)",
    )
    dropout_motion: Literal["hold", "odometry"] = Field(
        "hold",
        description="the translation predicted for a scan once the DVL's last valid reading is older than "
        "dropout_after_s: 'hold' (that reading's body velocity, the navigation prior's) or 'odometry' (the body "
        "velocity of the last accepted registration: a vehicle that speeds up or turns in a long outage leaves the "
        "held reading behind); the rotation is the prior's either way",
    )
    dropout_after_s: float = Field(
        1.0, gt=0, description="a DVL reading this old (s) is a dropout for dropout_motion (readings come at 5 Hz)"
    )
    factor_rotation: Literal["prior", "free", "conditional"] = Field(
        "prior",
        description="the rotation block of the emitted covariance: 'prior' (the registration's: with the attitude "
        "held, the AHRS's rates integrated between the scans), 'free' (σ 1 rad, information.FREE_ROTATION_SIGMA_RAD, no cross terms: "
        "the relative pose constrains the translation alone, with its marginal covariance; since stop 43 the graph "
        "links keyframes with the same integrated rates, so the held rotation would be counted twice) or "
        "'conditional' (the rotation's own information replaced by σ 1 rad's, the rest kept: the translation given "
        "the rotation, information.translation_given_rotation)",
    )
    normal_neighbours: int = Field(
        8,
        ge=3,
        description="map points a scan point's plane is fitted to (its nearest, all within twice the correspondence "
        "distance): they must span much more than the sensor's noise, or the plane's normal is the noise's and tilts "
        "at random; at a map edge such a plane pulls the scan back onto the map (a stereo seabed: "
        "experiments/odometry/README.md, stop 52)",
    )
    restart_after: int = Field(
        3, ge=1, description="this many rejected scans in a row start a new local map at the next usable scan"
    )
    max_interval_s: float = Field(
        30.0, gt=0, description="a scan this long after the last accepted one restarts the local map (s)"
    )
    sensors: tuple[str, ...] = Field(
        (), description="point-cloud sensors to register (default: every laser sensor of the mission)"
    )


#: The settings changed from the defaults (tuned on the tank's laser) for dense, narrow stereo clouds of a
#: textured seabed (the pipeline scenario: ~40k points over ~0.6 × 0.5 m at 1.5–2 m): 5 cm voxels would
#: leave ~50 points, and the seabed's ripples, gravel and rocks are the structure to register, not a plane
#: to remove; so small a patch fixes the rotation to 1–3° only (the AHRS fixes it in the estimators), and a
#: fixed 1 cm correspondence σ keeps ICP off the view's edges; each map plane is fitted to 60 map points within 6 cm
#: (the stereo depth noise is several millimetres: 8 points a centimetre apart gave planes tilted by the noise, and
#: planes extrapolated past the map's leading edge pulled the scan back onto the map, short of the motion; measured:
#: experiments/odometry/README.md, stops 51–52).
STEREO_SEABED: dict = {
    "kiss_icp": {"voxel_size_m": 0.02, "fixed_threshold_m": 0.01},
    "planes": {"max_planes": 0},
    "gate": {"max_sigma_rad": 0.08},
    "normal_neighbours": 60,
}
