"""B-spline bases on a knot vector: the matrix of every B-spline (or a derivative) at given points, and the knots and
coefficients of the tensor-product spline that interpolates gridded data.

This is what the registration used from ``scipy.interpolate`` (``BSpline`` and ``RectBivariateSpline`` with
``s=0``), whose import, with the ``scipy.optimize`` it pulls in, took 0.10-0.14 s of every ``meshreg`` command.
The knots are FITPACK's (``RectBivariateSpline``'s) and the values agree with scipy's to rounding (about 1e-15
relative), by Cox-de Boor's recursion on dense matrices (the bases here have at most a few hundred functions).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from scipy.linalg import lu_factor, lu_solve

COLLOCATION_CACHE = 16  # LU factors of interpolation matrices kept (per grid axis: the surfaces', h's, the coarse ones)


def _spans(knots: np.ndarray, k: int, x: np.ndarray) -> np.ndarray:
    """The knot span l with knots[l] <= x < knots[l + 1] of each point (the last non-empty span at and beyond the
    right end, the first before the left end): right limits at inner knots, as scipy's ``BSpline``."""
    ncoef = len(knots) - k - 1
    return np.clip(np.searchsorted(knots, x, side="right") - 1, k, ncoef - 1)


def _ratio(num: np.ndarray, den: np.ndarray) -> np.ndarray:
    """num / den with 0 where den is 0 (a repeated knot: the term of Cox-de Boor's recursion is absent)."""
    return np.divide(num, den, out=np.zeros(np.broadcast_shapes(num.shape, den.shape)), where=den != 0)


def _lower_degrees(knots: np.ndarray, k: int, x: np.ndarray, degree: int) -> np.ndarray:
    """Every B-spline of ``degree`` (<= k) on ``knots`` at x, (len(x), len(knots) - degree - 1), built up from the
    degree-0 indicators of the spans of degree k's domain (:func:`_spans`)."""
    x = np.asarray(x, dtype=float)[:, None]
    values = np.zeros((len(x), len(knots) - 1))
    values[np.arange(len(x)), _spans(knots, k, x[:, 0])] = 1.0
    for q in range(1, degree + 1):
        n = len(knots) - q - 1
        left = _ratio(x - knots[:n], knots[q : q + n] - knots[:n])
        right = _ratio(knots[q + 1 : q + 1 + n] - x, knots[q + 1 : q + 1 + n] - knots[1 : 1 + n])
        values = left * values[:, :n] + right * values[:, 1 : n + 1]
    return values


def basis_matrix(knots: np.ndarray, k: int, x: np.ndarray, derivative: int = 0) -> np.ndarray:
    """The B-splines of degree k on ``knots`` (their ``derivative``-th derivatives) at the points x.

    Parameters
    ----------
    knots : ndarray, shape (n + k + 1,)
        Non-decreasing.
    k : int
        Degree.
    x : ndarray, shape (p,)
    derivative : int
        0 (values) to k.

    Returns
    -------
    ndarray, shape (p, n)
        Right limits at inner knots; at and beyond the ends, the polynomial pieces of the end spans.

    Examples
    --------
    >>> knots = np.array([0.0, 0.0, 0.0, 0.0, 0.5, 1.0, 1.0, 1.0, 1.0])
    >>> basis_matrix(knots, 3, np.array([0.0, 0.5, 1.0])).round(3).tolist()
    [[1.0, 0.0, 0.0, 0.0, 0.0], [0.0, 0.25, 0.5, 0.25, 0.0], [0.0, 0.0, 0.0, 0.0, 1.0]]
    """
    knots = np.asarray(knots, dtype=float)
    values = _lower_degrees(knots, k, x, k - derivative)
    for q in range(k - derivative + 1, k + 1):  # d/dx B_{i,q} = q (B_{i,q-1} / w_i - B_{i+1,q-1} / w_{i+1})
        n = len(knots) - q - 1
        scaled = q * _ratio(values, knots[q : q + n + 1] - knots[: n + 1])
        values = scaled[:, :n] - scaled[:, 1 : n + 1]
    return values


def interpolation_knots(x: np.ndarray, k: int) -> np.ndarray:
    """The knots of the degree-k spline interpolating data at the nodes x (m,), m > k: FITPACK's choice (that of
    ``scipy.interpolate.RectBivariateSpline`` with ``s=0``): k + 1 copies of each end and the inner nodes
    x[(k + 1) // 2 : m - (k + 1) // 2] (every inner node but the first and last (k - 1) // 2 for odd k; none for
    k = 2 with m = 3, the only even degree used), m + k + 1 knots in all."""
    x = np.asarray(x, dtype=float)
    m, half = len(x), (k + 1) // 2
    inner = x[half : m - half] if m - k - 1 > 0 else x[:0]
    return np.concatenate([np.full(k + 1, x[0]), inner, np.full(k + 1, x[-1])])


@lru_cache(maxsize=COLLOCATION_CACHE)
def _collocation(x_bytes: bytes, k: int):
    """Knots and the LU factors of the interpolation matrix (every B-spline at every node) for nodes given as the
    bytes of a float64 array."""
    x = np.frombuffer(x_bytes)
    knots = interpolation_knots(x, k)
    return knots, lu_factor(basis_matrix(knots, k, x))


def interpolating_coefficients(values: np.ndarray, r: np.ndarray, t: np.ndarray, kx: int, ky: int):
    """Knots and coefficients of the tensor-product spline of degrees (kx, ky) through gridded data.

    Parameters
    ----------
    values : ndarray, shape (M, N, C)
        Data at the nodes of the partitions r (M,) and t (N,), M > kx and N > ky.

    Returns
    -------
    tx : ndarray, shape (M + kx + 1,)
    ty : ndarray, shape (N + ky + 1,)
    coef : ndarray, shape (M, N, C)
        sum_ij coef[i, j] B_i(r) B_j(t) equals ``values`` at every node.
    """
    m, n, c = values.shape
    tx, lu_x = _collocation(np.ascontiguousarray(r, dtype=float).tobytes(), kx)
    ty, lu_y = _collocation(np.ascontiguousarray(t, dtype=float).tobytes(), ky)
    along_r = lu_solve(lu_x, values.reshape(m, n * c)).reshape(m, n, c)
    coef = lu_solve(lu_y, along_r.transpose(1, 0, 2).reshape(n, m * c)).reshape(n, m, c).transpose(1, 0, 2)
    return tx, ty, np.ascontiguousarray(coef)
