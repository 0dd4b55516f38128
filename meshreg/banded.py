"""Symmetric positive definite solves of normal matrices whose unknowns couple only locally, plus a few global ones.

The normal matrix of a B-spline level couples each coefficient with the coefficients whose supports overlap its own
(a 7 x 7 neighbourhood per component); the last ``border`` unknowns (the rotation's 3) couple with every one. After a
reverse Cuthill-McKee ordering of the local part its entries lie within a band of the diagonal (about 4 rows of
coefficients wide), and a banded Cholesky factorization costs n b^2 instead of n^3 / 3: for the 24-knot level (1059
unknowns, band about 160) 5 times less than the dense factorization. The border is eliminated by its Schur
complement. The solution is that of the dense Cholesky, to rounding.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg
import scipy.sparse as sp
from scipy.sparse.csgraph import reverse_cuthill_mckee

BANDED_MIN = 400  # below this many unknowns the dense factorization is as fast: not tried
BANDED_MAX_FRACTION = 0.4  # banded only when the band (after ordering) is at most this fraction of the unknowns


class _Ordering:
    """The reverse Cuthill-McKee order (k,) of the first k unknowns of a symmetric (n, n) matrix, its band (the
    largest |i - j| of a non-zero entry of the top left (k, k) corner after ordering) and where the band's lower
    form (band + 1, k) lies in the flattened matrix."""

    def __init__(self, matrix: np.ndarray, k: int):
        rows, cols = np.nonzero(matrix[:k, :k])
        self.order = reverse_cuthill_mckee(sp.csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(k, k)), True)
        position = np.empty(k, np.int64)
        position[self.order] = np.arange(k)
        self.band = int(np.abs(position[rows] - position[cols]).max(initial=0))
        j = np.arange(k) + np.arange(self.band + 1)[:, None]  # row j + d of the ordered corner, column j
        self.inside = j < k
        self.flat = self.order[np.where(self.inside, j, 0)] * matrix.shape[1] + self.order

    def lower(self, matrix: np.ndarray, k: int) -> np.ndarray | None:
        """The lower band form (band + 1, k) of the top left (k, k) corner of a contiguous (n, n) ``matrix`` in this
        order; None when the corner has non-zero entries outside the band (found by counting them)."""
        lower = np.where(self.inside, matrix.ravel().take(self.flat), 0.0)
        inside = 2 * np.count_nonzero(lower) - np.count_nonzero(lower[0])
        return lower if inside == np.count_nonzero(matrix[:k, :k]) else None


_ORDERINGS: dict[tuple[int, int], _Ordering] = {}  # per (n, k), the last ordering: the next matrix is tried on it


class BandedSystem:
    """A symmetric (n, n) matrix prepared for banded solves with any diagonal shift (:func:`banded_system`): the
    reverse Cuthill-McKee order of its first k = n - border unknowns and their lower band form, made once; a
    Levenberg-Marquardt step solves with one matrix and several shifts."""

    def __init__(self, matrix: np.ndarray, ordering: _Ordering, lower: np.ndarray, border: int):
        self.matrix, self.ordering, self.lower, self.border = matrix, ordering, lower, border

    def solve(self, shift: np.ndarray, rhs: np.ndarray) -> np.ndarray:
        """x (n,) with (matrix + diag(shift)) x = rhs: banded Cholesky of the first k unknowns, the Schur complement
        of the last ``border``.

        Raises
        ------
        numpy.linalg.LinAlgError
            When the shifted matrix is not positive definite.
        """
        matrix, order = self.matrix, self.ordering.order
        n = len(rhs)
        k = n - self.border
        lower = self.lower.copy()
        lower[0] += shift[:k][order]
        factor = scipy.linalg.cholesky_banded(lower, lower=True, check_finite=False)
        right = np.column_stack([rhs[:k], matrix[:k, k:]])[order]
        solved = scipy.linalg.cho_solve_banded((factor, True), right, check_finite=False)
        x_local, coupling = solved[:, 0], solved[:, 1:]
        x = np.empty(n)
        if self.border:
            edge = matrix[:k, k:][order]
            schur = matrix[k:, k:] + np.diag(shift[k:]) - edge.T @ coupling
            x[k:] = scipy.linalg.solve(schur, rhs[k:] - edge.T @ x_local, assume_a="pos")
            x_local = x_local - coupling @ x[k:]
        x[order] = x_local
        return x


def banded_system(matrix: np.ndarray, border: int) -> BandedSystem | None:
    """``matrix`` (n, n), symmetric, prepared for :meth:`BandedSystem.solve`: its first n - ``border`` unknowns
    reordered by reverse Cuthill-McKee into a band, the last ``border`` (which may couple with every other one)
    left to a Schur complement.

    Returns None when n < BANDED_MIN or the band is wider than BANDED_MAX_FRACTION n (the caller factorizes
    densely); the ordering is kept per size and reused while the next matrix's non-zero entries stay within its band.
    """
    n = matrix.shape[0]
    k = n - border
    if n < BANDED_MIN:
        return None
    matrix = np.ascontiguousarray(matrix)
    ordering = _ORDERINGS.get((n, k))
    if ordering is not None and ordering.band > BANDED_MAX_FRACTION * n:
        return None  # this size's last matrix was not banded: the dense factorization, without looking again
    lower = None if ordering is None else ordering.lower(matrix, k)
    if lower is None:
        ordering = _ORDERINGS[(n, k)] = _Ordering(matrix, k)
        if ordering.band > BANDED_MAX_FRACTION * n:
            return None
        lower = ordering.lower(matrix, k)
    return BandedSystem(matrix, ordering, lower, border)
