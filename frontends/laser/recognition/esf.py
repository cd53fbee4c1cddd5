"""Ensemble of Shape Functions (ESF), Wohlgemuth/Wohlkinger & Vincze 2011, as PCL's ``ESFEstimation``.

A 640-bin global descriptor of a (partial) point cloud: ten 64-bin histograms built from random
point triplets on a 64³ voxel grid of the cloud,

    A3 (angles)            in / out / mixed   weights 0.5 0.5 0.5
    D3 (sqrt triangle area) in / out / mixed   weights 0.5 0.5 1
    D2 (point distances)   in / out / mixed   weights 0.5·1 2 2
    D2 ratio (mixed lines: fraction of the line inside the surface)  weight 0.5·2

"In/out/mixed" says whether the segment between two points runs on the voxelised surface,
off it, or both, decided by tracing the segment through the grid (3-D Bresenham).

Follows PCL ``features/impl/esf.hpp`` (read, re-implemented vectorised in numpy). Deviations:

- Randomness is numpy's seedable generator instead of ``rand()`` seeded with the wall clock, so a
  descriptor is reproducible; rejected triplets (repeated index, degenerate triangle with Heron
  product ≤ 0.001 voxel⁴) are redrawn in vectorised batches rather than one by one.
- The triplets are drawn uniformly with replacement across triplets, exactly as PCL; nothing else
  differs in the histogram definitions, the voxel index convention (``floor(x)+32`` below zero,
  ``ceil(x)+31`` above), the 3×3×3 dilation of the occupied voxels, the line-classification
  thresholds (in: ≥ count−1 voxels on the surface, out: ≤ 7, else mixed), the triangle
  classification (out: ≤ 21 surface voxels on its three sides, in: fewer than 4 off the surface,
  else mixed) or the bin weights.
- Bins are rounded as PCL's ``pcl_round`` (half away from zero, ``floor(x + 0.5)``), not half to
  even. The D2-ratio bin is PCL's float32 arithmetic exactly (a table over (inside, count)): the
  ratio inside/count is rational, so ties are common (31 of the 1540 mixed (inside, count) pairs,
  e.g. 10 of 12 voxels → bin 52.5, which PCL puts in 53; before descriptor version 3 they went to
  the even bin). The other bins are computed in float64 (PCL: float32), which moves a value only
  when it lies within float32 precision of a bin edge.
- The Bresenham walk is evaluated in closed form: after ``k`` steps along the major axis, a minor
  axis of extent ``m`` has advanced ``floor((2·m·k + l − 1) / (2·l))`` voxels (``l`` the major
  extent), which is what PCL's error-accumulator loop produces (checked against a scalar port in
  the tests). Like PCL, the walk visits ``max(l, 1)`` voxels, from the start voxel up to but not
  including the end voxel.
- Three voxels of every walk are known to be on the surface without looking: the start voxel (a
  point's), the next one and the last one (both within one voxel of a point's, so set by the 3×3×3
  dilation). ``esf`` counts them and walks only the others (exact, checked in the tests); the
  general :func:`trace_lines` walks everything.

Speed (vectorisation): the 3·20000 lines are grouped by length into bands of 4 voxels (one stable
sort of a byte), each band is walked as one padded block per ~64k voxels: three rows gathered from
a per-band offset table, the start voxel's flat index added, one look-up in the (bordered) grid,
row sums of the 0/1 bytes four or eight at a time (summed as machine words, then folded). No
Python loop runs over samples, lines or voxels; the loops run over bands and blocks (~20 per call).
``esf_many`` describes several clouds in one such pass (one look-up grid per cloud in one buffer,
every bin offset by its cloud's histogram): a scan's ~20 segments with 1000 triplets each would
otherwise pay numpy's per-call overhead, most of ``esf``'s cost at that size, once per segment.

Frames and units: the input cloud is N×3 in any metric frame (metres); the descriptor is
invariant to translation (the cloud is centred on its centroid) and scale (scaled so that the
farthest point lies at 32 voxels), and nearly invariant to rotation (the grid is axis-aligned).
"""

from __future__ import annotations

import numpy as np

ESF_BINS = 640
GRID = 64
HALF = GRID // 2
_NB = 64  # bins per sub-histogram

# The look-up grid has a one-voxel border: the dilation may spill into it (PCL drops those voxels;
# no walk ever visits them, since a walk stays between two voxels of the 64³ grid).
_PG = GRID + 2
_STRIDES = np.array([_PG * _PG, _PG, 1], dtype=np.int64)
_ORIGIN = _PG * _PG + _PG + 1  # flat index of voxel (0, 0, 0) in the bordered grid

# Offsets of the 27 voxels of a 3×3×3 neighbourhood.
_NEIGHBOURS = np.stack(np.meshgrid([-1, 0, 1], [-1, 0, 1], [-1, 0, 1], indexing="ij"), -1).reshape(-1, 3)
_NEIGHBOUR_OFFSETS = (_NEIGHBOURS[:, 0] * _PG + _NEIGHBOURS[:, 1]) * _PG + _NEIGHBOURS[:, 2]

# Voxels of a walk known to be on the surface in ``esf`` (see the module doc): the first two, the last.
_KNOWN_HEAD, _KNOWN_TAIL = 2, 1


def _voxel_index(p: np.ndarray) -> np.ndarray:
    """PCL's grid index of scaled coordinates (in voxels, grid centred on the origin)."""
    return np.where(p < 0.0, np.floor(p) + HALF, np.ceil(p) + HALF - 1).astype(np.int32)


def _surface_lut(vox: np.ndarray, grid_of: np.ndarray | None = None, n_grids: int = 1) -> np.ndarray:
    """The voxels of the points dilated by one voxel (PCL ``voxelize9``), as a flat uint8 0/1 grid
    of (64 + 2)³ voxels: the 64³ grid with a one-voxel border (voxel (x, y, z) at
    ``_ORIGIN + x·66² + y·66 + z``). With ``grid_of`` (the grid of every point, < ``n_grids``),
    ``n_grids`` such grids one after the other (grid g's voxels offset by g·66³)."""
    occ = (vox[:, 0].astype(np.int64) * _PG + vox[:, 1]) * _PG + vox[:, 2] + _ORIGIN
    if grid_of is not None:
        occ += grid_of * _PG**3
    lut = np.zeros(n_grids * _PG**3, dtype=np.uint8)
    lut[(occ[:, None] + _NEIGHBOUR_OFFSETS[None, :]).ravel()] = 1
    return lut


_TABLES: dict[tuple[int, int], np.ndarray] = {}
_BAND_TABLES: dict[tuple[int, ...], np.ndarray] = {}


def _offset_table(head: int = 0, tail: int = 0) -> np.ndarray:
    """Flat-index offsets of the Bresenham walk, ``T[l, m, s, j]`` (64×64×6×64 int32, built once).

    For a segment whose major extent is ``l`` voxels, an axis of extent ``m`` with signed stride
    ``±_STRIDES[s % 3]`` (negative for ``s ≥ 3``) has advanced ``floor((2·m·k + l − 1) / (2·l))``
    voxels after ``k`` major steps — the closed form of PCL's error-accumulator loop (with ``m = l``
    it is just ``k``, so the major axis needs no special case). Entry ``j`` is step ``k = j + head``;
    entries past the walk's last counted voxel (``j ≥ max(l, 1) − head − tail``) are 0, i.e. they
    revisit the start voxel, which the caller takes off again.
    """
    key = (head, tail)
    if key not in _TABLES:
        l = np.arange(GRID)[:, None, None]
        m = np.arange(GRID)[None, :, None]
        l1 = np.maximum(l, 1)
        j = np.arange(GRID)[None, None, :]
        step = (2 * m * (j + head) + l1 - 1) // (2 * l1)
        signed = np.concatenate([_STRIDES, -_STRIDES])
        off = step[:, :, None, :] * signed[None, None, :, None]
        valid = (j < l1 - head - tail)[:, :, None, :]
        _TABLES[key] = np.ascontiguousarray(np.where(valid, off, 0).astype(np.int32))
    return _TABLES[key]


def _band_table(l_lo: int, l_hi: int, width: int, head: int, tail: int) -> np.ndarray:
    """Rows ``l_lo ≤ l ≤ l_hi`` of the offset table, first ``width`` entries, as a contiguous
    (rows × width) array: the gathers of a band then copy short contiguous rows."""
    key = (l_lo, l_hi, width, head, tail)
    t = _BAND_TABLES.get(key)
    if t is None:
        full = _offset_table(head, tail)
        t = _BAND_TABLES[key] = np.ascontiguousarray(full[l_lo : l_hi + 1, :, :, :width]).reshape(-1, width)
    return t


# Row offset of an axis by its signed extent d (index d + 63): |d|·6 + 3·(d < 0) + axis.
_D = np.arange(-(GRID - 1), GRID)
_EXTENT_ROW = ((np.abs(_D) * 6 + 3 * (_D < 0))[None, :] + np.arange(3)[:, None]).astype(np.int32)


def _pcl_round(x: np.ndarray) -> np.ndarray:
    """PCL's ``pcl_round`` of non-negative values (half away from zero), as bin indices."""
    return np.floor(x + 0.5).astype(np.int64)


def _ratio_bins() -> np.ndarray:
    """D2-ratio bin of a mixed line by (inside, count), in PCL's float32 arithmetic:
    ``pcl_round(float(inside) / float(count) * 63)``."""
    i = np.arange(GRID + 1, dtype=np.float32)[:, None]
    c = np.maximum(np.arange(GRID + 1, dtype=np.float32), 1)[None, :]
    x = (i / c) * np.float32(_NB - 1)
    return np.floor(x + np.float32(0.5)).astype(np.int64)


_RATIO_BIN = _ratio_bins()


def _line_tables() -> tuple[np.ndarray, np.ndarray]:
    """By ``inside·65 + count`` of a walk: PCL's line class (0 in, 1 out, 2 mixed; "in" tested
    first) and the D2-ratio bin of a mixed line (64, past the histogram, for the others)."""
    i = np.arange(GRID + 1)[:, None]
    c = np.arange(GRID + 1)[None, :]
    cls = np.where(i >= c - 1, 0, np.where(i <= 7, 1, 2))
    ratio = np.where(cls == 2, _RATIO_BIN, _NB)
    return cls.ravel().astype(np.int64), ratio.ravel().astype(np.int64)


_LINE_CLASS, _LINE_RATIO_BIN = _line_tables()


def _row_sums(hit: np.ndarray) -> np.ndarray:
    """Row sums of an n×W array of 0/1 bytes (W a multiple of 4, ≤ 64): the rows are added as
    8- or 4-byte words (no byte can carry: at most 16 ones per byte), then the bytes of the sum
    are folded by one multiplication."""
    if hit.shape[1] % 8 == 0:
        v, mult, shift = hit.view(np.uint64), np.uint64(0x0101010101010101), np.uint64(56)
    else:
        v, mult, shift = hit.view(np.uint32), np.uint32(0x01010101), np.uint32(24)
    acc = v[:, 0].copy()
    for k in range(1, v.shape[1]):  # ≤ 16 word columns
        acc += v[:, k]
    return ((acc * mult) >> shift).astype(np.int64)


def _walk(
    lut: np.ndarray, start: tuple[np.ndarray, ...], end: tuple[np.ndarray, ...], *,
    chunk: int = 65536, band: int | None = None, head: int = 0, tail: int = 0,
    grid_offset: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """PCL's ``lci`` for every segment ``start → end`` (per-axis integer voxel coordinates in
    [0, 64)) in the bordered grid ``lut`` (see :func:`_surface_lut`): ``(inside, count)``.
    ``grid_offset`` (per segment) is the flat offset of its grid in a ``lut`` of several grids.

    The first ``head`` and the last ``tail`` voxels of every walk are counted as inside without a
    look-up (only valid when they are known to be, as in :func:`esf`).
    """
    sx, sy, sz = start
    dx, dy, dz = end[0] - sx, end[1] - sy, end[2] - sz
    l = np.maximum(np.maximum(np.abs(dx), np.abs(dy)), np.abs(dz))
    count = np.maximum(l, 1)
    if band is None:
        # Wider bands pad more, narrower ones loop more: ~sqrt(8e5 / lines) balances the two
        # (4 voxels for PCL's 60000 lines, 16 for the 3000 of a 1000-triplet segment).
        band = int(np.clip(np.sqrt(8e5 / max(len(sx), 1)), 4, 32))
    band = max(4, band - band % 4)  # widths multiple of 4: the row sums add 4-byte words
    n_bands = -(-(GRID - head - tail) // band)
    mid = count - (head + tail)  # voxels to look up
    band_of = np.where(mid > 0, (mid - 1) // band, n_bands).astype(np.uint8)
    order = np.argsort(band_of, kind="stable")  # radix sort of bytes
    edges = np.cumsum(np.bincount(band_of, minlength=n_bands + 1))[:n_bands]
    o = order[: int(edges[-1])]  # the lines with voxels to look up, by band
    # Per line (in band order): the offset-table rows of its three axes and its start voxel.
    l_rows = (l * (GRID * 6)).astype(np.int32)
    rows = np.empty((3, len(o)), dtype=np.int32)
    for ax, d in enumerate((dx, dy, dz)):
        np.take(l_rows + np.take(_EXTENT_ROW[ax], d + (GRID - 1)), o, out=rows[ax])
    start_flat = (sx * _PG + sy) * _PG + sz + _ORIGIN
    if grid_offset is not None:
        start_flat = start_flat + grid_offset
    base = np.take(start_flat, o).astype(np.int32)
    # The padding (offset 0) revisits the start voxel (width − mid) times: taken off at the end.
    width_of = np.minimum((band_of[o].astype(np.int32) + 1) * band, GRID)
    padding = (width_of - np.take(mid, o)) * np.take(lut, base)
    walked = np.empty(len(o), dtype=np.int64)
    lo = 0
    for b, hi in enumerate(edges.tolist()):
        if hi == lo:
            continue
        width = min((b + 1) * band, GRID)
        # Lines of band b look up mid ∈ (b·band, (b+1)·band] voxels: l = mid + head + tail
        # (l = 0 or 1 when count is 1).
        l_lo = 0 if b == 0 else b * band + 1 + head + tail
        table = _band_table(l_lo, min((b + 1) * band + head + tail, GRID - 1), width, head, tail)
        step = max(1, chunk // width)
        for i in range(lo, hi, step):
            j = min(i + step, hi)
            r = rows[:, i:j] - l_lo * (GRID * 6) if l_lo else rows[:, i:j]
            flat = np.take(table, r, axis=0).sum(axis=0, dtype=np.int32)
            flat += base[i:j, None]
            walked[i:j] = _row_sums(np.take(lut, flat))
        lo = hi
    inside = np.minimum(count, head + tail).astype(np.int64)
    inside[o] += walked - padding
    return inside, count


def trace_lines(
    lut: np.ndarray, start: np.ndarray, end: np.ndarray, chunk: int = 65536, band: int | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Walk every segment ``start[i] → end[i]`` (integer voxel coordinates in [0, 64), L×3) through
    the flat boolean 64³ grid ``lut``, as PCL's ``lci``.

    Returns ``(inside, count)``: per segment, how many visited voxels are set in ``lut`` and how
    many voxels were visited. Vectorised: see the module doc (every voxel is looked up here).
    """
    grid = np.pad(np.asarray(lut).reshape(GRID, GRID, GRID).astype(np.uint8), 1).ravel()
    s = np.asarray(start, dtype=np.int32)
    e = np.asarray(end, dtype=np.int32)
    return _walk(grid, tuple(s.T.copy()), tuple(e.T.copy()), chunk=chunk, band=band)


def _triangles(px: np.ndarray, py: np.ndarray, pz: np.ndarray, i1: np.ndarray, i2: np.ndarray, i3: np.ndarray):
    """Side vectors u = v21, v = v31, w = v23 (3-tuples of coordinates), side lengths a = |v21|,
    b = |v31|, c = |v23| and Heron product of candidate triplets (index arrays of distinct points)."""
    x1, y1, z1 = px[i1], py[i1], pz[i1]
    ux, uy, uz = px[i2] - x1, py[i2] - y1, pz[i2] - z1  # v21
    vx, vy, vz = px[i3] - x1, py[i3] - y1, pz[i3] - z1  # v31
    wx, wy, wz = ux - vx, uy - vy, uz - vz  # v23 = p2 − p3
    a = np.sqrt(ux * ux + uy * uy + uz * uz)
    b = np.sqrt(vx * vx + vy * vy + vz * vz)
    c = np.sqrt(wx * wx + wy * wy + wz * wz)
    s = 0.5 * (a + b + c)
    heron = s * (s - a) * (s - b) * (s - c)
    return (ux, uy, uz), (vx, vy, vz), (wx, wy, wz), a, b, c, heron


def _cosines(u, v, w, a, b, c) -> np.ndarray:
    """The three |cos| of PCL's angles (3×n: at p1 between v21 and v31, at p3 between v23 and v31,
    at p2 between v23 and v21) from :func:`_triangles`' sides."""
    (ux, uy, uz), (vx, vy, vz), (wx, wy, wz) = u, v, w
    cos = np.empty((3, len(a)))
    np.abs(ux * vx + uy * vy + uz * vz, out=cos[0])
    np.abs(wx * vx + wy * vy + wz * vz, out=cos[1])
    np.abs(wx * ux + wy * uy + wz * uz, out=cos[2])
    cos /= np.stack([a * b, c * b, c * a])
    return cos


def _candidates(n_points: int, n: int, rng: np.random.Generator) -> np.ndarray:
    """A round of random triplets (m×3 indices) when ``n`` are still needed."""
    return rng.integers(0, n_points, size=(int(n * 1.25) + 64, 3))


def _distinct(idx: np.ndarray) -> np.ndarray:
    """Mask of the triplets (m×3) of three distinct indices."""
    i1, i2, i3 = idx[:, 0], idx[:, 1], idx[:, 2]
    return (i1 != i2) & (i1 != i3) & (i2 != i3)


def _sample_triplets(pts: np.ndarray, n: int, rng: np.random.Generator) -> tuple[np.ndarray, ...]:
    """``n`` random index triplets of distinct points spanning a non-degenerate triangle (Heron
    product > 0.001), as ``(i1, i2, i3, a, b, c, heron, cos)``: side lengths a = |p2 − p1|,
    b = |p3 − p1|, c = |p2 − p3|, and the three |cos| of PCL's angles (3×n, see
    :func:`_cosines`). Computed per coordinate on the candidate triplets, rejected ones dropped
    before the angles."""
    N = len(pts)
    px, py, pz = (np.ascontiguousarray(pts[:, k]) for k in range(3))
    parts: list[tuple[np.ndarray, ...]] = []
    have = 0
    for _ in range(50):
        idx = _candidates(N, n - have, rng)
        idx = idx[_distinct(idx)]
        i1, i2, i3 = idx[:, 0], idx[:, 1], idx[:, 2]
        u, v, w, a, b, c, heron = _triangles(px, py, pz, i1, i2, i3)
        keep = np.flatnonzero(heron > 0.001)[: n - have]
        u, v, w = (tuple(x[keep] for x in side) for side in (u, v, w))
        a, b, c = a[keep], b[keep], c[keep]
        parts.append((i1[keep], i2[keep], i3[keep], a, b, c, heron[keep], _cosines(u, v, w, a, b, c)))
        have += len(keep)
        if have >= n:
            break
    else:
        raise ValueError("ESF: the cloud is degenerate (no non-collinear point triplets)")
    if len(parts) == 1:
        return parts[0]
    return tuple(np.concatenate(p, axis=-1) for p in zip(*parts))


def _scaled(cloud: np.ndarray) -> np.ndarray:
    """The cloud centred on its centroid, scaled so that its farthest point lies at 32 voxels."""
    pts = np.asarray(cloud, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) < 3:
        raise ValueError(f"ESF needs an N×3 cloud with N ≥ 3, got shape {pts.shape}")
    pts = pts - pts.mean(axis=0)
    r = np.sqrt((pts**2).sum(axis=1).max())
    if r == 0.0:
        raise ValueError("ESF: all points coincide")
    pts *= HALF / r
    return pts


def esf(cloud: np.ndarray, *, n_samples: int = 20000, seed: int | np.random.Generator | None = 0) -> np.ndarray:
    """The 640-bin ESF descriptor of an N×3 cloud (N ≥ 3), normalised to sum 1.

    ``seed`` makes the triplet sampling reproducible (an int, a Generator, or None for fresh
    entropy).
    """
    pts = _scaled(cloud)
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    vox = _voxel_index(pts)
    i1, i2, i3, a, b, c, heron, cos = _sample_triplets(pts, n_samples, rng)
    rows = (x[None] for x in (i1, i2, i3, a, b, c, heron))
    return _histograms(vox, None, 1, *rows, cos[:, None])[0]


def esf_many(clouds: list[np.ndarray], *, n_samples: int = 20000, seed: int | None = 0) -> list[np.ndarray | None]:
    """``esf(cloud, n_samples=n_samples, seed=seed)`` of every cloud (the same descriptors, each
    sampled from its own generator seeded ``seed``), None where ``esf`` raises ValueError.

    All clouds go through each step together (one concatenated array, one look-up grid per cloud
    in one buffer): on the ~20 segments of a scan with 1000 triplets each, numpy's per-call
    overhead is most of ``esf``'s cost, and it is paid once here instead of per segment.
    """
    out: list[np.ndarray | None] = [None] * len(clouds)
    scaled, where = [], []
    for k, cloud in enumerate(clouds):
        try:
            scaled.append(_scaled(cloud))
            where.append(k)
        except ValueError:
            pass
    if not scaled:
        return out
    pts = np.concatenate(scaled)
    sizes = np.array([len(p) for p in scaled])
    first_point = np.cumsum(sizes) - sizes
    grid_of = np.repeat(np.arange(len(scaled)), sizes)
    done, trip = _first_triplets(pts, scaled, first_point, n_samples, seed)
    D = _histograms(_voxel_index(pts), grid_of, len(scaled), *trip)
    for row, k in enumerate(np.flatnonzero(done)):
        out[where[k]] = D[row]
    return out


def _first_triplets(pts, scaled, first_point, n: int, seed):
    """Every cloud's ``_sample_triplets(cloud, n, default_rng(seed))``, the first round of all
    clouds at once (global point indices; a cloud whose first round keeps fewer than ``n`` redoes
    it alone, then draws more). Returns (mask of the clouds sampled (False: degenerate), their
    (i1, i2, i3, a, b, c, heron) as K×n arrays and cos as 3×K×n)."""
    K = len(scaled)
    idx = np.concatenate([_candidates(len(p), n, np.random.default_rng(seed)) for p in scaled])
    m = len(idx) // K  # candidates per cloud (the same number for all)
    owner = np.repeat(np.arange(K), m)
    idx += np.repeat(first_point, m)[:, None]  # global point indices
    distinct = _distinct(idx)
    idx, owner = idx[distinct], owner[distinct]
    i1, i2, i3 = idx[:, 0], idx[:, 1], idx[:, 2]
    px, py, pz = (np.ascontiguousarray(pts[:, k]) for k in range(3))
    u, v, w, a, b, c, heron = _triangles(px, py, pz, i1, i2, i3)
    # The first n non-degenerate triplets of each cloud, in order.
    ok = np.flatnonzero(heron > 0.001)
    rank = np.arange(len(ok)) - np.searchsorted(owner[ok], owner[ok])
    keep = ok[rank < n]
    full = np.bincount(owner[keep], minlength=K) == n
    keep = keep[full[owner[keep]]]
    u, v, w = (tuple(x[keep] for x in side) for side in (u, v, w))
    a, b, c = a[keep], b[keep], c[keep]
    cols = [i1[keep], i2[keep], i3[keep], a, b, c, heron[keep]]
    cos = _cosines(u, v, w, a, b, c)
    rows = [x.reshape(-1, n) for x in cols]
    cos = cos.reshape(3, -1, n)
    if full.all():
        return full, (*rows, cos)
    # The clouds that needed more rounds (rare), sampled alone: spliced in at their rows.
    done = full.copy()
    extra: dict[int, tuple] = {}
    for k in np.flatnonzero(~full):
        try:
            extra[k] = _sample_triplets(scaled[k], n, np.random.default_rng(seed))
            done[k] = True
        except ValueError:  # degenerate: no descriptor
            pass
    at = np.cumsum(done) - 1  # row of each sampled cloud
    out = [np.empty((int(done.sum()), n), x.dtype) for x in rows]
    out_cos = np.empty((3, int(done.sum()), n))
    for x, o in zip(rows, out):
        o[at[full]] = x
    out_cos[:, at[full]] = cos
    for k, t in extra.items():
        for j, o in enumerate(out):
            o[at[k]] = t[j] + (first_point[k] if j < 3 else 0)
        out_cos[:, at[k]] = t[7]
    return done, (*out, out_cos)


def _histograms(vox, grid_of, n_grids: int, i1, i2, i3, a, b, c, heron, cos) -> np.ndarray:
    """The normalised ESF histograms (K×640) of K clouds' triplets: ``vox`` the voxels of all
    their points (``grid_of`` the cloud of each, None for one cloud), the triplets' point indices,
    side lengths and Heron products K×n (one row per cloud), their |cos| 3×K×n.

    Every value of a cloud is computed, and every bin filled, as for that cloud alone (the bins of
    cloud k are offset by k whole histograms; ``np.bincount`` adds the weights of a bin in input
    order, and each cloud's entries keep theirs).
    """
    K, n = i1.shape
    T = K * n
    lut = _surface_lut(vox, grid_of, n_grids)
    # A3 bins of the angles at p1, p3, p2 (rows of ``th``).
    th = _pcl_round(np.arccos(np.clip(cos, 0.0, 1.0)) / (np.pi / 2) * (_NB - 1)).reshape(3, T)

    # Lines 1→2, 1→3, 2→3 (PCL's order), traced between the voxels of their endpoints.
    p = np.concatenate([i1.ravel(), i1.ravel(), i2.ravel()])
    q = np.concatenate([i2.ravel(), i3.ravel(), i3.ravel()])
    axes = [np.ascontiguousarray(vox[:, k]) for k in range(3)]
    offset = None if grid_of is None else np.take(grid_of, p) * _PG**3
    inside, count = _walk(
        lut, tuple(v[p] for v in axes), tuple(v[q] for v in axes), head=_KNOWN_HEAD, tail=_KNOWN_TAIL,
        grid_offset=offset,
    )  # fmt: skip
    key = inside * (GRID + 1) + count
    line_cls = np.take(_LINE_CLASS, key)

    in3 = inside[:T] + inside[T : 2 * T] + inside[2 * T :]
    pc12, pc13, pc23 = count[:T], count[T : 2 * T], count[2 * T :]
    cnt3 = pc12 + pc13 + pc23

    # Triangle class: 0 out, 1 in, 2 mixed (PCL tests "out" first). PCL's D3 class follows from
    # its weight (1 in, 0 out, else in3 / cnt3: above 21/192 and at most 1 − 4/192 for a mixed
    # triangle), so it is the triangle class itself.
    tri = np.where(in3 <= 21, 0, np.where(cnt3 - in3 < 4, 1, 2))
    cloud = np.repeat(np.arange(K), n)  # of every triplet
    tri_bin = (tri + 3 * cloud) * _NB  # cloud k's three histograms (out, in, mixed) at 3k·64

    # A3: each angle weighted by the voxel length of the side opposite to it, / 32; one histogram
    # per triangle class.
    a3 = np.bincount(
        (th + tri_bin).ravel(), weights=np.concatenate([pc23, pc12, pc13]) / 32.0, minlength=3 * _NB * K
    ).reshape(K, 3, _NB)

    d3 = np.sqrt(np.sqrt(heron))
    d3_bin = _pcl_round(d3 / d3.max(axis=1, keepdims=True) * (_NB - 1))
    d3h = np.bincount(tri_bin + d3_bin.ravel(), minlength=3 * _NB * K).reshape(K, 3, _NB).astype(np.float64)

    d2 = np.stack([a, b, c])  # the lines' lengths, 3×K×n
    d2_bin = _pcl_round(d2 / d2.max(axis=(0, 2))[None, :, None] * (_NB - 1)).ravel()
    line_cloud = np.tile(cloud, 3)
    h = np.bincount((line_cls + 3 * line_cloud) * _NB + d2_bin, minlength=3 * _NB * K)
    h = h.reshape(K, 3, _NB).astype(np.float64)  # in, out, mixed
    ratio = np.bincount(np.take(_LINE_RATIO_BIN, key) + (_NB + 1) * line_cloud, minlength=(_NB + 1) * K)
    h_ratio = ratio.reshape(K, _NB + 1)[:, :_NB].astype(np.float64)  # (bin 64: not a mixed line)

    hist = np.concatenate(
        [
            0.5 * a3[:, 1], 0.5 * a3[:, 0], 0.5 * a3[:, 2],
            0.5 * d3h[:, 1], 0.5 * d3h[:, 0], 1.0 * d3h[:, 2],
            0.5 * h[:, 0], 2.0 * h[:, 1], 2.0 * h[:, 2],
            1.0 * h_ratio,
        ],
        axis=1,
    )  # fmt: skip
    return hist / hist.sum(axis=1, keepdims=True)
