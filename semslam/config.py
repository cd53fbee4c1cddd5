"""The typed configuration of semslam: every default lives here (or in the section model it names),
documented by its Field description. ``semslam config dump`` prints the resolved configuration."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from semslam.backend.config import GraphConfig
from semslam.ekf.config import EkfConfig
from semslam.errors import ConfigError
from semslam.mission.config import ReaderConfig


class MotionNoiseConfig(BaseModel):
    """Process noise of the vehicle motion model, shared by every estimator (no estimator gets its own tuning)."""

    model_config = ConfigDict(extra="forbid")
    accel_sigma_m_s2: float = Field(0.05, gt=0, description="white linear-acceleration noise (body frame)")
    angular_rate_sigma_rad_s: float = Field(0.01, gt=0, description="white angular-rate noise")


# The heading bias's prior σ at the start when the mission declares none (an AHRS's heading is
# typically good to a degree), and the least one used (a bias declared exactly known).
DEFAULT_BIAS_SIGMA0 = 0.0175
MIN_BIAS_SIGMA0 = 1e-4


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
        description="prior σ of the heading bias at the start of the mission (rad); None: the mission's "
        f"declared one (simulated missions: 0, their AHRS heading at the start defines the world's yaw), "
        f"else {DEFAULT_BIAS_SIGMA0} (1°)",
    )

    def _declared_ahrs(self, metadata) -> dict:
        return (getattr(metadata, "extras", None) or {}).get("noise", {}).get("ahrs", {})

    def heading_bias_walk(self, metadata) -> float:
        """The heading-bias random-walk intensity for ``metadata``'s mission (rad/√s)."""
        if self.heading_bias_walk_rad_per_sqrt_s is not None:
            return self.heading_bias_walk_rad_per_sqrt_s
        ahrs = self._declared_ahrs(metadata)
        drift, over = ahrs.get("heading_bias_drift_rad"), ahrs.get("heading_bias_drift_over_s")
        if drift and over:
            return float(drift) / float(over) ** 0.5  # a walk whose σ reaches the drift at the end
        return 0.0

    def heading_bias_sigma0(self, metadata) -> float:
        """The prior σ of the heading bias at the mission's start (rad), at least MIN_BIAS_SIGMA0: a
        bias known exactly is still a proper Gaussian prior, for the filter's covariance and the
        graph's noise model alike."""
        s0 = self.heading_bias_initial_sigma_rad
        if s0 is None:
            s0 = self._declared_ahrs(metadata).get("heading_bias_initial_sigma_rad", DEFAULT_BIAS_SIGMA0)
        return max(float(s0), MIN_BIAS_SIGMA0)


class AssociationConfig(BaseModel):
    """Data association (JCBB) and landmark initialisation, shared by the graph and the EKF."""

    model_config = ConfigDict(extra="forbid")
    confidence: float = Field(0.99, gt=0, lt=1, description="chi-square confidence of the compatibility gates")
    min_observations: int = Field(3, ge=1, description="consistent observations before a landmark enters the map")
    merge_angle_rad: float = Field(0.175, gt=0, description="collinear pipe segments merged below this angle")
    merge_distance_m: float = Field(0.3, gt=0, description="... and this distance between them")
    min_separation_m: float = Field(
        0.08,
        gt=0,
        description="two landmarks of a kind are never closer than this (objects: centres; pipes: axes, "
        "parallel and overlapping): an unpaired observation that close to one is it seen badly and "
        "starts no new landmark",
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
        description="an observed pipe segment pairs with a mapped pipe only if it comes within this gap (m, "
        "along the axis) of what has been seen of that pipe",
    )


class SemslamConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")
    reader: ReaderConfig = Field(default_factory=ReaderConfig)
    motion: MotionNoiseConfig = Field(default_factory=MotionNoiseConfig)
    sensors: SensorModelConfig = Field(default_factory=SensorModelConfig)
    association: AssociationConfig = Field(default_factory=AssociationConfig)
    graph: GraphConfig = Field(default_factory=GraphConfig, description="graph back-end (semslam.backend)")
    ekf: EkfConfig = Field(default_factory=EkfConfig, description="EKF-SLAM and dead reckoning (semslam.ekf)")
    frontends: dict[str, dict[str, Any]] = Field(
        default_factory=dict, description="front-end name → its own section, validated by the front-end"
    )


def load_config(path: str | Path | None = None) -> SemslamConfig:
    """The defaults, overridden by the YAML file at ``path`` if given."""
    if path is None:
        return SemslamConfig()
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"{path}: configuration file not found")
    try:
        data = yaml.safe_load(path.read_text()) or {}
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML ({str(exc).splitlines()[0]})") from exc
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a mapping at the top level")
    try:
        return SemslamConfig.model_validate(data)
    except ValidationError as exc:
        err = exc.errors()[0]
        key = ".".join(str(x) for x in err["loc"])
        raise ConfigError(f"{path}: {key}: {err['msg']}") from exc


def dump_config(config: SemslamConfig) -> str:
    return yaml.safe_dump(config.model_dump(mode="json"), sort_keys=False)
