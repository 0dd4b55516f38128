"""Reparametrizations of the unit square sampled on a grid.

A reparametrization is an array ``h`` of shape (M, N, 2) holding h(r_i, t_j) in [0, 1]^2. Valid
ones map each side of the square to itself (h1(0, t) = 0, h1(1, t) = 1, h2(r, 0) = 0, h2(r, 1) = 1)
and preserve orientation: every grid cell maps to a quad whose four corner triangles are positively
oriented (the discrete form of det Jh > 0, which also rules out folds between nodes of a cell).
Between nodes, h is the bicubic interpolant of its node values (:class:`meshreg.spline.GridInterpolator`).
"""

from __future__ import annotations

import numpy as np

from .spline import GridInterpolator


def identity(r: np.ndarray, t: np.ndarray) -> np.ndarray:
    """The identity reparametrization at the nodes of partitions r (M,), t (N,): shape (M, N, 2)."""
    rr, tt = np.meshgrid(r, t, indexing="ij")
    return np.stack([rr, tt], axis=-1)


def enforce_boundary(h: np.ndarray) -> np.ndarray:
    """Clip h to [0, 1]^2 and put each side of the square exactly on itself (in place; returns h)."""
    np.clip(h, 0.0, 1.0, out=h)
    h[0, :, 0] = 0.0
    h[-1, :, 0] = 1.0
    h[:, 0, 1] = 0.0
    h[:, -1, 1] = 1.0
    return h


def corner_areas(h: np.ndarray) -> np.ndarray:
    """Signed doubled areas of the 4 corner triangles of each mapped cell, shape (4, M-1, N-1).

    The triangle at each corner of a cell is formed by that corner and its two neighbours in the
    cell; all four are positive exactly when the mapped quad is convex and positively oriented.
    """
    a, b, c, d = h[:-1, :-1], h[1:, :-1], h[1:, 1:], h[:-1, 1:]  # counter-clockwise in (r, t)

    def cross(o, p, q):
        return (p[..., 0] - o[..., 0]) * (q[..., 1] - o[..., 1]) - (p[..., 1] - o[..., 1]) * (q[..., 0] - o[..., 0])

    return np.stack([cross(a, b, d), cross(b, c, a), cross(c, d, b), cross(d, a, c)])


def jacobian_determinant(h: np.ndarray, r: np.ndarray, t: np.ndarray) -> np.ndarray:
    """det Jh per cell from the cell's diagonals, shape (M-1, N-1) (its mean over the cell)."""
    d1 = h[1:, 1:] - h[:-1, :-1]
    d2 = h[:-1, 1:] - h[1:, :-1]
    area = 0.5 * (d1[..., 0] * d2[..., 1] - d1[..., 1] * d2[..., 0])
    return area / np.outer(np.diff(r), np.diff(t))


def is_valid(h: np.ndarray, tol: float = 1e-9) -> bool:
    """True when h maps sides to sides, stays in the square, and keeps every cell positively oriented."""
    boundary_ok = (
        np.allclose(h[0, :, 0], 0.0, atol=tol)
        and np.allclose(h[-1, :, 0], 1.0, atol=tol)
        and np.allclose(h[:, 0, 1], 0.0, atol=tol)
        and np.allclose(h[:, -1, 1], 1.0, atol=tol)
    )
    inside = bool(np.all(h >= -tol) and np.all(h <= 1 + tol))
    return boundary_ok and inside and bool(np.all(corner_areas(h) > 0))


def compose(h: np.ndarray, r: np.ndarray, t: np.ndarray, g: np.ndarray) -> np.ndarray:
    """h o g at the nodes: h interpolated (bicubic) at the points g (M, N, 2); sides kept exact."""
    value, _, _ = GridInterpolator(h, r, t)(g[..., 0], g[..., 1])
    return enforce_boundary(value)
