"""The rotation-invariant circular descriptor of Guerneve et al. and its branch-and-bound search.

A circular patch of radius R (the model's footprint radius) is cut into N concentric rings of equal
width; each ring holds the histogram of the heights above the seabed of its cells over P bins
(empty cells do not count: each ring's histogram is normalised by its filled cells). Turning the
patch about its centre permutes the cells of every ring, so the descriptor is invariant to yaw.

Two descriptors are compared ring by ring with the Earth Mover's Distance. In 1-D, with P bins of
width w, the EMD has a closed form: w · Σ_p |F_a(p) − F_b(p)|, the L1 distance between the
cumulative histograms (scipy.stats.wasserstein_distance computes the same number from the bin
centres and weights). The score of a candidate is the Euclidean norm of its N ring distances.

Search (:func:`search`): candidate centres every Δ on a grid of cell Δ; the partial norm over the
rings evaluated so far can only grow, so a candidate is dropped as soon as it exceeds the bound,
the smaller of the acceptance threshold and the best complete score found so far (branch and
bound, rings inner to outer). All candidates alive are evaluated together, ring by ring, with
gathers and ``bincount`` — no Python loop over centres.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import open3d as o3d


@dataclass(frozen=True)
class DescriptorSpec:
    """Ring and bin layout shared by a model's descriptor and the field's."""

    radius: float
    rings: int
    cell: float
    edges: np.ndarray  # P+1 bin edges (heights, m)

    @property
    def bins(self) -> int:
        return len(self.edges) - 1

    @property
    def bin_width(self) -> float:
        return float(self.edges[1] - self.edges[0])

    def offsets(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """Per ring, the (row, column) offsets of its cells from the centre cell."""
        k = int(np.ceil(self.radius / self.cell))
        di, dj = np.mgrid[-k : k + 1, -k : k + 1]
        r = np.hypot(di, dj) * self.cell
        ring = np.floor(r / self.radius * self.rings).astype(int)
        return [(di[ring == n], dj[ring == n]) for n in range(self.rings)]

    def bin_of(self, heights: np.ndarray) -> np.ndarray:
        """Bin index (int8) of every height; −1 for NaN. Heights beyond the edges go to the end bins."""
        h = np.asarray(heights, float)
        b = np.floor((h - self.edges[0]) / self.bin_width)
        b = np.clip(np.nan_to_num(b, nan=-1.0), 0, self.bins - 1)
        b[~np.isfinite(h)] = -1
        return b.astype(np.int8)


def make_spec(radius: float, rings: int, cell: float, hmin: float, hmax: float, bins: int) -> DescriptorSpec:
    return DescriptorSpec(float(radius), int(rings), float(cell), np.linspace(hmin, hmax, bins + 1))


def emd_1d(cdf_a: np.ndarray, cdf_b: np.ndarray, bin_width: float) -> np.ndarray:
    """Earth Mover's Distance between 1-D histograms given by their cumulative sums (last axis)."""
    return bin_width * np.abs(np.asarray(cdf_a) - np.asarray(cdf_b)).sum(axis=-1)


def ring_histograms(bins: np.ndarray, spec: DescriptorSpec, centre: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """(N×P histograms normalised per ring, N filled-cell counts) of the patch centred at grid cell
    ``centre`` of the bin-index grid ``bins`` (−1 = empty). Cells outside the grid are empty."""
    H, W = bins.shape
    P = spec.bins
    hist = np.zeros((spec.rings, P))
    counts = np.zeros(spec.rings, int)
    for n, (di, dj) in enumerate(spec.offsets()):
        i, j = centre[0] + di, centre[1] + dj
        ok = (i >= 0) & (i < H) & (j >= 0) & (j < W)
        b = bins[i[ok], j[ok]]
        b = b[b >= 0]
        counts[n] = len(b)
        if len(b):
            hist[n] = np.bincount(b, minlength=P) / len(b)
    return hist, counts


def descriptor_cdf(hist: np.ndarray) -> np.ndarray:
    return np.cumsum(hist, axis=-1)


def score(cdf_a: np.ndarray, cdf_b: np.ndarray, bin_width: float) -> float:
    """Norm of the ring-by-ring EMDs."""
    return float(np.linalg.norm(emd_1d(cdf_a, cdf_b, bin_width)))


# ----------------------------------------------------------------------------------------------
# model elevation maps


def model_height_map(
    mesh: o3d.geometry.TriangleMesh,
    cell: float,
    radius: float,
    T: np.ndarray | None = None,
    centre: tuple[float, float] = (0.0, 0.0),
) -> np.ndarray:
    """Heights above the base (m) of a model ray-cast straight down on a grid of ``cell`` centred on
    ``centre`` (model x = rows, y = columns) out to ``radius``; 0 where a ray misses the mesh (the
    seabed around the structure). ``T`` optionally turns/moves the mesh first (4×4)."""
    k = int(np.ceil(radius / cell))
    x = centre[0] + np.arange(-k, k + 1) * cell
    y = centre[1] + np.arange(-k, k + 1) * cell
    X, Y = np.meshgrid(x, y, indexing="ij")
    m = o3d.geometry.TriangleMesh(mesh)
    if T is not None:
        m.transform(np.asarray(T, float))
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(m))
    zmin = float(np.asarray(m.vertices)[:, 2].min()) - 1.0
    rays = np.zeros((X.size, 6), np.float32)
    rays[:, 0], rays[:, 1], rays[:, 2] = X.ravel(), Y.ravel(), zmin
    rays[:, 5] = 1.0  # +z: down in {M}
    t = scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()
    h = np.where(np.isfinite(t), -(zmin + t), 0.0)
    return np.maximum(h, 0.0).reshape(X.shape)


@dataclass
class Template:
    """A model's descriptor: ``cdf`` N×P, its distance to a flat seabed (the normalising scale)."""

    name: str
    spec: DescriptorSpec
    cdf: np.ndarray
    flat_score: float
    heights: np.ndarray  # the model's elevation map at the descriptor cell (centred)
    ring_contrast: np.ndarray | None = None  # per ring, the EMD between the model and a flat seabed


def model_template(name: str, mesh, spec: DescriptorSpec) -> Template:
    h = model_height_map(mesh, spec.cell, spec.radius)
    k = h.shape[0] // 2
    hist, _ = ring_histograms(spec.bin_of(h), spec, (k, k))
    cdf = descriptor_cdf(hist)
    flat = np.zeros_like(hist)
    flat[:, spec.bin_of(np.array([0.0]))[0]] = 1.0
    contrast = emd_1d(cdf, descriptor_cdf(flat), spec.bin_width)
    return Template(name, spec, cdf, float(np.linalg.norm(contrast)), h, contrast)


# ----------------------------------------------------------------------------------------------
# branch-and-bound search


@dataclass
class SearchResult:
    centre: tuple[int, int] | None  # grid cell of the best candidate (None: nothing under the bound)
    score: float
    coverage: float
    evaluated_rings: int  # ring evaluations done (candidates × rings), for the benchmark
    candidates: int
    survivors: np.ndarray | None = None  # candidates (indices into the input) under ``bound`` after the first ring


def search(
    bins: np.ndarray,
    template: Template,
    candidates: np.ndarray,
    bound: float,
    min_coverage: float = 0.75,
    min_ring_coverage: float = 0.4,
    bootstrap: int = 8,
    chunk: int = 40000,
) -> SearchResult:
    """Best candidate centre (grid cells, K×2 ``candidates``) for ``template`` on the bin-index grid
    ``bins`` (−1 empty), among those whose score is below ``bound``; branch and bound over rings.

    A ring with fewer than ``min_ring_coverage`` of its cells filled (the top of a tall narrow
    structure out of the fan's reach, a shadow) is left out of the score, which is then the norm
    over the rings used scaled by √(N / N_used); a candidate whose disc has fewer than
    ``min_coverage`` of its cells filled is dropped. The unscaled partial norm is a lower bound of
    the final score, so pruning on it is exact.
    """
    spec = template.spec
    P = spec.bins
    N = spec.rings
    offs = spec.offsets()
    k = int(np.ceil(spec.radius / spec.cell))
    H, W = bins.shape
    padded = np.full((H + 2 * k, W + 2 * k), -1, np.int8)
    padded[k : k + H, k : k + W] = bins
    Wp = W + 2 * k
    flat_off = [(di * Wp + dj).astype(np.int64) for di, dj in offs]
    ring_size = np.array([len(o) for o in flat_off])
    total = ring_size.sum()
    cand = np.asarray(candidates, np.int64).reshape(-1, 2)
    ok = (cand[:, 0] >= 0) & (cand[:, 0] < H) & (cand[:, 1] >= 0) & (cand[:, 1] < W)
    cand = cand[ok]
    centres = (cand[:, 0] + k) * Wp + (cand[:, 1] + k)
    flatb = padded.ravel()
    evals = 0

    def ring_emd(idx: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
        """EMD of ring n (0 where the ring is too sparse to count) and its filled cells."""
        out_e = np.empty(len(idx))
        out_c = np.empty(len(idx), np.int64)
        step = max(1, chunk * 64 // max(len(flat_off[n]), 1))
        for s in range(0, len(idx), step):
            c = idx[s : s + step]
            b = flatb[c[:, None] + flat_off[n][None, :]]
            rows = np.broadcast_to(np.arange(len(c))[:, None], b.shape)
            m = b >= 0
            hist = np.bincount(rows[m] * P + b[m], minlength=len(c) * P).reshape(len(c), P).astype(float)
            cnt = hist.sum(1)
            cdf = np.cumsum(hist, 1) / np.maximum(cnt, 1)[:, None]
            e = spec.bin_width * np.abs(cdf - tcdf[n]).sum(1)
            out_e[s : s + step] = np.where(cnt >= min_ring_coverage * ring_size[n], e, 0.0)
            out_c[s : s + step] = cnt
        return out_e, out_c

    # rings in decreasing order of pruning power per cell evaluated (the model's squared distance
    # to a flat seabed in that ring over the ring's size): the seabed, most of the field, is then
    # pruned after the fewest cells gathered (any order is exact)
    sizes0 = np.array([len(o) for o in flat_off])
    order = np.argsort(-(template.ring_contrast**2) / sizes0) if template.ring_contrast is not None else np.arange(N)
    flat_off = [flat_off[n] for n in order]
    ring_size = ring_size[order]
    tcdf = template.cdf[order]
    n_cand = len(centres)
    survivors = np.zeros(0, np.int64)
    partial = np.zeros(n_cand)
    filled = np.zeros(n_cand, np.int64)
    used = np.zeros(n_cand, np.int64)
    best_score, best_idx = np.inf, None
    b2 = bound**2

    def finish(idx: np.ndarray, start: int) -> None:
        """Complete candidates ``idx`` from ring ``start`` on (no pruning) and update the best."""
        nonlocal best_score, best_idx, b2
        for n in range(start, N):
            e, c = ring_emd(centres[idx], n)
            partial[idx] += e**2
            filled[idx] += c
            used[idx] += c >= min_ring_coverage * ring_size[n]
        final = np.sqrt(partial[idx] * N / np.maximum(used[idx], 1))
        good = (filled[idx] >= min_coverage * total) & (used[idx] > 0)
        if good.any():
            j = int(np.argmin(np.where(good, final, np.inf)))
            if final[j] < min(best_score, bound):
                best_score, best_idx = float(final[j]), int(idx[j])
                b2 = min(b2, best_score**2)

    alive = np.arange(n_cand)
    for n in range(N):
        if len(alive) == 0:
            break
        e, c = ring_emd(centres[alive], n)
        evals += len(alive)
        partial[alive] += e**2
        filled[alive] += c
        used[alive] += c >= min_ring_coverage * ring_size[n]
        # the disc coverage must still be reachable with the remaining rings
        keep = (partial[alive] < b2) & (filled[alive] + ring_size[n + 1 :].sum() >= min_coverage * total)
        alive = alive[keep]
        if n == 0:
            survivors = alive.copy()
        if n == 0 and len(alive) and N > 1:
            # bootstrap the bound: complete the best few after the first ring
            top = alive[np.argsort(partial[alive])[:bootstrap]]
            evals += len(top) * (N - 1)
            finish(top, 1)
            alive = np.setdiff1d(alive, top, assume_unique=True)
            alive = alive[partial[alive] < b2]
    if len(alive):
        finish_idx = alive
        # every ring was evaluated for these: only the final scaling remains
        final = np.sqrt(partial[finish_idx] * N / np.maximum(used[finish_idx], 1))
        good = (filled[finish_idx] >= min_coverage * total) & (used[finish_idx] > 0)
        if good.any():
            j = int(np.argmin(np.where(good, final, np.inf)))
            if final[j] < min(best_score, bound):
                best_score, best_idx = float(final[j]), int(finish_idx[j])
    kept = np.flatnonzero(ok)[survivors]  # back to the caller's candidate indices
    if best_idx is None:
        return SearchResult(None, float("inf"), 0.0, evals, n_cand, kept)
    return SearchResult(
        (int(cand[best_idx, 0]), int(cand[best_idx, 1])),
        best_score,
        float(filled[best_idx] / total),
        evals,
        n_cand,
        kept,
    )


def exhaustive_scores(
    bins: np.ndarray, template: Template, candidates: np.ndarray, min_ring_coverage: float = 0.4
) -> tuple[np.ndarray, np.ndarray]:
    """Every candidate's full score and disc coverage, without pruning (rings in their natural
    order, one histogram per candidate and ring): the reference the branch and bound must agree
    with, and the score maps of the experiments."""
    spec = template.spec
    P, N = spec.bins, spec.rings
    cand = np.asarray(candidates, np.int64).reshape(-1, 2)
    H, W = bins.shape
    sq = np.zeros(len(cand))
    used = np.zeros(len(cand))
    filled = np.zeros(len(cand))
    total = 0
    for n, (di, dj) in enumerate(spec.offsets()):
        total += len(di)
        i = cand[:, 0, None] + di[None, :]
        j = cand[:, 1, None] + dj[None, :]
        inside = (i >= 0) & (i < H) & (j >= 0) & (j < W)
        b = np.where(inside, bins[np.clip(i, 0, H - 1), np.clip(j, 0, W - 1)], -1)
        hist = np.stack([(b == p).sum(1) for p in range(P)], 1).astype(float)
        cnt = hist.sum(1)
        e = emd_1d(np.cumsum(hist, 1) / np.maximum(cnt, 1)[:, None], template.cdf[n], spec.bin_width)
        ok = cnt >= min_ring_coverage * len(di)
        sq += np.where(ok, e**2, 0.0)
        used += ok
        filled += cnt
    scores = np.where(used > 0, np.sqrt(sq * N / np.maximum(used, 1)), np.inf)
    return scores, filled / total
