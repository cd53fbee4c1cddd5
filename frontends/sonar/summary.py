"""End of mission: the map re-placed with the final estimate, each structure registered once more on
all of its data, the pipelines of the whole map, the swaths' disagreement before and after, the
world model, the figures and the ``sonar`` block of metrics.json."""

from __future__ import annotations

import time

import numpy as np

from frontends.sonar.grid import ElevationMap, GridSpec, estimate_ground
from frontends.sonar.known import KnownStructure
from frontends.sonar.patches import overlap_area, transform, yaw_of
from frontends.sonar.registration import Registration, half_turn_check, icp
from frontends.sonar.swath_registration import _smoothed_gradient
from semslam.registry import FrontendSummary


def place_all(fe, pose_fn, patches=None, stride: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Every patch's points in {W} with its anchor placed by ``pose_fn(patch)``: (points, patch index)."""
    pts, ids = [], []
    for p in patches if patches is not None else fe.patches:
        T = pose_fn(p)
        if T is None or not len(p.points):
            continue
        P = p.points[::stride]
        pts.append(transform(T, P))
        ids.append(np.full(len(P), p.id, np.int32))
    if not pts:
        return np.zeros((0, 3)), np.zeros(0, np.int32)
    return np.concatenate(pts), np.concatenate(ids)


def overlapping_pairs(fe, max_pairs: int = 400) -> list[tuple[int, int]]:
    """Pairs of patches of different passes (at least ``min_age_s`` apart) whose boxes overlap."""
    min_age = fe.config.swath_registration.min_age_s
    turn = np.radians(fe.config.patches.max_turn_deg)
    P = [p for p in fe.patches if len(p.points) and p.heading_change <= turn]
    pairs = []
    for i, a in enumerate(P):
        for b in P[:i]:
            if (a.anchor_stamp - b.anchor_stamp) * 1e-9 < min_age:
                continue
            if overlap_area(a.lo, a.hi, b.lo, b.hi) > 0.5:
                pairs.append((b.id, a.id))
    if len(pairs) > max_pairs:
        keep = np.linspace(0, len(pairs) - 1, max_pairs).round().astype(int)
        pairs = [pairs[k] for k in keep]
    return pairs


TEXTURE_SLOPE = 0.25


def swath_disagreement(fe, pose_fn, pairs, cell: float = 0.05) -> dict:
    """Median |depth difference| between overlapping patches of different passes, pooled over the
    cells both fill (each patch gridded alone at ``cell``, median per cell), placed by ``pose_fn``.

    ``median_m`` is over every common cell: on a smooth seabed a misplacement of decimetres changes
    the depth by millimetres, so it is dominated by the range noise; ``textured_median_m`` is over
    the cells where either map slopes more than 1 in 4 (pipes, structures' edges, boulders), where
    a misplacement shows."""
    diffs = []
    tex = []
    world = {}

    def pts(pid):
        if pid not in world:
            p = fe.patches[pid]
            T = pose_fn(p)
            world[pid] = None if T is None else transform(T, p.points)
        return world[pid]

    n_pairs = 0
    for a, b in pairs:
        A, B = pts(a), pts(b)
        if A is None or B is None:
            continue
        lo = np.maximum(A[:, :2].min(0), B[:, :2].min(0))
        hi = np.minimum(A[:, :2].max(0), B[:, :2].max(0))
        if np.any(hi - lo <= cell):
            continue
        spec = GridSpec.around(lo, hi, cell)
        ea = ElevationMap.from_points(A[np.all((A[:, :2] >= lo) & (A[:, :2] <= hi), 1)], spec=spec)
        eb = ElevationMap.from_points(B[np.all((B[:, :2] >= lo) & (B[:, :2] <= hi), 1)], spec=spec)
        both = ea.filled & eb.filled
        if both.sum() < 20:
            continue
        diffs.append(np.abs(ea.depth[both] - eb.depth[both]))
        steep = np.zeros_like(both)
        for em in (ea, eb):
            gn, ge = _smoothed_gradient(em, 0.05)  # one-cell smoothing: range noise is no slope
            steep |= np.nan_to_num(np.hypot(gn.depth, ge.depth)) > TEXTURE_SLOPE
        tex.append(np.abs(ea.depth - eb.depth)[both & steep])
        n_pairs += 1
    if not diffs:
        return {
            "median_m": None,
            "p90_m": None,
            "mean_m": None,
            "n_cells": 0,
            "n_pairs": 0,
            "textured_median_m": None,
            "textured_cells": 0,
        }
    d = np.concatenate(diffs)
    t = np.concatenate(tex)
    return {
        "median_m": float(np.median(d)),
        "p90_m": float(np.percentile(d, 90)),
        "mean_m": float(d.mean()),
        "n_cells": int(len(d)),
        "n_pairs": n_pairs,
        "textured_median_m": float(np.median(t)) if len(t) else None,
        "textured_cells": int(len(t)),
    }


def final_registrations(fe, pts_W: np.ndarray, patch_ids: np.ndarray) -> None:
    """Each known structure registered by ICP on all of its data, re-placed with the final estimate.

    ``patch_ids``: the patch of each point (:func:`place_all`). The patches near a structure, with
    their points there and their anchor's pose as placed, are kept as its ``support``: what the
    evaluation needs to tell the registration's error from the navigation's where it was seen
    (:mod:`semslam.eval.structures`).

    The quality test of a new structure applies again, now on all the data (with ``final_min_fitness``):
    a structure whose ICP does not pass it is registered afresh there (4-D search, half-turn
    alternative); one that still fails is not confirmed (reported apart, never as a structure of the
    map)."""
    rc = fe.config.registration
    for ks in fe.structures:
        t0 = time.process_time()
        md = fe.recogniser.model_data[ks.model]
        T0 = fe._current_T(ks)
        R = md.model.footprint_radius + 0.5
        near = np.hypot(pts_W[:, 0] - T0[0, 3], pts_W[:, 1] - T0[1, 3]) <= R
        ids, counts = np.unique(patch_ids[near], return_counts=True)
        ks.support = [
            (fe.patches[i].anchor_stamp, int(n), fe.place(fe.patches[i])) for i, n in zip(ids, counts, strict=True)
        ]
        if near.sum() >= rc.min_points:
            reg = icp(md, pts_W[near], T0, rc)
            checked = fe.recogniser.quality_test(ks.model, pts_W[near], reg, rc.final_min_fitness)
            if checked is None:
                wide = np.hypot(pts_W[:, 0] - T0[0, 3], pts_W[:, 1] - T0[1, 3]) <= R + 1.5
                checked = fe.recogniser.register_anew(
                    ks.model, pts_W[wide], T0[:2, 3], fe._ground_kw(), rc.final_min_fitness
                )
            if checked is None and rc.final_pass_vote:
                passes = pass_of(fe, patch_ids[near])
                checked = settled_by_passes(fe.recogniser, ks.model, pts_W[near], passes, reg)
                ks.settled_by_passes = checked is not None
            ks.confirmed = checked is not None
            ks.final = checked or reg
        fe.timing["registration_s"] += time.process_time() - t0


def pass_of(fe, patch_ids: np.ndarray) -> np.ndarray:
    """The pass of each point of the patches ``patch_ids``: their anchors in time order, a new pass where two
    are ``swath_registration.min_age_s`` apart or more (what tells a neighbouring line from the track just
    flown)."""
    ids = np.unique(patch_ids)
    stamps = np.array([fe.patches[i].anchor_stamp for i in ids], np.int64)
    order = np.argsort(stamps, kind="stable")
    gap = np.diff(stamps[order]) * 1e-9 >= fe.config.swath_registration.min_age_s
    label = np.empty(len(ids), np.int64)
    label[order] = np.r_[0, np.cumsum(gap)]
    return label[np.searchsorted(ids, patch_ids)]


def settled_by_passes(
    recogniser, name: str, pts: np.ndarray, passes: np.ndarray, reg: Registration
) -> Registration | None:
    """A structure's fit ``reg`` on all its data ``pts`` (each point's pass in ``passes``) refused by the final
    quality test only as ambiguous, settled by its passes: each pass is registered alone from the fit's better
    orientation and votes when it passes a new structure's test (:meth:`Recogniser.quality_test`) for the
    orientation that test keeps. The better orientation is returned when there is a vote and every vote is
    for it; None otherwise, and for a fit refused for its fitness or median (passes misaligned by the
    navigation lower both orientations' fitness on all the data: each pass alone is not misaligned)."""
    rc = recogniser.reg_cfg
    md = recogniser.model_data[name]
    if reg.median_m > rc.max_median_m or reg.fitness < rc.min_fitness:
        return None
    best, ambiguous = half_turn_check(md, pts, reg, rc)
    if not ambiguous or best.median_m > rc.max_median_m or best.fitness < rc.final_min_fitness:
        return None
    period = md.model.yaw_period
    votes = []
    for k in np.unique(passes):
        own = pts[passes == k]
        if len(own) < rc.min_points:
            continue
        vote = recogniser.quality_test(name, own, icp(md, own, best.T, rc))
        if vote is not None:
            d = (yaw_of(vote.T) - yaw_of(best.T)) % period
            votes.append(min(d, period - d) < period / 4)
    return best if votes and all(votes) else None


def summarise(fe) -> FrontendSummary:
    cfg = fe.config
    t_start = time.process_time()
    final_pose = fe.place
    nav_pose = lambda p: p.T_nav  # noqa: E731
    pts_W, patch_ids = place_all(fe, final_pose)
    # a last recognition pass over the whole map for structures the online search missed
    late = []
    if cfg.recognition.enabled and cfg.recognition.final_pass and len(pts_W):
        t0 = time.process_time()
        removed = [(fe._current_T(ks)[:2, 3], fe.library[ks.model].footprint_radius + 0.3) for ks in fe.structures]
        dets = fe.recogniser.recognise(pts_W, None, None, removed, ground_kw=fe._ground_kw())
        for det in dets:
            ks = KnownStructure(det.model, det.registration.T.copy(), det, -1)
            fe.structures.append(ks)
            late.append(ks)
            fe.timing["registration_s"] += det.timing.get("registration_s", 0.0)
        fe.timing["recognition_s"] += time.process_time() - t0 - sum(d.timing.get("registration_s", 0.0) for d in dets)
    final_registrations(fe, pts_W, patch_ids)
    # the final map, its pipelines and the world model
    map_em = ElevationMap.from_points(pts_W, cfg.figures.cell_m) if len(pts_W) else None
    pipes = fe.detect_pipes(pts_W) if (cfg.pipes.enabled and len(pts_W)) else []
    pairs = overlapping_pairs(fe)
    before = swath_disagreement(fe, nav_pose, pairs)
    after = swath_disagreement(fe, final_pose, pairs)
    raw = None
    extras = getattr(fe.metadata, "extras", None) or {}
    if isinstance(extras.get("sonar"), dict) and extras["sonar"].get("raw_cloud_bytes"):
        raw = int(extras["sonar"]["raw_cloud_bytes"])
    raw = raw or fe.n_points * 12
    world, world_info = None, {}
    if map_em is not None:
        from frontends.sonar.world_model import build_world_model

        spec, bare = bare_seabed(fe, map_em, pipes)
        structs = [
            (fe.library[ks.model], ks.final.T if ks.final is not None else ks.T_WM)
            for ks in fe.structures
            if ks.confirmed
        ]
        world, world_info = build_world_model(structs, pipes, bare, spec, cfg.world_model, raw)
        world_info["seabed_under_structures"] = cfg.world_model.seabed_under_structures
    structures, unconfirmed = [], []
    for ks in fe.structures:
        reg = ks.final or ks.detection.registration
        (structures if ks.confirmed else unconfirmed).append(
            {
                "model": ks.model,
                "pose": (reg.T if reg is not None else ks.T_WM).tolist(),
                "median_error_m": None if reg is None else float(reg.median_m),
                "symmetry": fe.library[ks.model].symmetry,
                "fitness": None if reg is None else float(reg.fitness),
                "structure_points": None if reg is None else int(reg.n_structure),
                "recognition_score": float(ks.detection.normalised),
                "recognition_coverage": float(ks.detection.coverage),
                "recognised_at_stamp": ks.stamp if ks.stamp >= 0 else None,
                "online": ks not in late,
                "settled_by_passes": ks.settled_by_passes,
                "observations_emitted": ks.n_observations,
                "landmark_id": ks.landmark_id,
                "landmark_pose": None if ks.landmark_id is None else fe._current_T(ks).tolist(),
                "support": [
                    {"stamp": int(stamp), "points": n, "T_WB": np.round(T, 6).tolist()} for stamp, n, T in ks.support
                ],
            }
        )
    regs = fe.swath_registrations
    t = dict(fe.timing)
    metrics = {
        "structures": structures,
        # registered online but failing the quality test on all the data at the end (not map structures)
        "unconfirmed_structures": unconfirmed,
        "runtime_s": float(t.get("recognition_s", 0.0) + t.get("registration_s", 0.0)),
        "world_model_bytes": world_info.get("bytes"),
        "raw_cloud_bytes": raw,
        "world_model_fraction": (world_info["bytes"] / raw) if world_info.get("bytes") and raw else None,
        "world_model": world_info,
        "swath_disagreement_before_m": before["median_m"],
        "swath_disagreement_after_m": after["median_m"],
        "swath_disagreement": {
            "before": before,
            "after": after,
            "before_is": "as navigated: each patch placed with the estimate when it closed",
            "after_is": "re-placed with the final graph estimate",
        },
        "swath_registration": {
            "accepted": len(regs),
            "rejected": dict(fe.rejected),
            "both_directions": int(sum(r["informative"] == 2 for r in regs)),
            "median_shift_m": float(np.median([np.hypot(*r["shift"]) for r in regs])) if regs else None,
            "median_sigma_m": float(np.median([r["sigma"] for r in regs])) if regs else None,
        },
        "pipes": [
            {
                "p": s.p.tolist(),
                "q": s.q.tolist(),
                "radius_m": s.radius,
                "length_m": s.length,
                "connected_models": list(s.connected),
            }
            for s in pipes
        ],
        "pipe_observations": fe.pipe_observations,
        "patches": len(fe.patches),
        "points": fe.n_points,
        "timing_s": {k: float(v) for k, v in t.items()},
    }
    fe.timing["summary_s"] += time.process_time() - t_start
    fe.final = {
        "map": map_em,
        "pipes": pipes,
        "world": world,
        "pts_W": pts_W,
        "pairs": pairs,
        "before": before,
        "after": after,
        "world_info": world_info,
        "raw_bytes": raw,
    }
    files = {}
    if world is not None:
        from frontends.sonar.world_model import write_ply

        files["world_model.ply"] = lambda path, w=world: write_ply(w, path)
    if cfg.figures.enabled and map_em is not None:
        from frontends.sonar import figures

        files["figures/sonar_elevation_map.png"] = lambda path: figures.elevation_figure(fe, path)
        files["figures/sonar_world_model.png"] = lambda path: figures.world_model_figure(fe, path)
        files["figures/sonar_swath_registration.png"] = lambda path: figures.disagreement_figure(fe, path)
    return FrontendSummary(section="sonar", metrics=metrics, files=files)


def bare_seabed(fe, map_em: ElevationMap, pipes) -> tuple[GridSpec, np.ndarray]:
    """The seabed without structures and pipes on the world model's grid: the map's median depth,
    and the seabed level interpolated around them under their footprints."""
    cfg = fe.config
    c = map_em.spec.cell
    ground = estimate_ground(map_em.depth, c, **fe._ground_kw())
    mask = fe._structure_mask(map_em.spec, 0.3)
    N, E = map_em.spec.centres()
    nn, ee = np.meshgrid(N, E, indexing="ij")
    for s in pipes:
        a, b = s.p[:2], s.q[:2]
        ab = b - a
        t = np.clip(((nn - a[0]) * ab[0] + (ee - a[1]) * ab[1]) / max(ab @ ab, 1e-9), 0, 1)
        d = np.hypot(nn - a[0] - t * ab[0], ee - a[1] - t * ab[1])
        mask |= d <= s.radius + 0.25
    # anything standing clearly above the seabed (an unrecognised object) is not seabed either
    mask |= (ground - map_em.depth) > 0.15
    depth = np.where(mask & map_em.filled, ground, map_em.depth)
    if cfg.world_model.seabed_under_structures == "cut":
        depth[fe._structure_mask(map_em.spec, 0.0)] = np.nan
    f = max(int(round(cfg.world_model.seabed_cell_m / c)), 1)
    H, W = depth.shape
    Hc, Wc = -(-H // f), -(-W // f)
    pad = np.full((Hc * f, Wc * f), np.nan)
    pad[:H, :W] = depth
    blocks = pad.reshape(Hc, f, Wc, f).transpose(0, 2, 1, 3).reshape(Hc, Wc, f * f)
    cnt = np.isfinite(blocks).sum(-1)
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        coarse = np.nanmedian(blocks, axis=-1)
    coarse[cnt < max(1, f * f // 4)] = np.nan
    spec = GridSpec(map_em.spec.n0, map_em.spec.e0, c * f, (Hc, Wc))
    return spec, coarse
