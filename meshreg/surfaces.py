"""Whatever a user hands to ``meshreg.register``, as one of the two things meshreg registers: a grid surface or a
triangle mesh.

Accepted: a :class:`~meshreg.grid.GridSurface`; an array of shape (M, N, 3) (a grid); a path (a grid file by its
suffix ``.npy``, ``.npz`` or text, a mesh by ``.ply .obj .stl .off .glb .gltf``); a ``trimesh.Trimesh``; an
Open3D ``TriangleMesh``; a tuple ``(vertices (n, 3), faces (m, 3))`` (a nested list is read as grid data).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import InputError
from .grid import GridSurface, coordinates, read_grid


@dataclass(frozen=True)
class Mesh:
    """A triangle mesh as given: vertices (n, 3) float, faces (m, 3) int, and a name for messages."""

    vertices: np.ndarray
    faces: np.ndarray
    name: str = "mesh"


def as_input(surface, name: str | None = None) -> GridSurface | Mesh:
    """A GridSurface or a Mesh from anything :func:`meshreg.register` accepts (see the module docstring).

    Raises
    ------
    InputError
        When ``surface`` is none of those, naming what was given and what is accepted.
    """
    from .mesh.topology import MESH_SUFFIXES, load_mesh

    if isinstance(surface, (GridSurface, Mesh)):
        return surface
    if isinstance(surface, (str, Path)):
        path = Path(surface)
        if path.suffix.lower() in MESH_SUFFIXES:
            return Mesh(*load_mesh(path), name=str(path))
        return read_grid(path)
    if hasattr(surface, "vertices") and (hasattr(surface, "faces") or hasattr(surface, "triangles")):
        faces = surface.faces if hasattr(surface, "faces") else surface.triangles  # trimesh / Open3D
        return _mesh(surface.vertices, faces, name or type(surface).__name__)
    if isinstance(surface, tuple) and len(surface) == 2:  # a nested list is grid data, a pair of arrays a mesh
        return _mesh(surface[0], surface[1], name or "(vertices, faces)")
    if isinstance(surface, np.ndarray) or (isinstance(surface, (tuple, list)) and len(surface)):
        try:
            return GridSurface.from_array(surface)
        except InputError as err:
            raise (InputError(f"{name}: {err}") if name else err) from None
    raise InputError(
        f"cannot register a {type(surface).__name__}: give a grid (GridSurface, (M, N, 3) array, grid file), "
        "a mesh (file, trimesh.Trimesh, open3d TriangleMesh) or a (vertices, faces) pair"
    )


def _array(values, what: str, name: str) -> np.ndarray:
    """``values`` as an array, or an InputError naming ``what`` of mesh ``name`` when they are not rectangular
    (rows of different lengths) or not numbers."""
    try:
        return np.asarray(values)
    except (ValueError, TypeError) as err:
        raise InputError(
            f"{name}: the {what} are not an (n, 3) table of numbers ({err}): give them as an (n, 3) array"
        ) from None


def _mesh(vertices, faces, name: str) -> Mesh:
    vertices, faces = _array(vertices, "vertices", name), _array(faces, "faces", name)
    if vertices.ndim != 2 or vertices.shape[1] != 3 or faces.ndim != 2 or faces.shape[1] != 3:
        raise InputError(
            f"{name}: a mesh needs vertices (n, 3) and triangular faces (m, 3), got {vertices.shape} and {faces.shape}"
        )
    if not np.issubdtype(faces.dtype, np.integer):
        raise InputError(f"{name}: faces must be integer vertex indices, got {faces.dtype}")
    return Mesh(coordinates(vertices, f"{name}: mesh vertex coordinates"), faces.astype(np.int64), name)
