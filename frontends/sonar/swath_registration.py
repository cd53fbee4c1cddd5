"""Swath registration (Guerneve et al.): align new swaths on an older overlapping elevation map.

The new points (north, east, depth) are compared with the reference elevation map sampled at
their shifted positions. For a north/east shift s the residuals are r_i(s) = D_ref(x_i + s) − d_i;
the depth offset is their signed median δ(s), and the cost is the median unsigned difference
median |r_i(s) − δ(s)|. The shift minimising it is searched coarse to fine (a grid over
± max_shift, then ± 2 steps around the best at halved steps down to ``fine_step``).

Covariance (linearised, honest about texture): around the optimum the residual moves by
∇D_ref(x_i)·Δs − Δδ; with the depth offset profiled out, the information on s is
Σ (g_i − ḡ)(g_i − ḡ)ᵀ / σ̂² where g_i is the gradient of the reference map *smoothed at 15 cm*
(so that range noise does not masquerade as texture), σ̂ = 1.4826·MAD of the inlier residuals,
divided by ``correlation_cells`` because neighbouring points share reference cells and the same
texture (calibrated on seeds with ground truth so that the constraints' NEES matches their
dimension). A flat seabed gives no north/east information: a direction whose σ exceeds
``max_sigma_m`` keeps no shift and an uninformative σ; with both directions flat the registration
is rejected (depth alone is already known from the pressure sensor).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from frontends.sonar.config import SwathRegistrationConfig
from frontends.sonar.grid import ElevationMap

GRADIENT_SMOOTH_M = 0.05  # one cell: noise off the gradient without blurring edges across the map
TEXTURE_SLOPE = 0.25  # only points on slopes steeper than this carry north/east information


@dataclass
class SwathRegistration:
    shift: np.ndarray  # (north, east) to add to the new points (m), informative part only
    depth: float  # depth offset to add to the new points (m)
    cov: np.ndarray  # 3×3 covariance of (north, east, depth) in {W}
    sigma: float  # robust σ of the residuals at the optimum (m)
    n_points: int
    cost_before: float  # median unsigned difference at zero shift (after the depth offset)
    cost_after: float
    informative: int  # informative north/east directions (1 or 2)
    raw_shift: np.ndarray  # the cost minimiser before dropping flat directions


def _smoothed_gradient(ref: ElevationMap, sigma_m: float) -> tuple[ElevationMap, ElevationMap]:
    """Gradient (∂D/∂north, ∂D/∂east) of the reference map smoothed with a NaN-aware Gaussian."""
    D = ref.depth
    w = np.isfinite(D).astype(float)
    s = max(sigma_m / ref.spec.cell, 0.5)
    num = ndimage.gaussian_filter(np.nan_to_num(D), s)
    den = ndimage.gaussian_filter(w, s)
    with np.errstate(invalid="ignore", divide="ignore"):
        sm = np.where((den > 0.5) & (w > 0), num / den, np.nan)
    smoothed = ElevationMap(ref.spec, sm, ref.count)
    gn, ge = smoothed.gradient()
    return ElevationMap(ref.spec, gn, ref.count), ElevationMap(ref.spec, ge, ref.count)


def _without_tall(ref: ElevationMap, cfg: SwathRegistrationConfig) -> ElevationMap:
    """The reference map without what stands taller than ``max_height_m`` above the seabed (and a
    margin around it): a structure's elevation map depends on the side it is seen from (its
    flanks, its shadow), which would bias the shift; structures are landmarks of their own."""
    from frontends.sonar.grid import estimate_ground

    g = estimate_ground(ref.depth, ref.spec.cell)
    tall = np.nan_to_num(g - ref.depth, nan=0.0) > cfg.max_height_m
    if not tall.any():
        return ref
    tall = ndimage.binary_dilation(tall, iterations=max(int(round(cfg.tall_margin_m / ref.spec.cell)), 1))
    return ElevationMap(ref.spec, np.where(tall, np.nan, ref.depth), ref.count)


def _cost(ref: ElevationMap, pts: np.ndarray, shifts: np.ndarray, min_points: int):
    """For every shift (K×2): (cost, depth offset, valid count)."""
    out_c = np.full(len(shifts), np.inf)
    out_d = np.zeros(len(shifts))
    out_n = np.zeros(len(shifts), int)
    for k, s in enumerate(shifts):
        D = ref.sample(pts[:, 0] + s[0], pts[:, 1] + s[1])
        r = D - pts[:, 2]
        r = r[np.isfinite(r)]
        out_n[k] = len(r)
        if len(r) < min_points:
            continue
        d = np.median(r)
        out_c[k] = np.median(np.abs(r - d))
        out_d[k] = d
    return out_c, out_d, out_n


def _mean_square(
    ref: ElevationMap, pts: np.ndarray, shifts: np.ndarray, min_points: int, clip: float = 0.3
) -> np.ndarray:
    """Mean squared residual (depth offset removed, residuals clipped at ``clip``) per shift."""
    out = np.full(len(shifts), np.inf)
    for k, s in enumerate(shifts):
        r = ref.sample(pts[:, 0] + s[0], pts[:, 1] + s[1]) - pts[:, 2]
        r = r[np.isfinite(r)]
        if len(r) < min_points:
            continue
        r = np.clip(r - np.median(r), -clip, clip)
        out[k] = float(np.mean(r**2))
    return out


def _valid_everywhere(ref: ElevationMap, pts: np.ndarray, reach: float) -> np.ndarray:
    """Points whose neighbourhood of ± ``reach`` lies on filled reference cells: the cost is then
    taken over the same points at every shift (a shift must not win by moving the points onto the
    better-sampled part of the reference)."""
    ok = np.ones(len(pts), bool)
    for dn in (-reach, 0.0, reach):
        for de in (-reach, 0.0, reach):
            ok &= np.isfinite(ref.sample(pts[:, 0] + dn, pts[:, 1] + de))
    return ok


def _least_squares(ref: ElevationMap, grads, pts: np.ndarray, s0: np.ndarray, radius: float, iterations: int = 10):
    """Trimmed Gauss-Newton on r_i = D_ref(x_i + s) − d_i − δ from s0, kept within ± ``radius`` of
    s0 (a trust region: along a flat direction the least squares would wander): (s, δ, σ, J)."""
    gn, ge = grads
    s = np.array(s0, float)
    for _ in range(iterations):
        x, y = pts[:, 0] + s[0], pts[:, 1] + s[1]
        r = ref.sample(x, y) - pts[:, 2]
        G = np.column_stack([gn.sample(x, y), ge.sample(x, y)])
        ok = np.isfinite(r) & np.isfinite(G).all(1)
        if ok.sum() < 20:
            return None
        r, G = r[ok], G[ok]
        d = float(np.median(r))
        sigma = max(1.4826 * float(np.median(np.abs(r - d))), 1e-3)
        inl = np.abs(r - d) < 3 * sigma
        J = np.column_stack([G[inl], -np.ones(inl.sum())])
        res = r[inl] - d
        step = np.linalg.lstsq(J, -res, rcond=None)[0]
        step[:2] = np.clip(step[:2], -0.05, 0.05)
        s_new = s0 + np.clip(s + step[:2] - s0, -radius, radius)
        moved = np.abs(s_new - s).max()
        s = s_new
        if moved < 1e-4:
            break
    x, y = pts[:, 0] + s[0], pts[:, 1] + s[1]
    r = ref.sample(x, y) - pts[:, 2]
    G = np.column_stack([gn.sample(x, y), ge.sample(x, y)])
    ok = np.isfinite(r) & np.isfinite(G).all(1)
    r, G = r[ok], G[ok]
    d = float(np.median(r))
    sigma = max(1.4826 * float(np.median(np.abs(r - d))), 1e-3)
    inl = np.abs(r - d) < 3 * sigma
    d = float(np.mean(r[inl]))
    return s, d, sigma, np.column_stack([G[inl], -np.ones(inl.sum())])


def register(
    new_pts: np.ndarray,
    ref: ElevationMap,
    cfg: SwathRegistrationConfig,
    rng: np.random.Generator | None = None,
    why: dict | None = None,
) -> SwathRegistration | None:
    """Register new points (N×3 north, east, depth in {W}) on the reference map; None when the
    overlap is too small, the match poor, the optimum on the border of the search or inconsistent
    with its least-squares refinement, or the seabed flat in both directions (the reason is
    counted in ``why`` when given)."""
    rng = rng or np.random.default_rng(cfg.seed)

    def reject(reason: str):
        if why is not None:
            why[reason] = why.get(reason, 0) + 1
        return None

    if cfg.max_height_m > 0:
        ref = _without_tall(ref, cfg)

    pts = np.asarray(new_pts, float)
    R, step = cfg.max_shift_m, cfg.coarse_step_m
    pts = pts[np.isfinite(ref.sample(pts[:, 0], pts[:, 1]))]
    if len(pts) < cfg.min_overlap_points:
        return reject("overlap")
    if len(pts) > cfg.max_points:
        pts = pts[rng.choice(len(pts), cfg.max_points, replace=False)]
    # a shift is only scored if it keeps most of the points on the reference: it must not win by
    # moving them onto its better-sampled part (or off its holes)
    min_pts = max(int(cfg.min_kept * len(pts)), 10)
    # the paper's search: signed median depth, then the shift minimising the median unsigned
    # difference, coarse to fine
    g = np.arange(-np.floor(R / step), np.floor(R / step) + 1) * step
    S = np.stack(np.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)
    c, d, n = _cost(ref, pts, S, min_pts)
    if not np.isfinite(c).any():
        return reject("overlap")
    zero = int(np.argmin(np.abs(S).sum(1)))
    cost_before = float(c[zero])
    best = S[int(np.argmin(c))]
    if np.any(np.abs(best) >= g[-1] - 1e-9):
        return reject("border")  # the match is outside the range (or ambiguous)
    while step > cfg.fine_step_m + 1e-12:
        step = max(step / 2, cfg.fine_step_m)
        loc = np.arange(-2, 3) * step
        S = best + np.stack(np.meshgrid(loc, loc, indexing="ij"), -1).reshape(-1, 2)
        c, d, n = _cost(ref, pts, S, min_pts)
        best = S[int(np.argmin(c))]
    c_best, _, _ = _cost(ref, pts, best[None], min_pts)
    # least-squares refinement from there: its information is the covariance's
    grads = _smoothed_gradient(ref, GRADIENT_SMOOTH_M)
    ls = _least_squares(ref, grads, pts, best, cfg.coarse_step_m)
    if ls is None:
        return reject("overlap")
    s_ls, d_ls, sigma, J = ls
    if sigma > cfg.max_residual_m or len(J) < cfg.min_overlap_points * 0.5:
        return reject("residual")
    G = J[:, :2]
    sig2 = max(sigma, 1e-3) ** 2
    corr = cfg.correlation_cells
    gbar = G.mean(0)
    # information on (north, east, depth offset): J_i = [g_i, −1]; only sharp texture (pipe
    # flanks, structure edges: slopes steeper than TEXTURE_SLOPE) counts for north/east, because
    # the gentle relief's gradient cannot be told from the range noise's on a 5 cm map
    steep = np.hypot(G[:, 0], G[:, 1]) > TEXTURE_SLOPE
    G = np.where(steep[:, None], G, 0.0)
    J = np.column_stack([G, -np.ones(len(G))])
    I3 = J.T @ J / sig2 / corr
    I_sd, I_dd = I3[:2, 2], I3[2, 2]
    prof = I3[:2, :2] - np.outer(I_sd, I_sd) / I_dd  # = Σ (g − ḡ)(g − ḡ)ᵀ / σ² / corr
    w, V = np.linalg.eigh(prof)
    informative = w > 1.0 / cfg.max_sigma_m**2
    # each direction must also show in the data: the mean squared residual must rise on both sides
    # of the optimum along it (a long straight ridge gives gradients that alias into the direction
    # along it on a grid, but moving along it changes nothing). The mean square, not the median:
    # where the texture is a pipe crossing a tenth of the overlap, the median does not move
    c0 = _mean_square(ref, pts, s_ls[None], min_pts)[0]
    for k in range(2):
        if not informative[k]:
            continue
        probe = s_ls + np.outer([-1.0, 1.0], V[:, k]) * cfg.probe_m
        ck = _mean_square(ref, pts, probe, min_pts)
        if not np.isfinite(ck).all() or ck.min() - c0 < cfg.probe_rise * c0:
            informative[k] = False
    if not informative.any():
        return reject("flat")
    # along an informative direction the least squares must agree with the median search (it
    # stays within a coarse step of it: at the trust region's edge the two disagree)
    off = V.T @ (s_ls - best)
    if np.any(informative & (np.abs(off) > 0.9 * cfg.coarse_step_m)):
        return reject("inconsistent")
    w_kept = np.where(informative, w, 1.0 / cfg.uninformative_sigma_m**2)
    I3k = I3.copy()
    I3k[:2, :2] = V @ np.diag(w_kept) @ V.T + np.outer(I_sd, I_sd) / I_dd
    cov = np.linalg.inv(I3k)
    cov[:2, :2] += (V * np.where(informative, cfg.shift_sigma_floor_m**2, 0.0)) @ V.T
    cov[2, 2] += cfg.depth_sigma_floor_m**2
    # keep the shift only along the informative directions; the depth offset follows the slope
    shift = V @ np.where(informative, V.T @ s_ls, 0.0)
    d_kept = float(d_ls + gbar @ (shift - s_ls))
    return SwathRegistration(
        shift, d_kept, cov, sigma, int(len(pts)), cost_before, float(c_best[0]), int(informative.sum()), s_ls
    )
