"""The banded solve of normal matrices with a dense border agrees with the dense Cholesky solve."""

import numpy as np
import pytest

from meshreg.banded import BANDED_MIN, banded_system


def _local_matrix(k: int, width: int, rng) -> np.ndarray:
    """A symmetric positive semi-definite (k, k) matrix coupling unknowns within ``width`` of each other, shuffled
    (so that the band only appears after reordering)."""
    factor = np.zeros((k, k))
    for d in range(width):
        factor += np.diag(rng.normal(size=k - d), -d)
    matrix = factor @ factor.T
    shuffle = rng.permutation(k)
    return matrix[np.ix_(shuffle, shuffle)]


@pytest.mark.parametrize("border", [0, 3])
def test_banded_solve_matches_dense(border):
    rng = np.random.default_rng(0)
    k = BANDED_MIN + 50
    matrix = np.zeros((k + border, k + border))
    matrix[:k, :k] = _local_matrix(k, 6, rng)
    edge = rng.normal(size=(k, border))
    matrix[:k, k:], matrix[k:, :k] = edge, edge.T
    matrix[k:, k:] = edge.T @ edge + np.eye(border)
    shift = 0.1 + rng.random(k + border)
    rhs = rng.normal(size=k + border)
    system = banded_system(matrix, border)
    assert system is not None
    x = system.solve(shift, rhs)
    expected = np.linalg.solve(matrix + np.diag(shift), rhs)
    np.testing.assert_allclose(x, expected, rtol=1e-9, atol=1e-12 * np.abs(expected).max())
    # a matrix of the same size with entries outside the kept ordering's band is ordered again, still solved exactly
    other = matrix.copy()
    other[0, k - 1] = other[k - 1, 0] = 0.5
    x = banded_system(other, border).solve(shift + 1.0, rhs)
    expected = np.linalg.solve(other + np.diag(shift + 1.0), rhs)
    np.testing.assert_allclose(x, expected, rtol=1e-9, atol=1e-12 * np.abs(expected).max())


def test_dense_and_small_matrices_are_left_to_the_caller():
    rng = np.random.default_rng(1)
    small = np.eye(BANDED_MIN - 10)
    assert banded_system(small, 3) is None
    k = BANDED_MIN + 7
    full = rng.normal(size=(k, k))
    full = full @ full.T
    assert banded_system(full, 0) is None
