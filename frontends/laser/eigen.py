"""Eigen-decomposition of many symmetric 3×3 matrices at once, in closed form: the local shape of
point neighbourhoods (normals, curvature) for segmentation and for the recognition descriptors."""

from __future__ import annotations

import numpy as np


def eigen3(cov: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Eigenvalues λ0 ≤ λ1 ≤ λ2 of symmetric 3×3 matrices and the unit eigenvector of λ0, in closed form.

    Eigenvalues by the trigonometric solution of the characteristic cubic (Smith 1961); the
    eigenvector is the largest cross product of two rows of (C − λ0·I), which span its complement.
    Much faster than a batched LAPACK call on tens of thousands of 3×3 matrices.
    """
    a00, a11, a22 = cov[:, 0, 0], cov[:, 1, 1], cov[:, 2, 2]
    a01, a02, a12 = cov[:, 0, 1], cov[:, 0, 2], cov[:, 1, 2]
    lam0, lam1, lam2 = _eigenvalues(a00, a11, a22, a01, a02, a12)
    M = cov - lam0[:, None, None] * np.eye(3)
    rows = [(M[:, r, 0], M[:, r, 1], M[:, r, 2]) for r in range(3)]
    return np.maximum(lam0, 0.0), np.maximum(lam1, 0.0), np.maximum(lam2, 0.0), _null_vector(*rows)


def eigen3_parts(parts: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`eigen3` of symmetric matrices given by their 6×R distinct entries (xx, xy, xz, yy,
    yz, zz): the same results, on contiguous rows rather than strided matrix entries."""
    a00, a01, a02, a11, a12, a22 = parts
    lam0, lam1, lam2 = _eigenvalues(a00, a11, a22, a01, a02, a12)
    rows = [(a00 - lam0, a01, a02), (a01, a11 - lam0, a12), (a02, a12, a22 - lam0)]  # of C − λ0·I
    return np.maximum(lam0, 0.0), np.maximum(lam1, 0.0), np.maximum(lam2, 0.0), _null_vector(*rows)


def _eigenvalues(a00, a11, a22, a01, a02, a12):
    """λ0 ≤ λ1 ≤ λ2 (λ0 not clamped at 0) of the symmetric matrices with these entries."""
    q = (a00 + a11 + a22) / 3.0
    p1 = a01**2 + a02**2 + a12**2
    p2 = (a00 - q) ** 2 + (a11 - q) ** 2 + (a22 - q) ** 2 + 2.0 * p1
    p = np.sqrt(np.maximum(p2 / 6.0, 1e-300))
    b00, b11, b22 = (a00 - q) / p, (a11 - q) / p, (a22 - q) / p
    b01, b02, b12 = a01 / p, a02 / p, a12 / p
    det = b00 * (b11 * b22 - b12 * b12) - b01 * (b01 * b22 - b12 * b02) + b02 * (b01 * b12 - b11 * b02)
    phi = np.arccos(np.clip(det / 2.0, -1.0, 1.0)) / 3.0
    lam0 = q + 2.0 * p * np.cos(phi + 2.0 * np.pi / 3.0)
    lam2 = q + 2.0 * p * np.cos(phi)
    lam1 = 3.0 * q - lam0 - lam2
    return lam0, lam1, lam2


def _null_vector(r0, r1, r2):
    """Unit eigenvector of λ0: the longest of the cross products of the rows r0, r1, r2 of
    C − λ0·I (each a triple of component arrays)."""
    n = len(r0[0])
    c = np.empty((n, 3, 3))  # [matrix, pair of rows, component], written in place (no stacking)
    _cross_into(r0, r1, c[:, 0])
    _cross_into(r0, r2, c[:, 1])
    _cross_into(r1, r2, c[:, 2])
    norms = np.sqrt(np.einsum("nkj,nkj->nk", c, c))
    # The longest of each matrix's three, by flat row gathers (2-D fancy indexing costs more).
    pick = np.arange(0, 3 * n, 3) + norms.argmax(axis=1)
    v = np.take(c.reshape(-1, 3), pick, axis=0)
    nv = np.take(norms.reshape(-1), pick)
    degenerate = nv < 1e-300  # isotropic or zero covariance: no preferred normal
    v /= np.where(degenerate, 1.0, nv)[:, None]
    if degenerate.any():
        v[degenerate] = (0.0, 0.0, 1.0)
    return v


def _cross_into(a, b, out: np.ndarray) -> None:
    """Cross products of vectors given as component triples (a0, a1, a2), (b0, b1, b2) into the
    N×3 ``out`` (``np.cross`` costs several times more)."""
    np.subtract(a[1] * b[2], a[2] * b[1], out=out[:, 0])
    np.subtract(a[2] * b[0], a[0] * b[2], out=out[:, 1])
    np.subtract(a[0] * b[1], a[1] * b[0], out=out[:, 2])
