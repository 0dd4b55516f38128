"""A triangle mesh as a target of geometric queries: nearest vertices, closest points on its triangles, normals
and the distance of a point to its rim (boundary), for the alignment and overlap of two meshes.

numpy/scipy, with the closest-point search in numba.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
from functools import cached_property

import numba
import numpy as np
from scipy.spatial import cKDTree

from .graph import face_normals, side_lengths
from .topology import boundary_edges

NORMAL_AGREEMENT = np.cos(np.radians(60.0))  # |n1 . n2| below this: a pair of points on different sheets
RIM_CANDIDATES = 16  # boundary segments (nearest midpoints) tried per point for its exact distance to the rim
NEAREST_VERTICES = 6  # a point's closest point is sought on the triangles around its nearest vertices


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals (n, 3) (zero for unreferenced vertices)."""
    fn = face_normals(vertices, faces)
    corners, n = faces.ravel(), len(vertices)
    out = np.stack([np.bincount(corners, np.repeat(fn[:, c], 3), minlength=n) for c in range(3)], axis=1)
    norm = np.linalg.norm(out, axis=1, keepdims=True)
    return np.divide(out, norm, out=np.zeros_like(out), where=norm > 0)


def median_edge(vertices: np.ndarray, faces: np.ndarray) -> float:
    """Median length of the triangles' edges (their first two sides: an inner edge is seen about once)."""
    return float(np.median(side_lengths(vertices, faces, 2)))


@numba.njit(cache=True)
def _incident_triangles(faces: np.ndarray, n: int, width: int) -> np.ndarray:
    """Per vertex of n, the triangles (m, 3) that hold it, in increasing order (n, width), padded with -1."""
    out = np.full((n, width), -1, np.int64)
    filled = np.zeros(n, np.int64)
    for f in range(len(faces)):
        for k in range(3):
            v = faces[f, k]
            out[v, filled[v]] = f
            filled[v] += 1
    return out


def cube_labels(points: np.ndarray, spacing: float) -> np.ndarray:
    """Per point (n, 3), the index (n,) of the cube of side ``spacing`` that holds it, among the occupied cubes
    in the order of their (x, y, z) grid indices."""
    keys = np.floor((points - points.min(axis=0)) / spacing).astype(np.int64)
    size = keys.max(axis=0) + 1  # one int64 per cube: much faster than np.unique(axis=0)
    return np.unique((keys[:, 0] * size[1] + keys[:, 1]) * size[2] + keys[:, 2], return_inverse=True)[1].ravel()


@numba.njit(cache=True)
def _closest_on_triangle(px, py, pz, ax, ay, az, bx, by, bz, cx, cy, cz):
    """Barycentric weights (u, v, w) of the closest point of triangle abc to p (Ericson, Real-Time Collision
    Detection, 5.1.5)."""
    abx, aby, abz = bx - ax, by - ay, bz - az
    acx, acy, acz = cx - ax, cy - ay, cz - az
    apx, apy, apz = px - ax, py - ay, pz - az
    d1 = abx * apx + aby * apy + abz * apz
    d2 = acx * apx + acy * apy + acz * apz
    if d1 <= 0.0 and d2 <= 0.0:
        return 1.0, 0.0, 0.0
    bpx, bpy, bpz = px - bx, py - by, pz - bz
    d3 = abx * bpx + aby * bpy + abz * bpz
    d4 = acx * bpx + acy * bpy + acz * bpz
    if d3 >= 0.0 and d4 <= d3:
        return 0.0, 1.0, 0.0
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        t = d1 / (d1 - d3)
        return 1.0 - t, t, 0.0
    cpx, cpy, cpz = px - cx, py - cy, pz - cz
    d5 = abx * cpx + aby * cpy + abz * cpz
    d6 = acx * cpx + acy * cpy + acz * cpz
    if d6 >= 0.0 and d5 <= d6:
        return 0.0, 0.0, 1.0
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        t = d2 / (d2 - d6)
        return 1.0 - t, 0.0, t
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
        t = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        return 0.0, 1.0 - t, t
    denom = va + vb + vc
    if denom == 0.0:  # a degenerate triangle: its first corner
        return 1.0, 0.0, 0.0
    v, w = vb / denom, vc / denom
    return 1.0 - v - w, v, w


@numba.njit(cache=True)
def _closest_points(points, vertices, faces, candidates, closest, weights, triangle):
    for k in range(points.shape[0]):
        px, py, pz = points[k, 0], points[k, 1], points[k, 2]
        best = np.inf
        for c in range(candidates.shape[1]):
            f = candidates[k, c]
            if f < 0:
                continue
            a, b, cc = faces[f, 0], faces[f, 1], faces[f, 2]
            u, v, w = _closest_on_triangle(
                px, py, pz,
                vertices[a, 0], vertices[a, 1], vertices[a, 2],
                vertices[b, 0], vertices[b, 1], vertices[b, 2],
                vertices[cc, 0], vertices[cc, 1], vertices[cc, 2],
            )  # fmt: skip
            qx = u * vertices[a, 0] + v * vertices[b, 0] + w * vertices[cc, 0]
            qy = u * vertices[a, 1] + v * vertices[b, 1] + w * vertices[cc, 1]
            qz = u * vertices[a, 2] + v * vertices[b, 2] + w * vertices[cc, 2]
            d = (qx - px) ** 2 + (qy - py) ** 2 + (qz - pz) ** 2
            if d < best:
                best = d
                closest[k, 0], closest[k, 1], closest[k, 2] = qx, qy, qz
                weights[k, 0], weights[k, 1], weights[k, 2] = u, v, w
                triangle[k] = f


@numba.njit(cache=True)
def _nearest_segment(points, vertices, segments, candidates):
    """Per point (k, 3), the distance to the closest of its candidate segments (k, c) (rows of segments (s, 2),
    vertex ids)."""
    out = np.empty(len(points))
    for k in range(len(points)):
        best = np.inf
        for c in range(candidates.shape[1]):
            a, b = segments[candidates[k, c], 0], segments[candidates[k, c], 1]
            along, length2 = 0.0, 0.0
            for x in range(3):
                along += (points[k, x] - vertices[a, x]) * (vertices[b, x] - vertices[a, x])
                length2 += (vertices[b, x] - vertices[a, x]) ** 2
            t = min(max(along / max(length2, 1e-300), 0.0), 1.0)
            gap2 = 0.0
            for x in range(3):
                gap2 += (points[k, x] - vertices[a, x] - t * (vertices[b, x] - vertices[a, x])) ** 2
            best = min(best, gap2)
        out[k] = np.sqrt(best)
    return out


@dataclass
class Surface:
    """A triangle mesh with what the alignment and the overlap ask of it.

    Attributes
    ----------
    vertices : ndarray, shape (n, 3)
    faces : ndarray, shape (m, 3)
    normals : ndarray, shape (n, 3)
        Area-weighted unit vertex normals.
    rim : ndarray of bool, shape (n,)
        Vertices on a boundary edge.
    edge : float
        Median edge length.
    area : float
    """

    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray = field(init=False)
    rim: np.ndarray = field(init=False)
    edge: float = field(init=False)
    area: float = field(init=False)

    def __post_init__(self):
        self.vertices = np.ascontiguousarray(self.vertices, dtype=float)
        self.faces = np.ascontiguousarray(self.faces, dtype=np.int64)
        self.normals = vertex_normals(self.vertices, self.faces)
        self.rim = np.zeros(len(self.vertices), dtype=bool)
        self.rim[self.rim_edges.ravel()] = True
        self.edge = median_edge(self.vertices, self.faces)
        self.area = 0.5 * float(np.linalg.norm(face_normals(self.vertices, self.faces), axis=1).sum())

    @cached_property
    def rim_edges(self) -> np.ndarray:
        """Boundary edges (b, 2)."""
        return boundary_edges(self.faces)

    @cached_property
    def tree(self) -> cKDTree:
        """KD-tree of the vertices."""
        return cKDTree(self.vertices)

    @cached_property
    def _rim_tree(self) -> cKDTree:
        ends = self.vertices[self.rim_edges]
        return cKDTree(ends.mean(axis=1))

    def closest(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Closest points (k, 3) on the triangles to ``points`` (k, 3), their distances (k,) and the unit normals
        (k, 3) of the triangles that hold them."""
        closest, distance, triangle, _ = self.project(points)
        fn = face_normals(self.vertices, self.faces[triangle])
        fn /= np.maximum(np.linalg.norm(fn, axis=1, keepdims=True), 1e-300)
        return closest, distance, fn

    @cached_property
    def incident(self) -> np.ndarray:
        """Per vertex, the triangles around it in increasing order (n, max valence), padded with -1."""
        counts = np.bincount(self.faces.ravel(), minlength=len(self.vertices))
        return _incident_triangles(self.faces, len(self.vertices), max(int(counts.max()), 1))

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Closest points (k, 3) on the triangles to ``points`` (k, 3), their distances (k,), the triangles that
        hold them (k,) and their barycentric weights there (k, 3).

        Sought on the triangles around each point's NEAREST_VERTICES nearest vertices (exact for meshes whose
        triangles are not far longer than the distance between neighbouring vertices)."""
        points = np.ascontiguousarray(points, dtype=float).reshape(-1, 3)
        closest = np.empty_like(points)
        weights = np.empty_like(points)
        triangle = np.zeros(len(points), dtype=np.int64)
        k = min(NEAREST_VERTICES, len(self.vertices))
        _, near = self.tree.query(points, k=k)
        candidates = np.ascontiguousarray(self.incident[near.reshape(len(points), k)].reshape(len(points), -1))
        _closest_points(points, self.vertices, self.faces, candidates, closest, weights, triangle)
        return closest, np.linalg.norm(closest - points, axis=1), triangle, weights

    def at(self, values: np.ndarray, triangle: np.ndarray, weights: np.ndarray) -> np.ndarray:
        """Per-vertex values (n, d) at points given by triangles (k,) and barycentric weights (k, 3): (k, d)."""
        return np.einsum("kc,kcd->kd", weights, np.asarray(values)[self.faces[triangle]])

    @cached_property
    def vertex_rim_distance(self) -> np.ndarray:
        """Distance (n,) from each vertex to the rim."""
        return self.rim_distance(self.vertices)

    def rim_distance(self, points: np.ndarray) -> np.ndarray:
        """Distance (k,) from each point (k, 3) to the rim (the boundary edges); inf without a rim."""
        points = np.asarray(points, dtype=float)
        if len(self.rim_edges) == 0:
            return np.full(len(points), np.inf)
        k = min(RIM_CANDIDATES, len(self.rim_edges))
        _, idx = self._rim_tree.query(points, k=k)
        points = np.ascontiguousarray(points)
        return _nearest_segment(points, self.vertices, self.rim_edges, idx.reshape(len(points), k))

    def moved(self, matrix: np.ndarray) -> Surface:
        """The surface moved by a similarity ``matrix`` (4 x 4): what does not depend on the pose (the rim, the
        triangles around each vertex) is kept, lengths scale, the KD-trees are rebuilt when asked for."""
        scale = float(np.cbrt(np.linalg.det(matrix[:3, :3])))
        out = copy.copy(self)
        for cached in ("tree", "_rim_tree", "vertex_rim_distance"):
            out.__dict__.pop(cached, None)
        out.vertices = np.ascontiguousarray(transform_points(matrix, self.vertices))
        out.normals = transform_normals(matrix, self.normals)
        out.edge, out.area = scale * self.edge, scale**2 * self.area
        if "vertex_rim_distance" in self.__dict__:
            out.vertex_rim_distance = scale * self.vertex_rim_distance
        return out


def transform_points(matrix: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Points (..., 3) moved by the 4 x 4 matrix (a similarity or any affine map)."""
    return np.asarray(points, dtype=float) @ matrix[:3, :3].T + matrix[:3, 3]


def transform_normals(matrix: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Unit normals (..., 3) turned by the rotation of a similarity ``matrix``."""
    rotated = np.asarray(normals, dtype=float) @ matrix[:3, :3].T
    return rotated / np.maximum(np.linalg.norm(rotated, axis=-1, keepdims=True), 1e-300)
