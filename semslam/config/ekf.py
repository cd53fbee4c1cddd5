"""Configuration of the EKF-SLAM and dead reckoning (section ``ekf``). The start state, motion noise,
the AHRS heading-bias model and the map-building rules are shared with the graph and live in
``initial``, ``motion``, ``sensors`` and ``association``."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field


class EkfConfig(BaseModel):
    """EKF-SLAM of Vallicrosa et al. 2021 (Section 4) and dead reckoning."""

    model_config = ConfigDict(extra="forbid")
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
    pipe_promote_direction_sigma_rad: float | None = Field(
        0.044,
        gt=0,
        description="the EKF's map takes a pipe only once a view knows its direction to this σ (rad; the segment's "
        "end covariances across it over its length): it starts a pipe from its latest view and, with "
        "first_estimate line Jacobians, linearises it there for good, so a short, far view a few degrees off "
        "is read as vehicle motion for the rest of the mission. The graph starts its pipes from all their views "
        "and relinearises: it does not wait (a pipe held back is a constraint lost meanwhile). None: no wait",
    )
    line_min_distance_m: float = Field(
        0.05, gt=0, description="pipe observations whose line passes closer than this to the sensor are ignored (ρ ≈ 0)"
    )
    history_period_s: float = Field(
        0.5, ge=0, description="vehicle covariance recorded in the history at most this often (0 = every update)"
    )
    odometry_gate_probability: float | None = Field(
        0.99,
        gt=0,
        lt=1,
        description="an odometry velocity pseudo-measurement whose NIS exceeds χ²₃ at this probability is rejected "
        "(a registration that converged wrong, as the graph's Cauchy kernel discounts it); null: no gate",
    )
