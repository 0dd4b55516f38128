"""Resample a parametrized mesh on a grid over the unit square (barycentric interpolation, numba)."""

from __future__ import annotations

import numba
import numpy as np

from ..errors import InputError
from ..grid import GridSurface

DEFAULT_GRID = 101


@numba.njit(cache=True)
def _rasterize(uv, faces, values, r, t, out, hit, tol):
    m, n = r.shape[0], t.shape[0]
    for f in range(faces.shape[0]):
        a, b, c = faces[f, 0], faces[f, 1], faces[f, 2]
        ax, ay, bx, by, cx, cy = uv[a, 0], uv[a, 1], uv[b, 0], uv[b, 1], uv[c, 0], uv[c, 1]
        det = (bx - ax) * (cy - ay) - (cx - ax) * (by - ay)
        if abs(det) < 1e-300:
            continue
        i0 = np.searchsorted(r, min(ax, bx, cx) - tol)
        i1 = np.searchsorted(r, max(ax, bx, cx) + tol, side="right")
        j0 = np.searchsorted(t, min(ay, by, cy) - tol)
        j1 = np.searchsorted(t, max(ay, by, cy) + tol, side="right")
        for i in range(i0, min(i1, m)):
            for j in range(j0, min(j1, n)):
                px, py = r[i], t[j]
                l1 = ((px - ax) * (cy - ay) - (cx - ax) * (py - ay)) / det
                l2 = ((bx - ax) * (py - ay) - (px - ax) * (by - ay)) / det
                l0 = 1.0 - l1 - l2
                worst = min(l0, l1, l2)
                if worst >= -tol and worst > hit[i, j]:
                    hit[i, j] = worst
                    for k in range(values.shape[1]):
                        out[i, j, k] = l0 * values[a, k] + l1 * values[b, k] + l2 * values[c, k]


def resample_grid(
    vertices: np.ndarray, faces: np.ndarray, uv: np.ndarray, m: int = DEFAULT_GRID, n: int = DEFAULT_GRID
) -> GridSurface:
    """The mesh sampled at the nodes of a uniform m x n grid of its uv square.

    Each node takes the barycentric interpolation of the triangle that contains it (with a small
    tolerance so that nodes on the square's edges are never missed; of several candidates the one
    the node lies deepest inside wins).
    """
    r, t = np.linspace(0, 1, m), np.linspace(0, 1, n)
    out = np.zeros((m, n, 3))
    hit = np.full((m, n), -np.inf)
    _rasterize(
        np.ascontiguousarray(uv, dtype=float),
        np.ascontiguousarray(faces, dtype=np.int64),
        np.ascontiguousarray(vertices, dtype=float),
        r,
        t,
        out,
        hit,
        1e-9,
    )
    missing = int(np.sum(hit == -np.inf))
    if missing:
        raise InputError(f"{missing} grid nodes fall in no triangle of the parametrization (it has folds or gaps)")
    return GridSurface.from_array(out, r, t)
