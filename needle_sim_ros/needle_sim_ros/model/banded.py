"""Banded matrices: Cholesky (symmetric positive definite) and LU with partial pivoting, solves (numba).

Storage (as LAPACK gbtrf, but row-major): an n x n matrix with lower and upper bandwidth kl keeps entry (i, j) in
``band[i, j - i + kl]``; each row has 3 kl + 1 entries so that the kl extra upper diagonals created by row
interchanges fit.  ANCF coordinates of one element are contiguous, so the tangent matrices of the needle have
kl = 11 (``ELEMENT_BANDWIDTH``) in the model API layout, whatever the number of elements.
"""
from __future__ import annotations

import numpy as np
from numba import njit

ELEMENT_BANDWIDTH = 11
# reassociation lets LLVM vectorize the dot products; no finite-math flags, so NaN still propagates and is caught
FAST = {"reassoc", "contract"}
# The step's kernels (these, assembly, elastic forces, reaction) without numba's reference counts (NRT): an atomic
# increment and decrement for every array argument and view (22 % of a step, ~190 pairs). Such a kernel, and every
# kernel it calls, allocates nothing and returns no new array (its work areas come from the caller).
NO_REFCOUNTS = {"_nrt": False}


def band_width_columns(kl: int) -> int:
    """Row length of the band storage for bandwidth kl."""
    return 3 * kl + 1


# Band indices are non-negative: as unsigned integers numba indexes without its negative-index branch, which keeps
# LLVM from vectorizing the short row loops (Cholesky and solves 1.7x faster)
@njit(cache=True, **NO_REFCOUNTS)
def band_factor(band: np.ndarray, pivots: np.ndarray, kl: int) -> bool:
    """In-place LU factorization with partial pivoting (row interchanges within the band). False if singular."""
    n = band.shape[0]
    ku = 2 * kl
    for k in range(n):
        last = min(n - 1, k + kl)
        p = k
        best = abs(band[k, kl])
        for i in range(k + 1, last + 1):
            value = abs(band[i, k - i + kl])
            if value > best:
                best = value
                p = i
        pivots[k] = p
        if not best > 0.0:  # also catches NaN
            return False
        end = min(n - 1, k + ku)
        pivot_row = band[k]  # matrix column j at pivot_row[j - k + kl]
        if p != k:
            other = band[p]
            for j in range(k, end + 1):
                tmp = pivot_row[np.uint64(j - k + kl)]
                pivot_row[np.uint64(j - k + kl)] = other[np.uint64(j - p + kl)]
                other[np.uint64(j - p + kl)] = tmp
        diagonal = pivot_row[kl]
        for i in range(k + 1, last + 1):
            row = band[i]
            shift = np.uint64(i - k)  # matrix column j at row[j - i + kl] and at pivot_row[j - i + kl + shift]
            factor = row[np.uint64(k - i + kl)] / diagonal
            row[np.uint64(k - i + kl)] = factor
            if factor != 0.0:
                for c in range(k + 1 - i + kl, end + 1 - i + kl):
                    row[np.uint64(c)] -= factor * pivot_row[np.uint64(c) + shift]
    return True


@njit(cache=True, **NO_REFCOUNTS)
def band_solve(band: np.ndarray, pivots: np.ndarray, kl: int, rhs: np.ndarray) -> None:
    """Solve A x = rhs in place with the factors of ``band_factor``."""
    n = band.shape[0]
    ku = 2 * kl
    for k in range(n):
        p = pivots[k]
        if p != k:
            tmp = rhs[k]
            rhs[k] = rhs[p]
            rhs[p] = tmp
        value = rhs[k]
        if value != 0.0:
            for i in range(k + 1, min(n - 1, k + kl) + 1):
                rhs[i] -= band[i, k - i + kl] * value
    for k in range(n - 1, -1, -1):
        row = band[k]
        total = rhs[k]
        for j in range(k + 1, min(n - 1, k + ku) + 1):
            total -= row[np.uint64(j - k + kl)] * rhs[np.uint64(j)]
        rhs[k] = total / row[kl]




@njit(cache=True, fastmath=FAST, **NO_REFCOUNTS)
def band_cholesky(band: np.ndarray, kl: int) -> bool:
    """In-place Cholesky factor L (lower band) of a symmetric matrix, column by column: each column is scaled by its
    pivot and its outer product subtracted from the kl x kl block below, row stretch by row stretch (independent
    updates that LLVM vectorizes; a row-by-row dot-product order is a chain of dependent short sums, 2.8x slower at
    66 dof, kl = 11).  Reads the lower band and the diagonal, and writes L there and, as its work area, L^T into the
    upper band.  False if the matrix is not positive definite."""
    n = band.shape[0]
    for j in range(n):
        total = band[j, kl]
        if not total > 0.0:  # also catches NaN
            return False
        diagonal = np.sqrt(total)
        band[j, kl] = diagonal
        inverse = 1.0 / diagonal
        last = min(kl, n - 1 - j)
        column = band[j, kl:]  # L[j + r, j] also at column[r], r = 1 .. kl: L^T's row j, in the upper band
        for r in range(1, last + 1):
            value = band[j + r, kl - r] * inverse
            band[j + r, kl - r] = value
            column[r] = value
        if last == kl == ELEMENT_BANDWIDTH:  # the needle's case: constant bounds, fully unrolled (1.5x faster)
            for r in range(1, ELEMENT_BANDWIDTH + 1):
                row = band[j + r]
                below = column[r]
                for s in range(1, r + 1):
                    row[ELEMENT_BANDWIDTH - r + s] -= below * column[s]
        else:
            for r in range(1, last + 1):
                row = band[j + r]  # matrix column j + s of row j + r is at row[kl - r + s]
                below = column[r]
                for s in range(1, r + 1):
                    row[np.uint64(kl - r + s)] -= below * column[s]
    return True


@njit(cache=True, fastmath=FAST, **NO_REFCOUNTS)
def cholesky_solve(band: np.ndarray, kl: int, rhs: np.ndarray) -> None:
    """Solve L L^T x = rhs in place with the factor of ``band_cholesky`` (both sweeps read L by rows; rows with a
    full window of the needle's bandwidth with constant bounds, unrolled: 1.4x faster)."""
    n = band.shape[0]
    for i in range(n):
        row = band[i]
        total = rhs[i]
        if kl == ELEMENT_BANDWIDTH and i >= kl:
            for m in range(ELEMENT_BANDWIDTH):
                total -= row[m] * rhs[i - ELEMENT_BANDWIDTH + m]
        else:
            for m in range(max(0, kl - i), kl):
                total -= row[np.uint64(m)] * rhs[np.uint64(i - kl + m)]
        rhs[i] = total / row[kl]
    for i in range(n - 1, -1, -1):
        row = band[i]
        value = rhs[i] / row[kl]
        rhs[i] = value
        if kl == ELEMENT_BANDWIDTH and i >= kl:
            for m in range(ELEMENT_BANDWIDTH):
                rhs[i - ELEMENT_BANDWIDTH + m] -= row[m] * value
        else:
            for m in range(max(0, kl - i), kl):
                rhs[np.uint64(i - kl + m)] -= row[np.uint64(m)] * value


@njit(cache=True)
def band_structure(matrix: np.ndarray) -> tuple[int, bool]:
    """(largest |i - j| of a nonzero entry, whether the matrix is symmetric) in one pass."""
    n = matrix.shape[0]
    width = 0
    symmetric = True
    for i in range(n):
        for j in range(i, n):
            upper = matrix[i, j]
            lower = matrix[j, i]
            if upper != 0.0 or lower != 0.0:
                if j - i > width:
                    width = j - i
                if upper != lower:
                    symmetric = False
    return width, symmetric


@njit(cache=True)
def add_dense_to_band(matrix: np.ndarray, factor: float, band: np.ndarray, kl: int) -> None:
    """band += factor * matrix for the entries within the bandwidth kl (the caller checked there are no others)."""
    n = matrix.shape[0]
    for i in range(n):
        for j in range(max(0, i - kl), min(n, i + kl + 1)):
            band[i, j - i + kl] += factor * matrix[i, j]


@njit(cache=True, **NO_REFCOUNTS)
def band_symmetric(band: np.ndarray, kl: int) -> bool:
    """Whether the band matrix (row i, column j at band[i, j - i + kl]) is symmetric; from the last row up, where a
    force at the tip (the bevel's, through r_x) makes the external forces' matrix unsymmetric."""
    n = band.shape[0]
    for i in range(n - 1, -1, -1):
        for j in range(i + 1, min(n, i + kl + 1)):
            if band[i, j - i + kl] != band[j, i - j + kl]:
                return False
    return True


def band_to_dense(band: np.ndarray, kl: int) -> np.ndarray:
    """Dense copy of an (unfactored) band matrix with bandwidth kl."""
    n = band.shape[0]
    dense = np.zeros((n, n))
    for offset in range(-kl, kl + 1):
        rows = np.arange(max(0, -offset), min(n, n - offset))
        dense[rows, rows + offset] = band[rows, offset + kl]
    return dense
