"""Recognition of CAD structures in an elevation map: descriptors of the library, the search
(largest structure first, its area removed before the next), and the registration of each find.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from frontends.sonar.config import RecognitionConfig, StructureRegistrationConfig
from frontends.sonar.descriptor import Template, make_spec, model_template, search
from frontends.sonar.grid import ElevationMap, estimate_ground
from frontends.sonar.registration import ModelData, Registration, half_turn_check, model_data, register_structure
from semslam.models.structures import StructureModel


@dataclass
class Detection:
    model: str
    centre: np.ndarray  # (north, east) of the best candidate
    score: float  # norm of the ring EMDs (m)
    normalised: float  # score / the model's score against a flat seabed
    coverage: float
    registration: Registration | None = None
    timing: dict = field(default_factory=dict)


class Recogniser:
    """Templates of the library's models (largest footprint first) at the descriptor cell Δ."""

    def __init__(
        self,
        models: list[StructureModel],
        cfg: RecognitionConfig,
        reg_cfg: StructureRegistrationConfig,
        delta_m: float | None = None,
    ):
        self.cfg = cfg
        self.reg_cfg = reg_cfg
        self.delta = float(delta_m or cfg.delta_m)
        self.models = sorted(models, key=lambda m: -m.footprint_radius)
        self.templates: dict[str, Template] = {}
        for m in self.models:
            spec = make_spec(m.footprint_radius, cfg.rings, self.delta, cfg.height_min_m, cfg.height_max_m, cfg.bins)
            self.templates[m.name] = model_template(m.name, m.mesh, spec)
        self.model_data: dict[str, ModelData] = {m.name: model_data(m, reg_cfg) for m in self.models}
        self.rejected: list[Detection] = []  # descriptor matches whose registration failed

    @property
    def max_radius(self) -> float:
        return max((m.footprint_radius for m in self.models), default=0.0)

    def heights(self, points: np.ndarray, spec=None, ground_kw: dict | None = None):
        """(elevation map at Δ of the upper surface, seabed level, heights) of points (north, east, depth)."""
        em = ElevationMap.from_points(points, self.delta, spec=spec, quantile=0.1)
        ground = estimate_ground(em.depth, self.delta, **(ground_kw or {}))
        return em, ground, ground - em.depth

    def recognise(
        self,
        points: np.ndarray,
        region_lo=None,
        region_hi=None,
        removed: list[tuple[np.ndarray, float]] = (),
        ground_kw: dict | None = None,
        register: bool = True,
        full_points=None,
        skip: list[tuple[str, np.ndarray]] = (),
    ) -> list[Detection]:
        """Search the map of ``points`` ({W}) for every model, largest first; candidate centres in
        [region_lo, region_hi] (north, east; default everywhere), discs (centre, radius) in
        ``removed`` masked out. Each find is registered (4-D + ICP) unless ``register`` is False,
        on ``full_points(centre, radius)`` (default: ``points`` themselves); a find whose
        registration fails the quality checks is dropped. Nothing is searched when no cell of the
        region rises ``trigger_height_m`` above the seabed (every model is taller)."""
        cfg = self.cfg
        t0 = time.process_time()
        em, ground, h = self.heights(points, ground_kw=ground_kw)
        t_map = time.process_time() - t0
        N, E = em.spec.centres()
        mask = np.zeros(h.shape, bool)
        for c, r in removed:
            mask |= np.hypot(N[:, None] - c[0], E[None, :] - c[1]) <= r
        lo = np.array([-np.inf, -np.inf]) if region_lo is None else np.asarray(region_lo, float)
        hi = np.array([np.inf, np.inf]) if region_hi is None else np.asarray(region_hi, float)
        rmax = self.max_radius
        rows = np.flatnonzero((N >= lo[0]) & (N <= hi[0]))
        cols = np.flatnonzero((E >= lo[1]) & (E <= hi[1]))
        out: list[Detection] = []
        if len(rows) == 0 or len(cols) == 0:
            return out
        near_rows = np.flatnonzero((N >= lo[0] - rmax) & (N <= hi[0] + rmax))
        near_cols = np.flatnonzero((E >= lo[1] - rmax) & (E <= hi[1] + rmax))
        sub = h[np.ix_(near_rows, near_cols)]
        if cfg.trigger_height_m > 0 and not np.any(
            (np.nan_to_num(sub) > cfg.trigger_height_m) & ~mask[np.ix_(near_rows, near_cols)]
        ):
            return out
        if full_points is None:
            full_points = lambda c, r: points[np.hypot(points[:, 0] - c[0], points[:, 1] - c[1]) <= r]  # noqa: E731
        G = ElevationMap(em.spec, ground, em.count)
        for model in self.models:
            tpl = self.templates[model.name]
            tried = np.zeros(h.shape, bool)  # this model's rejected candidates (its registration failed)
            for name, c in skip:
                if name == model.name:
                    tried |= np.hypot(N[:, None] - c[0], E[None, :] - c[1]) <= 0.5 * model.footprint_radius
            ii, jj = np.meshgrid(rows, cols, indexing="ij")
            cand = np.column_stack([ii.ravel(), jj.ravel()])
            cand = cand[np.isfinite(h[cand[:, 0], cand[:, 1]])]
            reach = int(np.ceil(2 * model.footprint_radius / self.delta)) + 1
            while True:
                t1 = time.process_time()
                blocked = mask | tried
                hh = np.where(mask, np.nan, h)
                bins = tpl.spec.bin_of(hh)
                cand = cand[~blocked[cand[:, 0], cand[:, 1]]]
                res = search(
                    bins,
                    tpl,
                    cand,
                    cfg.threshold * tpl.flat_score,
                    cfg.min_coverage,
                    cfg.min_ring_coverage,
                    cfg.bootstrap,
                    cfg.chunk,
                )
                if res.centre is not None:
                    # the next search of this model needs only the candidates that passed the first
                    # ring under the threshold, and those whose disc the removed area changes
                    ci, cj = res.centre
                    changed = (np.abs(cand[:, 0] - ci) <= reach) & (np.abs(cand[:, 1] - cj) <= reach)
                    keep = np.zeros(len(cand), bool)
                    keep[res.survivors] = True
                    cand = cand[keep | changed]
                t_search = time.process_time() - t1
                if res.centre is None:
                    break
                centre = np.array([N[res.centre[0]], E[res.centre[1]]])
                det = Detection(
                    model.name,
                    centre,
                    res.score,
                    res.score / tpl.flat_score,
                    res.coverage,
                    timing={"map_s": t_map, "search_s": t_search},
                )
                t_map = 0.0
                disc = np.hypot(N[:, None] - centre[0], E[None, :] - centre[1]) <= model.footprint_radius
                if register:
                    t2 = time.process_time()
                    det.registration = self.register(
                        model.name, full_points(centre, model.footprint_radius + 1.5), G, centre
                    )
                    det.timing["registration_s"] = time.process_time() - t2
                    if det.registration is None:
                        # the CAD does not fit there: not this model (maybe a smaller one), search on
                        tried |= (
                            np.hypot(N[:, None] - centre[0], E[None, :] - centre[1]) <= 0.5 * model.footprint_radius
                        )
                        self.rejected.append(det)
                        continue
                # the largest structure's area is removed before the next (and the same model's next) search
                mask |= disc
                out.append(det)
        return out

    def register(
        self,
        name: str,
        points: np.ndarray,
        ground: ElevationMap,
        centre: np.ndarray,
        min_fitness: float | None = None,
    ) -> Registration | None:
        """4-D + ICP registration of model ``name`` recognised at ``centre``; None if it fails the checks."""
        md = self.model_data[name]
        pts = np.asarray(points, float)
        gd = ground.sample(pts[:, 0], pts[:, 1])
        ok = np.isfinite(gd)
        if ok.sum() < 50:
            return None
        pts_h = np.column_stack([pts[ok, :2], gd[ok] - pts[ok, 2]])
        gc = ground.sample(np.array([centre[0]]), np.array([centre[1]]))[0]
        if not np.isfinite(gc):
            gc = float(np.median(gd[ok]))
        try:
            reg = register_structure(md, pts_h, pts, centre, gc, self.reg_cfg)
        except ValueError:
            return None
        return self.quality_test(name, pts, reg, min_fitness)

    def quality_test(
        self, name: str, pts: np.ndarray, reg: Registration, min_fitness: float | None = None
    ) -> Registration | None:
        """``reg`` (of model ``name`` on the points ``pts``), or its half-turn alternative if that fits
        better, when it is a new structure's registration: it fits (median, ``min_fitness``, by default
        ``new_min_fitness``) and is not ambiguous; a new structure (no ``min_fitness`` given) must also
        explain the structure around it (``max_unexplained``: at the mission's end, all the passes
        misaligned by the navigation put a right model's edges off its footprint); else None."""
        c = self.reg_cfg
        if reg.median_m > c.max_median_m or reg.fitness < c.min_fitness:
            return None  # not worth the alternative's ICP
        reg, ambiguous = half_turn_check(self.model_data[name], pts, reg, c)
        need = c.new_min_fitness if min_fitness is None else min_fitness
        if ambiguous or reg.median_m > c.max_median_m or reg.fitness < need:
            return None
        if min_fitness is None and reg.unexplained > c.max_unexplained:
            return None
        return reg

    def register_anew(
        self,
        name: str,
        points: np.ndarray,
        centre: np.ndarray,
        ground_kw: dict | None = None,
        min_fitness: float | None = None,
    ) -> Registration | None:
        """Model ``name`` registered afresh (4-D + ICP + :meth:`quality_test` with ``min_fitness``) on
        ``points`` ({W}) around ``centre`` (north, east), the seabed estimated from them; None if it fails."""
        em, ground, _ = self.heights(points, ground_kw=ground_kw)
        G = ElevationMap(em.spec, ground, em.count)
        return self.register(name, points, G, np.asarray(centre, float), min_fitness)
