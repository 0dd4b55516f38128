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


def shape_function_jacobians(points: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """q per cell and its derivatives with respect to the cell's four corner points.

    Parameters
    ----------
    points : ndarray, shape (M, N, 3)
    weights : ndarray, shape (M-1, N-1)

    Returns
    -------
    q : ndarray, shape (M-1, N-1, 3)
    jac : ndarray, shape (4, M-1, N-1, 3, 3)
        ``jac[c]`` maps a displacement of corner c (order c00, c10, c01, c11) to the change of q.
    """
    d1, d2, w, v, norm, q = _cells(points, weights)
    vhat = v / norm
    dq_dn = (np.eye(3) - 0.5 * vhat[..., :, None] * vhat[..., None, :]) / (np.sqrt(_derivative_scale(norm)) * w)[
        ..., None
    ]
    s1 = 0.5 * dq_dn @ _skew(d1)
    s2 = 0.5 * dq_dn @ _skew(d2)
    return q, np.stack([s2, -s1, s1, -s2])
