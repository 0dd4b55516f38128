"""Point location in a planar triangulation of any extent (material coordinates of a sheet, a scan's plane, a
parametrization's uv): which triangle holds a point, its barycentric coordinates, and values carried there.

:mod:`meshreg.mesh.locate` does the same on the unit square with a bucket grid (fast, for registrations);
this one takes planes of any size and also says, for a point outside every triangle, which triangle it is least
outside of (what the known-answer pairs of :mod:`meshreg.mesh.deform` need at ragged crops).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

INSIDE_TOL = 1e-9  # a point whose smallest barycentric coordinate is above -INSIDE_TOL lies in the triangle
LOCATE_CANDIDATES = (8, 64, 512)  # triangles tried per point (nearest centroids), more for the points missed


def locate(params: np.ndarray, faces: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The triangle of a planar triangulation that contains each point, and the point's barycentric coordinates.

    Parameters
    ----------
    params : ndarray (n, 2)
        Vertex positions in the plane (material coordinates, or a parametrization's uv).
    faces : ndarray (m, 3)
    points : ndarray (k, 2)

    Returns
    -------
    face : ndarray of int (k,)
        The containing triangle, or for a point outside every triangle the one it is least outside of.
    bary : ndarray (k, 3)
        Barycentric coordinates in that triangle, clipped to the triangle for points outside.
    inside : ndarray of bool (k,)
        Whether the point lies in a triangle (within ``INSIDE_TOL``).
    """
    params, faces, points = np.asarray(params, float), np.asarray(faces, np.int64), np.asarray(points, float)
    tree = cKDTree(params[faces].mean(axis=1))
    face = tree.query(points)[1]  # the nearest centroid's triangle unless a better one is found
    bary = np.full((len(points), 3), 1 / 3)
    worst = np.full(len(points), -np.inf)
    todo = np.arange(len(points))
    for k in LOCATE_CANDIDATES:
        if len(todo) == 0:
            break
        _, cand = tree.query(points[todo], k=min(k, len(faces)))
        cand = cand.reshape(len(todo), -1)
        a, b, c = (params[faces[cand, i]] for i in range(3))
        p = points[todo, None, :]
        det = _cross(b - a, c - a)
        det = np.where(np.abs(det) < 1e-300, np.nan, det)
        l1, l2 = _cross(p - a, c - a) / det, _cross(b - a, p - a) / det
        lam = np.stack([1 - l1 - l2, l1, l2], axis=-1)
        low = np.nan_to_num(lam.min(axis=-1), nan=-np.inf)
        best = low.argmax(axis=1)
        rows = np.arange(len(todo))
        better = low[rows, best] > worst[todo]
        at = todo[better]
        face[at], bary[at], worst[at] = cand[rows, best][better], lam[rows, best][better], low[rows, best][better]
        todo = todo[worst[todo] < -INSIDE_TOL]
    bary = np.clip(bary, 0.0, None)
    return face, bary / bary.sum(axis=1, keepdims=True), worst >= -INSIDE_TOL


def _cross(d1: np.ndarray, d2: np.ndarray) -> np.ndarray:
    """z of the cross product of 2D vectors (..., 2)."""
    return d1[..., 0] * d2[..., 1] - d1[..., 1] * d2[..., 0]


def interpolate(values: np.ndarray, faces: np.ndarray, face: np.ndarray, bary: np.ndarray) -> np.ndarray:
    """Per-vertex values (n, d) at barycentric locations (face (k,), bary (k, 3)): shape (k, d)."""
    return np.einsum("kj,kjd->kd", bary, np.asarray(values)[np.asarray(faces)[face]])
