"""Configuration of the oracle front-end (section ``frontends.oracle``)."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field


class OracleConfig(BaseModel):
    """Ground truth → noisy observations. Visibility is a cone: range in [min_range_m, max_range_m]
    and angle to the sensor's ``view_axis`` below ``fov_half_angle_deg`` (no occlusion)."""

    model_config = ConfigDict(extra="forbid")
    seed: int = Field(0, description="random seed of the noise, misses, false positives and classification")
    max_range_m: float = Field(5.0, gt=0, description="farthest visible point (m)")
    min_range_m: float = Field(0.2, ge=0, description="nearest visible point (m)")
    fov_half_angle_deg: float = Field(
        45.0, gt=0, le=180, description="half-angle of the visibility cone about view_axis"
    )
    view_axis: tuple[float, float, float] = Field((0.0, 0.0, 1.0), description="sensor-frame viewing direction")
    point_sigma_m: float = Field(0.02, ge=0, description="object position noise (per axis, sensor frame)")
    point_sigma_per_m: float = Field(0.002, ge=0, description="... plus this much per metre of range")
    line_sigma_m: float = Field(0.02, ge=0, description="pipe endpoint noise perpendicular to the axis")
    line_along_sigma_m: float = Field(0.05, ge=0, description="pipe endpoint noise along the axis (clipping)")
    min_pipe_length_m: float = Field(0.3, gt=0, description="a visible pipe stretch shorter than this is not reported")
    pipe_samples_per_m: float = Field(50.0, gt=0, description="sampling of a pipe axis for visibility clipping")
    structure_sigma_m: float = Field(0.03, ge=0, description="structure position noise (per axis)")
    structure_sigma_rad: float = Field(0.01, ge=0, description="structure rotation noise (per axis)")
    structures: bool = Field(True, description="also report ground-truth structures in view")
    miss_rate: float = Field(0.0, ge=0, lt=1, description="probability that a visible landmark is not reported")
    false_positive_rate: float = Field(
        0.0,
        ge=0,
        lt=1,
        description="expected spurious observations per true one (objects and pipes, uniform in the cone)",
    )
    classification_accuracy: float = Field(
        0.8,
        gt=0,
        le=1,
        description="probability that the detected class is right; the likelihood vector is the confusion column",
    )
