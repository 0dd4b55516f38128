"""Register two disk meshes and colour them so that corresponding points share a colour."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import LinearNDInterpolator, NearestNDInterpolator, RegularGridInterpolator
from scipy.spatial import cKDTree

from ..register import Registration, register
from ..search import best_start
from ..spline import GridInterpolator
from .harmonic import HarmonicMap, arc_fraction, choose_corners, has_sharp_corners, quarter_corners
from .resample import DEFAULT_GRID, resample_grid
from .topology import DiskMesh, prepare_disk

CORNER_SEARCH = 8  # trial corner placements of the second mesh within a quarter of its boundary
CORNER_SEARCH_GRID = 21  # coarse grid on which the trial placements are ranked

# colours of the square's corners (0,0), (1,0), (1,1), (0,1), blended bilinearly
_CORNERS = np.array([[0.85, 0.10, 0.10], [0.95, 0.80, 0.10], [0.10, 0.55, 0.95], [0.15, 0.75, 0.25]])


def uv_colors(uv: np.ndarray) -> np.ndarray:
    """RGB in [0, 1] (n, 3) for points (n, 2) of the square: a smooth bilinear blend of four distinct colours."""
    u, v = uv[:, :1], uv[:, 1:]
    return (1 - u) * (1 - v) * _CORNERS[0] + u * (1 - v) * _CORNERS[1] + u * v * _CORNERS[2] + (1 - u) * v * _CORNERS[3]


def corresponding_uv(result: Registration, uv2: np.ndarray) -> np.ndarray:
    """For points uv2 (n, 2) of the second surface's square, the (r, t) of the first that h maps onto them."""
    nodes = np.stack(np.meshgrid(result.r, result.t, indexing="ij"), axis=-1).reshape(-1, 2)
    images = result.h.reshape(-1, 2)
    inverse = LinearNDInterpolator(images, nodes)(uv2)
    outside = np.isnan(inverse[:, 0])
    if outside.any():
        inverse[outside] = NearestNDInterpolator(images, nodes)(uv2[outside])
    return np.clip(inverse, 0, 1)


@dataclass
class MeshRegistration:
    """Two disk meshes, their uv, their grids (GridSurface pair), the registration and the correspondence colours."""

    first: DiskMesh
    second: DiskMesh
    uv1: np.ndarray
    uv2: np.ndarray
    grids: tuple
    result: Registration
    colors1: np.ndarray
    colors2: np.ndarray
    info: dict


def placement_starts(disk: DiskMesh, trials: int) -> np.ndarray:
    """Arc-length fractions (trials,) of the trial corner placements of a disk: quarter arc lengths from
    ``trials`` starts spaced by 1/(4 trials) of its boundary, the first at the point where
    :func:`~meshreg.mesh.harmonic.choose_corners` would start (a quarter turn is a symmetry of the square)."""
    return arc_fraction(disk, int(choose_corners(disk)[0])) + 0.25 / trials * np.arange(trials)


def placement_corners(disk: DiskMesh, trials: int) -> list[np.ndarray]:
    """Corner loop positions (4,) of each trial placement of :func:`placement_starts`; the first is the
    placement a round-boundary mesh uses as the first surface of a pair."""
    return [quarter_corners(disk, start % 1.0) for start in placement_starts(disk, trials)]


def placement_energy(coarse1, coarse2) -> float:
    """Rank of a corner placement: the best coarse DP energy over the square's symmetries and rotations."""
    return best_start(coarse1, coarse2)[0].energy


def search_corners(first: HarmonicMap, corners1: np.ndarray, second: HarmonicMap, trials: int = CORNER_SEARCH) -> tuple[np.ndarray, list]:
    """Corners of the second mesh that best match the first's: the ``trials`` placements of
    :func:`placement_starts`, then one halving step around the best, ranked by :func:`placement_energy`
    on 21 x 21 grids.

    A smooth boundary (a round crop) has no natural corners: two meshes of one surface get corners at
    different places, and no reparametrization that keeps the corners can undo that. This finds them.

    Returns the second's corner loop positions (4,) and the (start, energy) pairs tried.
    """
    n = CORNER_SEARCH_GRID
    disk1, disk2 = first.disk, second.disk
    coarse1 = resample_grid(disk1.vertices, disk1.faces, first(corners1)[0], n, n)

    def energy(start):
        uv = second(quarter_corners(disk2, start))[0]
        return placement_energy(coarse1, resample_grid(disk2.vertices, disk2.faces, uv, n, n))

    starts = placement_starts(disk2, trials)
    tried = [(start, energy(start)) for start in starts]
    best = min(tried, key=lambda x: x[1])[0]
    tried += [(best + d, energy(best + d)) for d in (-0.125 / trials, 0.125 / trials)]
    best = min(tried, key=lambda x: x[1])[0]
    return quarter_corners(disk2, best % 1.0), tried


def register_meshes(
    first,
    second,
    *,
    grid: int = DEFAULT_GRID,
    cleanup: bool = True,
    weights: str = "mean-value",
    corners: tuple = (None, None),
    corner_search: int = CORNER_SEARCH,
    **params,
) -> MeshRegistration:
    """Register two meshes given as (vertices, faces): clean, parametrize, resample, register, colour.

    Parameters
    ----------
    first, second : tuple (vertices (n, 3), faces (m, 3))
    grid : int
        Both meshes are resampled on grid x grid nodes. Default 101.
    cleanup : bool
        Repairs of :func:`meshreg.mesh.prepare_disk` (default on, always reported in ``info``).
    weights : {"mean-value", "cotangent"}
        Laplacian weights of the map to the square.
    corners : pair of (4 vertex ids or None)
        Corner vertices of each mesh (ids in the mesh as given); default: chosen by
        :func:`meshreg.mesh.harmonic.choose_corners`.
    corner_search : int
        Trial corner placements for the second mesh (:func:`search_corners`) when no corners are given
        and the two boundaries do not both have four clear corners. 0 turns the search off. Default 8.
    **params
        Passed to :func:`meshreg.register` (default mode "auto", which tries the 8 symmetries of the
        square: which corner of the boundary became (0, 0) does not matter).
    """
    disks, maps, infos = [], [], {}
    for name, (v, f) in (("first", first), ("second", second)):
        disk = prepare_disk(v, f, cleanup=cleanup)
        disks.append(disk)
        maps.append(HarmonicMap(disk, weights))
        infos[name] = {"cleanup": disk.report}
    pos = [choose_corners(d, None if c is None else d.input_ids(c)) for d, c in zip(disks, corners)]
    search = corner_search > 0 and corners == (None, None) and not all(has_sharp_corners(d) for d in disks)
    if search:
        pos[0] = placement_corners(disks[0], 1)[0]
        pos[1], tried = search_corners(maps[0], pos[0], maps[1], corner_search)
        infos["second"]["corner_search"] = tried
    uvs = []
    for name, m, p in zip(("first", "second"), maps, pos):
        uv, info = m(p)
        uvs.append(uv)
        infos[name].update(info)
    grids = [resample_grid(d.vertices, d.faces, uv, grid, grid) for d, uv in zip(disks, uvs)]
    result = register(grids[0], grids[1], **params)
    colors1 = uv_colors(uvs[0])
    colors2 = uv_colors(corresponding_uv(result, uvs[1]))
    return MeshRegistration(disks[0], disks[1], uvs[0], uvs[1], tuple(grids), result, colors1, colors2, infos)


def similarity_transform(mr: MeshRegistration) -> np.ndarray:
    """The similarity x -> s R x + b (4 x 4) taking the first mesh into the second's frame.

    R is the registration's rotation; the scale s and shift b are the least-squares fit of the first's
    grid points onto the second surface at h (their corresponding points), with R fixed.
    """
    g1, g2 = mr.grids
    p = g1.points.reshape(-1, 3)
    q = GridInterpolator(g2.points, g2.r, g2.t)(mr.result.h[..., 0], mr.result.h[..., 1])[0].reshape(-1, 3)
    rp = (p - p.mean(axis=0)) @ mr.result.rotation.T
    scale = float(np.sum(rp * (q - q.mean(axis=0))) / np.sum(rp * rp))
    out = np.eye(4)
    out[:3, :3] = scale * mr.result.rotation
    out[:3, 3] = q.mean(axis=0) - scale * mr.result.rotation @ p.mean(axis=0)
    return out


def vertex_pairs(mr: MeshRegistration) -> np.ndarray:
    """Pairs (k, 2) of input vertex ids (first, second): each kept vertex of the first mesh and the vertex
    of the second whose uv is nearest to h(uv) (the point the registration matches it with)."""
    k1, k2 = len(mr.first.vertex_map), len(mr.second.vertex_map)
    h = RegularGridInterpolator((mr.result.r, mr.result.t), mr.result.h)(np.clip(mr.uv1[:k1], 0, 1))
    _, nearest = cKDTree(mr.uv2[:k2]).query(h)
    return np.c_[mr.first.vertex_map, mr.second.vertex_map[nearest]]


def mesh_grids(vertices: np.ndarray, faces: np.ndarray, *, grid: int = DEFAULT_GRID, cleanup: bool = True,
               weights: str = "mean-value", corner_search: int = CORNER_SEARCH):
    """One mesh, on its own, to grid surfaces: clean, map to the square, resample on grid x grid nodes.

    With four clear corners (or ``corner_search=0``), one grid (corners by
    :func:`~meshreg.mesh.harmonic.choose_corners`); else one grid per trial corner placement of
    :func:`placement_starts` (one LU serves them all), the first of which is the mesh's own placement when
    it is the first surface of a pair; a pair ranks the second's placements by :func:`placement_energy`.

    Returns the list of GridSurfaces and an info dict (cleanup report, corners, flipped and degenerate counts).
    """
    disk = prepare_disk(vertices, faces, cleanup=cleanup)
    hmap = HarmonicMap(disk, weights)
    if corner_search > 0 and not has_sharp_corners(disk):
        placements = placement_corners(disk, corner_search)
    else:
        placements = [choose_corners(disk)]
    maps = [hmap(corners) for corners in placements]
    grids = [resample_grid(disk.vertices, disk.faces, uv, grid, grid) for uv, _ in maps]
    return grids, {**maps[0][1], "cleanup": disk.report}
