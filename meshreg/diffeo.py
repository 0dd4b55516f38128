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


def largest_step(h: np.ndarray, v: np.ndarray) -> float:
    """The largest s such that h + s' v keeps every corner triangle of :func:`corner_areas` positive for all
    0 <= s' < s (``inf`` when no triangle limits it). h is valid; v has the shape of h.

    Each corner area is quadratic in s; the bound is the smallest positive root over all triangles.
    """
    hv = np.stack([h, v])
    a, b, c, d = hv[:, :-1, :-1], hv[:, 1:, :-1], hv[:, 1:, 1:], hv[:, :-1, 1:]

    def coefficients(o, p, q):
        (dp, dvp), (dq, dvq) = p - o, q - o
        c0 = dp[..., 0] * dq[..., 1] - dp[..., 1] * dq[..., 0]
        c1 = dp[..., 0] * dvq[..., 1] - dp[..., 1] * dvq[..., 0] + dvp[..., 0] * dq[..., 1] - dvp[..., 1] * dq[..., 0]
        c2 = dvp[..., 0] * dvq[..., 1] - dvp[..., 1] * dvq[..., 0]
        return c0, c1, c2

    corners = ((a, b, d), (b, c, a), (c, d, b), (d, a, c))
    c0, c1, c2 = (np.stack(x) for x in zip(*(coefficients(*t) for t in corners), strict=True))
    with np.errstate(divide="ignore", invalid="ignore"):
        linear = np.where(c1 < 0, -c0 / c1, np.inf)
        disc = c1 * c1 - 4.0 * c2 * c0
        sq = np.sqrt(np.maximum(disc, 0.0))
        roots = np.stack([(-c1 - sq) / (2 * c2), (-c1 + sq) / (2 * c2)])
        roots = np.where((disc >= 0) & (roots > 0), roots, np.inf).min(axis=0)
    bound = np.where(np.abs(c2) > 1e-14 * (np.abs(c1) + np.abs(c0)), roots, linear)
    return float(bound.min())


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
