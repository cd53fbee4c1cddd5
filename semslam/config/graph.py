"""Configuration of the graph back-end (section ``graph``). The start state, motion noise and the
map-building rules are shared with the EKF and live in ``initial``, ``motion`` and ``association``."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, PositiveFloat


class GraphConfig(BaseModel):
    """iSAM2 online smoothing (and the batch re-optimisation) over keyframes."""

    model_config = ConfigDict(extra="forbid")
    batch: bool = Field(
        False, description="after the online pass, re-optimise the whole mission with Levenberg–Marquardt"
    )
    keyframe_max_interval_s: float = Field(
        1.0, gt=0, description="a keyframe at least this often, besides one per exteroceptive observation batch"
    )
    dvl_max_age_s: float = Field(
        0.5, gt=0, description="a DVL sample older than this at a keyframe is not a velocity factor"
    )
    ahrs_max_age_s: float = Field(
        0.5,
        gt=0,
        description="an AHRS sample older than this at a keyframe is not used, nor its rate to carry the attitude on",
    )
    depth_max_age_s: float = Field(
        0.5,
        gt=0,
        description="keyframe 0 with no depth reading since the AHRS's first: the newest one, unless older than this "
        "(a later interval without a reading adds none: the reading before it is already an earlier keyframe's)",
    )
    relinearize_threshold: float = Field(
        0.02, gt=0, description="iSAM2 relinearises a variable whose update exceeds this (tangent-space norm)"
    )
    relinearize_skip: int = Field(
        5, ge=1, description="iSAM2 checks for relinearisation every this many updates (1: every update)"
    )
    robust_kernel: Literal["huber", "cauchy", "tukey", "none"] = Field(
        "huber", description="m-estimator on the landmark factors"
    )
    robust_k: float = Field(1.345, gt=0, description="width of the robust kernel, in whitened units (σ)")
    odometry_cauchy_k: dict[Literal["laser", "sonar"], PositiveFloat] = Field(
        {"laser": 5.3},
        description="Cauchy m-estimator width (whitened units) on the relative-pose factors, by the kind of the sensor "
        "that measured them (laser: laser odometry; a kind not listed stays Gaussian). Registrations that converged "
        "wrong are heavy-tailed beyond their covariance; 5.3 is the maximum-likelihood width on the tuning seeds' "
        "registrations (experiments/odometry/README.md)",
    )
    window_s: float | None = Field(
        600.0,
        gt=0,
        description="online smoothing window (mission seconds): keyframes older than this, and landmarks no newer "
        "keyframe sees, are marginalised into a linear prior on what stays, every half window, so that the cost per "
        "update stays flat on long missions; a landmark seen again re-enters with its last estimate and the "
        "covariance of its own views. None: smooth the whole mission. The batch always spans the whole mission. "
        "Must exceed twice association.track_timeout_s (a tentative landmark's views are still in the window "
        "when it is promoted)",
    )
    batch_max_iterations: int = Field(100, ge=1, description="Levenberg–Marquardt iterations in batch mode")
    covariance_in_result: bool = Field(
        True,
        description="marginal covariances of keyframes and landmarks in the result: with batch, from the whole "
        "mission's graph; without, what is still in the window from the window's graph, and what left it (every "
        "landmark, one keyframe in ten) with the covariance it had when it left (the factors of the whole mission "
        "are kept only for the batch)",
    )
    result_covariance_keyframes: int = Field(
        150,
        ge=2,
        description="keyframes (evenly spaced) whose marginal covariance the result carries, the others NaN: "
        "each costs a partial elimination of a graph where every landmark links to every pose",
    )
