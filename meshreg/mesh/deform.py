"""Pairs of meshes whose true point-to-point (material) correspondence is known, for tests and benchmarks.

Every pair is built from one *material* surface with 2D material coordinates (the parameter square of a sheet,
the scan plane of a range scan). The first mesh triangulates part of it; the second mesh triangulates the same
or another part with other random vertices, is deformed (bent around a cylinder, folded, rolled, stretched), then
rotated, scaled and shifted, and its vertex order is shuffled. Each vertex of the second mesh keeps its material
coordinates, so its true corresponding point on the first mesh is the first mesh at those coordinates (the
barycentric interpolation of the first mesh's triangle that contains them).

Kinds (each a function returning a :class:`Pair`):

- :func:`remeshed_pair`: the same surface, new triangulation, rotated, scaled, shifted (no deformation);
- :func:`bent_pair`: bent around a cylinder by a given angle over a band of the sheet (the whole width: a wrap or
  a roll; a narrow band: a fold along a crease); isometric on the sheet's base plane, relief stretched by
  (R + z) / R at height z over a cylinder of radius R;
- :func:`stretched_pair`: x -> x + a x^2 along the sheet, a known non-isometric map;
- :func:`partial_pair`: the second covers a rectangle of the first's square (a centred crop, a corner, a strip);
- :func:`scan_pair`: crops of a real range scan (pymeshlab's face000), optionally offset from each other and
  bent.

To score a registration: :func:`matched_points` (meshreg's answer for each vertex of the second mesh, a point on
the first) and :func:`parametrization_points` (the parametrization alone, h = a symmetry of the square), then
:meth:`Pair.errors`.

Pure numpy/scipy; the real scan needs pymeshlab (:func:`meshreg.mesh.samples.face_scan_path`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy.interpolate import LinearNDInterpolator
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from ..errors import InputError
from ..search import inverse_symmetry, symmetry_map
from .plane import interpolate, locate
from .samples import face_scan_crop, random_disk_mesh, remeshed_range_scan, terrain_function
from .topology import triangle_areas

SECOND_ROTATION = Rotation.from_euler("xyz", [30, -20, 75], degrees=True).as_matrix()
PARTIAL_ROTATION = Rotation.from_euler("zyx", [-50, 25, 10], degrees=True).as_matrix()


@dataclass(frozen=True)
class Pair:
    """Two meshes and the true corresponding point on the first of every vertex of the second.

    Attributes
    ----------
    name : str
    first, second : (ndarray (n1, 3), ndarray (m1, 3)), (ndarray (n2, 3), ndarray (m2, 3))
        Vertices and faces.
    truth : ndarray, shape (n2, 3)
        For each vertex of the second mesh, its true corresponding point on the first mesh (in the first's
        frame); NaN where the second's material point is not on the first (partial overlap, holes).
    covered : ndarray of bool, shape (n1,)
        Which vertices of the first mesh the second covers (all for full-overlap pairs).
    overlap : float
        Fraction of the first mesh's area that the second covers.
    unit : float
        Length that errors are measured in: sqrt of the area of the first mesh for full-overlap pairs, of the
        second's material region (in the first's frame) for partial ones.
    partial : bool
        Whether the second covers only part of the first (by construction: a crop, not holes or a ragged rim).
    same_scale : bool
        Whether the second is at the first's scale (partial pairs: two scans of one object); else it is scaled.
    first_params, second_params : ndarray, shapes (n1, 2), (n2, 2)
        Material coordinates of each vertex (shared by both meshes).
    info : dict
        How the pair was made (kind, angles, sizes, the largest edge-length ratio of the deformation).
    """

    name: str
    first: tuple
    second: tuple
    truth: np.ndarray
    covered: np.ndarray
    overlap: float
    unit: float
    partial: bool
    same_scale: bool
    first_params: np.ndarray
    second_params: np.ndarray
    info: dict = field(default_factory=dict)

    def errors(self, predicted: np.ndarray) -> np.ndarray:
        """Distances (k,) from predicted points (n2, 3) on the first mesh to the true ones, in units of
        :attr:`unit`, over the second's vertices that have a true point (NaN predictions count as infinite)."""
        predicted = np.asarray(predicted, dtype=float)
        if predicted.shape != self.truth.shape:
            raise InputError(f"predicted points must have shape {self.truth.shape}, got {predicted.shape}")
        known = np.isfinite(self.truth[:, 0])
        d = np.linalg.norm(predicted[known] - self.truth[known], axis=1) / self.unit
        return np.where(np.isfinite(d), d, np.inf)


def bend(points: np.ndarray, angle: float, start: float = 0.0, width: float = 1.0, side: float = 1.0) -> np.ndarray:
    """Bend a sheet lying along the (x, y) plane around a cylinder whose axis is parallel to y.

    The band start <= x <= start + width is wrapped around a cylinder of radius R = width / angle (its base
    plane z = 0 keeps its lengths; a point at height z lands at distance R - side z from the axis); x < start is
    unchanged, x > start + width continues along the tangent plane at the band's end (rigidly moved).
    ``side`` = 1 bends towards +z, -1 towards -z. Returns the bent points (n, 3).

    Examples
    --------
    >>> p = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    >>> bend(p, np.pi).round(6).tolist()  # the far edge of a half roll lands above the first, 2R away
    [[0.0, 0.0, 0.0], [0.0, 0.0, 0.63662]]
    """
    if not (0 < abs(angle) < 2 * np.pi and width > 0 and side in (-1, 1)):
        raise InputError("bend needs 0 < |angle| < 2 pi, width > 0 and side +-1")
    p = np.asarray(points, dtype=float)
    x, y, z = p[:, 0], p[:, 1], side * p[:, 2]
    radius = width / angle
    s = np.clip(x - start, 0.0, width)
    beyond = np.maximum(x - start - width, 0.0)
    theta = s / radius
    tangent = np.stack([np.cos(theta), np.sin(theta)], axis=-1)
    normal = np.stack([-np.sin(theta), np.cos(theta)], axis=-1)
    base = np.stack([start + radius * np.sin(theta), radius * (1 - np.cos(theta))], axis=-1)
    base[x < start, 0] = x[x < start]
    out = base + beyond[:, None] * tangent + z[:, None] * normal
    return np.stack([out[:, 0], y, side * out[:, 1]], axis=-1)


def stretch(points: np.ndarray, a: float) -> np.ndarray:
    """x -> x + a x^2 (a sheet along x in [0, 1] stretched by 1 + 2 a x locally: not an isometry)."""
    p = np.array(points, dtype=float)
    p[:, 0] += a * p[:, 0] ** 2
    return p


def relief_sheet(height: float = 1.0) -> Callable:
    """The sheet with relief the pairs use by default: the terrain patch of
    :func:`meshreg.mesh.samples.terrain_function` (unit square, relief of about +-0.09), its heights times
    ``height``."""
    terrain = terrain_function()

    def surface(u, v):
        return terrain(u, v) * np.array([1.0, 1.0, height])

    return surface


def _mesh_area(vertices, faces) -> float:
    return float(triangle_areas(np.asarray(vertices), np.asarray(faces)).sum())


def edge_ratio(before: np.ndarray, after: np.ndarray, faces: np.ndarray) -> float:
    """The largest factor (>= 1) by which a deformation lengthens or shortens an edge of a mesh."""
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    l0 = np.linalg.norm(before[e[:, 0]] - before[e[:, 1]], axis=1)
    l1 = np.linalg.norm(after[e[:, 0]] - after[e[:, 1]], axis=1)
    ratio = l1[l0 > 0] / l0[l0 > 0]
    return float(max(ratio.max(), 1 / max(ratio.min(), 1e-300)))


def _assemble(
    name: str,
    first: tuple,
    first_params: np.ndarray,
    second_faces: np.ndarray,
    second_params: np.ndarray,
    material: np.ndarray,
    deformed: np.ndarray,
    *,
    rotation: np.ndarray | None,
    scale: float,
    partial: bool,
    seed: int,
    info: dict,
) -> Pair:
    """A pair from the first mesh, the second's faces and material coordinates, its material points (on or near
    the first surface, in its frame) and those points deformed: rotate, scale, shift and shuffle the second; its
    true points on the first are the first mesh at its material coordinates."""
    v1, f1 = first
    rng = np.random.default_rng(seed)
    ratio = edge_ratio(material, deformed, second_faces)
    moved = deformed if rotation is None else deformed @ np.asarray(rotation).T
    moved = scale * moved + rng.normal(size=3) * np.sqrt(_mesh_area(v1, f1))
    perm = rng.permutation(len(moved))
    second_faces = np.argsort(perm)[second_faces]
    moved, second_params, material = moved[perm], second_params[perm], material[perm]
    face, bary, inside = locate(first_params, f1, second_params)
    truth = interpolate(v1, f1, face, bary)
    truth[~inside] = np.nan
    covered = locate(second_params, second_faces, first_params)[2]
    area1 = triangle_areas(v1, f1)
    overlap = float(area1[locate(second_params, second_faces, first_params[f1].mean(axis=1))[2]].sum() / area1.sum())
    unit = np.sqrt(_mesh_area(material, second_faces) if partial else area1.sum())
    info = {**info, "edge_ratio": ratio, "n_first": len(v1), "n_second": len(moved), "scale": scale}
    return Pair(
        name,
        (v1, f1),
        (moved, second_faces),
        truth,
        covered,
        overlap,
        float(unit),
        bool(partial),
        bool(partial and scale == 1.0),
        first_params,
        second_params,
        info,
    )


def sheet_pair(
    name: str,
    surface: Callable | None = None,
    *,
    region: tuple[float, float, float, float] = (0.0, 1.0, 0.0, 1.0),
    deform: Callable | None = None,
    n_first: int = 2500,
    n_second: int = 3500,
    seed: int = 0,
    rotation: np.ndarray | None = SECOND_ROTATION,
    scale: float = 2.5,
    info: dict | None = None,
) -> Pair:
    """Two random triangulations of a sheet ``surface`` ((u, v) in [0, 1]^2 -> (n, 3), default
    :func:`relief_sheet`): the first covers the square, the second the rectangle ``region`` = (u0, u1, v0, v1)
    with its vertices on the first mesh (the same piecewise-linear surface), deformed by ``deform`` (points
    (n, 3) in the sheet's own frame -> (n, 3)), then rotated, scaled and shifted. The pair is partial when
    ``region`` is not the whole square."""
    surface = surface or relief_sheet()
    u0, u1, v0, v1 = region
    if not (0 <= u0 < u1 <= 1 and 0 <= v0 < v1 <= 1):
        raise InputError(f"region must be (u0, u1, v0, v1) inside [0, 1]^2 with u0 < u1 and v0 < v1, got {region}")
    first_v, first_f, first_p = random_disk_mesh(surface, n_first, seed=seed)
    shift = first_v[0] - surface(first_p[:1, 0], first_p[:1, 1])[0]  # random_disk_mesh's seeded shift
    _, faces, unit_params = random_disk_mesh(lambda u, v: np.c_[u, v, 0 * u], n_second, seed=seed + 1)
    params = np.c_[u0 + (u1 - u0) * unit_params[:, 0], v0 + (v1 - v0) * unit_params[:, 1]]
    face, bary, _ = locate(first_p, first_f, params)
    sheet = interpolate(first_v - shift, first_f, face, bary)  # on the first mesh: the same surface exactly
    deformed = sheet if deform is None else deform(sheet)
    partial = region != (0.0, 1.0, 0.0, 1.0)
    return _assemble(
        name,
        (first_v, first_f),
        first_p,
        faces,
        params,
        sheet + shift,
        deformed + shift,
        rotation=rotation,
        scale=scale,
        partial=partial,
        seed=seed,
        info={"region": region, **(info or {})},
    )


def remeshed_pair(name: str = "remeshed", **kw) -> Pair:
    """The same sheet with relief, triangulated anew, rotated, scaled by 2.5 and shifted (no deformation)."""
    return sheet_pair(name, info={"kind": "remeshed"}, **kw)


def bent_pair(name: str, angle: float, *, start: float = 0.0, width: float = 1.0, **kw) -> Pair:
    """A sheet and a remeshed copy with the band start <= u <= start + width bent around a cylinder by ``angle``
    degrees (the whole width: a roll; a narrow band: a fold along a crease), rotated, scaled and shifted."""
    info = {"kind": "bent", "angle": angle, "start": start, "width": width}
    return sheet_pair(name, deform=lambda p: bend(p, np.radians(angle), start, width), info=info, **kw)


def stretched_pair(name: str = "stretched", a: float = 0.5, **kw) -> Pair:
    """A sheet and a remeshed copy stretched by u -> u + a u^2 along the sheet (lengths change by up to 1 + 2a)."""
    return sheet_pair(name, deform=lambda p: stretch(p, a), info={"kind": "stretched", "a": a}, **kw)


def partial_pair(
    name: str, region: tuple[float, float, float, float], *, rotation=PARTIAL_ROTATION, seed: int = 0, **kw
) -> Pair:
    """A sheet and a remeshed copy of the rectangle ``region`` of its square, at the same scale, rotated and
    shifted (e.g. a centred crop, a corner, a strip)."""
    info = {"kind": "partial"}
    return sheet_pair(name, region=region, rotation=rotation, scale=1.0, seed=seed, info=info, **kw)


def centred_region(fraction: float) -> tuple[float, float, float, float]:
    """The centred square covering ``fraction`` of the unit square."""
    if not 0 < fraction <= 1:
        raise InputError(f"fraction must be in (0, 1], got {fraction}")
    side = np.sqrt(fraction)
    return ((1 - side) / 2, (1 + side) / 2, (1 - side) / 2, (1 + side) / 2)


def _crop(vertices, faces, centre, radius):
    inside = np.linalg.norm(vertices[:, :2] - centre, axis=1) < radius
    kept = faces[inside[faces].all(axis=1)]
    used = np.unique(kept)
    return vertices[used], np.searchsorted(used, kept)


def scan_pair(
    name: str,
    *,
    radius: float = 45.0,
    offset: float = 0.0,
    bend_angle: float | None = None,
    n_second: int = 8000,
    seed: int = 1,
    rotation: np.ndarray | None = PARTIAL_ROTATION,
    scale: float | None = None,
) -> Pair:
    """Crops of pymeshlab's face000 range scan (mm, viewed along z): the first, the raw triangles within
    ``radius`` of the scan's median point (holes and all); the second, a new random triangulation of the crop of
    the same radius centred ``offset`` mm away along x, optionally bent by ``bend_angle`` degrees around a
    vertical cylinder (axis along y behind the face, the wrap spanning the crop's width), rotated, scaled and
    shifted. Material coordinates are the scan's (x, y). The pair is partial when ``offset`` is not 0;
    ``scale`` defaults to 1 for partial pairs (same scale) and to 0.01 otherwise."""
    partial = offset != 0
    scale = (1.0 if partial else 0.01) if scale is None else scale
    scan_v, scan_f = face_scan_crop(radius + abs(offset) + 5.0)
    centre = np.median(scan_v[:, :2], axis=0)  # face_scan_crop's centre (the median of the whole scan)
    first = _crop(scan_v, scan_f, centre, radius)
    second_v, second_f = _crop(scan_v, scan_f, centre + np.array([offset, 0.0]), radius)
    _, faces, xy = remeshed_range_scan(second_v, second_f, n_second, seed)
    face, bary, inside = locate(scan_v[:, :2], scan_f, xy)
    material = interpolate(scan_v, scan_f, face, bary)  # exactly on the scan's triangles
    used = np.unique(scan_f)  # points over the scan's small gaps: its linear interpolant, as the copy's lift
    material[~inside, 2] = LinearNDInterpolator(scan_v[used, :2], scan_v[used, 2])(xy[~inside])
    material[~inside, :2] = xy[~inside]
    deformed, info = material, {"kind": "scan", "radius": radius, "offset": offset}
    if bend_angle is not None:
        x0, x1 = xy[:, 0].min(), xy[:, 0].max()
        base = np.array([x0, 0.0, np.median(material[:, 2])])
        deformed = bend(material - base, np.radians(bend_angle), 0.0, x1 - x0, -1.0) + base
        info.update(kind="scan-bent", angle=bend_angle)
    return _assemble(
        name,
        first,
        first[0][:, :2],
        faces,
        xy,
        material,
        deformed,
        rotation=rotation,
        scale=scale,
        partial=partial,
        seed=seed,
        info=info,
    )


def surface_points(disk, disk_uv: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Points (k, 3) of a parametrized disk mesh (its vertices' uv (n, 2)) at points uv (k, 2) of its square (NaN
    rows stay NaN)."""
    out = np.full((len(uv), 3), np.nan)
    ok = np.isfinite(uv[:, 0])
    face, bary, _ = locate(disk_uv, disk.faces, uv[ok])
    out[ok] = interpolate(disk.vertices, disk.faces, face, bary)
    return out


def first_points(mr, uv: np.ndarray) -> np.ndarray:
    """Points (k, 3) of a :class:`~meshreg.mesh.correspond.MeshRegistration`'s first mesh at points uv (k, 2) of
    its square (NaN rows stay NaN)."""
    return surface_points(mr.first, mr.uv1, uv)


def matched_points(mr, n_second: int) -> np.ndarray:
    """For each of the ``n_second`` input vertices of the second mesh, the point of the first mesh that the
    registration matches it with (n_second, 3); NaN for vertices that cleanup dropped."""
    return first_points(mr, mr.second.to_input(mr.matched_uv2, n_second, [np.nan, np.nan]))


def parametrization_points(mr, n_second: int, symmetry: int | None = None) -> np.ndarray:
    """The parametrization alone, no optimization: for each input vertex of the second mesh, the point of the
    first with the same uv up to the symmetry of the square (h = sigma; default the registration's own
    ``result.symmetry``), shape (n_second, 3)."""
    k = mr.result.symmetry if symmetry is None else symmetry
    uv2 = mr.second.to_input(mr.uv2, n_second, [np.nan, np.nan])
    return first_points(mr, symmetry_map(inverse_symmetry(k), uv2))  # the first's uv that h = sigma_k matches


def material_corners(pair: Pair, mr) -> tuple[tuple, tuple]:
    """Input vertex ids of the first's corners as meshreg chose them, and of the second's boundary vertices
    whose true points are nearest to those corners."""
    first = tuple(int(c) for c in mr.info["first"]["corners"])
    loop = mr.second.boundary[mr.second.boundary < len(mr.second.vertex_map)]
    ids = mr.second.vertex_map[loop]
    known = np.isfinite(pair.truth[ids, 0])
    tree = cKDTree(pair.truth[ids[known]])
    second = tuple(int(ids[known][tree.query(pair.first[0][c])[1]]) for c in first)
    return first, second
