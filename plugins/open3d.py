"""Open3D utility: elastic registration of two ``open3d.geometry.TriangleMesh`` disks.

Examples
--------
>>> import open3d as o3d                                             # doctest: +SKIP
>>> from meshreg.plugins import open3d as mo3d                       # doctest: +SKIP
>>> result = mo3d.register(source, target)                           # doctest: +SKIP
>>> source.transform(result.transformation)                          # doctest: +SKIP
>>> o3d.visualization.draw_geometries([result.source_colored, result.target_colored])  # doctest: +SKIP
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from meshreg.mesh.harmonic import HarmonicMap, choose_corners
from meshreg.mesh.topology import prepare_disk
from meshreg.options import Options
from meshreg.result import Registration

from ._common import register_arrays, require

o3d = require("open3d", "open3d")


@dataclass
class ElasticRegistrationResult:
    """Shaped like Open3D's ``RegistrationResult``, plus the elastic quantities.

    Attributes
    ----------
    transformation : ndarray (4, 4)
        The similarity (rotation, uniform scale, translation) taking the source into the target's frame.
    correspondence_set : ndarray (k, 2) int
        Source vertex id -> target vertex id of matched points (every source vertex kept by cleanup).
    fitness : float
        Fraction of source vertices whose matched point lies within the inlier distance (1% of sqrt(target
        area)) of the source vertex moved by ``transformation``, as in Open3D.
    inlier_rmse : float
        Root mean square of those distances over the inliers, as in Open3D.
    energy : float
        E, the squared elastic shape distance (both surfaces at area 1).
    distance : float
        sqrt(E).
    residual : float
        The coordinate residual: RMS of R c1 - c2 o h on both grids, centred and at area 1
        (:attr:`meshreg.Registration.residual`).
    alternatives : list of dict
        Other correspondences as good as this one (a symmetric shape; :attr:`meshreg.Registration.alternatives`).
    source_colored, target_colored : open3d.geometry.TriangleMesh
        Copies of the inputs with vertex_colors: corresponding points share a colour.
    registered : open3d.geometry.TriangleMesh
        The target resampled at h on the source's grid, in the source's frame.
    registration : meshreg.Registration
        The underlying result (R, h, energy history, parameters, timings).
    """

    transformation: np.ndarray
    correspondence_set: np.ndarray
    fitness: float
    inlier_rmse: float
    energy: float
    distance: float
    residual: float
    alternatives: list
    source_colored: object
    target_colored: object
    registered: object
    registration: Registration


def _arrays(mesh, name: str = "mesh") -> tuple[np.ndarray, np.ndarray]:
    """Vertices (n, 3) and triangles (m, 3) of an ``open3d.geometry.TriangleMesh``; TypeError for anything else."""
    if not isinstance(mesh, o3d.geometry.TriangleMesh):
        hint = " (convert a tensor mesh with .to_legacy())" if isinstance(mesh, o3d.t.geometry.TriangleMesh) else ""
        raise TypeError(f"{name} must be an open3d.geometry.TriangleMesh, got {type(mesh).__name__}{hint}")
    return np.asarray(mesh.vertices, dtype=float), np.asarray(mesh.triangles, dtype=np.int64)


def _colored(mesh, colors: np.ndarray):
    out = o3d.geometry.TriangleMesh(mesh)
    out.vertex_colors = o3d.utility.Vector3dVector(np.ascontiguousarray(colors, dtype=float))
    return out


def register(source, target, options: Options | None = None) -> ElasticRegistrationResult:
    """Rotate (and scale, shift) ``source`` onto ``target`` and reparametrize ``target`` elastically.

    Parameters
    ----------
    source, target : open3d.geometry.TriangleMesh
        Disk-topology meshes (cleanup as in :func:`meshreg.mesh.prepare_disk`); neither is modified.
    options : meshreg.Options, optional
        Mesh preparation and registration settings (resolution, weights, corners1/2, mode, window, ...).

    Raises
    ------
    TypeError
        ``source`` or ``target`` is not an ``open3d.geometry.TriangleMesh`` (None, a point cloud, a tuple).
    meshreg.InputError
        A mesh that cannot be made a disk (no triangles, all degenerate, closed, ...) or bad options.
    """
    mr, c1, c2, (rv, rf, rc) = register_arrays(
        _arrays(source, "source"), _arrays(target, "target"), options, names=("source", "target")
    )
    registered = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(rv), o3d.utility.Vector3iVector(rf.astype(np.int32))
    )
    registered.vertex_colors = o3d.utility.Vector3dVector(rc)
    return ElasticRegistrationResult(
        transformation=mr.result.transform,
        correspondence_set=mr.result.vertex_pairs(),
        fitness=mr.result.fitness(),
        inlier_rmse=mr.result.inlier_rmse(),
        energy=mr.result.energy,
        distance=mr.result.distance,
        residual=mr.result.residual,
        alternatives=mr.result.alternatives,
        source_colored=_colored(source, c1),
        target_colored=_colored(target, c2),
        registered=registered,
        registration=mr.result,
    )


def parametrize(mesh, *, weights: str = "mean-value", corners=None):
    """A copy of ``mesh`` with ``triangle_uvs`` (3 per triangle) on the unit square: its map to the square.

    ``corners``: four boundary vertex ids (default: :func:`meshreg.mesh.harmonic.choose_corners`).
    Vertices dropped by cleanup (see :func:`meshreg.mesh.prepare_disk`) get uv NaN.
    """
    v, f = _arrays(mesh)
    disk = prepare_disk(v, f)
    uv, _ = HarmonicMap(disk, weights)(choose_corners(disk, None if corners is None else disk.input_ids(corners)))
    per_vertex = disk.to_input(uv, len(v), [np.nan, np.nan])
    out = o3d.geometry.TriangleMesh(mesh)
    out.triangle_uvs = o3d.utility.Vector2dVector(per_vertex[f].reshape(-1, 2))
    return out
