"""Point location on a parametrized mesh: which triangle of the uv layout holds a point of the square, and where.

A registration matches points of the unit square; to hand a user points on the actual triangles of a mesh (not
on its resampled grid, and not snapped to a vertex), each point is located in the mesh's uv layout and carried
to 3D by its barycentric coordinates in that triangle.
"""

from __future__ import annotations

import numba
import numpy as np

BUCKETS = 64  # the square is cut into BUCKETS x BUCKETS cells to find candidate triangles quickly


@numba.njit(cache=True)
def uv_triangle(uv, faces, f):
    """Corners (ax, ay, bx, by, cx, cy) of face f in the uv layout and twice its signed area (det)."""
    a, b, c = faces[f, 0], faces[f, 1], faces[f, 2]
    ax, ay, bx, by, cx, cy = uv[a, 0], uv[a, 1], uv[b, 0], uv[b, 1], uv[c, 0], uv[c, 1]
    return ax, ay, bx, by, cx, cy, (bx - ax) * (cy - ay) - (cx - ax) * (by - ay)


@numba.njit(cache=True)
def barycentric(ax, ay, bx, by, cx, cy, det, px, py):
    """Barycentric coordinates (l0, l1, l2) of the point (px, py) in the triangle of :func:`uv_triangle`."""
    l1 = ((px - ax) * (cy - ay) - (cx - ax) * (py - ay)) / det
    l2 = ((bx - ax) * (py - ay) - (px - ax) * (by - ay)) / det
    return 1.0 - l1 - l2, l1, l2


@numba.njit(cache=True)
def _locate(uv, faces, points, order, starts, buckets, tol, face_out, bary_out, depth):
    n = buckets
    for f in range(faces.shape[0]):
        ax, ay, bx, by, cx, cy, det = uv_triangle(uv, faces, f)
        if abs(det) < 1e-300:
            continue
        i0 = max(0, min(n - 1, int((min(ax, bx, cx) - tol) * n)))
        i1 = max(0, min(n - 1, int((max(ax, bx, cx) + tol) * n)))
        j0 = max(0, min(n - 1, int((min(ay, by, cy) - tol) * n)))
        j1 = max(0, min(n - 1, int((max(ay, by, cy) + tol) * n)))
        for i in range(i0, i1 + 1):
            for j in range(j0, j1 + 1):
                cell = i * n + j
                for k in range(starts[cell], starts[cell + 1]):
                    p = order[k]
                    px, py = points[p, 0], points[p, 1]
                    l0, l1, l2 = barycentric(ax, ay, bx, by, cx, cy, det, px, py)
                    worst = min(l0, l1, l2)
                    if worst >= -tol and worst > depth[p]:
                        depth[p] = worst
                        face_out[p] = f
                        bary_out[p, 0], bary_out[p, 1], bary_out[p, 2] = l0, l1, l2


def locate(uv: np.ndarray, faces: np.ndarray, points: np.ndarray, tol: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
    """The triangle of a uv layout that holds each point, and the point's barycentric coordinates in it.

    Parameters
    ----------
    uv : ndarray, shape (n, 2)
        The mesh's vertices on the unit square.
    faces : ndarray, shape (m, 3)
    points : ndarray, shape (k, 2)
        Points of the square.
    tol : float
        Points this far (in barycentric terms) outside every triangle still count as inside the nearest one
        (points on the square's sides, rounding). Default 1e-6.

    Returns
    -------
    face : ndarray, shape (k,) int
        The triangle holding each point (the one it lies deepest inside), -1 where none does.
    barycentric : ndarray, shape (k, 3)
        Weights of the triangle's three vertices (NaN where ``face`` is -1).

    Examples
    --------
    >>> uv = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    >>> face, bary = locate(uv, np.array([[0, 1, 2], [0, 2, 3]]), np.array([[0.75, 0.25], [0.25, 0.75]]))
    >>> face.tolist(), bary.round(2).tolist()
    ([0, 1], [[0.25, 0.5, 0.25], [0.25, 0.25, 0.5]])
    """
    points = np.ascontiguousarray(points, dtype=float).reshape(-1, 2)
    cells = np.clip((points * BUCKETS).astype(np.int64), 0, BUCKETS - 1)
    key = cells[:, 0] * BUCKETS + cells[:, 1]
    order = np.argsort(key, kind="stable")
    starts = np.searchsorted(key[order], np.arange(BUCKETS * BUCKETS + 1))
    face = np.full(len(points), -1, dtype=np.int64)
    bary = np.full((len(points), 3), np.nan)
    depth = np.full(len(points), -np.inf)
    _locate(
        np.ascontiguousarray(uv, dtype=float),
        np.ascontiguousarray(faces, dtype=np.int64),
        points,
        order,
        starts,
        BUCKETS,
        tol,
        face,
        bary,
        depth,
    )
    return face, bary


def surface_points(vertices: np.ndarray, faces: np.ndarray, face: np.ndarray, barycentric: np.ndarray) -> np.ndarray:
    """Points (k, d) on a mesh of vertices (n, d) given by triangle ids (k,) and barycentric weights (k, 3); NaN
    where the id is -1."""
    out = np.full((len(face), vertices.shape[1]), np.nan)
    ok = face >= 0
    corners = vertices[faces[face[ok]]]  # (k, 3 corners, 3)
    out[ok] = np.einsum("kc,kcx->kx", barycentric[ok], corners)
    return out
