"""Configuration of the sonar front-end (the ``frontends.sonar`` section), every default documented.

Distances in metres, angles in degrees only where the key says ``_deg``. The defaults follow
Guerneve, Subr & Petillot (elevation maps, swath registration by signed median depth then the
north/east shift minimising the median unsigned depth difference, a circular ring × depth-bin
descriptor compared ring by ring with the Earth Mover's Distance, a search every Δ = 8 cm, largest
structure first, exhaustive 4-D match then robust ICP); values the paper does not give are chosen
for a 512-beam, 80° multibeam at ~5 m altitude (beam spacing 1.6–2.8 cm across track, one swath
every 4 cm along track, σ 1.5 cm range noise) and say why in their description.
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator


class _Section(BaseModel):
    model_config = ConfigDict(extra="forbid")


class MapConfig(_Section):
    """Elevation maps (:mod:`frontends.sonar.grid`: median depth per cell, empty cells stay empty)
    are built at the cell each stage's data supports — ``swath_registration.cell_m`` (5 cm),
    ``recognition.delta_m`` (8 cm), ``recognition.map_cell_m`` and ``pipes.cell_m`` (4 cm),
    ``figures.cell_m`` (8 cm): beams 1.6–2.8 cm apart across track and swaths 4 cm apart leave a
    1 cm grid (the class's default) mostly empty. The patches keep every return."""

    min_range_m: float = Field(0.5, ge=0, description="sonar returns closer than this are dropped (m)")
    max_range_m: float = Field(30.0, gt=0, description="... and farther than this (m)")
    ground_block_m: float = Field(
        0.5, gt=0, description="seabed level: blocks of this size give a deep quantile of their depths ..."
    )
    ground_window_m: float = Field(
        9.0,
        gt=0,
        description="... median-filtered over this window, wider than twice the largest structure's half-width "
        "so that a structure never fills half of it",
    )
    ground_smooth_m: float = Field(
        1.0, gt=0, description="σ of the normalised convolution that re-interpolates the seabed from cells near it"
    )
    ground_band_m: float = Field(
        0.10, gt=0, description="cells within this of the seabed estimate are seabed when it is refined"
    )


class PatchConfig(_Section):
    length_m: float = Field(
        1.0,
        gt=0,
        description="consecutive swaths over this much track form a patch, stored rigidly in the frame of its "
        "middle swath (its anchor); 1 m keeps a structure seen by ≥ 2–3 independent patches per pass (the graph "
        "needs 3 consistent observations to create a landmark)",
    )
    max_swaths: int = Field(200, ge=2, description="a patch closes after this many swaths even when the vehicle hovers")
    max_turn_deg: float = Field(
        15.0, gt=0, description="patches whose heading changes more than this (the turns) are mapped but not registered"
    )


class SwathRegistrationConfig(_Section):
    enabled: bool = Field(
        True, description="register new patches against older overlapping ones (relative-pose constraints)"
    )
    window_patches: int = Field(
        3,
        ge=1,
        description="a registration aligns the last this-many patches of the current line (3 m: enough seabed "
        "texture) as one rigid piece; windows do not overlap, so constraints are independent",
    )
    min_age_s: float = Field(
        30.0,
        gt=0,
        description="reference patches are at least this much older than the new ones (a neighbouring line, "
        "not the track just flown)",
    )
    cell_m: float = Field(
        0.05, gt=0, description="cell of the reference elevation map the new points are compared with"
    )
    max_shift_m: float = Field(
        0.6, gt=0, description="north/east search range (m): the field's between-line drift is ≤ 0.32 m"
    )
    coarse_step_m: float = Field(0.08, gt=0, description="first level of the coarse-to-fine shift search")
    fine_step_m: float = Field(0.01, gt=0, description="last level of the coarse-to-fine shift search")
    max_points: int = Field(6000, ge=100, description="new points used per registration (random subset, seeded)")
    max_height_m: float = Field(
        0.8,
        ge=0,
        description="reference cells higher than this above the seabed (structures), and tall_margin_m "
        "around them, are left out: a structure's elevation map depends on the side it is seen from (0: keep all)",
    )
    tall_margin_m: float = Field(0.6, ge=0, description="margin around the tall cells left out")
    min_kept: float = Field(
        0.85, gt=0, le=1, description="a shift is scored only if this share of the points still lands on the reference"
    )
    min_overlap_points: int = Field(
        800, ge=10, description="fewest new points over the reference map for a registration"
    )
    max_residual_m: float = Field(
        0.05, gt=0, description="reject when the robust σ of the depth residual at the optimum exceeds this"
    )
    max_sigma_m: float = Field(
        0.10,
        gt=0,
        description="a north/east direction whose σ exceeds this is flat (no texture): its information is "
        "dropped (σ set to uninformative_sigma_m) and the shift along it kept at zero",
    )
    uninformative_sigma_m: float = Field(5.0, gt=0, description="σ given to a direction without information (m)")
    probe_m: float = Field(
        0.2, gt=0, description="a direction counts only if the mean squared residual rises, this far on both sides ..."
    )
    probe_rise: float = Field(0.5, gt=0, description="... by at least this share of its value at the optimum")
    correlation_cells: float = Field(
        16.0,
        ge=1,
        description="covariance inflation: neighbouring points share reference cells and texture, so the "
        "linearised information is divided by this",
    )
    rotation_sigma_rad: float = Field(
        0.05,
        gt=0,
        description="σ of the relative rotation (not measured by an elevation-map registration: taken from "
        "the current estimate and left nearly uninformative)",
    )
    depth_sigma_floor_m: float = Field(0.005, gt=0, description="σ floor of the depth offset (m)")
    shift_sigma_floor_m: float = Field(
        0.03,
        gt=0,
        description="σ floor of an informative north/east direction (m): a structure seen from two sides "
        "does not give quite the same elevation map (occlusions, oblique sides)",
    )
    seed: int = Field(0, description="seed of the point subsets (deterministic runs)")


class RecognitionConfig(_Section):
    enabled: bool = Field(True, description="recognise CAD structures in the elevation map")
    models: tuple[str, ...] | None = Field(
        None, description="structure models searched (default: the whole library, largest first)"
    )
    delta_m: float = Field(
        0.08, gt=0, description="Δ: spacing of the candidate centres and cell of the descriptor grid (paper: 8 cm)"
    )
    rings: int = Field(
        8, ge=1, le=64, description="N concentric rings of equal width over the model's footprint radius"
    )
    bins: int = Field(13, ge=2, le=128, description="P height bins over [height_min_m, height_max_m]")
    height_min_m: float = Field(-0.125, description="lower edge of the first height bin (above the seabed, m)")
    height_max_m: float = Field(3.125, description="upper edge of the last height bin (m); heights beyond are clipped")
    threshold: float = Field(
        0.40,
        gt=0,
        description="accept a candidate when its score (norm of the ring EMDs) is below this share of the "
        "model's score against a flat seabed (a dimensionless threshold for every model). Calibrated on seeds 3–5 "
        "(experiments/sonar_calibrate.py): true structures score ≤ 0.26, the seabed and pipelines ≥ 0.63, a smaller "
        "model on a larger structure ≥ 0.45 (largest first removes those areas anyway)",
    )
    min_coverage: float = Field(
        0.75,
        gt=0,
        le=1,
        description="share of the descriptor disc's cells that must hold data (footprint well covered)",
    )
    min_ring_coverage: float = Field(0.4, ge=0, le=1, description="... and of every ring's cells")
    bootstrap: int = Field(
        8, ge=1, description="branch and bound: candidates fully evaluated after the first ring to set the bound"
    )
    every_patches: int = Field(3, ge=1, description="search the newly covered area every this many patches")
    trigger_height_m: float = Field(
        0.6, ge=0, description="the search runs only where a cell rises this far above the seabed (every model does)"
    )
    map_cell_m: float = Field(
        0.04,
        gt=0,
        description="each patch keeps one point per cell of this size (its upper surface) for the "
        "recognition maps: a 5× lighter map at Δ = 8 cm; registration uses every point",
    )
    final_pass: bool = Field(
        True,
        description="at the end of the mission, search the whole map once more for structures the online search "
        "missed (reported, but too late to become graph landmarks)",
    )
    chunk: int = Field(40000, ge=100, description="candidates evaluated together (memory bound)")


class StructureRegistrationConfig(_Section):
    yaw_step_deg: float = Field(4.0, gt=0, description="yaw step of the coarse level of the exhaustive 4-D search")
    coarse_cell_m: float = Field(
        0.16,
        gt=0,
        description="cell (and north/east step) of the coarse level; each refinement halves cell, step and yaw step",
    )
    coarse_max_cells: int = Field(
        1500, ge=50, description="the coarse level compares at most this many field cells (an even subsample)"
    )
    refine_levels: int = Field(
        2, ge=0, description="refinements around the best coarse hypotheses (0.16 → 0.08 → 0.04 m)"
    )
    fine_seeds: int = Field(3, ge=1, description="best distinct coarse yaws refined")
    shift_range_m: float = Field(
        0.3, gt=0, description="north/east search range around the recognised centre, at least (m)"
    )
    shift_range_frac: float = Field(
        0.4,
        gt=0,
        description="... or this share of the model's footprint radius: the descriptor's best centre can sit "
        "off the model's origin along an elongated structure (a manifold's repeated bays)",
    )
    icp_distances_m: tuple[float, ...] = Field(
        (0.20, 0.08), description="ICP max correspondence distances, coarse to fine"
    )
    icp_iterations: int = Field(20, ge=1, description="ICP iterations per distance")
    icp_voxel_m: float = Field(0.04, ge=0, description="field points are voxel-downsampled to this before ICP (0: all)")
    tukey_k_m: float = Field(0.05, gt=0, description="Tukey robust kernel width of the point-to-plane ICP (m)")
    model_sample_m: float = Field(0.05, gt=0, description="spacing of the points sampled on the CAD mesh for ICP")
    ground_plane: bool = Field(
        True,
        description="the ICP target includes the seabed pad the structure stands on (a disc at the base): it "
        "constrains depth, roll and pitch",
    )
    max_median_m: float = Field(
        0.05, gt=0, description="reject a registration whose median point-to-model distance exceeds this"
    )
    min_points: int = Field(
        60, ge=10, description="fewest structure points (above the pad, on the model's footprint) for a re-observation"
    )
    min_fitness: float = Field(0.5, ge=0, le=1, description="share of structure points within tukey_k_m of the model")
    new_min_fitness: float = Field(
        0.85,
        ge=0,
        le=1,
        description="a new structure (a recognition, and the final registration on all of its data) needs at least "
        "this fitness: placed right, the structure's points lie on the model up to the range noise; slid "
        "along a manifold's bays, turned end for end or fitted to something else it fits less (see the README)",
    )
    max_unexplained: float = Field(
        0.1,
        ge=0,
        le=1,
        description="a new structure's registration (not the final re-check) is refused when more than this "
        "share of the high points around it (over 1 m above its base, within 1 m beyond its footprint) lie off the model's footprint: "
        "structure the model does not explain, as when it is slid along a manifold's bays on a partial view "
        "whose points on the footprint all fit",
    )
    final_min_fitness: float = Field(
        0.80,
        ge=0,
        le=1,
        description="... and at the end of the mission, on all of a structure's data (its passes misaligned by the "
        "navigation error between them lower the fitness of a right registration)",
    )
    ambiguity_margin: float = Field(
        0.05,
        ge=0,
        le=1,
        description="a registration whose alternative (the model turned by half its symmetry period, end for "
        "end for a PLET) fits within this much of its fitness is ambiguous: not accepted until more is seen",
    )
    final_pass_vote: bool = Field(
        True,
        description="at the end of the mission, a structure's fit on all its data refused only as ambiguous (its "
        "fitness and median pass) is kept when each pass over it that passes a new structure's test alone "
        "(passes split where the patches are swath_registration.min_age_s apart) votes for its orientation: "
        "passes misaligned by the navigation lower both orientations' fitness on all the data",
    )
    correlation_points: float = Field(
        8.0,
        ge=1,
        description="ICP covariance inflation: the linearised information is divided by this (calibrated: NEES)",
    )
    sigma_floor_m: float = Field(
        0.025,
        gt=0,
        description="σ floor of a structure observation's translation (m): a 1 m strip sees part of the "
        "structure, from one side; the point-to-plane information alone is far too confident (calibrated: NEES)",
    )
    sigma_floor_rad: float = Field(0.010, gt=0, description="σ floor of its rotation (rad; calibrated likewise)")
    max_sigma_m: float = Field(
        0.3,
        gt=0,
        description="an observation whose largest translation σ exceeds this is not emitted (too partial a view)",
    )
    max_jump_m: float = Field(
        0.25, gt=0, description="a re-observation may move the structure at most this far from its current estimate ..."
    )
    max_turn_deg: float = Field(
        5.0, gt=0, description="... and turn it at most this much (else it slid on a partial view)"
    )
    carry_sigma_per_m: float = Field(
        0.01,
        ge=0,
        description="σ added per metre of track between a patch's anchor and the current swath (the "
        "observation is re-expressed in the current sensor frame with the estimated motion); the same σ per "
        "metre of the vehicle's pose relative to a structure since its last accepted view (see gap_search)",
    )
    gap_search: bool = Field(
        True,
        description="a re-observation after a gap whose track times carry_sigma_per_m exceeds max_jump_m (the "
        "pose relative to the structure uncertain beyond the reach of an ICP from the prior) is searched: the "
        "coarse ICP from a grid of starts over the recognition's shift range, each distinct place refined, the "
        "best fit within that range the view, its covariance grown by any rival place that fits within "
        "ambiguity_margin (two alike give no view); false: the ICP from the prior, as after a short gap",
    )
    recent_s: float = Field(
        12.0,
        gt=0,
        description="at recognition, patches of the current pass closed within this time are also registered "
        "and emitted (one per swath, each at its own keyframe)",
    )


class PipeDetectionConfig(_Section):
    enabled: bool = Field(True, description="detect pipelines on the elevation map once structures are removed")
    min_height_m: float = Field(0.06, gt=0, description="ridge cells rise at least this above the seabed")
    max_height_m: float = Field(1.2, gt=0, description="... and at most this (taller: a structure)")
    tall_exclusion_m: float = Field(
        1.8, ge=0, description="cells this close to a taller cell (an unrecognised structure) are not pipe"
    )
    structure_margin_m: float = Field(0.3, ge=0, description="recognised footprints grown by this are not pipe")
    min_length_m: float = Field(1.0, gt=0, description="shortest pipe segment reported")
    max_gap_m: float = Field(0.8, gt=0, description="gaps along a segment up to this are bridged")
    min_radius_m: float = Field(0.04, gt=0, description="smallest pipe radius")
    max_radius_m: float = Field(0.40, gt=0, description="largest pipe radius")
    ransac_iterations: int = Field(300, ge=10, description="line hypotheses per extracted pipe")
    inlier_m: float = Field(0.12, gt=0, description="ridge cells within this of a line are its inliers")
    min_cells: int = Field(60, ge=5, description="fewest ridge cells of a pipe")
    max_pipes: int = Field(6, ge=1, description="most pipes per window")
    cell_m: float = Field(0.04, gt=0, description="grid cell of the pipe detection")
    max_fit_residual_m: float = Field(0.03, gt=0, description="median residual of the cross-section arc fit")
    lateral_sigma_m: float = Field(0.03, gt=0, description="σ of an endpoint perpendicular to the axis")
    along_sigma_m: float = Field(0.3, gt=0, description="σ of an endpoint along the axis (windows cut the pipe)")
    hub_distance_m: float = Field(1.2, gt=0, description="a segment end this close to a recognised hub connects to it")
    window_patches: int = Field(
        6,
        ge=1,
        description="pipes are detected, every every_patches patches, on this many of the latest patches. "
        "More than every_patches makes consecutive views of a pipe overlap (the graph associates a view "
        "with a pipe track only where it meets what was seen of it: with 3 patches every 3, the graph mapped "
        "1, 2 and 0 of the 2 pipelines on seeds 0-2; with 6, 2, 2 and 2); each cell is then used "
        "window_patches / every_patches times and the covariance is inflated by that factor",
    )
    every_patches: int = Field(
        2,
        ge=1,
        description="pipes are detected every this many patches (1 m each): a pipe crossing the track is in "
        "window_patches / every_patches windows, so in one pass it gives that many views, and a tentative "
        "landmark needs association.min_observations of them within association.track_timeout_s "
        "(3 in 60 s; a lawnmower's passes over it are 115-130 s apart). 3: the swath-registration windows' cadence",
    )
    seed: int = Field(0, description="RANSAC seed")


class WorldModelConfig(_Section):
    seabed_cell_m: float = Field(
        0.5, gt=0, description="level of detail of the seabed surface mesh (grid cell before simplification)"
    )
    seabed_max_error_m: float = Field(
        0.03,
        ge=0,
        description="the seabed mesh is simplified (quadric decimation) while its vertical error stays below this",
    )
    max_fraction: float = Field(
        0.01,
        gt=0,
        le=1,
        description="the world model is simplified further until it is at most this share of the raw cloud's bytes",
    )
    seabed_under_structures: Literal["filled", "cut"] = Field(
        "filled",
        description="under the registered structures' footprints the seabed surface is the level interpolated "
        "around them (filled: the CAD meshes stand on it) or left out (cut)",
    )
    pipe_facets: int = Field(12, ge=3, description="facets around a pipeline cylinder")


class FigureConfig(_Section):
    enabled: bool = Field(True, description="write figures/sonar_*.png")
    cell_m: float = Field(
        0.08, gt=0, description="cell of the elevation map drawn in the figure and meshed (the swaths are 4 cm apart)"
    )
    dpi: int = Field(110, ge=50, description="figure resolution")


class SonarConfig(_Section):
    """The ``frontends.sonar`` section."""

    map: MapConfig = Field(default_factory=MapConfig)
    patches: PatchConfig = Field(default_factory=PatchConfig)
    swath_registration: SwathRegistrationConfig = Field(default_factory=SwathRegistrationConfig)
    recognition: RecognitionConfig = Field(default_factory=RecognitionConfig)
    registration: StructureRegistrationConfig = Field(default_factory=StructureRegistrationConfig)
    pipes: PipeDetectionConfig = Field(default_factory=PipeDetectionConfig)
    world_model: WorldModelConfig = Field(default_factory=WorldModelConfig)
    figures: FigureConfig = Field(default_factory=FigureConfig)

    @model_validator(mode="after")
    def _check(self):
        if self.map.min_range_m >= self.map.max_range_m:
            raise ValueError("map.min_range_m must be below map.max_range_m")
        if self.recognition.height_min_m >= self.recognition.height_max_m:
            raise ValueError("recognition.height_min_m must be below recognition.height_max_m")
        if self.pipes.min_height_m >= self.pipes.max_height_m:
            raise ValueError("pipes.min_height_m must be below pipes.max_height_m")
        if self.pipes.min_radius_m >= self.pipes.max_radius_m:
            raise ValueError("pipes.min_radius_m must be below pipes.max_radius_m")
        if self.swath_registration.fine_step_m > self.swath_registration.coarse_step_m:
            raise ValueError("swath_registration.fine_step_m must not exceed coarse_step_m")
        if not self.registration.icp_distances_m:
            raise ValueError("registration.icp_distances_m: give at least one distance")
        return self
