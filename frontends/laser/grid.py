"""Sparse voxel grids: voxel downsampling and neighbour look-ups without a k-d tree.

A scan's voxels are the centroids of the raw points in each occupied cell. Their neighbours are
the occupied cells around them, found by hashing: a k-d tree's 50-NN search of a 20k-voxel scan
took ~0.15 s here (~150 ns per neighbour), a look-up in the grid takes ~10 ns. The hash is a
two-level table (blocks of 8³ cells, a dense table of blocks over the bounding box, then a dense
512-slot table per occupied block), so its memory follows the occupied blocks, not the bounding
box of a scan that may span 6 m at 1 cm.

Neighbourhoods are cubes of cells: ``offsets(h)`` are the (2h+1)³ cell offsets within h cells.
Repeated products with the 26-neighbourhood adjacency (:func:`adjacency_of`) give larger, smoothly
weighted neighbourhoods that follow the surface through occupied cells (see
``frontends.laser.preprocess``).
"""

from __future__ import annotations

import functools

import numpy as np
from scipy.sparse import csr_matrix

_B = 3  # log2 of the block edge: blocks of 8³ cells
_L = 1 << _B
_PAD = 1  # a block of margin around the occupied ones (their neighbours exist in the block table)

_POOLS: list = []  # the process's BLAS thread pools (threadpoolctl), found on first use


def single_threaded_blas(fn):
    """Run ``fn`` with the BLAS (OpenBLAS) on one thread.

    The front-end's products are many small ones with an inner dimension of 3 (points × axes,
    rays × directions): a second BLAS thread gains nothing on them, and OpenBLAS's threads
    spin while they wait for work, so on a machine whose cores are shared they cost CPU (measured
    on the tank scans: the see-through test's ray cones 16 ms → 1 ms, the whole scan's CPU time −18 %)
    and wall time. Results are identical (no product is split along its inner dimension). The
    previous thread count is restored on return.
    """

    @functools.wraps(fn)
    def run(*args, **kwargs):
        if not _POOLS:
            from threadpoolctl import ThreadpoolController  # a dependency (semslam's run_pipeline uses it too)

            _POOLS.append(ThreadpoolController())
        with _POOLS[0].limit(limits=1, user_api="blas"):
            return fn(*args, **kwargs)

    return run


def offsets(h: int) -> np.ndarray:
    """The (2h+1)³ integer offsets of a cube of half-width ``h`` cells, by shells: the centre
    first, then the 26 around it, then the 98 of the next shell... (so ``offsets(h)[:(2g+1)**3]``
    is ``offsets(g)``)."""
    r = np.arange(-h, h + 1)
    o = np.stack(np.meshgrid(r, r, r, indexing="ij"), -1).reshape(-1, 3)
    a = np.abs(o)
    return o[np.lexsort((a.sum(axis=1), a.max(axis=1)))]


def _step_tables(h: int) -> tuple[np.ndarray, np.ndarray]:
    """For every slot of a block (its local cell) and every offset within ``h`` cells: which of
    the 27 blocks around it the neighbour falls in, and its slot there (two 512×K tables)."""
    local = np.stack(np.meshgrid(*[np.arange(_L)] * 3, indexing="ij"), -1).reshape(-1, 3)
    new = local[:, None, :] + offsets(h)[None, :, :]
    carry = np.floor_divide(new, _L) + 1  # 0, 1, 2 per axis
    new = new % _L
    block = (carry[..., 0] * 3 + carry[..., 1]) * 3 + carry[..., 2]
    slot = (new[..., 0] * _L + new[..., 1]) * _L + new[..., 2]
    return block.astype(np.int32), slot.astype(np.int32)


_STEPS: dict[int, tuple[np.ndarray, np.ndarray]] = {}
# The 27 block offsets in (x, y, z) row-major order: the block codes of ``_step_tables``.
_ROW_MAJOR_27 = np.stack(np.meshgrid(*[np.arange(-1, 2)] * 3, indexing="ij"), -1).reshape(-1, 3)


_DIGIT = np.uint64(0xFFFF)


def stable_order(keys: np.ndarray) -> np.ndarray:
    """``np.argsort(keys, kind="stable")`` of non-negative integers, the same permutation (a stable
    sort's order is unique), by 16-bit digits from the lowest: numpy's stable sort of 16-bit
    integers is a radix sort, each pass a fraction of its merge sort of 64-bit keys (a scan's voxel
    keys hold 16-25 bits: two passes)."""
    keys = np.asarray(keys)
    if len(keys) == 0 or keys.dtype.kind not in "iu" or int(keys.min()) < 0:
        return np.argsort(keys, kind="stable")
    return _digit_passes(keys.astype(np.uint64, copy=False), max(int(keys.max()).bit_length(), 1))


def stable_order_float(x: np.ndarray) -> np.ndarray:
    """``np.argsort(x, kind="stable")`` of finite floats (any NaN: numpy's own sort), the same
    permutation: by 16-bit digits of the float64 bits mapped to unsigned integers in the floats'
    order (−0.0 taken as 0.0, which the comparison sort holds equal to it)."""
    x = np.asarray(x, dtype=np.float64)
    if len(x) == 0 or not np.isfinite(x).all():
        return np.argsort(x, kind="stable")
    b = (x + 0.0).view(np.int64)  # (+0.0: −0.0 becomes 0.0)
    u = np.where(b < 0, ~b, b | np.int64(-0x8000000000000000)).view(np.uint64)
    return _digit_passes(u, 64)


def _digit_passes(u: np.ndarray, bits: int) -> np.ndarray:
    """The stable order of unsigned 64-bit ``u`` below 2**``bits``: a stable sort by each 16-bit
    digit, lowest first (LSD radix sort)."""
    order = np.argsort((u & _DIGIT).astype(np.uint16), kind="stable")
    for shift in range(16, bits, 16):
        digit = (u.take(order) >> np.uint64(shift)) & _DIGIT
        order = order.take(np.argsort(digit.astype(np.uint16), kind="stable"))
    return order


def _unique(keys: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``np.unique(keys, return_inverse=True, return_counts=True)`` by a stable sort
    (:func:`stable_order`; the cells' keys are non-negative)."""
    order = stable_order(keys)
    s = keys[order]
    first = np.concatenate(([True], s[1:] != s[:-1]))
    inverse = np.empty(len(keys), np.int64)
    inverse[order] = np.cumsum(first) - 1
    return s[first], inverse, np.diff(np.append(np.flatnonzero(first), len(keys)))


class VoxelGrid:
    """Occupied cells of a voxel size ``size`` (m) of a cloud: ``points`` (M×3) the centroids of
    the input points in each, ``counts`` (M,) their numbers, ``inverse`` the cell of every input
    point.

    Neighbour look-ups go through a two-level table: cells are grouped in blocks of 8³; every
    occupied block has 512 slots (the index of the cell there, −1 if empty) and the indices of
    its 26 neighbouring blocks. A cell's neighbour at an offset is then three gathers from small
    precomputed tables (which neighbouring block, which slot there), with no key arithmetic.
    """

    def __init__(self, points: np.ndarray, size: float, keys: np.ndarray | None = None):
        """``keys`` (N×3 int64): the points' integer cells, when not ``floor(points / size)``."""
        pts = np.asarray(points, dtype=np.float64)
        self.size = size
        m = len(pts)
        # The integer cells as three contiguous columns (integer arithmetic is exact: the same keys as
        # on the N×3 array, without its strided passes)
        if keys is None:
            cols = [np.floor(pts[:, j] / size).astype(np.int64) for j in range(3)]
        else:
            cols = [np.ascontiguousarray(keys[:, j]) for j in range(3)]
        if m:
            for k in cols:
                k -= k.min() - _PAD * _L
        blk = [k >> _B for k in cols]
        bdims = np.array([b.max() for b in blk]) + 1 + _PAD if m else np.ones(3, np.int64)
        flat = blk[0] * bdims[1]
        flat += blk[1]
        flat *= bdims[2]
        flat += blk[2]
        flat <<= 3 * _B
        for k, shift in zip(cols, (2 * _B, _B, 0)):
            k &= _L - 1
            if shift:
                k <<= shift
            flat |= k
        uniq, self.inverse, self.counts = _unique(flat)
        n = len(uniq)
        sums = np.stack([np.bincount(self.inverse, weights=pts[:, j], minlength=n) for j in range(3)], axis=1)
        self.points = sums / np.maximum(self.counts, 1)[:, None]
        # Blocks: their ids in the box, the 27 around each (−1 → an empty block appended last).
        # Blocks of the cells (uniq is sorted, so are its blocks: np.unique's sort is not needed).
        cell_block = uniq >> 3 * _B
        new_block = np.ones(n, bool)
        np.not_equal(cell_block[1:], cell_block[:-1], out=new_block[1:])
        ub, self._block = cell_block[new_block], np.cumsum(new_block) - 1
        self._slot = (uniq & (_L**3 - 1)).astype(np.int32)
        table = np.full(int(np.prod(bdims)), len(ub), np.int32)  # ≤ (12 m / 8 cm)³ blocks: 14 MB at worst
        table[ub] = np.arange(len(ub))
        bk = np.column_stack([ub // (bdims[1] * bdims[2]), ub // bdims[2] % bdims[1], ub % bdims[2]])
        around = bk[:, None, :] + _ROW_MAJOR_27[None, :, :]
        around = table[(around[..., 0] * bdims[1] + around[..., 1]) * bdims[2] + around[..., 2]]
        self._around = np.concatenate([around.ravel(), np.full(27, len(ub))]).astype(np.int32)
        self._cells = np.full((len(ub) + 1) << 3 * _B, -1, np.int32)
        self._cells[(self._block << 3 * _B) + self._slot] = np.arange(n, dtype=np.int32)
        self._block = self._block.astype(np.int32)

    def __len__(self) -> int:
        return len(self.points)

    def neighbours(self, h: int = 1, rows: np.ndarray | None = None, columns: np.ndarray | None = None) -> np.ndarray:
        """Indices of the occupied cells within ``h`` ≤ 8 cells (cube) of each cell
        (R×(2h+1)³, in the order of ``offsets(h)``: itself first; −1 where empty), for the cells
        ``rows`` (all when None); only the offsets ``columns`` (R×C indices into ``offsets(h)``)
        when given."""
        if h not in _STEPS:
            _STEPS[h] = _step_tables(h)
        step_block, step_slot = _STEPS[h]
        block = self._block if rows is None else self._block[rows]
        slot = self._slot if rows is None else self._slot[rows]
        if columns is None:
            sb, ss = step_block.take(slot, axis=0), step_slot.take(slot, axis=0)
        else:
            sb, ss = step_block[slot[:, None], columns], step_slot[slot[:, None], columns]
        # Flat gathers (2-D fancy indexing is several times slower): the neighbouring block of
        # each offset, then the cell in its slot.
        nb_block = self._around.take((block * 27)[:, None] + sb)
        return self._cells.take((nb_block << 3 * _B) + ss)


def row_dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise dot products of N×3 arrays: ``(a * b).sum(axis=1)`` to the last bit (the same
    products added in the same order), ~5x faster (a reduction along rows of 3 pays numpy's
    per-row loop overhead)."""
    return a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1] + a[:, 2] * b[:, 2]


def median_of(x: np.ndarray) -> float:
    """``np.median`` of a 1-D array of finite values, to the last bit (the same partition and the
    same mean of the two middle values), without its ~20 µs of overhead per call: it runs a few
    times per pipe hypothesis on a few hundred values."""
    n = len(x)
    k = n // 2
    if n % 2:
        return float(np.partition(x, k)[k])
    s = np.partition(x, (k - 1, k))
    return float((s[k - 1] + s[k]) / 2)


def split_sorted(x: np.ndarray, cuts: np.ndarray) -> list[np.ndarray]:
    """``np.split(x, cuts)`` for increasing cut positions (the same views of ``x``), without its
    per-piece overhead (it runs on every pipe hypothesis's runs)."""
    bounds = [0, *cuts.tolist(), len(x)]
    return [x[i:j] for i, j in zip(bounds[:-1], bounds[1:])]


def adjacency_of(nb: np.ndarray) -> csr_matrix:
    """M×M 0/1 matrix linking every cell to the cells of its row of ``nb`` (M×K indices, −1 for
    none), as given by :meth:`VoxelGrid.neighbours` (``h = 1``: itself and its 26-neighbours)."""
    m = len(nb)
    ok = nb >= 0
    # int32 like the indices, so that scipy takes both as they are (no index-type conversion)
    indptr = np.zeros(m + 1, np.int32)
    np.cumsum(np.count_nonzero(ok, axis=1), out=indptr[1:])
    # (a gather at the mask's flat positions: ~3x faster than boolean indexing nb[ok], same order)
    return csr_matrix((np.ones(int(indptr[-1]), np.float64), nb.take(np.flatnonzero(ok)), indptr), shape=(m, m))
