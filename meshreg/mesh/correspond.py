"""Register two disk meshes: clean, map to the square, resample, register, and carry the correspondence back."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import LinearNDInterpolator, NearestNDInterpolator, RegularGridInterpolator
from scipy.spatial import cKDTree

from ..errors import InputError
from ..options import Options
from ..register import register_with
from ..result import Registration
from ..schedule import Progress
from .corners import corner_positions
from .harmonic import HarmonicMap
from .resample import resample_grid
from .topology import DiskMesh, prepare_disk


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
    """Two disk meshes, their maps to the square, their grids and the registration.

    Attributes
    ----------
    first, second : DiskMesh
        The meshes after cleanup (see :func:`meshreg.mesh.prepare_disk`).
    uv1, uv2 : ndarray, shape (n1, 2), (n2, 2)
        Each disk vertex's place on the unit square.
    grids : (GridSurface, GridSurface)
        The meshes resampled on the square; ``result`` registers them.
    result : Registration
    matched_uv2 : ndarray, shape (n2, 2)
        For each vertex of the second disk, the point of the first's square that the registration matches it
        with (corresponding points of the two meshes share this value).
    info : dict
        Per mesh ("first", "second"): the cleanup report, the map's flipped and degenerate triangles, corners,
        and for a searched corner placement the placements tried.
    """

    first: DiskMesh
    second: DiskMesh
    uv1: np.ndarray
    uv2: np.ndarray
    grids: tuple
    result: Registration
    matched_uv2: np.ndarray
    info: dict


def register_meshes(
    first, second, options: Options | None = None, callback: Progress | None = None, names=("first mesh", "second mesh")
) -> MeshRegistration:
    """Register two meshes given as (vertices (n, 3), faces (m, 3)): clean, parametrize, resample, register.

    Parameters
    ----------
    first, second : tuple (vertices, faces)
    options : Options, optional
        Mesh preparation (``resolution``, ``cleanup``, ``weights``, ``corners1``, ``corners2``,
        ``corner_search``) and registration settings (default mode "auto", which tries the 8 symmetries of
        the square: which corner of the boundary became (0, 0) does not matter).
    callback : callable, optional
        Progress, as for :func:`meshreg.register`.
    names : (str, str)
        What to call the meshes in error messages (their files, say).
    """
    options = options or Options()
    side = (options.resolution, options.resolution)
    options.check_grids(side, side)
    disks, maps, infos = [], [], {}
    for name, label, mesh in zip(("first", "second"), names, (first, second), strict=True):
        if not (isinstance(mesh, (tuple, list)) and len(mesh) == 2):
            raise InputError(f"{label}: a mesh is a pair (vertices (n, 3), faces (m, 3)), got {type(mesh).__name__}")
        try:
            disk = prepare_disk(*mesh, cleanup=options.cleanup)
        except InputError as err:
            raise InputError(f"{label}: {err}") from None
        disks.append(disk)
        maps.append(HarmonicMap(disk, options.weights))
        infos[name] = {"cleanup": disk.report}
    positions, tried = corner_positions(disks, maps, options)
    if tried is not None:
        infos["second"]["corner_search"] = tried
    uvs = []
    for name, m, p in zip(("first", "second"), maps, positions, strict=True):
        uv, info = m(p)
        uvs.append(uv)
        infos[name].update(info)
    n = options.resolution
    grids = [resample_grid(d.vertices, d.faces, uv, n, n) for d, uv in zip(disks, uvs, strict=True)]
    result = register_with(grids[0], grids[1], options, callback)
    return MeshRegistration(
        disks[0], disks[1], uvs[0], uvs[1], tuple(grids), result, corresponding_uv(result, uvs[1]), infos
    )


def similarity_transform(mr: MeshRegistration) -> np.ndarray:
    """The similarity x -> s R x + b (4 x 4) taking the first mesh into the second's frame.

    R is the registration's rotation; the scale s and shift b are the least-squares fit of the first's
    grid points onto the second surface at h (their corresponding points), with R fixed.
    """
    g1, g2 = mr.grids
    p = g1.points.reshape(-1, 3)
    q = g2.at(mr.result.h).reshape(-1, 3)
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
