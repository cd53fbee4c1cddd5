"""Registration of a recognised CAD structure: exhaustive 4-D match, then robust ICP to 6-D.

4-D (Guerneve et al.): north, east and yaw are searched exhaustively (yaw over [0, 2π/symmetry),
north/east within ± ``shift_range_m`` of the recognised centre), depth by the signed median of
the height differences; the cost is the median unsigned difference between the field's elevation
map (heights above the seabed, upper surface per cell) and the model's, coarse (8 cm cells, 3°)
then fine (4 cm, 1° and 2 cm around the three best coarse hypotheses).

6-D: point-to-plane ICP (open3d) with a Tukey kernel from that pose, the target being points
sampled on the mesh's faces that can be seen from above (and the levelled seabed pad the structure
stands on, which pins depth, roll and pitch), over decreasing correspondence distances.

Quality and covariance: the median distance from the structure's points (above the pad, inside
the model's footprint) to the mesh, and the share of them within the kernel width (fitness). The
covariance is the inverse of the linearised point-to-plane information
Σ J_iᵀ J_i / σ̂², J_i = [(n_i × y_i)ᵀ, −n_iᵀ] (rotation then translation, a right perturbation of
T_F,M: on the model side, as StructureObservation wants), with σ̂ the robust σ of the inlier
residuals, divided by ``correlation_points`` (neighbouring returns are not independent).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import open3d as o3d
from scipy import ndimage
from scipy.spatial import cKDTree

from frontends.sonar.config import StructureRegistrationConfig
from frontends.sonar.descriptor import model_height_map
from frontends.sonar.grid import ElevationMap, GridSpec
from frontends.sonar.patches import inv, transform
from semslam.models.structures import StructureModel, pose_matrix

PAD_MARGIN_M = 0.3  # the ground disc of the ICP target reaches this beyond the footprint
STRUCTURE_MIN_HEIGHT_M = 0.10  # structure points are this far above the pad at least
FOOTPRINT_DILATE_M = 0.05
# Points this high above the base are structure, never seabed or a pipe lying on it (≤ 0.5 m): seen
# within UNEXPLAINED_RING_M beyond the footprint, they are structure that the model does not explain.
UNEXPLAINED_HEIGHT_M = 1.0
UNEXPLAINED_RING_M = 1.0


@dataclass
class ModelData:
    """Everything the registration needs of one model, built once."""

    model: StructureModel
    cell: float
    heights: np.ndarray  # fine elevation map (model frame, centred), 0 = seabed
    k: int  # heights is (2k+1)²
    occupancy: np.ndarray  # footprint mask (dilated) on the same grid
    target: o3d.geometry.PointCloud  # ICP target in {M}
    tree: cKDTree
    target_points: np.ndarray
    normals: np.ndarray
    scene: o3d.t.geometry.RaycastingScene

    def height_at(self, xy: np.ndarray) -> np.ndarray:
        """Model height at model-frame (x, y) points (nearest cell; 0 outside the grid)."""
        i = np.rint(xy[..., 0] / self.cell).astype(np.int64) + self.k
        j = np.rint(xy[..., 1] / self.cell).astype(np.int64) + self.k
        n = self.heights.shape[0]
        ok = (i >= 0) & (i < n) & (j >= 0) & (j < n)
        out = np.zeros(i.shape)
        out[ok] = self.heights[i[ok], j[ok]]
        return out

    def on_footprint(self, xy: np.ndarray) -> np.ndarray:
        i = np.rint(xy[..., 0] / self.cell).astype(np.int64) + self.k
        j = np.rint(xy[..., 1] / self.cell).astype(np.int64) + self.k
        n = self.occupancy.shape[0]
        ok = (i >= 0) & (i < n) & (j >= 0) & (j < n)
        out = np.zeros(i.shape, bool)
        out[ok] = self.occupancy[i[ok], j[ok]]
        return out

    def footprint_coverage(self, xy: np.ndarray, block: float = 0.1) -> float:
        """Share of the footprint's ``block`` cells that hold at least one of the points (model x, y)."""
        f = max(int(round(block / self.cell)), 1)
        n = self.occupancy.shape[0]
        m = -(-n // f)
        occ = np.zeros((m * f, m * f), bool)
        occ[:n, :n] = self.occupancy
        occ_b = occ.reshape(m, f, m, f).any((1, 3))
        i = (np.rint(xy[:, 0] / self.cell).astype(np.int64) + self.k) // f
        j = (np.rint(xy[:, 1] / self.cell).astype(np.int64) + self.k) // f
        ok = (i >= 0) & (i < m) & (j >= 0) & (j < m)
        hit = np.zeros((m, m), bool)
        hit[i[ok], j[ok]] = True
        return float((hit & occ_b).sum() / max(occ_b.sum(), 1))

    def distance(self, y: np.ndarray) -> np.ndarray:
        return self.scene.compute_distance(o3d.core.Tensor(np.asarray(y, np.float32))).numpy()


def _sample_visible(mesh: o3d.geometry.TriangleMesh, spacing: float, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Points and normals sampled uniformly (one per spacing² of area) on the faces that are not
    turned down (a sonar above can see them)."""
    V = np.asarray(mesh.vertices)
    F = np.asarray(mesh.triangles)
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    cr = np.cross(b - a, c - a)
    area = 0.5 * np.linalg.norm(cr, axis=1)
    n = cr / np.maximum(2 * area, 1e-12)[:, None]
    # in {M} z is down: a face seen from above has a normal with n_z < 0 (up) or is vertical
    keep = (n[:, 2] < 0.3) & (area > 0)
    a, b, c, n, area = a[keep], b[keep], c[keep], n[keep], area[keep]
    rng = np.random.default_rng(seed)
    counts = rng.poisson(area / spacing**2)
    idx = np.repeat(np.arange(len(area)), counts)
    u, v = rng.random(len(idx)), rng.random(len(idx))
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    pts = a[idx] + u[:, None] * (b[idx] - a[idx]) + v[:, None] * (c[idx] - a[idx])
    normals = n[idx]
    normals = np.where(normals[:, 2:3] > 0, -normals, normals)  # orient upward-ish (sign is irrelevant)
    return pts, normals


_CACHE: dict = {}


def model_data(model: StructureModel, cfg: StructureRegistrationConfig, cell: float = 0.02) -> ModelData:
    key = (model.name, id(model.mesh), cell, cfg.model_sample_m, cfg.ground_plane)
    if key in _CACHE:
        return _CACHE[key]
    R = model.footprint_radius + 0.5
    h = model_height_map(model.mesh, cell, R)
    k = h.shape[0] // 2
    occ = ndimage.binary_dilation(h > 0.05, iterations=max(int(round(FOOTPRINT_DILATE_M / cell)), 1))
    pts, nrm = _sample_visible(model.mesh, cfg.model_sample_m)
    if cfg.ground_plane:
        rr = model.footprint_radius + PAD_MARGIN_M
        g = np.arange(-rr, rr + 1e-9, cfg.model_sample_m)
        X, Y = np.meshgrid(g, g, indexing="ij")
        disc = np.hypot(X, Y) <= rr
        gp = np.column_stack([X[disc], Y[disc], np.zeros(disc.sum())])
        pts = np.vstack([pts, gp])
        nrm = np.vstack([nrm, np.tile([0.0, 0.0, -1.0], (len(gp), 1))])
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    pcd.normals = o3d.utility.Vector3dVector(nrm)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(model.mesh))
    data = ModelData(model, cell, h, k, occ, pcd, cKDTree(pts), pts, nrm, scene)
    _CACHE[key] = data
    return data


@dataclass
class Registration:
    T: np.ndarray  # T_F,M (4×4) in the frame F of the points given
    median_m: float  # median distance of the structure points to the mesh
    fitness: float  # share of structure points within the kernel width
    n_structure: int  # structure points (above the pad, on the footprint)
    cov: np.ndarray  # 6×6, rotation then translation, model side
    sigma: float  # robust σ of the point-to-plane residuals
    coverage: float = 1.0  # share of the model's footprint (10 cm blocks) the structure points cover
    cost_4d: float | None = None
    # share of the high points around the model (above UNEXPLAINED_HEIGHT_M, within the footprint's
    # radius + UNEXPLAINED_RING_M) that lie off its footprint: a model slid along a structure leaves
    # the structure's far end unexplained, which fitness (on the footprint only) never sees
    unexplained: float = 0.0


# ----------------------------------------------------------------------------------------------
# 4-D exhaustive search


def _field_grid(pts_h: np.ndarray, centre: np.ndarray, radius: float, cell: float) -> tuple[np.ndarray, np.ndarray]:
    """Cells (centres relative to ``centre``, K×2) and their heights (upper surface) of the points
    (north, east, height above the seabed) within ``radius``."""
    rel = pts_h[:, :2] - centre
    sel = np.hypot(rel[:, 0], rel[:, 1]) <= radius
    if not sel.any():
        return np.zeros((0, 2)), np.zeros(0)
    spec = GridSpec.around(-np.full(2, radius), np.full(2, radius), cell)
    # ElevationMap works on depth: use −height so that the 0.1 quantile of depth is the top
    em = ElevationMap.from_points(np.column_stack([rel[sel], -pts_h[sel, 2]]), spec=spec, quantile=0.1)
    ok = em.filled
    ni, ei = spec.centres()
    N, E = np.meshgrid(ni, ei, indexing="ij")
    return np.column_stack([N[ok], E[ok]]), -em.depth[ok]


def _costs(md: ModelData, cells: np.ndarray, hf: np.ndarray, yaws: np.ndarray, shifts: np.ndarray, radius: float):
    """Median unsigned height difference (after the signed-median offset) over the field cells
    within ``radius`` of the shifted model origin, for every yaw × shift: (cost Y×S, offset Y×S).
    Cells outside the disc count as seabed-vs-field mismatches only through the disc: a model
    moved off the data therefore does not win by seeing less of it (the disc is always full)."""
    cost = np.empty((len(yaws), len(shifts)))
    off = np.empty((len(yaws), len(shifts)))
    rel_all = cells[None, :, :] - shifts[:, None, :]  # S×K×2 in {W} axes about the centre
    inside = np.einsum("skc,skc->sk", rel_all, rel_all) <= radius**2
    # the same number of cells for every shift: the K0 cells nearest each shifted origin
    k0 = int(inside.sum(1).min())
    if k0 < 10:
        return np.full((len(yaws), len(shifts)), np.inf), np.zeros((len(yaws), len(shifts)))
    d2 = np.einsum("skc,skc->sk", rel_all, rel_all)
    nearest = np.argpartition(d2, k0 - 1, axis=1)[:, :k0]
    rel_all = np.take_along_axis(rel_all, nearest[..., None], axis=1)
    hf_s = hf[nearest]
    for a, th in enumerate(yaws):
        c, s = np.cos(th), np.sin(th)
        rel = rel_all
        xm = c * rel[..., 0] + s * rel[..., 1]  # Rᵀ(θ)·rel
        ym = -s * rel[..., 0] + c * rel[..., 1]
        hm = md.height_at(np.stack([xm, ym], -1))
        r = (hf_s - hm).astype(np.float32)
        d = np.median(r, axis=1)
        cost[a] = np.median(np.abs(r - d[:, None]), axis=1)
        off[a] = d
    return cost, off


def search_4d(
    md: ModelData, pts_h: np.ndarray, centre: np.ndarray, cfg: StructureRegistrationConfig
) -> tuple[float, np.ndarray, float, float]:
    """(yaw, north/east of the model origin, height offset, cost) of the best 4-D match, searched
    exhaustively over yaw ∈ [0, 2π/symmetry) and north/east within ± the shift range of ``centre``
    on a coarse grid, then refined twice around the best hypotheses at halved cells, steps and yaw
    steps. ``pts_h``: field points (north, east, height above the seabed estimate)."""
    model = md.model
    R = model.footprint_radius + 0.2
    period = model.yaw_period
    rng = max(cfg.shift_range_m, cfg.shift_range_frac * model.footprint_radius)
    cell = cfg.coarse_cell_m
    ystep = np.radians(cfg.yaw_step_deg)
    cells, hf = _field_grid(pts_h, centre, R + rng, cell)
    if len(cells) < 20:
        raise ValueError("too few field cells for the 4-D search")
    if len(cells) > cfg.coarse_max_cells:  # the coarse level on an even subsample of its cells
        keep = np.linspace(0, len(cells) - 1, cfg.coarse_max_cells).round().astype(int)
        cells, hf = cells[keep], hf[keep]
    yaws = np.arange(0.0, period - 1e-9, ystep)
    g = np.arange(-np.floor(rng / cell), np.floor(rng / cell) + 1) * cell
    shifts = np.stack(np.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)
    cost, off = _costs(md, cells, hf, yaws, shifts, R)
    # the best distinct yaws, each with its best shift
    order = np.argsort(cost.min(1))
    seeds: list[tuple[float, np.ndarray]] = []
    for a in order:
        if all(abs((yaws[a] - y + period / 2) % period - period / 2) > 2.5 * ystep for y, _ in seeds):
            seeds.append((float(yaws[a]), shifts[int(np.argmin(cost[a]))]))
        if len(seeds) == cfg.fine_seeds:
            break
    best = (np.inf, 0.0, np.zeros(2), 0.0)
    for level in range(cfg.refine_levels):
        step, cell, ystep = cell / 2, cell / 2, ystep / 2
        cells_f, hf_f = _field_grid(pts_h, centre, R + rng, cell)
        loc = np.arange(-2, 3) * step
        dy = np.arange(-2, 3) * ystep
        new_seeds = []
        for y0, s0 in seeds:
            sh = s0 + np.stack(np.meshgrid(loc, loc, indexing="ij"), -1).reshape(-1, 2)
            c2, o2 = _costs(md, cells_f, hf_f, y0 + dy, sh, R)
            i, j = np.unravel_index(int(np.argmin(c2)), c2.shape)
            new_seeds.append((float(c2[i, j]), float((y0 + dy[i]) % period), sh[j], float(o2[i, j])))
        new_seeds.sort(key=lambda t: t[0])
        best = new_seeds[0]
        seeds = [(y, s_) for _, y, s_, _ in new_seeds[: max(1, cfg.fine_seeds // (level + 1))]]
    cost_b, yaw, s_b, off_b = best
    return yaw, centre + s_b, off_b, cost_b


# ----------------------------------------------------------------------------------------------
# ICP


def icp(
    md: ModelData,
    pts: np.ndarray,
    T0: np.ndarray,
    cfg: StructureRegistrationConfig,
    distances: tuple[float, ...] | None = None,
) -> Registration:
    """Robust point-to-plane ICP of the field points ``pts`` (N×3, frame F) on the model from T_F,M
    ``T0``; returns the registration with its quality and covariance."""
    y = transform(inv(T0), pts)
    src = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(y))
    if cfg.icp_voxel_m > 0:
        src = src.voxel_down_sample(cfg.icp_voxel_m)
    T_corr = np.eye(4)
    for dist in distances or cfg.icp_distances_m:
        k = max(cfg.tukey_k_m, dist / 2)
        est = o3d.pipelines.registration.TransformationEstimationPointToPlane(o3d.pipelines.registration.TukeyLoss(k=k))
        crit = o3d.pipelines.registration.ICPConvergenceCriteria(1e-6, 1e-6, cfg.icp_iterations)
        res = o3d.pipelines.registration.registration_icp(src, md.target, dist, T_corr, est, crit)
        T_corr = np.asarray(res.transformation)
    T = T0 @ inv(T_corr)
    return evaluate(md, pts, T, cfg)


def evaluate(md: ModelData, pts: np.ndarray, T: np.ndarray, cfg: StructureRegistrationConfig) -> Registration:
    """Quality and covariance of the registration T_F,M of points ``pts`` (frame F)."""
    y = transform(inv(T), pts)
    on = md.on_footprint(y[:, :2])
    struct = (y[:, 2] < -STRUCTURE_MIN_HEIGHT_M) & on
    ys = y[struct]
    if len(ys):
        dist = md.distance(ys)
        median = float(np.median(dist))
        fitness = float(np.mean(dist < cfg.tukey_k_m))
    else:
        median, fitness = float("inf"), 0.0
    # linearised point-to-plane information at the solution
    near = np.hypot(y[:, 0], y[:, 1]) <= md.model.footprint_radius + PAD_MARGIN_M
    yy = y[near]
    cov = np.eye(6) * 1e6
    sigma = float("inf")
    if len(yy) >= 6:
        d, idx = md.tree.query(yy, distance_upper_bound=cfg.icp_distances_m[-1])
        ok = np.isfinite(d)
        if ok.sum() >= 6:
            n = md.normals[idx[ok]]
            m = md.target_points[idx[ok]]
            yo = yy[ok]
            r = np.einsum("ij,ij->i", n, yo - m)
            sigma = 1.4826 * float(np.median(np.abs(r - np.median(r))))
            sigma = max(sigma, 1e-3)
            inl = np.abs(r) < 3 * sigma
            J = np.column_stack([np.cross(n[inl], yo[inl]), -n[inl]])
            info = J.T @ J / sigma**2 / cfg.correlation_points
            try:
                cov = np.linalg.inv(info + np.eye(6) * 1e-9)
            except np.linalg.LinAlgError:
                pass
            cov = 0.5 * (cov + cov.T)
    coverage = md.footprint_coverage(ys[:, :2]) if len(ys) else 0.0
    high = (y[:, 2] < -UNEXPLAINED_HEIGHT_M) & (
        np.hypot(y[:, 0], y[:, 1]) <= md.model.footprint_radius + UNEXPLAINED_RING_M
    )
    unexplained = float(np.mean(~on[high])) if high.any() else 0.0
    # a partial view (a 1 m strip over the structure) constrains the pose less than its points
    # suggest: the linearised part grows as the footprint coverage shrinks; the floors stand for
    # what the points cannot tell (a structure seen from one side, the CAD's small departures)
    cov = cov / max(coverage, 0.1)
    cov[:3, :3] += np.eye(3) * cfg.sigma_floor_rad**2
    cov[3:, 3:] += np.eye(3) * cfg.sigma_floor_m**2
    return Registration(T, median, fitness, int(struct.sum()), cov, sigma, coverage, unexplained=unexplained)


def register_structure(
    md: ModelData,
    pts_h: np.ndarray,
    pts: np.ndarray,
    centre: np.ndarray,
    ground_depth: float,
    cfg: StructureRegistrationConfig,
) -> Registration:
    """Recognised at ``centre`` (north, east): 4-D search on the heights ``pts_h`` then ICP on the
    points ``pts`` ({W}); the base starts at ``ground_depth`` − the 4-D height offset."""
    yaw, ne, dh, cost = search_4d(md, pts_h, np.asarray(centre, float), cfg)
    T0 = pose_matrix((ne[0], ne[1], ground_depth - dh), yaw)
    R = md.model.footprint_radius + PAD_MARGIN_M + 0.2
    near = np.hypot(pts[:, 0] - ne[0], pts[:, 1] - ne[1]) <= R
    reg = icp(md, pts[near], T0, cfg)
    reg.cost_4d = cost
    return reg


def half_turn_check(
    md: ModelData, pts: np.ndarray, reg: Registration, cfg: StructureRegistrationConfig
) -> tuple[Registration, bool]:
    """The registration ``reg`` of the points ``pts`` against its alternative, the model turned by half
    its symmetry period about its vertical axis (a PLET end for end: its two ends look alike from
    above) and registered again by ICP: (the better fitting of the two, ambiguous), ambiguous when
    the other fits within ``cfg.ambiguity_margin`` of it (too little of the structure seen to tell)."""
    half = 0.5 * md.model.yaw_period
    turn = np.eye(4)
    turn[:2, :2] = [[np.cos(half), -np.sin(half)], [np.sin(half), np.cos(half)]]
    T = reg.T
    near = np.hypot(pts[:, 0] - T[0, 3], pts[:, 1] - T[1, 3]) <= md.model.footprint_radius + PAD_MARGIN_M + 0.2
    alt = icp(md, pts[near], T @ turn, cfg)
    alt.cost_4d = reg.cost_4d
    best, other = (alt, reg) if (alt.fitness, -alt.median_m) > (reg.fitness, -reg.median_m) else (reg, alt)
    return best, other.fitness >= best.fitness - cfg.ambiguity_margin
