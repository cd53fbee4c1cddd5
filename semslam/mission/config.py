"""How a bag is read: which topic feeds which sensor, and physical constants for conversions."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field


class TopicBinding(BaseModel):
    """Binds a sensor name to a topic. ``kind`` is dvl, ahrs, depth, laser, sonar or ground_truth."""

    model_config = ConfigDict(extra="forbid")
    topic: str
    kind: str
    T_BS: list[list[float]] | None = Field(
        default=None, description="4×4 extrinsic of the sensor in the body frame; overrides the sidecar"
    )


class ReaderConfig(BaseModel):
    """Bag reading. With no ``sensors`` given, every topic of a known message type becomes a sensor
    named after its topic, its kind found from the message type."""

    model_config = ConfigDict(extra="forbid")
    sensors: dict[str, TopicBinding] = Field(default_factory=dict, description="sensor name → topic binding")
    water_density_kg_m3: float = Field(1025.0, gt=0, description="for pressure → depth; 1000 for fresh water")
    atmospheric_pressure_pa: float = Field(101325.0, gt=0, description="pressure at the surface")
    gravity_m_s2: float = Field(9.80665, gt=0)
    dvl_min_valid_beams: int = Field(3, ge=1, le=4, description="per-beam DVLs: fewer valid beams → invalid")
    reorder_window_s: float = Field(
        2.0,
        ge=0,
        description="stamp-order buffer: messages of different topics may arrive this much out of "
        "header-stamp order; a message later than that is an error",
    )
    on_nonfinite: Literal["drop", "error"] = Field(
        "drop", description="a measurement with NaN/inf: drop it and count it (reported by info), or fail"
    )
