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


def band_width_columns(kl: int) -> int:
    """Row length of the band storage for bandwidth kl."""
    return 3 * kl + 1


@njit(cache=True)
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
        if p != k:
            for j in range(k, end + 1):
                tmp = band[k, j - k + kl]
                band[k, j - k + kl] = band[p, j - p + kl]
                band[p, j - p + kl] = tmp
        diagonal = band[k, kl]
        for i in range(k + 1, last + 1):
            factor = band[i, k - i + kl] / diagonal
            band[i, k - i + kl] = factor
            if factor != 0.0:
                for j in range(k + 1, end + 1):
                    band[i, j - i + kl] -= factor * band[k, j - k + kl]
    return True


@njit(cache=True)
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
        total = rhs[k]
        for j in range(k + 1, min(n - 1, k + ku) + 1):
            total -= band[k, j - k + kl] * rhs[j]
        rhs[k] = total / band[k, kl]


# reassociation lets LLVM vectorize the dot products; no finite-math flags, so NaN still propagates and is caught
FAST = {"reassoc", "contract"}


@njit(cache=True, fastmath=FAST)
def band_cholesky(band: np.ndarray, kl: int) -> bool:
    """In-place Cholesky factor L (lower band) of a symmetric matrix; False if it is not positive definite."""
    n = band.shape[0]
    for j in range(n):
        total = band[j, kl]
        for k in range(max(0, j - kl), j):
            total -= band[j, k - j + kl] ** 2
        if not total > 0.0:  # also catches NaN
            return False
        diagonal = np.sqrt(total)
        band[j, kl] = diagonal
        for i in range(j + 1, min(n, j + kl + 1)):
            total = band[i, j - i + kl]
            for k in range(max(0, i - kl), j):
                total -= band[i, k - i + kl] * band[j, k - j + kl]
            band[i, j - i + kl] = total / diagonal
    return True


@njit(cache=True, fastmath=FAST)
def cholesky_solve(band: np.ndarray, kl: int, rhs: np.ndarray) -> None:
    """Solve L L^T x = rhs in place with the factor of ``band_cholesky``."""
    n = band.shape[0]
    for i in range(n):
        total = rhs[i]
        for k in range(max(0, i - kl), i):
            total -= band[i, k - i + kl] * rhs[k]
        rhs[i] = total / band[i, kl]
    for i in range(n - 1, -1, -1):
        total = rhs[i]
        for k in range(i + 1, min(n, i + kl + 1)):
            total -= band[k, i - k + kl] * rhs[k]
        rhs[i] = total / band[i, kl]


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


@njit(cache=True)
def band_symmetric(band: np.ndarray, kl: int) -> bool:
    """Whether the band matrix (row i, column j at band[i, j - i + kl]) is symmetric."""
    n = band.shape[0]
    for i in range(n):
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
