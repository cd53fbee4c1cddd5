"""How a bag is read: which topic feeds which sensor, whose clock stamps it, and the constants of
the conversions (pressure → depth, geodetic → local NED, covariances a message leaves unknown)."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

StampPolicy = Literal["auto", "header", "receive"]

#: Pressure at sea level (Pa): what ``atmospheric_pressure_pa`` falls back to when ``auto`` finds
#: no surface period, and what the writer converts depth with when given ``auto``.
STANDARD_ATMOSPHERE_PA = 101325.0


class TopicBinding(BaseModel):
    """Binds a sensor name to a topic. ``kind`` is dvl, ahrs, depth, gps, laser, sonar or ground_truth."""

    model_config = ConfigDict(extra="forbid")
    topic: str
    kind: str
    T_BS: list[list[float]] | None = Field(
        default=None, description="4×4 extrinsic of the sensor in the body frame; overrides the sidecar"
    )
    stamp: StampPolicy | None = Field(default=None, description="this sensor's stamp policy; default reader.stamp")


class Datum(BaseModel):
    """The geodetic origin of the local NED frame (WGS84)."""

    model_config = ConfigDict(extra="forbid")
    latitude_deg: float = Field(ge=-90, le=90)
    longitude_deg: float = Field(ge=-180, le=180)
    altitude_m: float = Field(0.0, description="ellipsoidal height of the origin")


class AssumedSigmas(BaseModel):
    """The standard deviations assumed where a message says its covariance is unknown (all zeros, a
    -1 marker on a rate only, or COVARIANCE_TYPE_UNKNOWN): an estimator must never take a sensor
    as perfect. Each use is counted and reported by ``semslam info``."""

    model_config = ConfigDict(extra="forbid")
    dvl_m_s: float = Field(0.02, gt=0, description="DVL velocity, each axis")
    ahrs_rad: float = Field(0.0175, gt=0, description="AHRS roll, pitch and heading")
    depth_m: float = Field(0.05, gt=0, description="depth from pressure")
    gps_horizontal_m: float = Field(2.5, gt=0, description="GPS north and east")
    gps_vertical_m: float = Field(5.0, gt=0, description="GPS height")


class PlausibleBounds(BaseModel):
    """Physical bounds of a reading, generous: a finite value beyond them is nonsense (damaged bytes,
    a driver's sentinel such as a velocity of 1e188 m/s), dropped and counted like a non-finite one
    (``reader.on_nonfinite``). Point clouds are left to ``cloud_range_m`` (they may be in a world frame)."""

    model_config = ConfigDict(extra="forbid")
    speed_m_s: float = Field(10.0, gt=0, description="DVL velocity magnitude")
    depth_m: float = Field(12000.0, gt=0, description="depth (either sign) and DVL altitude")
    angular_rate_rad_s: float = Field(50.0, gt=0, description="AHRS angular rate magnitude")
    position_m: float = Field(
        2.1e7, gt=0, description="GPS fix and ground-truth position from the local origin (half the Earth's girth)"
    )
    range_m: float = Field(20000.0, gt=0, description="a sonar beam's range")


class ReaderConfig(BaseModel):
    """Bag reading. With no ``sensors`` given, the sidecar's sensors and one topic per sensor kind,
    chosen by the rule of ``semslam.mission.binding`` (``semslam info`` prints the choice)."""

    model_config = ConfigDict(extra="forbid")
    sensors: dict[str, TopicBinding] = Field(default_factory=dict, description="sensor name → topic binding")
    stamp: StampPolicy = Field(
        "auto",
        description="header: message header stamps; receive: the recorder's receive time, mapped onto the "
        "header clock; auto: header stamps, except for a topic whose stamps are zero, constant, running "
        "backwards or on a clock of their own (receive time mapped onto the header clock)",
    )
    water_density_kg_m3: float = Field(1025.0, gt=0, description="for pressure → depth; 997 for fresh water")
    atmospheric_pressure_pa: Annotated[float, Field(gt=0)] | Literal["auto"] = Field(
        "auto",
        description="pressure at the surface (Pa). auto: the mission's sidecar value if it has one, else the "
        "median pressure while at the surface (while the GPS has a fix, else the first seconds before the "
        f"depth rises), else {STANDARD_ATMOSPHERE_PA:g}",
    )
    gravity_m_s2: float = Field(9.80665, gt=0)
    dvl_min_valid_beams: int = Field(3, ge=1, le=4, description="per-beam DVLs: fewer valid beams → invalid")
    dvl_max_fom_m_s: float | None = Field(
        None, gt=0, description="Water Linked DVLs: a reading whose figure of merit is larger is invalid"
    )
    datum: Datum | None = Field(
        None, description="origin of the local NED frame for GPS fixes; default: the sidecar's, else the first fix"
    )
    gps_max_depth_m: float = Field(
        0.5, ge=0, description="a GPS fix taken while the depth sensor reads deeper than this is dropped"
    )
    unknown_covariance: AssumedSigmas = Field(default_factory=AssumedSigmas)
    cloud_range_m: tuple[float, float] = Field(
        (0.01, 300.0),
        description="a point cloud whose median point distance from the sensor is outside this range "
        "(millimetres, a world-frame cloud) is warned about",
    )
    reorder_window_s: float = Field(
        2.0,
        ge=0,
        description="stamp-order buffer: messages of different topics may arrive this much out of "
        "stamp order; a message later than that is an error",
    )
    on_nonfinite: Literal["drop", "error"] = Field(
        "drop",
        description="a measurement with NaN/inf, a covariance that cannot be one or a value beyond "
        "reader.plausible: drop it and count it (reported by info, run and metrics.json), or fail",
    )
    plausible: PlausibleBounds = Field(default_factory=PlausibleBounds)
    on_clock_jump: Literal["error", "split"] = Field(
        "error",
        description="header stamps that go back on every topic at once (a clock reset): error refuses the "
        "mission; split reads one part of it, reader.segment (see semslam.mission.clock_guard)",
    )
    segment: int = Field(
        1,
        ge=1,
        description="with on_clock_jump: split, the part read: 1 = up to the first clock jump, 2 = from it "
        "to the next, ... (semslam info lists them)",
    )
    clock_jump_s: float = Field(
        1.0,
        gt=0,
        description="a topic's header stamp going back at least this much is a clock jump (when its next "
        "message goes on from there); a smaller step back is one late message, dropped and counted",
    )

    @model_validator(mode="after")
    def _ordered_range(self):
        lo, hi = self.cloud_range_m
        if not 0 <= lo < hi:
            raise ValueError(f"cloud_range_m: expected 0 <= min < max, got {list(self.cloud_range_m)}")
        return self


def writing_atmosphere_pa(cfg: ReaderConfig) -> float:
    """The surface pressure a writer converts depth to pressure with: the configured one, else (auto)
    the standard atmosphere. The writer records it in the sidecar, so ``auto`` reads it back."""
    p = cfg.atmospheric_pressure_pa
    return STANDARD_ATMOSPHERE_PA if p == "auto" else float(p)
