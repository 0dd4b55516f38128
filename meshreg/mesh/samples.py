"""Sample disk meshes made at run time: a terrain patch from matplotlib's Jacksboro fault DEM and a random
re-triangulated, rotated, scaled copy of it (so nothing is downloaded and nothing large is committed)."""

from __future__ import annotations

import numpy as np
from scipy.interpolate import RegularGridInterpolator
from scipy.spatial import Delaunay
from scipy.spatial.transform import Rotation


def terrain_function(size: int = 20):
    """(u, v) in [0,1]^2 -> points of a terrain patch (the DEM's first size x size samples, in km-ish units)."""
    from matplotlib import cbook

    with cbook.get_sample_data("jacksboro_fault_dem.npz") as data:
        z = np.asarray(data["elevation"], dtype=float)[:size, :size]
    z = (z - z.mean()) / 1000.0  # metres -> km, like the ~10 m grid spacing scaled to the patch
    axis = np.linspace(0, 1, size)
    interp = RegularGridInterpolator((axis, axis), z, method="cubic")
    return lambda u, v: np.stack([u, v, 1.5 * interp(np.stack([u, v], -1))], -1)


def random_disk_mesh(surface, n_points: int, seed: int, border: int = 24, rotation=None, scale: float = 1.0):
    """A Delaunay triangulation of random points of the square (plus a border), mapped by ``surface``.

    Vertex order is shuffled and the boundary starts at a random vertex, like a mesh from elsewhere.
    Returns vertices (n, 3), faces (m, 3) and each vertex's parameter (n, 2).
    """
    rng = np.random.default_rng(seed)
    b = np.sort(rng.random(border))
    edge = np.concatenate([np.c_[b, 0 * b], np.c_[0 * b + 1, b], np.c_[1 - b, 0 * b + 1], np.c_[0 * b, 1 - b]])
    pts = np.vstack([[[0, 0], [1, 0], [1, 1], [0, 1]], edge, 0.01 + 0.98 * rng.random((n_points, 2))])
    faces = Delaunay(pts).simplices
    verts = surface(pts[:, 0], pts[:, 1])
    if rotation is not None:
        verts = verts @ rotation.T
    verts = scale * verts + rng.normal(size=3)
    perm = rng.permutation(len(pts))
    inv = np.argsort(perm)
    return verts[perm], inv[faces], pts[perm]


def demo_pair():
    """Two meshes of one terrain patch: 2500 and 4000 random vertices, the second rotated and scaled."""
    surface = terrain_function()
    first = random_disk_mesh(surface, 2500, seed=1)
    second = random_disk_mesh(surface, 4000, seed=2, rotation=Rotation.from_euler("xyz", [30, -20, 75], degrees=True).as_matrix(), scale=2.5)
    return first, second
