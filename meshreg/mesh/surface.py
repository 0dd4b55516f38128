"""A triangle mesh as a target of geometric queries: nearest vertices, closest points on its triangles, normals
and the distance of a point to its rim (boundary), for the alignment and overlap of two meshes.

Pure numpy/scipy, with trimesh's closest-point query (rtree) for exact points on the triangles.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
from scipy.spatial import cKDTree

NORMAL_AGREEMENT = np.cos(np.radians(60.0))  # |n1 . n2| below this: a pair of points on different sheets
RIM_CANDIDATES = 16  # boundary segments (nearest midpoints) tried per point for its exact distance to the rim


def face_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Unnormalized normals (m, 3) of the triangles: twice their area times the unit normal."""
    v = vertices
    return np.cross(v[faces[:, 1]] - v[faces[:, 0]], v[faces[:, 2]] - v[faces[:, 0]])


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals (n, 3) (zero for unreferenced vertices)."""
    fn = face_normals(vertices, faces)
    out = np.zeros_like(vertices, dtype=float)
    for k in range(3):
        np.add.at(out, faces[:, k], fn)
    norm = np.linalg.norm(out, axis=1, keepdims=True)
    return np.divide(out, norm, out=np.zeros_like(out), where=norm > 0)


def boundary_edges(faces: np.ndarray) -> np.ndarray:
    """Edges (b, 2) used by one triangle only (the rim and the rims of holes)."""
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    key = np.sort(e, axis=1)
    _, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    return e[counts[inverse.ravel()] == 1]


def median_edge(vertices: np.ndarray, faces: np.ndarray) -> float:
    """Median length of the triangles' edges."""
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]]])
    return float(np.median(np.linalg.norm(vertices[e[:, 0]] - vertices[e[:, 1]], axis=1)))


def segment_distance(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance (...,) from points (..., 3) to the segments from a to b (..., 3)."""
    ab = b - a
    length2 = np.maximum(np.sum(ab * ab, axis=-1), 1e-300)
    t = np.clip(np.sum((points - a) * ab, axis=-1) / length2, 0.0, 1.0)
    return np.linalg.norm(points - (a + t[..., None] * ab), axis=-1)


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
        self.vertices = np.asarray(self.vertices, dtype=float)
        self.faces = np.asarray(self.faces, dtype=np.int64)
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

    @cached_property
    def _mesh(self):
        import trimesh

        return trimesh.Trimesh(self.vertices, self.faces, process=False)

    def closest(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Closest points (k, 3) on the triangles to ``points`` (k, 3), their distances (k,) and the unit normals
        (k, 3) of the triangles that hold them."""
        closest, distance, triangle, _ = self.project(points)
        fn = face_normals(self.vertices, self.faces[triangle])
        fn /= np.maximum(np.linalg.norm(fn, axis=1, keepdims=True), 1e-300)
        return closest, distance, fn

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Closest points (k, 3) on the triangles to ``points`` (k, 3), their distances (k,), the triangles that
        hold them (k,) and their barycentric weights there (k, 3)."""
        import trimesh

        points = np.asarray(points, dtype=float)
        if len(points) == 0:
            return np.empty((0, 3)), np.empty(0), np.empty(0, dtype=np.int64), np.empty((0, 3))
        closest, distance, triangle = trimesh.proximity.closest_point(self._mesh, points)
        weights = trimesh.triangles.points_to_barycentric(self.vertices[self.faces[triangle]], closest)
        return np.asarray(closest), np.asarray(distance), np.asarray(triangle, dtype=np.int64), weights

    def at(self, values: np.ndarray, triangle: np.ndarray, weights: np.ndarray) -> np.ndarray:
        """Per-vertex values (n, d) at points given by triangles (k,) and barycentric weights (k, 3): (k, d)."""
        return np.einsum("kc,kcd->kd", weights, np.asarray(values)[self.faces[triangle]])

    def rim_distance(self, points: np.ndarray) -> np.ndarray:
        """Distance (k,) from each point (k, 3) to the rim (the boundary edges); inf without a rim."""
        points = np.asarray(points, dtype=float)
        if len(self.rim_edges) == 0:
            return np.full(len(points), np.inf)
        k = min(RIM_CANDIDATES, len(self.rim_edges))
        _, idx = self._rim_tree.query(points, k=k)
        idx = idx.reshape(len(points), k)
        ends = self.vertices[self.rim_edges[idx]]  # (p, k, 2, 3)
        return segment_distance(points[:, None, :], ends[..., 0, :], ends[..., 1, :]).min(axis=1)


def transform_points(matrix: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Points (..., 3) moved by the 4 x 4 matrix (a similarity or any affine map)."""
    return np.asarray(points, dtype=float) @ matrix[:3, :3].T + matrix[:3, 3]


def transform_normals(matrix: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Unit normals (..., 3) turned by the rotation of a similarity ``matrix``."""
    rotated = np.asarray(normals, dtype=float) @ matrix[:3, :3].T
    return rotated / np.maximum(np.linalg.norm(rotated, axis=-1, keepdims=True), 1e-300)
