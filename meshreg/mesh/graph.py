"""Linear-time kernels of triangle meshes (numba): edge table, connected components, triangle normals and areas,
side lengths, and how a planar layout's triangles turn.

Sorting 3m edge keys (``np.unique``) or building an n x n sparse adjacency for ``connected_components`` costs
O(m log m) and several copies of the mesh; bucketing edges by their lower vertex and a union-find over the faces
cost O(n + m) and no more than a few int64 arrays. On a 1M-triangle mesh the checks of
:func:`~meshreg.mesh.topology.prepare_disk` went from about 3 s to well under one.
"""

from __future__ import annotations

import numba
import numpy as np

from .locate import uv_triangle


@numba.njit(cache=True, nogil=True)
def _edge_table(faces: np.ndarray, n: int):
    """Directed edges (3m, 2), the undirected edge id of each (bucketed by its lower vertex: O(n + m)), the first
    directed edge of each undirected edge, and how many directed edges use each."""
    m = faces.shape[0]
    size = 3 * m
    directed = np.empty((size, 2), np.int64)
    start = np.zeros(n + 1, np.int64)
    for k in range(size):
        a, b = faces[k % m, k // m], faces[k % m, (k // m + 1) % 3]
        directed[k, 0], directed[k, 1] = a, b
        start[min(a, b) + 1] += 1
    for a in range(n):
        start[a + 1] += start[a]
    order, upper = np.empty(size, np.int64), np.empty(size, np.int64)  # each bucket's edges and their upper vertex
    fill = start[:-1].copy()
    for k in range(size):
        lo = min(directed[k, 0], directed[k, 1])
        order[fill[lo]], upper[fill[lo]] = k, max(directed[k, 0], directed[k, 1])
        fill[lo] += 1
    mark = np.full(n, -1, np.int64)
    inverse = np.empty(size, np.int64)
    first = np.empty(size, np.int64)
    counts = np.zeros(size, np.int64)
    edges = 0
    for a in range(n):
        for p in range(start[a], start[a + 1]):
            k, hi = order[p], upper[p]
            if mark[hi] < 0:
                mark[hi] = edges
                first[edges] = k
                edges += 1
            inverse[k] = mark[hi]
            counts[mark[hi]] += 1
        for p in range(start[a], start[a + 1]):
            mark[upper[p]] = -1
    return directed, inverse, first[:edges], counts[:edges]


def edge_table(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The edges of a triangle mesh in O(n + m).

    Parameters
    ----------
    faces : ndarray (m, 3), int64

    Returns
    -------
    directed : ndarray (3m, 2)
        Directed edges, side k of every face in block k (side k runs from corner k to corner k + 1).
    first : ndarray (e,)
        Index in ``directed`` of the first directed edge of each undirected edge.
    inverse : ndarray (3m,)
        Undirected edge id of each directed edge.
    counts : ndarray (e,)
        Directed edges (triangles) using each undirected edge: 1 on the boundary, 2 inside, more when non-manifold.
    """
    faces = np.ascontiguousarray(faces, dtype=np.int64)
    directed, inverse, first, counts = _edge_table(faces, int(faces.max()) + 1 if len(faces) else 0)
    return directed, first, inverse, counts


@numba.njit(cache=True)
def _root(parent: np.ndarray, a: int) -> int:
    while parent[a] != a:
        parent[a] = parent[parent[a]]  # path halving
        a = parent[a]
    return a


@numba.njit(cache=True, nogil=True)
def _components(faces: np.ndarray, n: int):
    parent = np.arange(n)
    for f in range(faces.shape[0]):
        for k in (1, 2):
            a, b = _root(parent, faces[f, 0]), _root(parent, faces[f, k])
            if a != b:
                parent[max(a, b)] = min(a, b)
    label = np.full(n, -1, np.int64)
    labels = np.empty(faces.shape[0], np.int64)
    count = 0
    for f in range(faces.shape[0]):
        r = _root(parent, faces[f, 0])
        if label[r] < 0:
            label[r] = count
            count += 1
        labels[f] = label[r]
    return labels, count


def face_components(faces: np.ndarray, n: int) -> tuple[np.ndarray, int]:
    """Connected-component label (m,) of each face, faces being connected through shared vertices, numbered 0, 1,
    .. in the order of their first face, and the number of components (a union-find over ``n`` vertices)."""
    return _components(np.ascontiguousarray(faces, dtype=np.int64), n)


@numba.njit(cache=True)
def _cross(v: np.ndarray, a: int, b: int, c: int) -> tuple[float, float, float]:
    """(b - a) x (c - a) for the vertices a, b, c of ``v`` (n, 3), as ``np.cross`` computes it."""
    x1, y1, z1 = v[b, 0] - v[a, 0], v[b, 1] - v[a, 1], v[b, 2] - v[a, 2]
    x2, y2, z2 = v[c, 0] - v[a, 0], v[c, 1] - v[a, 1], v[c, 2] - v[a, 2]
    return y1 * z2 - z1 * y2, z1 * x2 - x1 * z2, x1 * y2 - y1 * x2


@numba.njit(cache=True, nogil=True)
def _areas(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    out = np.empty(f.shape[0])
    for t in range(f.shape[0]):
        cx, cy, cz = _cross(v, f[t, 0], f[t, 1], f[t, 2])
        out[t] = 0.5 * np.sqrt(cx * cx + cy * cy + cz * cz)
    return out


@numba.njit(cache=True, nogil=True)
def _normals(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    out = np.empty((f.shape[0], 3))
    for t in range(f.shape[0]):
        out[t, 0], out[t, 1], out[t, 2] = _cross(v, f[t, 0], f[t, 1], f[t, 2])
    return out


def face_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Unnormalized normals (m, 3) of the triangles: twice their area times the unit normal (the cross product of
    their sides from the first corner, as ``np.cross`` computes it)."""
    return _normals(np.ascontiguousarray(vertices, dtype=float), np.ascontiguousarray(faces, dtype=np.int64))


@numba.njit(cache=True, nogil=True)
def _side_lengths(points: np.ndarray, faces: np.ndarray, sides: int) -> np.ndarray:
    out = np.empty(sides * faces.shape[0])
    for t in range(faces.shape[0]):
        for k in range(sides):
            a, b = faces[t, k], faces[t, (k + 1) % 3]
            total = 0.0
            for d in range(points.shape[1]):
                total += (points[a, d] - points[b, d]) ** 2
            out[sides * t + k] = np.sqrt(total)
    return out


def side_lengths(points: np.ndarray, faces: np.ndarray, sides: int = 3) -> np.ndarray:
    """Lengths (sides * m,) of the first ``sides`` sides (corner k to corner k + 1) of every triangle (m, 3), for
    points (n, d) in any dimension (3D vertices, uv on the square)."""
    return _side_lengths(np.ascontiguousarray(points, dtype=float), np.ascontiguousarray(faces, dtype=np.int64), sides)


@numba.njit(cache=True, nogil=True)
def _turn_counts(uv: np.ndarray, f: np.ndarray, tiny: float) -> tuple[int, int, int]:
    positive = negative = degenerate = 0
    for t in range(f.shape[0]):
        signed = uv_triangle(uv, f, t)[6]
        positive += signed > 0
        negative += signed < 0
        degenerate += abs(signed) < tiny
    return positive, negative, degenerate


def turn_counts(uv: np.ndarray, faces: np.ndarray, tiny: float = 1e-14) -> tuple[int, int, int]:
    """How many triangles (m, 3) of a planar layout uv (n, 2) turn counterclockwise, clockwise, and have twice
    their area below ``tiny`` (degenerate)."""
    return _turn_counts(np.ascontiguousarray(uv, dtype=float), np.ascontiguousarray(faces, dtype=np.int64), tiny)


def triangle_areas(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area of each triangle (m,) of vertices (n, 3) and faces (m, 3)."""
    return _areas(np.ascontiguousarray(vertices, dtype=float), np.ascontiguousarray(faces, dtype=np.int64))


@numba.njit(cache=True, nogil=True)
def _neighbourhood_sums(faces: np.ndarray, values: np.ndarray, incident: np.ndarray) -> np.ndarray:
    """Per face, the sum of ``values`` (m, d) over the faces that share a corner with it (itself included), each
    once, the faces around each vertex read from ``incident``. Summed in the order of scipy's ``(I @ I.T) @ values``
    for the face-vertex incidence I (CSR, sorted): for each corner in increasing vertex order, its faces in
    increasing order, first meetings last to first."""
    m, d = faces.shape[0], values.shape[1]
    mark = np.full(m, -1, np.int64)
    met = np.empty(incident.size, np.int64)
    out = np.zeros((m, d))
    for t in range(m):
        a0, a1, a2 = faces[t, 0], faces[t, 1], faces[t, 2]
        a0, a1 = min(a0, a1), max(a0, a1)
        a1, a2 = min(a1, a2), max(a1, a2)
        a0, a1 = min(a0, a1), max(a0, a1)
        count = 0
        for k in range(3):
            a = a0 if k == 0 else a1 if k == 1 else a2
            if (k == 1 and a == a0) or (k == 2 and a == a1):
                continue
            for p in range(incident.shape[1]):
                g = incident[a, p]
                if g < 0:
                    break
                if mark[g] != t:
                    mark[g] = t
                    met[count] = g
                    count += 1
        for i in range(count - 1, -1, -1):
            for c in range(d):
                out[t, c] += values[met[i], c]
    return out


def neighbourhood_sums(faces: np.ndarray, values: np.ndarray, incident: np.ndarray) -> np.ndarray:
    """Per triangle of ``faces`` (m, 3), the sum of the per-triangle ``values`` (m, d) over the triangles that share
    a corner with it, itself included, each once (m, d): the same numbers, to the last bit, as the sparse product
    (I I^T with its entries set to 1) @ values of the face-vertex incidence I, in O(m) and without the (m, m)
    matrix. ``incident`` (n, width): per vertex, the triangles that hold it in increasing order, padded with -1
    (:attr:`meshreg.mesh.surface.Surface.incident`)."""
    return _neighbourhood_sums(
        np.ascontiguousarray(faces, dtype=np.int64),
        np.ascontiguousarray(values, dtype=float),
        np.ascontiguousarray(incident, dtype=np.int64),
    )
