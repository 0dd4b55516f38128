"""Shape functions of grid surfaces, the energy E and its derivative with respect to the points.

Discretization (one q per grid cell, as in docs/dp.md): for the cell (i, j) with corners
c_ij, c_i+1,j, c_i,j+1, c_i+1,j+1 the vector area is ``n = 1/2 (c_i+1,j+1 - c_ij) x (c_i,j+1 - c_i+1,j)``,
``v = n / (dr_i dt_j)`` approximates c_r x c_t and ``q = v / sqrt|v|`` (0 where v = 0). Integrals over
the square are sums over cells with weights ``dr_i dt_j``, so ``sum |q|^2 dr dt`` is the surface area.

References
----------
Bernal & Lawrence, "Elastic shape registration of surfaces in 3D space with gradient descent and
dynamic programming", Section 2 (shape function q, the action (q, h)).
"""

from __future__ import annotations

import numba
import numpy as np

_TINY = 1e-300
# q = v / sqrt|v| has a derivative ~ |v|^(-1/2), unbounded on collapsed cells (a DP map that is flat in
# places, a crease): derivatives use |v| no smaller than this fraction of the median cell's |v|.
COLLAPSED = 1e-6


def cell_weights(r: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Cell areas ``dr_i dt_j`` in the parameter square, shape (M-1, N-1)."""
    return np.outer(np.diff(r), np.diff(t))


def cell_normals(points: np.ndarray) -> np.ndarray:
    """Vector areas of the grid cells, shape (M-1, N-1, 3), from points of shape (M, N, 3)."""
    d1 = points[1:, 1:] - points[:-1, :-1]
    d2 = points[:-1, 1:] - points[1:, :-1]
    return 0.5 * np.cross(d1, d2)


def shape_function(points: np.ndarray, r: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Shape function q = (c_r x c_t) / sqrt|c_r x c_t| per cell.

    Parameters
    ----------
    points : ndarray, shape (M, N, 3)
    r : ndarray, shape (M,)
    t : ndarray, shape (N,)

    Returns
    -------
    q : ndarray, shape (M-1, N-1, 3)

    Examples
    --------
    >>> import numpy as np
    >>> r = t = np.linspace(0, 1, 3)
    >>> R, T = np.meshgrid(r, t, indexing="ij")
    >>> round(float(shape_function(np.stack([2 * R, T, 0 * R], -1), r, t)[0, 0, 2]) ** 2, 9)
    2.0
    """
    return _cells(points, cell_weights(r, t))[-1]


def energy(q1: np.ndarray, q2: np.ndarray, weights: np.ndarray, rotation: np.ndarray | None = None) -> float:
    """E = sum_cells w |R q1 - q2|^2, the discretized integral of |R q1 - q2|^2 over the square.

    Parameters
    ----------
    q1, q2 : ndarray, shape (M-1, N-1, 3)
    weights : ndarray, shape (M-1, N-1)
    rotation : ndarray, shape (3, 3), optional
        R applied to q1 (identity when omitted).
    """
    p = q1 if rotation is None else q1 @ rotation.T
    return float(np.sum(weights * np.sum((p - q2) ** 2, axis=-1)))


def cross_covariance(q1: np.ndarray, q2: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """H = sum_cells w q1 q2^T (3, 3), the matrix Kabsch-Umeyama maximizes trace(R H) over."""
    return np.einsum("ij,ija,ijb->ab", weights, q1, q2)


def _cells(points: np.ndarray, weights: np.ndarray):
    """Per cell: diagonals d1, d2, weight w (..., 1), v = n / w, |v| (clamped away from 0) and q."""
    d1 = points[1:, 1:] - points[:-1, :-1]
    d2 = points[:-1, 1:] - points[1:, :-1]
    w = weights[..., None]
    v = cell_normals(points) / w
    norm = np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), _TINY)
    return d1, d2, w, v, norm, v / np.sqrt(norm)


def _derivative_scale(norm: np.ndarray) -> np.ndarray:
    """|v| for the derivatives of q: floored at ``COLLAPSED`` times the median cell (see there)."""
    return np.maximum(norm, COLLAPSED * np.median(norm))


def energy_gradient_points(target: np.ndarray, points: np.ndarray, weights: np.ndarray) -> tuple[float, np.ndarray]:
    """E(points) = sum w |target - q(points)|^2 and its gradient with respect to the points.

    Parameters
    ----------
    target : ndarray, shape (M-1, N-1, 3)
        R q1 per cell.
    points : ndarray, shape (M, N, 3)
        The (reparametrized) second surface at the nodes.
    weights : ndarray, shape (M-1, N-1)
        Cell weights dr dt.

    Returns
    -------
    E : float
    dE_dpoints : ndarray, shape (M, N, 3)
    """
    d1, d2, w, v, norm, q = _cells(points, weights)
    diff = target - q
    e = float(np.sum(w * diff * diff))
    g_q = -2.0 * w * diff
    vhat = v / norm
    g_v = (g_q - 0.5 * np.sum(g_q * vhat, axis=-1, keepdims=True) * vhat) / np.sqrt(_derivative_scale(norm))
    g_n = g_v / w
    g_d1 = 0.5 * np.cross(d2, g_n)
    g_d2 = 0.5 * np.cross(g_n, d1)
    grad = np.zeros_like(points)
    grad[1:, 1:] += g_d1
    grad[:-1, :-1] -= g_d1
    grad[:-1, 1:] += g_d2
    grad[1:, :-1] -= g_d2
    return e, grad


def _skew(a: np.ndarray) -> np.ndarray:
    """Matrices S(a) with S(a) b = a x b, shape a.shape + (3,)."""
    s = np.zeros(a.shape + (3,))
    s[..., 0, 1], s[..., 0, 2] = -a[..., 2], a[..., 1]
    s[..., 1, 0], s[..., 1, 2] = a[..., 2], -a[..., 0]
    s[..., 2, 0], s[..., 2, 1] = -a[..., 1], a[..., 0]
    return s


def shape_function_blocks(points: np.ndarray, weights: np.ndarray, columns: np.ndarray):
    """q per cell and its derivatives along K unknowns of each of the cell's four corners.

    Parameters
    ----------
    points : ndarray, shape (M, N, 3)
    weights : ndarray, shape (M-1, N-1)
    columns : ndarray, shape (M, N, 3, K)
        The derivatives of the points along the K unknowns of each node.

    Returns
    -------
    q : ndarray, shape (M-1, N-1, 3)
    blocks : ndarray, shape (M-1, N-1, 3, 4 K)
        Column ``c K + k``: the derivative of the cell's q along unknown k of its corner c (order c00, c10,
        c01, c11).
    """
    d1, d2, w, v, norm, q = _cells(points, weights)
    factor = 0.5 / (np.sqrt(_derivative_scale(norm)) * w)[..., 0]
    blocks = np.empty(q.shape + (4 * columns.shape[-1],))
    _corner_blocks(d1, d2, v / norm, factor, np.ascontiguousarray(columns, dtype=float), blocks)
    return q, blocks


@numba.njit(cache=True)
def _corner_blocks(d1, d2, vhat, factor, columns, out):
    """out[i, j, :, c K + k] = dq/dn (+-1/2 d x x) for x = columns at corner c of cell (i, j): n = (d1 x d2) / 2,
    so a move x of corner c00 changes n by d2 x x / 2, of c10 by -d1 x x / 2, of c01 by d1 x x / 2, of c11 by
    -d2 x x / 2; dq/dn = (I - vhat vhat^T / 2) / (sqrt|v| w), ``factor`` = 1 / (2 sqrt|v| w)."""
    m, n, nk = d1.shape[0], d1.shape[1], columns.shape[3]
    y = np.empty(3)
    for i in range(m):
        for j in range(n):
            for c in range(4):
                d = d2[i, j] if c == 0 or c == 3 else d1[i, j]
                scale = factor[i, j] if c == 0 or c == 2 else -factor[i, j]
                for k in range(nk):
                    x = columns[i + c % 2, j + c // 2, :, k]
                    y[0] = d[1] * x[2] - d[2] * x[1]
                    y[1] = d[2] * x[0] - d[0] * x[2]
                    y[2] = d[0] * x[1] - d[1] * x[0]
                    dot = 0.5 * (vhat[i, j, 0] * y[0] + vhat[i, j, 1] * y[1] + vhat[i, j, 2] * y[2])
                    for a in range(3):
                        out[i, j, a, c * nk + k] = scale * (y[a] - dot * vhat[i, j, a])
