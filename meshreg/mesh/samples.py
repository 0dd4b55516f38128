"""Sample disk meshes made at run time from data inside installed wheels (nothing is downloaded and nothing
large is committed): a terrain patch from matplotlib's Jacksboro fault DEM, a crop of pymeshlab's face000
range scan (GPL: read from the wheel, never copied into the project), and random re-triangulated, rotated,
scaled copies of them."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.interpolate import LinearNDInterpolator, RegularGridInterpolator
from scipy.spatial import Delaunay, cKDTree
from scipy.spatial.transform import Rotation

from ..errors import InputError


def terrain_function(size: int = 20):
    """(u, v) in [0,1]^2 -> points of a terrain patch (the DEM's first size x size samples, in km-ish units)."""
    from matplotlib import cbook

    with cbook.get_sample_data("jacksboro_fault_dem.npz") as data:
        z = np.asarray(data["elevation"], dtype=float)[:size, :size]
    z = (z - z.mean()) / 1000.0  # metres -> km, like the ~10 m grid spacing scaled to the patch
    axis = np.linspace(0, 1, size)
    interp = RegularGridInterpolator((axis, axis), z, method="cubic")
    return lambda u, v: np.stack([u, v, 1.5 * interp(np.stack([u, v], -1))], -1)


def face_scan_path() -> Path:
    """Path of pymeshlab's ``tests/sample_meshes/rangemaps/face000.ply`` (a range scan of a sculpted head)."""
    try:
        import pymeshlab
    except ImportError:
        raise InputError("the face scan sample ships with pymeshlab: pip install 'meshreg[meshlab]'") from None
    path = Path(pymeshlab.__file__).parent / "tests" / "sample_meshes" / "rangemaps" / "face000.ply"
    if not path.is_file():
        raise InputError(f"{path} is missing from this pymeshlab installation")
    return path


def face_scan_crop(radius: float = 60.0):
    """The raw triangles of the face scan within ``radius`` (mm) of its median point, seen along the scan's
    view axis z: holes, pinched boundary vertices and stray fragments included. Returns vertices (n, 3), faces
    (m, 3)."""
    from .topology import load_mesh

    v, f = load_mesh(face_scan_path())
    inside = np.linalg.norm(v[:, :2] - np.median(v[:, :2], axis=0), axis=1) < radius
    return v, f[inside[f].all(axis=1)]


def remeshed_range_scan(vertices, faces, n_points: int, seed: int, rotation=None, scale: float = 1.0):
    """A new random triangulation of a range scan (z a function of x, y) over the same region, holes kept.

    Random points of the region's bounding disc (plus its rim) are Delaunay-triangulated, lifted by linear
    interpolation of the scan, and triangles far from any scan vertex (holes, outside) are dropped. The
    result is rotated, scaled, shifted and its vertex order shuffled. Returns vertices (k, 3), faces and
    each vertex's (x, y) before the motion (k, 2), which identifies corresponding points.
    """
    rng = np.random.default_rng(seed)
    used = np.unique(faces)
    xy, z = vertices[used, :2], vertices[used, 2]
    centre = np.median(xy, axis=0)
    radius = np.linalg.norm(xy - centre, axis=1).max()
    rim = 2 * np.pi * rng.random(n_points // 20)
    disc = np.sqrt(rng.random(n_points)) * radius, 2 * np.pi * rng.random(n_points)
    pts = centre + np.vstack(
        [radius * np.c_[np.cos(rim), np.sin(rim)], np.c_[disc[0] * np.cos(disc[1]), disc[0] * np.sin(disc[1])]]
    )
    tri = Delaunay(pts).simplices
    spacing = np.median(np.linalg.norm(vertices[faces[:, 0], :2] - vertices[faces[:, 1], :2], axis=1))
    gap, _ = cKDTree(xy).query(pts[tri].mean(axis=1))
    height = LinearNDInterpolator(xy, z)(pts)
    tri = tri[(gap < 1.2 * spacing) & np.isfinite(height[tri]).all(axis=1)]
    lifted = np.c_[pts, height]
    longest = np.max([np.linalg.norm(lifted[tri[:, k]] - lifted[tri[:, k - 1]], axis=1) for k in range(3)], axis=0)
    tri = tri[longest < 4 * np.median(longest)]  # no walls across depth jumps of the scan
    kept = np.unique(tri)
    pts, verts, tri = pts[kept], lifted[kept], np.searchsorted(kept, tri)
    if rotation is not None:
        verts = verts @ np.asarray(rotation).T
    verts = scale * verts + rng.normal(size=3)
    perm = rng.permutation(len(pts))
    inv = np.argsort(perm)
    return verts[perm], inv[tri], pts[perm]


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


DEMO_ROTATION = Rotation.from_euler("xyz", [30, -20, 75], degrees=True).as_matrix()
DEMO_SCALE = 2.5


def demo_pair():
    """Two meshes of one terrain patch from 2500 and 4000 random interior points (plus their borders), the second
    rotated by :data:`DEMO_ROTATION`, scaled by :data:`DEMO_SCALE` and shifted. Each is (vertices, faces, params):
    a vertex's parameter on the patch, which identifies corresponding points."""
    surface = terrain_function()
    first = random_disk_mesh(surface, 2500, seed=1)
    second = random_disk_mesh(surface, 4000, seed=2, rotation=DEMO_ROTATION, scale=DEMO_SCALE)
    return first, second


def write_demo_meshes(folder, pair=None) -> tuple[Path, Path]:
    """Write the two meshes of :func:`demo_pair` (or of ``pair``, as it returns them) as ``terrain_a.ply`` and
    ``terrain_b.ply`` (light grey) into ``folder`` (made if missing); returns their paths."""
    import trimesh

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    paths = folder / "terrain_a.ply", folder / "terrain_b.ply"
    for path, (v, f, _) in zip(paths, pair or demo_pair(), strict=True):
        grey = np.tile([204, 204, 204, 255], (len(v), 1)).astype(np.uint8)
        trimesh.Trimesh(v, f, vertex_colors=grey, process=False).export(path)
    return paths


def terrain_family(count: int = 12, seed: int = 0, n_points: int = 1000):
    """A collection with known generating parameters: deformed variants of the terrain patch, each a random
    triangulation (``n_points`` +-10% random interior vertices, about 2 ``n_points`` triangles), randomly rotated,
    scaled and shifted.

    Member k is (u, v, relief_k z(u, v) + uplift_k sin(pi u) sin(pi v)), z the patch's height
    (:func:`terrain_function`): relief in [1, 2.5] is its vertical exaggeration, uplift in [-0.15, 0.15] a dome
    (or a basin) across the patch, both drawn uniformly.

    Returns the meshes [(vertices, faces)] and the parameters (count, 2): relief, uplift.
    """
    rng = np.random.default_rng(seed)
    base = terrain_function()
    params = np.c_[rng.uniform(1.0, 2.5, count), rng.uniform(-0.15, 0.15, count)]
    meshes = []
    for k, (relief, uplift) in enumerate(params):

        def surface(u, v, relief=relief, uplift=uplift):
            p = base(u, v)
            return np.stack(
                [p[..., 0], p[..., 1], relief * p[..., 2] + uplift * np.sin(np.pi * u) * np.sin(np.pi * v)], -1
            )

        size = int(n_points * rng.uniform(0.9, 1.1))
        rotation = Rotation.random(random_state=rng.integers(2**31)).as_matrix()
        v, f, _ = random_disk_mesh(surface, size, seed + 1000 + k, rotation=rotation, scale=rng.uniform(0.5, 2.0))
        meshes.append((v, f))
    return meshes, params


FACE_ROTATION = Rotation.from_euler("zxz", [70, 35, -120], degrees=True).as_matrix()


def face_scan_pair(
    radius: float = 50.0, n_points: int = 20000, seed: int = 1, rotation=FACE_ROTATION, scale: float = 0.01
):
    """Two meshes of one real surface: the raw face-scan crop (unused vertices dropped) and a re-triangulated,
    rotated, scaled copy. Returns (vertices, faces), (vertices, faces, xy) of the copy (see
    :func:`remeshed_range_scan`) and the true rotation."""
    v, f = face_scan_crop(radius)
    used = np.unique(f)
    v, f = v[used], np.searchsorted(used, f)
    return (v, f), remeshed_range_scan(v, f, n_points, seed, rotation=rotation, scale=scale), rotation


def face_scan_errors(result, crop: tuple, xy: np.ndarray) -> np.ndarray:
    """How far a registration of :func:`face_scan_pair` is from the truth, per vertex of the remeshed copy.

    Parameters
    ----------
    result : meshreg.Registration
        The crop (first) registered with the copy (second).
    crop : (vertices (n, 3), faces (m, 3))
        The crop as registered.
    xy : ndarray, shape (k, 2)
        Each copy vertex's (x, y) before the motion, as :func:`face_scan_pair` returns it.

    Returns
    -------
    ndarray, shape (k,)
        For each copy vertex, the distance between the point of the crop the registration matches it with and
        its true partner (the crop's surface at its original (x, y), linear in the crop's triangles), in units of
        sqrt(area) of the crop; NaN where that (x, y) lies outside the crop or cleanup dropped the vertex.
    """
    from .topology import triangle_areas

    vertices, faces = crop
    truth = LinearNDInterpolator(vertices[:, :2], vertices)(xy)
    area = float(triangle_areas(vertices, faces).sum())
    return np.linalg.norm(result.correspondence_on_first() - truth, axis=1) / np.sqrt(area)
