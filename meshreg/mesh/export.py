"""What a mesh registration gives back as meshes: correspondence colours, the registered grid as a mesh, PLY files."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .correspond import MeshRegistration
from .ply import write_ply_bytes

UNMATCHED = np.array([0.6, 0.6, 0.6])  # colour of input vertices dropped by the cleanup
# colours of the square's corners (0,0), (1,0), (1,1), (0,1), blended bilinearly
_CORNERS = np.array([[0.85, 0.10, 0.10], [0.95, 0.80, 0.10], [0.10, 0.55, 0.95], [0.15, 0.75, 0.25]])


CHECKER = 8  # squares per side of the checkerboard carried from the first surface to the second
CHECKER_SHADE = 0.7  # brightness of the dark squares


def uv_colors(uv: np.ndarray) -> np.ndarray:
    """RGB in [0, 1] (n, 3) for points (n, 2) of the square: a smooth bilinear blend of four distinct colours."""
    u, v = uv[:, :1], uv[:, 1:]
    return (1 - u) * (1 - v) * _CORNERS[0] + u * (1 - v) * _CORNERS[1] + u * v * _CORNERS[2] + (1 - u) * v * _CORNERS[3]


def texture_colors(uv: np.ndarray) -> np.ndarray:
    """:func:`uv_colors` with a CHECKER x CHECKER checkerboard of the square on top: the smooth blend says roughly
    where a point corresponds, the squares' edges show a local error of a fraction of a square."""
    cells = np.floor(np.clip(uv, 0, 1 - 1e-12) * CHECKER).astype(int)
    dark = (cells[:, 0] + cells[:, 1]) % 2 == 1
    return uv_colors(uv) * np.where(dark, CHECKER_SHADE, 1.0)[:, None]


def grid_faces(m: int, n: int) -> np.ndarray:
    """Two triangles per cell of an m x n grid of nodes numbered i * n + j, shape (2 (m-1)(n-1), 3)."""
    idx = np.arange(m * n).reshape(m, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    return np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])


def write_ply(path, vertices: np.ndarray, faces: np.ndarray, colors: np.ndarray) -> None:
    """A binary PLY mesh with per-vertex RGB colours (colours in [0, 1]; :func:`meshreg.mesh.ply.write_ply_bytes`)."""
    rgba = np.hstack([np.clip(colors, 0, 1) * 255, np.full((len(colors), 1), 255)]).astype(np.uint8)
    Path(path).write_bytes(write_ply_bytes(vertices, faces, rgba))


def registered_mesh(mr: MeshRegistration):
    """The second surface sampled at h on the first's grid, brought into the first's frame (R^T, scale, centroid).

    Returns vertices (M N, 3), faces and colours (those of the first's grid nodes).
    """
    res = mr.result
    g1, g2 = mr.grids
    pts = g2.scaled().at(res.h) @ res.rotation * np.sqrt(g1.area())
    pts = pts + (g1.points.reshape(-1, 3).mean(0) - pts.reshape(-1, 3).mean(0))
    uv = np.stack(np.meshgrid(res.r, res.t, indexing="ij"), -1).reshape(-1, 2)
    return pts.reshape(-1, 3), grid_faces(len(res.r), len(res.t)), texture_colors(uv)


def colored_outputs(mr: MeshRegistration, n_first: int, n_second: int):
    """What a mesh registration gives back: colours (n_first, 3) and (n_second, 3) in [0, 1] on the input
    vertices of both meshes, such that corresponding points share a colour (grey where cleanup dropped a
    vertex), and the registered mesh of :func:`registered_mesh` (vertices, faces, colours)."""
    c1 = mr.first.to_input(texture_colors(mr.uv1), n_first, UNMATCHED)
    c2 = mr.second.to_input(texture_colors(mr.matched_uv2), n_second, UNMATCHED)
    return c1, c2, registered_mesh(mr)
