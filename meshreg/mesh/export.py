"""Writing the mesh results: coloured PLY meshes, the registered grid as a mesh, and a side-by-side figure."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .correspond import MeshRegistration, uv_colors

UNMATCHED = np.array([0.6, 0.6, 0.6])  # colour of input vertices dropped by the cleanup


def grid_faces(m: int, n: int) -> np.ndarray:
    """Two triangles per cell of an m x n grid of nodes numbered i * n + j, shape (2 (m-1)(n-1), 3)."""
    idx = np.arange(m * n).reshape(m, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    return np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])


def write_ply(path, vertices: np.ndarray, faces: np.ndarray, colors: np.ndarray) -> None:
    """A PLY mesh with per-vertex RGB colours (colours in [0, 1])."""
    import trimesh

    rgba = np.hstack([np.clip(colors, 0, 1) * 255, np.full((len(colors), 1), 255)]).astype(np.uint8)
    trimesh.Trimesh(vertices, faces, vertex_colors=rgba, process=False).export(Path(path))


def registered_mesh(mr: MeshRegistration, objective):
    """The second surface sampled at h on the first's grid, brought into the first's frame (R^T, scale, centroid).

    ``objective`` is the :class:`meshreg.objective.Objective` of ``mr.grids``. Returns vertices
    (M N, 3), faces and colours (those of the first's grid nodes).
    """
    res = mr.result
    g1 = mr.grids[0]
    pts = objective.points(res.h) @ res.rotation * np.sqrt(g1.area())
    pts = pts + (g1.points.reshape(-1, 3).mean(0) - pts.reshape(-1, 3).mean(0))
    uv = np.stack(np.meshgrid(res.r, res.t, indexing="ij"), -1).reshape(-1, 2)
    return pts.reshape(-1, 3), grid_faces(len(res.r), len(res.t)), uv_colors(uv)


def colored_outputs(mr: MeshRegistration, n_first: int, n_second: int, objective):
    """What a mesh registration gives back: colours (n_first, 3) and (n_second, 3) in [0, 1] on the input
    vertices of both meshes (grey where cleanup dropped a vertex) and the registered mesh of
    :func:`registered_mesh` (vertices, faces, colours). ``objective`` is the Objective of ``mr.grids``."""
    c1 = mr.first.to_input(mr.colors1, n_first, UNMATCHED)
    c2 = mr.second.to_input(mr.colors2, n_second, UNMATCHED)
    return c1, c2, registered_mesh(mr, objective)


def _view_rotation(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    """A rotation (3, 3) taking the mesh's mean (area-weighted) normal to +z: the camera then faces the surface."""
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]).sum(axis=0)
    z = n / max(np.linalg.norm(n), 1e-300)
    x = np.cross([0.0, 1.0, 0.0] if abs(z[1]) < 0.9 else [1.0, 0.0, 0.0], z)
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(z, x), z])


def plot_meshes(path, v1, f1, c1, v2, f2, c2, title: str = "", second_to_first: np.ndarray | None = None) -> None:
    """PNG: the two meshes side by side, coloured by correspondence, both seen from the first's mean normal.

    ``second_to_first`` (4, 4), the similarity from the second's frame to the first's, puts the second
    mesh in the first's pose so that the two pictures can be compared point by point.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if second_to_first is not None:
        v2 = v2 @ second_to_first[:3, :3].T + second_to_first[:3, 3]
    view = _view_rotation(v1, f1)
    fig = plt.figure(figsize=(11, 5))
    for k, (v, f, c, name) in enumerate(((v1, f1, c1, "first"), (v2, f2, c2, "second"))):
        ax = fig.add_subplot(1, 2, k + 1, projection="3d")
        p = (v - v.mean(axis=0)) @ view.T
        ax.plot_trisurf(p[:, 0], p[:, 1], p[:, 2], triangles=f, color="w", linewidth=0, shade=False).set_facecolor(c[f].mean(1))
        ax.set_title(f"{name} mesh ({len(v)} vertices)" + (", in the first's pose" if k and second_to_first is not None else ""))
        ax.set_box_aspect(np.ptp(p, axis=0) + 1e-9)
        ax.view_init(elev=65, azim=-90)
        ax.set_axis_off()
    fig.suptitle(title or "corresponding points share a colour")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
