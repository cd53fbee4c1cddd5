"""Configuration of the laser front-end (the ``frontends.laser`` section), every default documented.

Distances in metres, angles in degrees only where the key says ``_deg``. The defaults follow
Vallicrosa et al. 2021 (30° normals, 50-point neighbourhood, curvature threshold 0.025, pipe radius
≤ 0.064 m, length ≥ 0.30 m); values the paper does not give are chosen for a scanner with ~5 mm
range noise looking at a structure 1–4 m away, and say why in their description.
"""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field, model_validator

from frontends.laser.recognition.config import RecognitionConfig


class _Section(BaseModel):
    model_config = ConfigDict(extra="forbid")


class PreprocessConfig(_Section):
    min_range: float = Field(0.3, ge=0, description="points closer to the sensor are dropped (vehicle, bubbles)")
    max_range: float = Field(6.0, gt=0, description="points farther are dropped (range noise grows with range)")
    voxel_size: float = Field(
        0.03,
        gt=0,
        description="voxel grid of the plane segmentation (the whole scan, mostly floor and walls): 3 cm keeps a "
        "100k-point scan near 0.2 s; pipes and objects use structure_voxel_size",
    )
    structure_voxel_size: float = Field(
        0.01,
        gt=0,
        description="the structure (what plane removal keeps, a few % of a scan) is re-sampled from the raw "
        "points at this finer grid for pipes and objects: a 3 cm-radius pipe needs ~1 cm",
    )
    outlier_min_voxels: int = Field(
        4,
        ge=1,
        description="outlier removal: voxels of 26-connected clusters of fewer voxels than this are stray returns "
        "(bubbles, particles); surfaces, even thin parts like a valve stem, are larger connected clusters",
    )
    sparse_cluster_voxels: int = Field(
        30,
        ge=0,
        description="... and so are clusters of fewer voxels than this holding on average at most sparse_mean_points "
        "raw points each: marine snow near a camera fills many voxels with a point each, a surface near enough to "
        "make such a cluster has several per voxel (0: off)",
    )
    sparse_mean_points: float = Field(1.5, ge=0, description="see sparse_cluster_voxels")


class PlaneConfig(_Section):
    normal_hops: int = Field(
        3,
        ge=1,
        le=8,
        description="neighbourhood of the normal and curvature estimate: the voxels reached in this many steps "
        "through occupied 26-neighbours (weighted by their number of paths); at 3 cm, 3 steps cover ~50 voxels "
        "of a plane, the paper's 50-point neighbourhood. The region-growing graph links 26-neighbours",
    )
    max_normal_angle_deg: float = Field(30.0, gt=0, lt=90, description="region growing: max angle between normals")
    growth_curvature: float = Field(
        0.05,
        gt=0,
        description="only points below this curvature propagate a region (PCL's seed rule); pipes of radius "
        "≤ 0.064 m seen over a 50-point neighbourhood are above it, so regions stop at them",
    )
    min_planarity: float = Field(
        0.2,
        ge=0,
        le=1,
        description="only surface-like neighbourhoods (λ1/λ2 above this) propagate a region: a thin pipe's is a "
        "ribbon (≪ 0.2), a plane's a disc (≈ 1) or at its border a half disc (≈ 0.5)",
    )
    flat_curvature: float = Field(0.025, gt=0, description="a region with mean curvature below this is flat (paper)")
    min_plane_extent: float = Field(
        0.4,
        gt=0,
        description="a flat region is a tank plane only if its second principal extent (√12·σ) exceeds this; "
        "smaller flat regions (object faces) are structure unless coplanar with a tank plane",
    )
    min_plane_area: float = Field(
        0.25,
        gt=0,
        description="... or if its area (points × voxel²) exceeds this, m² (a wall seen as a narrow strip)",
    )
    max_plane_offset: float = Field(
        0.03, gt=0, description="points of a tank plane's regions farther than this from the plane are structure (m)"
    )
    plane_distance: float = Field(
        0.012, gt=0, description="points within this distance of a tank plane and next to it join it (border strip)"
    )
    border_hops: int = Field(3, ge=0, description="graph hops over which the border strip may join a plane")


class GroundConfig(_Section):
    """The ground as a height field (``frontends.laser.ground``): a natural seabed, which has no large
    flat regions for plane removal to take. Points near it seed no pipe and join no object."""

    enabled: bool = Field(True, description="model the ground under the scan (up from the AHRS)")
    cell: float = Field(0.05, gt=0, description="grid cell across the up direction (m)")
    open_radius: float = Field(
        0.15,
        gt=0,
        description="the opening's half window (m): wider than half the width of anything lying on the ground "
        "that is not ground (pipes ≤ 6 cm, fittings, stones); the ground's own slope must not fall more than "
        "``band`` over it (≤ 11° at the defaults)",
    )
    band: float = Field(0.03, gt=0, description="ground candidates lie within this above the opened surface (m)")
    fit_radius: float = Field(
        0.25, gt=0, description="each cell's ground plane is fitted to the candidates within this (m)"
    )
    max_slope_deg: float = Field(
        30.0, gt=0, lt=90, description="the ground is never steeper than this (a fitted plane is brought back to it)"
    )
    height: float = Field(
        0.012, gt=0, description="a point less than this above the ground (or below it) is ground (m) ..."
    )
    height_sigmas: float = Field(
        2.5, ge=0, description="... or less than this many times the scan's measured noise σ, whichever is larger"
    )


class PipeConfig(_Section):
    normal_hops: int = Field(
        2,
        ge=1,
        le=8,
        description="neighbourhood of the normals used by the cylinder fit: the structure voxels within this many "
        "26-neighbour steps (2: ±2 cm at 1 cm, weighted towards the centre; smaller than a pipe's half-circumference; "
        "1 step is too noisy under 5 mm range noise)",
    )
    max_radius: float = Field(0.064, gt=0, description="largest pipe radius (paper)")
    min_radius: float = Field(0.015, gt=0, description="smallest pipe radius accepted")
    radius_prior: float | None = Field(
        None, gt=0, description="known pipe radius; when given, fits use it and the fitting test is finer"
    )
    nominal_radii: list[float] = Field(
        default_factory=list,
        description="without radius_prior: the nominal radii of the pipes (m; an inspection knows its pipeline's "
        "sizes). A cylinder whose free fit reads a radius above max_radius (a pipe seen over a narrow arc at stereo "
        "noise) is fitted again with the nominal radius that gathers the most inliers held; it must still pass "
        "the seabed's tests. Empty: off",
    )
    over_line_max_radii: float = Field(
        8.0,
        ge=0,
        description="a segment shorter than this many radii of a longer segment of the scan lying on the ground, at "
        "least "
        "over_line_angle_deg across it, whose axis passes over that one's axis line (above it, along up, by more "
        "than the two radii: no branch, which meets its line axis to axis) within this length of its ends, is a "
        "fitting's part standing over a line on the seabed (a valve's lever, handle or gear head, which scale "
        "with the line's radius): never reported, its points left to the objects. 0: off",
    )
    over_line_angle_deg: float = Field(
        60.0, gt=0, le=90, description="see over_line_max_radii: the least angle between the two axes (deg)"
    )
    held_short_objects: bool = Field(
        True,
        description="with nominal_radii: a held-radius run shorter than color_max_length (never reported: it may be "
        "a stone's top) is still given to the object stage when it passes the seabed's geometric tests (not the "
        "colour), so that a fitting at its end is found: it takes no points from the pipe search, is no line "
        "observation, counts as lying on the seabed (a fitting at its end must rise over it) and connects no "
        "object when shorter than min_partial_length (the edge of a narrow view shows a valve's pipe only over "
        "such short narrow arcs); an object at its end is placed along the pipe only to within the body box "
        "(objects.body_size[0]/sqrt(12): the run's end need not be the fitting's port)",
    )
    surface_offset: float = Field(
        0.0025,
        ge=0,
        description="with radius_prior: how far inside the true surface the structure points of a pipe lie (the "
        "centroids of 1 cm voxels of a convex surface seen with range noise); the axis is placed this much "
        "nearer to them than the radius. Measured on the tank (5 mm range noise): without it the axes lie 2.3 mm "
        "too far from the sensor and junctions 2.9 mm; with 2.5 mm, 0.1 and 0.0 mm, m",
    )
    radius_tolerance: float = Field(
        0.004, gt=0, description="allowed deviation from radius_prior (sockets are ≥ 6 mm wider than their pipe)"
    )
    min_length: float = Field(0.30, gt=0, description="shortest pipe segment reported as an observation (paper)")
    min_detect_length: float = Field(
        0.07,
        gt=0,
        description="shortest pipe segment detected: shorter pipes than min_length are not reported, but they "
        "still separate objects and count in their connectivity (the tank has 13 cm pipes between fittings, "
        "of which the sockets leave ~7-9 cm in view)",
    )
    min_partial_length: float = Field(
        0.15,
        gt=0,
        description="a segment shorter than min_length but at least this long is still reported, as a partial view "
        "of a pipe (its ends are where the view, a burial or an occlusion cut it; the back-end grows a pipe's "
        "extent over views), when it passes every shape test (arc, radius profile)",
    )
    report_between_fittings: bool = Field(
        True,
        description="a segment shorter than min_partial_length (at least min_detect_length) is still reported when "
        "both its ends stop at a fitting (flagged bins of the fitting cut next to its first and last inliers): "
        "the whole of a short pipe between two valves or sockets, its extent seen from end to end (tank world 72's "
        "0.124 m pipe between two valves was otherwise never observed); not on the ground (see ground_gap), where "
        "such a run may be a stone's top between two stones",
    )
    between_fittings_radii: float = Field(
        3.2,
        ge=0,
        description="... and at least this many radii long: a fitting's own middle found as a pipe between its hubs "
        "(a tee's run, a valve's body) is shorter. Measured on tank worlds 60, 62, 72, 77 (every 4th scan, true "
        "poses): such segments off any pipe 0.074-0.10 m (p90 0.10), those of a pipe 0.10-0.15 m (p10 0.10) at "
        "31.5 mm radius",
    )
    ground_gap: float = Field(
        0.07,
        ge=0,
        description="a segment whose underside lies less than this above the ground model lies on the ground (m; "
        "resting on it, buried in part, or spanning a hollow) and must pass the tests of "
        "frontends.laser.pipe_shape (sand crests, mounds and stones fit cylinders too), and objects at its ends "
        "must stand over it; one standing clear of the ground (the tank's lowest pipes: 8.9 cm) is not tested. "
        "Measured on the simulated pipeline: pipes resting on the sand 0-3 cm (the ground model is the sand's "
        "mean level), spanning up to ~6 cm",
    )
    min_axis_height: float = Field(
        0.0,
        description="on the ground: the axis lies at least this many radii above the ground around it (a pipe at "
        "most half buried; a crest fitted by a cylinder has its axis below the sand)",
    )
    min_arc_deg: float = Field(
        60.0,
        ge=0,
        le=360,
        description="on the ground: the inliers span at least this arc about the axis (5th-95th percentile of "
        "their angles; measured on the simulated pipeline: pipes on the sand mostly 140-170°, down to 60° where "
        "the stereo pair loses a flank; crests, mounds and stones 30-130°)",
    )
    max_bow: float = Field(
        0.006,
        ge=0,
        description="on the ground: the inliers' distance to the axis may fall off from the middle of the segment "
        "to its ends by at most this (m; frontends.laser.pipe_shape.bow) ... Measured on the simulated pipeline "
        "(seeds 1 and 3, every 2nd cloud, reported segments): on the pipes -3 to 5.6 mm (1st-99th percentile; one "
        "of 290 above 6 mm), on stones' domed tops median 11 mm (14 of 18 above 6 mm); 0: off",
    )
    bow_sigmas: float = Field(3.0, ge=0, description="... or this many times the bow's standard error, if larger")
    min_color_contrast: float = Field(
        15.0,
        ge=0,
        description="on the ground, with an RGB cloud: the segment's median colour differs from the ground's around "
        "it by at least this (0-255 scale; 0: colour not used). Measured on the simulated pipeline (seeds 1-3): "
        "coated pipes ≥ 18, crests, mounds and stones ≤ 13; but a pale pipe in turbid water 4-33 (seed 9), hence "
        "color_max_length",
    )
    color_max_length: float = Field(
        0.30,
        ge=0,
        description="the colour test applies to segments shorter than this only (m): a longer one on the ground "
        "is judged by its geometry alone, and so are the runs of one cylinder fit cut at fittings whose lengths "
        "add up to this (those passing the geometric tests: one axis, one radius, interrupted by a valve or a "
        "socket). Turbid water and a pale coating can leave a pipe as dull as the sand "
        "(pipeline seed 9: contrast 4-16 on 0.45 m views of its pipes); the seabed's cylinder-like shapes that "
        "pass the geometric tests are shorter (pipeline seeds 1, 4, 9, every 3rd cloud: 0.22-0.28 m, none of "
        "10 at 0.30 m or more)",
    )
    color_reach: float = Field(0.10, gt=0, description="the ground around a segment: within this of its surface (m)")
    min_points: int = Field(40, ge=5, description="fewest inliers of a pipe segment")
    distance_tolerance: float = Field(0.012, gt=0, description="inlier: |distance to axis − radius| below this (m) ...")
    distance_sigmas: float = Field(
        2.5,
        ge=0,
        description="... or below this many times the scan's measured noise σ (at the structure's median range), "
        "whichever is larger: 12 mm is 2.4 σ of a 5 mm laser, stereo at 2 m has σ ≈ 10 mm",
    )
    normal_tolerance_deg: float = Field(30.0, gt=0, lt=90, description="inlier: normal within this of radial")
    hypotheses: int = Field(
        40, ge=5, description="RANSAC hypotheses per extracted pipe (one per seed patch), scored together"
    )
    score_sample: int = Field(1000, ge=100, description="points on which hypotheses are scored (then all points)")
    refine_rounds: int = Field(5, ge=1, description="at most this many fit → inliers rounds per hypothesis")
    max_pipes: int = Field(40, ge=1, description="most pipe segments extracted from one scan")
    max_failures: int = Field(
        4, ge=1, description="RANSAC stops after this many rounds in a row without a pipe, at the least ..."
    )
    detection_confidence: float = Field(
        0.0,
        ge=0,
        lt=1,
        description="... or after as many as it takes for a pipe as rare among the seedable points as the rarest "
        "found so far (its inliers' share: the inlier ratio) to have seeded a hypothesis with this probability "
        "(adaptive RANSAC; e.g. 0.95: pipes that are 1 % of the points need ~8 rounds). Off (0) by default: "
        "measured, with the ground model taking the seabed out of the seeds no stereo view of the simulated "
        "pipeline gained a pipe, while on the tank the extra rounds split pipes and cost 20 % more CPU ...",
    )
    max_failures_cap: int = Field(12, ge=1, description="... but never more than this many rounds in a row")
    max_gap: float = Field(
        0.25,
        gt=0,
        description="a gap without a fitting in it (occlusion) is bridged up to this length along the axis",
    )
    min_open_gap: float = Field(
        0.06,
        ge=0,
        description="along a cylinder lying on the seabed (see ground_gap), a gap in its inliers longer than this "
        "(m) is not bridged (max_gap) where the scan's rays end inside the cylinder over it, more than half its "
        "radius past their entry (the pipe is absent there: bare seabed; an occluder in front ends them before "
        "it): a stone or a sand crest in line with a pipe's free end does not extend the pipe. 0: off",
    )
    fitting_reach: float = Field(
        0.04, gt=0, description="points up to this far outside a pipe's surface are looked at for fittings"
    )
    fitting_points: int = Field(
        6, ge=1, description="this many such points in one bin along the axis mark a fitting (a body, a branch)"
    )
    fitting_window_deg: float = Field(
        60.0,
        gt=0,
        le=180,
        description="along a pipe lying on the ground (see ground_gap), fitting evidence (the points of "
        "fitting_points and gap_reach) lies within this angle about the direction from its axis towards the "
        "sensor: a fitting surrounds its pipe and shows over it, while stones beside it and a stereo camera's "
        "mixed pixels along its silhouette do not (180: all around)",
    )
    gap_reach: float = Field(
        0.10, gt=0, description="a gap in a pipe's inliers with points this close to its surface holds a fitting (m)"
    )
    min_fitting_length: float = Field(
        0.04, gt=0, description="fitting evidence must span this much of the axis to cut a pipe (m)"
    )
    end_fitting_points: int = Field(
        10,
        ge=0,
        description="a bump at an extreme of a pipe's inliers (none of them kept beyond it) cuts the pipe there only "
        "if at least this many points within gap_reach outside its surface lie from the pipe's last unbumped "
        "inlier to end_fitting_reach beyond the bump (a fitting's end faces, body, branch); else it is the pipe's "
        "own end (free pipe ends of the tank: noise on their sparse last cm cut them 4-36 cm short, and their rest "
        "was read as an object). It may let a pipe run into a fitting that shows only its hub (an elbow or socket "
        "whose other side is not seen); measured in experiments/laser/README.md; 0: off",
    )
    end_fitting_reach: float = Field(0.12, gt=0, description="see end_fitting_points (m)")
    end_see_through: bool = Field(
        True,
        description="... and only if the scan sees through the cylinder continued 2-10 cm past the last inlier "
        "(the pipe ends there; a fitting's hub has its body or the next pipe beyond it, or lies at the view's "
        "edge). Measured per scan on tank seeds 5, 7, 10: pipe segments ending > 5 cm off their pipe +9 % "
        "with it against +18 % without it, and false object views 35 -> 20 with it against 35 -> 25",
    )
    bump_bin: float = Field(0.02, gt=0, description="bin along the axis in which fittings are looked for")
    bump_window: float = Field(0.15, gt=0, description="half-width of the pipe's local level around a bin (m)")
    bump_height: float = Field(
        0.004,
        gt=0,
        description="a bin whose median distance to the axis exceeds the pipe's by this is a fitting (sockets are "
        "≥ 6 mm wider than their pipe) and cuts the pipe",
    )
    bump_sigmas: float = Field(
        3.0,
        ge=0,
        description="... and at least this many times the noise of a bin's median (from the scatter of the pipe's "
        "points about their bins' medians, measured per pipe: stereo noise makes the profile itself bumpy); 0: off",
    )
    bump_smooth: bool = Field(
        True, description="a bin also stands out when the mean residual over it and its two neighbours does"
    )
    bump_height_known_radius: float = Field(
        0.003,
        gt=0,
        description="the same when radius_prior is given: the fit then has no radius bias, so the test can be finer",
    )
    bump_sigmas_known_radius: float = Field(
        0.0,
        ge=0,
        description="bump_sigmas when radius_prior is given",
    )
    max_see_through: float = Field(
        0.15,
        ge=0,
        le=1,
        description="a segment is dropped when more than this fraction of the rays crossing its cylinder return "
        "behind it (a pipe is solid; a flat strip as wide as the pipe, like a valve lever, fits its visible "
        "half). Measured on the tank: ≤ 0.08 for 99 % of true pipes, 0.48 median for butterfly-valve levers; "
        "0.22 for a lever seen from straight above (its gear head below fills part of the cylinder)",
    )
    see_through_chord: float = Field(
        0.03, gt=0, description="rays crossing the cylinder with a chord at least this long are tested (m)"
    )
    see_through_margin: float = Field(
        0.02, gt=0, description="a ray returning this far beyond its exit from the cylinder saw through it (m)"
    )
    merge_angle_deg: float = Field(10.0, gt=0, description="duplicates: axes within this angle ...")
    merge_distance: float = Field(0.03, gt=0, description="... axes this close (lateral) ...")
    merge_gap: float = Field(
        0.01,
        ge=0,
        description="... and intervals overlapping or separated by less than this: duplicates overlap, while two "
        "pipes cut apart at a socket are a few cm apart and must stay two",
    )
    range_sigma: float = Field(0.005, gt=0, description="range noise σ of one point at 1 m (endpoint covariance)")
    range_sigma_per_m: float = Field(0.002, ge=0, description="growth of the point σ per metre of range")
    axis_shift_sigma: float = Field(
        0.002,
        ge=0,
        description="σ per axis of a common sideways shift of both endpoints beyond the point noise's σ²/n: the "
        "fit's systematic error (normals, sockets, the visible half-shell), measured on the simulated tank, m",
    )
    axis_tilt_sigma: float = Field(
        0.003,
        ge=0,
        description="σ per axis of opposite sideways offsets of the two endpoints (a tilted axis) beyond the point "
        "noise's 3σ²/n, likewise measured; the two make the endpoints' offset across the axis ~3.6 mm (m)",
    )
    endpoint_sigma: float = Field(
        0.02, gt=0, description="along-axis σ of an endpoint (extreme projection; ≈ voxel size + ray spacing)"
    )
    seed: int = Field(0, description="RANSAC random seed (scans are processed deterministically)")

    @model_validator(mode="after")
    def _radii(self):
        if self.min_radius >= self.max_radius:
            raise ValueError("min_radius must be below max_radius")
        if any(not (r > 0) for r in self.nominal_radii):
            raise ValueError("nominal_radii: radii must be positive (m)")
        return self


class ObjectConfig(_Section):
    body_size: tuple[float, float, float] = Field(
        (0.30, 0.30, 0.30),
        description="body box (along pipe, across, up) centred on the object, m; larger than the largest body",
    )
    handle_size: tuple[float, float, float] = Field(
        (0.30, 0.30, 0.25), description="handle box stacked above the body (mushroom), same axes, m"
    )
    line_tolerance: float = Field(0.03, gt=0, description="pipe ends meet when their axes pass this close (m)")
    max_inline_gap: float = Field(0.30, gt=0, description="longest in-line object between two facing pipe ends (m)")
    min_inline_gap: float = Field(
        0.05,
        ge=0,
        description="a gap between two facing pipe ends shorter than this is a pipe cut at a short bump (a 2-bin "
        "stretch of outward noise, min_fitting_length), not an in-line part, unless min_inline_body points of the "
        "gap's cloud stand off the pipes' cylinder (m; the tank's shortest in-line part, the R-Socket, is 0.088 m "
        "between its ports; the false in-line objects of tank seed 10 lay in gaps of 0.041-0.049 m)",
    )
    min_inline_body: int = Field(
        40, ge=0, description="see min_inline_gap (false in-line objects of tank seed 10: 2-32 such points)"
    )
    max_port_distance: float = Field(
        0.15, gt=0, description="farthest a junction lies beyond the pipe ends meeting there (port to centre, m)"
    )
    collinear_angle_deg: float = Field(30.0, gt=0, lt=90, description="two pipes within this of opposite are collinear")
    min_points: int = Field(30, ge=1, description="fewest (non-pipe) points in the crop for an object")
    cluster_distance: float = Field(0.05, gt=0, description="Euclidean clustering radius inside the crop")
    attach_distance: float = Field(
        0.15,
        gt=0,
        description="an object at a lone pipe end is the largest crop cluster reaching back to within this of the "
        "end along the pipe and of its axis (m; a fitting starts at the end, around the axis, or a few cm beyond it "
        "where the end is seen short): a cluster only farther away belongs to something else (a neighbour's handle, "
        "another fitting; tank seeds 10 and 12: a valve of the layer above, 0.3 m over a free pipe end, was taken as "
        "its body). Its cloud adds the largest cluster within this of the end along the pipe alone (a valve's handle, "
        "its stem unseen)",
    )
    own_margin: float = Field(
        0.015, gt=0, description="a lone end's object point is its own when this far outside the pipe's cylinder (m)"
    )
    own_sigmas: float = Field(
        3.0,
        ge=0,
        description="... and by at least this many times the scatter of the pipe's inliers about their level, when "
        "that is more: the points off a lone end's pipe by range noise are no body (tank seed 10, laser σ 9.7 mm: "
        "the rest of a pipe beyond its fitted end, at free pipe ends, held 10-120 points 1.5 cm off the fitted "
        "cylinder, part of them by noise)",
    )
    own_beyond: float = Field(
        0.03, gt=0, description="... or this far beyond the pipe's end along its axis (m); its end cap is not"
    )
    min_own_points: int = Field(
        10,
        ge=0,
        description="fewest own points of an object at a lone pipe end: on the tank, free pipe ends (end caps) have "
        "0-1, the fittings seen from one pipe ≥ 14",
    )
    tail_tolerance: float = Field(
        0.003,
        gt=0,
        description="a lone pipe end's object is the pipe running on or ending (its sparse far part not fitted, "
        "its end cap or bore), not a fitting, when fewer than min_own_points of its points are off its cylinder "
        "and no 4 cm stretch of them beyond the end stands above the pipe's own radial level by more than this "
        "(their median; m); the gap between two facing ends of one pipe, when its points' median lies within this "
        "of that level: the tank's sockets are 4.5-5 mm wider than their pipes",
    )
    tail_sigmas: float = Field(
        2.0,
        ge=0,
        description="... and by this many times the noise of that median (from the pipe's own scatter; see "
        "tail_tolerance): a lone end's object without a body needs 4 cm of it wider than the pipe",
    )
    stub_start: float = Field(
        0.20,
        gt=0,
        description="a lone pipe end's object joins a second, collinear pipe that was not detected (too short or "
        "hidden in part: the tank's 13-18 cm pipes between fittings) when that pipe's stub shows on the axis beyond "
        "the object: looked for from this far beyond the end (m; past the longest in-line body, whose open port "
        "is a bore of the pipe's radius a few cm beyond the end) ...",
    )
    stub_reach: float = Field(0.50, gt=0, description="... up to this far beyond the end (m)")
    stub_tolerance: float = Field(
        0.006, gt=0, description="a stub point lies this close to the pipe's cylinder continued (m)"
    )
    stub_points: int = Field(
        10,
        ge=1,
        description="fewest stub points, spread over at least stub_bins bins of 2 cm (≥ 2 points each): measured "
        "on the tank (82 scans): 1 of 136 views of objects with one pipe shows such a stub beyond 0.20 m, 30 of 53 "
        "views of objects between two collinear pipes of which the second was not detected do",
    )
    stub_bins: int = Field(3, ge=1, description="see stub_points")
    # σ of an object position in its box frame (along the pipe, across, up), by how it was found;
    # measured (RMS error) on the simulated tank mission at 2-4 m, which includes the fits' systematic
    # errors: a gating estimator needs them honest, neither tighter nor looser.
    junction_sigma: float = Field(
        0.005, gt=0, description="σ per axis of a position where pipe axes cross (configurations 3 and 4), m"
    )
    inline_sigma: tuple[float, float] = Field(
        (0.017, 0.003),
        description="σ (along the pipes, across) of the middle of the gap between two collinear pipe ends "
        "(configuration 2): a valve is not symmetric about its ports, m",
    )
    end_sigma: tuple[float, float] = Field(
        (0.026, 0.007),
        description="σ (along the pipe, across) of the position beyond a lone pipe end (configuration 1): the "
        "middle of the visible extent, m",
    )
    centre_margin: float = Field(
        0.025,
        gt=0,
        description="a lone end's object is centred (along its pipe) on the middle of the extent of its points "
        "standing more than this outside the pipe's cylinder (a body, a branch port, a handle), m; of all its "
        "points when fewer than 5 do. The middle of the whole extent put elbows and tees 3-4 cm short of their "
        "centre, where their ports' axes cross (tank seeds 3, 13, 5, 11: median error along the pipe -1.4 → "
        "-0.1 cm, experiments/laser/object_range_eval.py); a large value: the whole extent, as before",
    )


class LaserConfig(_Section):
    """The ``frontends.laser`` section."""

    preprocess: PreprocessConfig = Field(default_factory=PreprocessConfig)
    planes: PlaneConfig = Field(default_factory=PlaneConfig)
    ground: GroundConfig = Field(default_factory=GroundConfig)
    pipes: PipeConfig = Field(default_factory=PipeConfig)
    objects: ObjectConfig = Field(default_factory=ObjectConfig)
    recognition: RecognitionConfig = Field(default_factory=RecognitionConfig)
    full_resolution_clouds: bool = Field(
        True, description="object clouds from the raw points of the segmented voxels (denser for recognition)"
    )
