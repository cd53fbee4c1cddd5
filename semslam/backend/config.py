"""Configuration of the graph back-end (section ``graph`` of the semslam configuration)."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator


class GraphConfig(BaseModel):
    """iSAM2 / batch graph back-end. Motion noise and association settings are shared with the EKF
    and live in ``motion`` and ``association``."""

    model_config = ConfigDict(extra="forbid")
    batch: bool = Field(
        False, description="after the online pass, re-optimise the whole mission with Levenberg–Marquardt"
    )
    keyframe_max_interval_s: float = Field(
        1.0, gt=0, description="a keyframe at least this often, besides one per exteroceptive observation batch"
    )
    initial_pose: Literal["first_ground_truth", "origin"] = Field(
        "first_ground_truth",
        description="start pose: the first GroundTruthPose of the stream (a surface fix) or the origin with the AHRS attitude",
    )
    initial_position_sigma_m: float = Field(0.01, gt=0, description="prior σ on the start position (per axis)")
    initial_rotation_sigma_rad: float = Field(
        0.05, gt=0, description="prior σ on the start attitude (the AHRS refines it)"
    )
    initial_velocity_sigma_m_s: float = Field(0.5, gt=0, description="prior σ on the start body velocity")
    dvl_max_age_s: float = Field(
        0.5, gt=0, description="a DVL sample older than this at a keyframe is not a velocity factor"
    )
    ahrs_max_age_s: float = Field(0.5, gt=0, description="an AHRS sample older than this at a keyframe is not used")
    depth_max_age_s: float = Field(0.5, gt=0, description="a depth sample older than this at a keyframe is not used")
    relinearize_threshold: float = Field(0.02, gt=0, description="iSAM2 relinearisation threshold (tangent norm)")
    relinearize_skip: int = Field(
        5,
        ge=1,
        description="iSAM2 relinearises every this many updates (every update: twice the cost, same accuracy on the tank)",
    )
    robust_kernel: Literal["huber", "cauchy", "tukey", "none"] = Field(
        "huber", description="m-estimator on landmark factors"
    )
    robust_k: float = Field(1.345, gt=0, description="kernel width in whitened units (σ)")
    pre_gate_m: float = Field(
        2.0, gt=0, description="Euclidean pre-gate (m) before the Mahalanobis test: cheaper association on large maps"
    )
    track_timeout_s: float = Field(
        60.0, gt=0, description="a tentative landmark not seen again within this time is forgotten (false positive)"
    )
    track_gate_confidence: float = Field(
        0.999, gt=0, lt=1, description="χ² confidence for an observation to extend a tentative landmark"
    )
    window_s: float | None = Field(
        600.0,
        gt=0,
        description="online smoothing window (mission seconds): keyframes older than this, and landmarks no newer "
        "keyframe sees, are marginalised into a linear prior on what stays, every half window, so that the cost per "
        "update stays flat on long missions; a landmark seen again re-enters with its last estimate and the "
        "covariance of its own views. None: smooth the whole mission. The batch always spans the whole mission",
    )
    batch_max_iterations: int = Field(100, ge=1, description="Levenberg–Marquardt iterations in batch mode")
    covariance_in_result: bool = Field(
        True, description="marginal covariances of keyframes and landmarks in the result"
    )
    result_covariance_keyframes: int = Field(
        150,
        ge=2,
        description="keyframes (evenly spaced) whose marginal covariance the result carries, the others NaN: "
        "each costs a partial elimination of a graph where every landmark links to every pose",
    )

    @model_validator(mode="after")
    def _window_holds_tracks(self) -> GraphConfig:
        # a tentative landmark's views must still be in the window when it is promoted
        if self.window_s is not None and self.window_s <= 2 * self.track_timeout_s:
            raise ValueError(
                f"graph.window_s ({self.window_s} s) must exceed twice graph.track_timeout_s ({self.track_timeout_s} s)"
            )
        return self
