"""MeshLab (pymeshlab) filter: elastic registration of two layers of a ``pymeshlab.MeshSet``.

pymeshlab has no Python plugin API, so this is a function over a MeshSet: it reads two layers, optionally
prepares copies of them (the MeshLab filter script shipped here, ``prepare_scan.mlx``: remove small pieces, repair
non-manifold edges and vertices; then MeshLab's Close Holes up to :data:`MAX_HOLE_EDGES` edges but always fewer
than the longest boundary has, so that the outer boundary of a disk stays open), registers them and adds the
results as new layers. The user's layers are never modified, nor the MeshSet's record of applied filters (which
preparing would add to); a failure leaves the MeshSet as it was (no extra layer, the same current mesh).

Examples
--------
>>> import pymeshlab                                                   # doctest: +SKIP
>>> from meshreg.plugins import meshlab                                # doctest: +SKIP
>>> ms = pymeshlab.MeshSet()                                           # doctest: +SKIP
>>> ms.load_new_mesh("scan_a.ply"); ms.load_new_mesh("scan_b.ply")     # doctest: +SKIP
>>> info = meshlab.apply(ms, prepare=True)                             # doctest: +SKIP
>>> info["energy"], ms.mesh(info["layers"]["second"]).vertex_color_matrix().shape  # doctest: +SKIP
"""

from __future__ import annotations

import numbers
import os
import sys
import tempfile
from contextlib import contextmanager, nullcontext
from pathlib import Path

import numpy as np

from meshreg.errors import InputError
from meshreg.mesh.topology import boundary_sizes
from meshreg.options import Options

from .._common import register_arrays, require

pymeshlab = require("pymeshlab", "meshlab")

PREPARE_SCRIPT = Path(__file__).with_name("prepare_scan.mlx")
MAX_HOLE_EDGES = 300  # holes of a scan closed by MeshLab; the outer boundary (the longest) never is
LAYER_NAMES = {
    "first": "meshreg first (coloured)",
    "second": "meshreg second (coloured)",
    "registered": "meshreg registered second",
}


@contextmanager
def _quiet():
    """Silence what pymeshlab's C++ code prints (one "Reading filter ..." line per filter of a script, on the
    process's standard error) while the block runs; failures still arrive as Python exceptions."""
    sys.stdout.flush()
    sys.stderr.flush()
    saved = [os.dup(1), os.dup(2)]
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 1)
            os.dup2(null.fileno(), 2)
            yield
    finally:
        for fd, copy in zip((1, 2), saved, strict=True):
            os.dup2(copy, fd)
            os.close(copy)


def _prepare_current(ms) -> None:
    """Run ``prepare_scan.mlx`` on the current mesh, then close its holes of fewer edges than both
    MAX_HOLE_EDGES and its longest boundary (the outer boundary of a disk is never closed)."""
    with _quiet():
        ms.load_filter_script(str(PREPARE_SCRIPT))
        try:
            ms.apply_filter_script()
        finally:
            ms.clear_filter_script()
    sizes = boundary_sizes(ms.current_mesh().face_matrix())
    if len(sizes) > 1:
        ms.apply_filter("meshing_close_holes", maxholesize=min(MAX_HOLE_EDGES, sizes[0] - 1), selfintersection=True)
    ms.apply_filter("meshing_remove_unreferenced_vertices")


@contextmanager
def _history_kept(ms):
    """The MeshSet's record of applied filters (what ``save_filter_script`` writes) as it was before the block, also
    when the block fails: preparing applies filters, which MeshLab records."""
    with tempfile.TemporaryDirectory() as folder:
        saved = Path(folder) / "history.mlx"
        with _quiet():
            ms.save_filter_script(str(saved))
        try:
            yield
        finally:
            with _quiet():
                ms.clear_filter_script()
                ms.load_filter_script(str(saved))


def _layer_id(mesh_id) -> int:
    """A layer id as an int (numpy's integers too); InputError for anything else."""
    if isinstance(mesh_id, bool) or not isinstance(mesh_id, numbers.Integral):
        raise InputError(f"a layer id is an integer, got {mesh_id!r}")
    return int(mesh_id)


def _layer(ms, mesh_id: int, prepare: bool) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and faces of a layer; with ``prepare``, of a prepared copy (the copy is then removed, also when
    preparing it fails)."""
    if not ms.mesh_id_exists(mesh_id):
        raise InputError(f"the MeshSet has no mesh with id {mesh_id!r}")
    ms.set_current_mesh(mesh_id)
    if ms.current_mesh().face_number() == 0:
        raise InputError(f"layer {mesh_id} has no triangles (a point cloud?): give a triangle mesh")
    if not prepare:
        mesh = ms.current_mesh()
        return np.array(mesh.vertex_matrix(), dtype=float), np.array(mesh.face_matrix(), dtype=np.int64)
    ms.generate_copy_of_current_mesh()
    copy = ms.current_mesh_id()
    try:
        _prepare_current(ms)
        mesh = ms.current_mesh()
        if mesh.face_number() == 0:
            raise InputError(
                f"layer {mesh_id}: preparing removed every triangle (prepare_scan.mlx drops pieces of fewer than 100 "
                "triangles): give prepare=False for a small mesh"
            )
        return np.array(mesh.vertex_matrix(), dtype=float), np.array(mesh.face_matrix(), dtype=np.int64)
    except pymeshlab.PyMeshLabException as err:
        raise InputError(f"layer {mesh_id}: MeshLab could not prepare it ({err})") from None
    finally:
        ms.set_current_mesh(copy)
        ms.delete_current_mesh()


def _add(ms, name: str, vertices: np.ndarray, faces: np.ndarray, colors: np.ndarray) -> int:
    rgba = np.c_[np.clip(colors, 0, 1), np.ones(len(colors))]
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=vertices, face_matrix=faces, v_color_matrix=rgba), mesh_name=name)
    return ms.current_mesh_id()


def apply(ms, first_id: int = 0, second_id: int = 1, prepare: bool = False, options: Options | None = None) -> dict:
    """Register layer ``first_id`` (rotated) with layer ``second_id`` (reparametrized) and add the results.

    Parameters
    ----------
    ms : pymeshlab.MeshSet
    first_id, second_id : int
        Layer ids of the two meshes.
    prepare : bool
        First prepare copies of both layers (raw scans -> disks): ``prepare_scan.mlx``, then holes closed up to
        MAX_HOLE_EDGES edges, never the longest boundary.
    options : meshreg.Options, optional
        Mesh preparation and registration settings.

    Returns
    -------
    dict
        ``energy`` (E), ``distance`` (sqrt E), ``residual`` and ``residual_mirrored`` (the coordinate residual
        against the second surface and against its mirror image, :attr:`meshreg.Registration.residual`),
        ``alternatives`` (other correspondences as good: a symmetric shape), ``transformation`` (4 x 4
        similarity taking the first into the second's frame), ``registration`` (the meshreg Registration) and
        ``layers`` (ids of the new layers "meshreg first (coloured)", "meshreg second (coloured)" and "meshreg
        registered second") and ``cleanup`` (what meshreg's own cleanup still had to do to each mesh).

    Raises
    ------
    meshreg.InputError
        A missing layer, a layer without triangles, a mesh that cannot be made a disk, bad options. The MeshSet is
        then as it was: no layer added, the same current mesh, the same record of applied filters.
    TypeError
        ``ms`` not a MeshSet, ``prepare`` not a bool, ``options`` not a :class:`meshreg.Options`.
    """
    if not isinstance(ms, pymeshlab.MeshSet):
        raise TypeError(f"apply takes a pymeshlab.MeshSet, got {type(ms).__name__}")
    if not isinstance(prepare, bool):
        raise TypeError(f"prepare must be True or False, got {prepare!r}")
    first_id, second_id = _layer_id(first_id), _layer_id(second_id)
    current = ms.current_mesh_id() if ms.mesh_number() else None
    try:
        with _history_kept(ms) if prepare else nullcontext():
            first, second = _layer(ms, first_id, prepare), _layer(ms, second_id, prepare)
        names = (f"layer {first_id}", f"layer {second_id}")
        mr, c1, c2, (rv, rf, rc) = register_arrays(first, second, options, names=names)
    except BaseException:
        if current is not None and ms.mesh_id_exists(current):
            ms.set_current_mesh(current)
        raise
    layers = {
        "first": _add(ms, LAYER_NAMES["first"], *first, c1),
        "second": _add(ms, LAYER_NAMES["second"], *second, c2),
        "registered": _add(ms, LAYER_NAMES["registered"], rv, rf, rc),
    }
    return {
        "energy": mr.result.energy,
        "distance": mr.result.distance,
        "residual": mr.result.residual,
        "residual_mirrored": mr.result.residual_mirrored,
        "alternatives": mr.result.alternatives,
        "transformation": mr.result.transform,
        "registration": mr.result,
        "layers": layers,
        "cleanup": {k: mr.info[k]["cleanup"] for k in ("first", "second")},
    }
