"""Register two disk meshes and colour them so that corresponding points share a colour."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import LinearNDInterpolator, NearestNDInterpolator

from ..register import Registration, register
from .harmonic import parametrize
from .resample import DEFAULT_GRID, resample_grid
from .topology import DiskMesh, prepare_disk

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


def register_meshes(first, second, *, grid: int = DEFAULT_GRID, cleanup: bool = True, weights: str = "mean-value", **params) -> MeshRegistration:
    """Register two meshes given as (vertices, faces): parametrize, resample on grid x grid, register, colour.

    Parameters are passed to :func:`meshreg.register` (default mode "auto", which tries the 8
    symmetries of the square: which boundary vertex became the corner (0, 0) does not matter).
    """
    disks, uvs, infos = [], [], {}
    for name, (v, f) in (("first", first), ("second", second)):
        disk = prepare_disk(v, f, cleanup=cleanup)
        uv, info = parametrize(disk, weights=weights)
        disks.append(disk)
        uvs.append(uv)
        infos[name] = {**info, "cleanup": disk.report}
    grids = [resample_grid(d.vertices, d.faces, uv, grid, grid) for d, uv in zip(disks, uvs)]
    result = register(grids[0], grids[1], **params)
    colors1 = uv_colors(uvs[0])
    colors2 = uv_colors(corresponding_uv(result, uvs[1]))
    return MeshRegistration(disks[0], disks[1], uvs[0], uvs[1], tuple(grids), result, colors1, colors2, infos)
