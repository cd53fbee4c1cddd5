"""Configuration of the EKF-SLAM and dead reckoning (the ``ekf`` section).

Motion noise (``motion``), the sensor error models beyond white noise (``sensors``: the AHRS heading
bias) and association (``association``) are shared with the graph back-end and are not repeated here.
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field


class EkfConfig(BaseModel):
    """EKF-SLAM of Vallicrosa et al. 2021 (Section 4) and dead reckoning."""

    model_config = ConfigDict(extra="forbid")
    initial_pose: Literal["first_ground_truth", "origin"] = Field(
        "first_ground_truth",
        description="start pose: the first GroundTruthPose of the stream (a surface fix), or the origin "
        "(x = y = 0, the first depth, the AHRS attitude); missions without ground truth use the origin",
    )
    initial_position_sigma_m: float = Field(0.01, gt=0, description="initial σ of the position (per axis)")
    initial_attitude_sigma_rad: float = Field(0.05, gt=0, description="initial σ of roll, pitch and yaw")
    initial_velocity_sigma_m_s: float = Field(0.5, gt=0, description="initial σ of the body velocity (per axis)")
    max_prediction_step_s: float = Field(
        0.1, gt=0, description="longer gaps between measurements are predicted in steps of at most this"
    )
    rate_max_age_s: float = Field(
        0.5, gt=0, description="the AHRS angular rate is the prediction input while younger than this; zero after"
    )
    line_jacobians: Literal["first_estimate", "current"] = Field(
        "first_estimate",
        description="where the pipe measurement Jacobians are evaluated: at the pipe's first estimate (FEJ, Huang, "
        "Mourikis & Roumeliotis 2008; keeps a common translation of vehicle and map unobservable, as it is — the "
        "world-origin line parameters make the current-estimate Jacobians gain spurious absolute-position "
        "information) or at the current estimate (the textbook EKF)",
    )
    heading_jacobians: Literal["first_estimate", "current"] = Field(
        "first_estimate",
        description="with the AHRS heading bias modelled (section sensors), only the map observes the heading, "
        "and a rotation of vehicle and map about the vertical is unobservable: first_estimate evaluates the "
        "prediction's ∂p/∂ψ with the propagated positions and every landmark Jacobian (objects, pipes, new "
        "features) at the propagated position and the landmarks' first estimates (FEJ-EKF, Huang, Mourikis & "
        "Roumeliotis 2009), which keeps it unobservable; current: the textbook EKF, whose Jacobians at the "
        "updated estimates observe it spuriously (the heading wanders and the bias with it)",
    )
    line_min_length_m: float = Field(0.05, gt=0, description="shorter pipe segments are ignored (no direction)")
    line_min_distance_m: float = Field(
        0.05, gt=0, description="pipe observations whose line passes closer than this to the sensor are ignored (ρ ≈ 0)"
    )
    pre_gate_m: float = Field(
        2.0,
        gt=0,
        description="Euclidean pre-gate (m, plus 3σ of the vehicle position) before the χ² tests: "
        "saves work on large maps; must exceed the plausible landmark position error",
    )
    duplicate_pipe_distance_m: float = Field(
        0.1,
        gt=0,
        description="two mapped pipes within the collinearity angle whose seen extents overlap over half "
        "the shorter and whose axes are closer than this (a pipe diameter: pipes cannot interpenetrate) are one pipe "
        "mapped twice, even when their estimates fail the χ² test; the younger is dropped",
    )
    track_timeout_s: float = Field(
        60.0, gt=0, description="a tentative feature not seen again within this time is forgotten (false positive)"
    )
    track_gate_confidence: float = Field(
        0.999, gt=0, lt=1, description="χ² confidence for an observation to extend a tentative feature"
    )
    history_period_s: float = Field(
        0.5, ge=0, description="vehicle covariance recorded in the history at most this often (0 = every update)"
    )
