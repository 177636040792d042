"""The banded Cholesky and pivoted LU solvers against LAPACK's dense solve (numpy), over sizes and bandwidths."""
import numpy as np
import pytest

from needle_sim_ros.model.banded import (add_dense_to_band, band_cholesky, band_factor, band_solve, band_to_dense,
                                         band_width_columns, cholesky_solve)


def _random_band(rng: np.random.Generator, n: int, kl: int) -> np.ndarray:
    """A random band matrix (row i, column j at [i, j - i + kl]) with lower and upper bandwidth kl."""
    band = np.zeros((n, band_width_columns(kl)))
    for i in range(n):
        for j in range(max(0, i - kl), min(n, i + kl + 1)):
            band[i, j - i + kl] = rng.standard_normal()
    return band


@pytest.mark.parametrize("n, kl", [(66, 11), (126, 11), (5, 11), (12, 11), (30, 3), (1, 2)])
def test_cholesky_solves_a_symmetric_positive_definite_band(n, kl):
    rng = np.random.default_rng(n + 100 * kl)
    general = band_to_dense(_random_band(rng, n, kl), kl)
    symmetric = general + general.T
    dense = symmetric + np.diag(np.abs(symmetric).sum(axis=1) + 1.0)  # diagonally dominant: positive definite
    band = np.zeros((n, band_width_columns(kl)))
    add_dense_to_band(dense, 1.0, band, kl)
    rhs = rng.standard_normal(n)
    assert band_cholesky(band, kl)
    solution = rhs.copy()
    cholesky_solve(band, kl, solution)
    np.testing.assert_allclose(solution, np.linalg.solve(dense, rhs), rtol=1e-12, atol=1e-14)


def test_cholesky_refuses_an_indefinite_matrix():
    band = np.zeros((4, band_width_columns(1)))
    band[:, 1] = [1.0, 1.0, -1.0, 1.0]  # diagonal with a negative entry
    assert not band_cholesky(band, 1)


@pytest.mark.parametrize("n, kl", [(66, 11), (12, 11), (40, 4), (3, 5)])
def test_pivoted_lu_solves_a_general_band(n, kl):
    rng = np.random.default_rng(7 * n + kl)
    band = _random_band(rng, n, kl)
    band[:, kl] *= 1e-3  # small diagonal: rows are interchanged
    dense = band_to_dense(band, kl)
    rhs = rng.standard_normal(n)
    pivots = np.zeros(n, dtype=np.int64)
    assert band_factor(band, pivots, kl)
    assert np.any(pivots != np.arange(n))
    solution = rhs.copy()
    band_solve(band, pivots, kl, solution)
    np.testing.assert_allclose(dense @ solution, rhs, atol=1e-10 * np.abs(dense).max() * np.abs(solution).max())


def test_lu_refuses_a_singular_matrix():
    band = _random_band(np.random.default_rng(3), 8, 2)
    band[5, :] = 0.0  # a zero row
    assert not band_factor(band, np.zeros(8, dtype=np.int64), 2)
