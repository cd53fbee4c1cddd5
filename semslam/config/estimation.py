"""The sections every estimator shares: the start state, the motion and sensor error models, and the
map-building rules (association, tentative landmarks, duplicates). No estimator repeats these keys in
its own section, so the graph, the EKF and dead reckoning are always compared under one setting."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field


class InitialStateConfig(BaseModel):
    """Where every estimator starts, and how sure it is of that start."""

    model_config = ConfigDict(extra="forbid")
    pose: Literal["first_ground_truth", "origin"] = Field(
        "first_ground_truth",
        description="start pose: the first GroundTruthPose of the stream (a surface fix), or the origin "
        "(x = y = 0, the first depth, the AHRS attitude); missions without ground truth use the origin",
    )
    position_sigma_m: float = Field(0.01, gt=0, description="prior σ of the start position (per axis)")
    attitude_sigma_rad: float = Field(0.05, gt=0, description="prior σ of the start roll, pitch and yaw")
    velocity_sigma_m_s: float = Field(0.5, gt=0, description="prior σ of the start body velocity (per axis)")
    at_rest_until_velocity_sigma_m_s: float | None = Field(
        0.1,
        gt=0,
        description="until the first valid DVL reading (or GPS fix), every estimator takes the vehicle as "
        "holding its horizontal position, a zero body x/y velocity with this σ (a vehicle waiting for bottom "
        "lock dives or holds station; without it the first reading is taken as the velocity held since the "
        "start); said in the run's warnings with how long it held; null: off",
    )
    at_rest_waiting_sigma_m_s: float | None = Field(
        0.01,
        gt=0,
        description="the σ of that zero velocity while the depth sensor says the vehicle still waits (its "
        "depth unchanged: holding station, as sure as the zero-velocity test below); from the depth's first "
        "change (the dive) at_rest_until_velocity_sigma_m_s; null: that σ throughout",
    )
    still_test_readings: int | None = Field(
        10,
        ge=1,
        description="after that, while the DVL's newest valid reading and the mean of its last this many are "
        "consistent with zero velocity (χ²(3) at 0.999), every estimator reads the horizontal body velocity as "
        "exactly zero (a zero-velocity test: a vehicle still on deck, in a tank or on the seabed with bottom "
        "lock); ends for good at the first reading that fails or a GPS fix; said in the run's warnings; null: off",
    )


# The gyro's noise density when neither the configuration nor the mission states it (rad/s/√Hz): loose, a
# consumer-grade rate sensor's.
DEFAULT_RATE_DENSITY = 0.01


class MotionNoiseConfig(BaseModel):
    """Process noise of the vehicle motion model, shared by every estimator (no estimator gets its own tuning)."""

    model_config = ConfigDict(extra="forbid")
    accel_sigma_m_s2: float = Field(
        0.02,
        gt=0,
        description="white linear-acceleration noise (body frame, m/s²/√Hz): what the vehicle's velocity may "
        "change between velocity readings; a model looser than the vehicle throws away the DVL's averaging",
    )
    angular_rate_sigma_rad_s: float | None = Field(
        None,
        gt=0,
        description="white angular-rate noise of the gyro (rad/s/√Hz), which every estimator integrates between "
        f"attitude readings; null: the mission's declared gyro noise (its σ over √rate), else {DEFAULT_RATE_DENSITY}",
    )

    gyro_link: bool = Field(
        True,
        description="the graph links consecutive keyframes' attitudes by the body rates integrated between them, "
        "with the gyro's bias as a state (sensors.gyro_bias_sigma_rad_s), and turns the DVL's samples into a "
        "keyframe's frame, and the pose predicted after the newest keyframe from it, by the same rates; false: no "
        "link and no bias state in the graph, the DVL's samples turned by the AHRS's readings and the predicted pose's "
        "rotation the AHRS reading, a keyframe without an AHRS reading carried from the one before, as before stop 42 "
        "(the EKF's and dead reckoning's prediction integrates the rates either way)",
    )

    def angular_rate_density(self, metadata: Any) -> float:
        """The gyro's white-noise density (rad/s/√Hz) every estimator uses for the mission of ``metadata``."""
        if self.angular_rate_sigma_rad_s is not None:
            return self.angular_rate_sigma_rad_s
        ahrs = (getattr(metadata, "extras", None) or {}).get("noise", {}).get("ahrs", {})
        sigma, rate = ahrs.get("angular_rate_sigma_rad_s"), ahrs.get("rate_hz")
        return float(sigma) / float(rate) ** 0.5 if sigma and rate else DEFAULT_RATE_DENSITY


# The heading bias's prior σ at the start when the mission declares none (an AHRS's heading is
# typically good to a degree), and the least one used (a bias declared exactly known).
DEFAULT_BIAS_SIGMA0 = 0.0175
MIN_BIAS_SIGMA0 = 1e-4
# The time over which the heading bias's rate may wander by its own prior σ when the mission
# declares no duration (s).
RATE_WALK_OVER_S = 600.0
# The gyro bias's prior σ per axis when the mission declares none (rad/s): a MEMS rate sensor's residual
# bias after its own calibration, loose; the least random walk of that bias (rad/s/√s), so that a bias
# declared constant stays a proper Gaussian process in the filter and the graph alike; and the least walk
# relative to the prior σ: a walk that would take longer than CONSTANT_BIAS_OVER_S to reach σ makes the
# graph's chain of bias states nearly rigid against a loose prior, an indeterminate system for iSAM2
# (world 62 with σ 0.005 and the walk 1e-7, stop 44).
DEFAULT_GYRO_BIAS_SIGMA = 0.005
MIN_GYRO_BIAS_WALK = 1e-7
CONSTANT_BIAS_OVER_S = 1e6


class SensorModelConfig(BaseModel):
    """Sensor error models beyond the white noise that the bag's covariances give, shared by every
    estimator that models them."""

    model_config = ConfigDict(extra="forbid")
    heading_bias_walk_rad_per_sqrt_s: float | None = Field(
        None,
        ge=0,
        description="random-walk intensity of the AHRS heading bias (an AHRS heading drifts: magnetic "
        "disturbances, gyro bias); None: from the mission's declared noise (simulated missions: the bias "
        "drift over the mission's duration), else 0 = no bias state",
    )
    heading_bias_initial_sigma_rad: float | None = Field(
        None,
        ge=0,
        description="prior σ of the heading bias at the start of the mission; None: the mission's declared "
        f"one (simulated missions: 0, their AHRS heading at the start defines the world's yaw), else "
        f"{DEFAULT_BIAS_SIGMA0} (1°)",
    )

    heading_bias_rate_sigma_rad_per_s: float | None = Field(
        None,
        ge=0,
        description="prior σ of the AHRS heading bias's rate of change (a drift rate state beside the bias, "
        "so that a learned drift carries on between sightings); None: the mission's declared drift over "
        "its duration (simulated missions), else 0 = no rate state",
    )

    gyro_bias_sigma_rad_s: float | None = Field(
        None,
        ge=0,
        description="prior σ per axis of the gyro's bias (a state of every estimator that integrates the body "
        "rates); None: the mission's declared one (simulated missions: the σ their bias is drawn from), else "
        f"{DEFAULT_GYRO_BIAS_SIGMA}; 0 = the rates are taken as unbiased (no bias state)",
    )
    gyro_bias_walk_rad_s_per_sqrt_s: float | None = Field(
        None,
        ge=0,
        description="random-walk intensity of the gyro's bias; None: the mission's declared one, else the prior "
        f"σ reached over {RATE_WALK_OVER_S:.0f} s; at least {MIN_GYRO_BIAS_WALK}",
    )

    @staticmethod
    def _declared_ahrs(metadata: Any) -> dict:
        return (metadata.extras or {}).get("noise", {}).get("ahrs", {})

    def heading_bias_walk(self, metadata: Any) -> float:
        """The heading-bias random-walk intensity (rad/√s) for the mission of ``metadata`` (a
        :class:`semslam.mission.mission.MissionMetadata`)."""
        if self.heading_bias_walk_rad_per_sqrt_s is not None:
            return self.heading_bias_walk_rad_per_sqrt_s
        ahrs = self._declared_ahrs(metadata)
        drift, over = ahrs.get("heading_bias_drift_rad"), ahrs.get("heading_bias_drift_over_s")
        if drift and over:
            return float(drift) / float(over) ** 0.5  # a walk whose σ reaches the drift at the end
        return 0.0

    def heading_bias_rate_sigma(self, metadata: Any) -> float:
        """The prior σ (rad/s) of the heading bias's rate of change for the mission of ``metadata``; 0:
        no rate state (nor without a bias state)."""
        if self.heading_bias_walk(metadata) <= 0:
            return 0.0
        if self.heading_bias_rate_sigma_rad_per_s is not None:
            return self.heading_bias_rate_sigma_rad_per_s
        ahrs = self._declared_ahrs(metadata)
        drift, over = ahrs.get("heading_bias_drift_rad"), ahrs.get("heading_bias_drift_over_s")
        if drift and over:
            return float(drift) / float(over)  # the rate that reaches the declared drift at the end
        return 0.0

    def heading_bias_rate_walk(self, metadata: Any) -> float:
        """The random-walk intensity (rad/s/√s) of the heading bias's rate: its σ reaches the rate's
        prior σ over the declared duration (else over RATE_WALK_OVER_S)."""
        sigma = self.heading_bias_rate_sigma(metadata)
        over = self._declared_ahrs(metadata).get("heading_bias_drift_over_s") or RATE_WALK_OVER_S
        return sigma / float(over) ** 0.5

    def heading_bias_sigma0(self, metadata: Any) -> float:
        """The prior σ of the heading bias at the mission's start (rad), at least MIN_BIAS_SIGMA0: a
        bias known exactly is still a proper Gaussian prior, for the filter's covariance and the
        graph's noise model alike."""
        s0 = self.heading_bias_initial_sigma_rad
        if s0 is None:
            s0 = self._declared_ahrs(metadata).get("heading_bias_initial_sigma_rad", DEFAULT_BIAS_SIGMA0)
        return max(float(s0), MIN_BIAS_SIGMA0)

    def gyro_bias_sigma(self, metadata: Any) -> float:
        """The prior σ per axis (rad/s) of the gyro's bias for the mission of ``metadata``; 0: no bias state."""
        if self.gyro_bias_sigma_rad_s is not None:
            return self.gyro_bias_sigma_rad_s
        return float(self._declared_ahrs(metadata).get("gyro_bias_sigma_rad_s", DEFAULT_GYRO_BIAS_SIGMA))

    def gyro_bias_walk(self, metadata: Any) -> float:
        """The random-walk intensity (rad/s/√s) of the gyro's bias, at least MIN_GYRO_BIAS_WALK and at least
        the walk that reaches the prior σ over CONSTANT_BIAS_OVER_S."""
        sigma = self.gyro_bias_sigma(metadata)
        walk = self.gyro_bias_walk_rad_s_per_sqrt_s
        if walk is None:
            walk = self._declared_ahrs(metadata).get("gyro_bias_walk_rad_s_per_sqrt_s")
        if walk is None:
            walk = sigma / RATE_WALK_OVER_S**0.5
        return max(float(walk), MIN_GYRO_BIAS_WALK, sigma / CONSTANT_BIAS_OVER_S**0.5)


class AssociationConfig(BaseModel):
    """How both estimators build their map (semslam.mapping): data association (JCBB), tentative
    landmarks and their promotion, pipe extents, and duplicates."""

    model_config = ConfigDict(extra="forbid")
    confidence: float = Field(0.99, gt=0, lt=1, description="χ² confidence of the compatibility gates")
    pre_gate_m: float = Field(
        2.0,
        gt=0,
        description="Euclidean pre-gate before the χ² tests (the EKF adds 3σ of the vehicle position): "
        "saves work on large maps; must exceed the plausible landmark position error",
    )
    min_observations: int = Field(3, ge=1, description="consistent observations before a landmark enters the map")
    object_view_ratio: float = Field(
        0.5,
        ge=0,
        le=1,
        description="an object enters the map only when it was seen in at least this share of the scans that had "
        "its place in view since its first view (scans that saw anything within object_view_reach_m of it; the views "
        "and scans of a track forgotten there after track_timeout_s count for the track that starts there): a real "
        "object in view is seen scan after scan, a front-end's false object views (a pipe detected in part) come in "
        "a few of the many scans that see the pipe beside them; 0: off",
    )
    object_confirm_ratio: float = Field(
        0.3,
        ge=0,
        le=1,
        description="a mapped object seen in fewer than this share of the scans that had it in view, once at least "
        "object_confirm_scans did, is left out of the map at the end of the mission (a false front-end view; real "
        "objects, partly hidden at times, are seen in half of them or more); 0: off",
    )
    object_confirm_scans: int = Field(
        15, ge=1, description="the scans that had a mapped object in view before object_confirm_ratio judges it"
    )
    object_view_margin_m: float | None = Field(
        0.05,
        ge=0,
        description="object_view_ratio (tentative objects) and object_confirm_ratio (mapped ones) count a scan as "
        "having an object in view only when the object's place also lay inside the sensor's view (the widest angles "
        "and range of what that sensor reported) widened by this much for the object's extent; null: any scan that "
        "saw something within object_view_reach_m counts",
    )
    object_view_reach_m: float = Field(
        0.3, gt=0, description="a scan that saw anything this close to a tentative object had that object in view"
    )
    min_segment_length_m: float = Field(
        0.05, gt=0, description="pipe segments shorter than this are dropped (no usable direction)"
    )
    track_timeout_s: float = Field(
        60.0, gt=0, description="a tentative landmark not seen again within this time is forgotten (false positive)"
    )
    track_gate_confidence: float = Field(
        0.999, gt=0, lt=1, description="χ² confidence for an observation to extend a tentative landmark"
    )
    track_ambiguity_odds: float = Field(
        100.0,
        ge=1,
        description="a scan's views continue tentative landmarks only when the least-cost assignment is at least "
        "this many times as likely as every alternative that shifts two or more of them by one common offset onto "
        "other tracks (a cost margin of 2 ln(odds) in χ²: 9.2 at 100); else the tracks either assignment gives those "
        "views are forgotten and the views start tracks of their own. On a rack's periodic lattice before the DVL "
        "locks, the row shifted by one spacing can cost nearly as little as the right one; 1: off",
    )
    merge_angle_rad: float = Field(
        0.175, gt=0, description="pipe segments are collinear (one pipe) when their directions differ by less than this"
    )
    merge_distance_m: float = Field(
        0.3,
        gt=0,
        description="... and each one's ends lie within this distance of the other's line, with a gap along "
        "the axis below it (the paper's collinear-segment merge)",
    )
    min_separation_m: float = Field(
        0.08,
        gt=0,
        description="two landmarks of a kind are never closer than this (objects: centres; pipes: axes, "
        "parallel and overlapping): an unpaired observation that close to one is it seen badly and "
        "starts no new landmark",
    )
    object_body_m: float = Field(
        0.12,
        gt=0,
        description="two object centres closer than this are one object (a centre lies inside its body, so two "
        "real objects are at least a body apart): a view this close to a mapped object starts no track, and two "
        "mapped objects this close are merged even when their covariances, overconfident by then, fail the χ² test",
    )
    inline_object_radius_m: float = Field(
        0.15,
        gt=0,
        description="an object this close to a pipe's axis, between two collinear segments, separates them "
        "(an in-line valve or socket joins two pipes): they are neither merged nor associated",
    )
    pipe_extent_gap_m: float = Field(
        0.3,
        ge=0,
        description="an observed pipe segment pairs with a mapped pipe only if it comes within this gap "
        "(along the axis) of what has been seen of that pipe",
    )
    pipe_track_gap_sigmas: float = Field(
        3.0,
        ge=0,
        description="a pipe view continues a tentative pipe track when its gap along the axis from what the track "
        "saw is below pipe_extent_gap_m or below this many σ of the gap (from the along-axis σ the front-end gives "
        "the view's ends and the track's: a sonar's pipe windows cut the pipe, a laser's views end where the pipe "
        "does); the mapped pipes keep pipe_extent_gap_m alone. 0: pipe_extent_gap_m for the tracks too",
    )
    duplicate_pipe_distance_m: float = Field(
        0.1,
        gt=0,
        description="two mapped pipes within duplicate_pipe_angle_rad whose seen extents overlap over half "
        "the shorter and whose axes are closer than this (a pipe diameter: pipes cannot interpenetrate) "
        "are one pipe mapped twice, even when their estimates fail the χ² test; the younger is dropped",
    )
    duplicate_pipe_angle_rad: float = Field(
        0.44,
        gt=0,
        lt=1.5708,
        description="the largest angle between two mapped pipes judged by duplicate_pipe_distance_m: wider than "
        "merge_angle_rad, as a short pipe's first views can leave its direction 10-15° off (a 4-view EKF twin 12° "
        "from its pipe), and narrower than a branch leaving a pipe at a fitting",
    )
