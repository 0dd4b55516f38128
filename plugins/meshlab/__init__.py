"""MeshLab (pymeshlab) filter: elastic registration of two layers of a ``pymeshlab.MeshSet``.

pymeshlab has no Python plugin API, so this is a function over a MeshSet: it reads two layers, optionally
prepares copies of them with the MeshLab filter script shipped here (``prepare_scan.mlx``: remove small
pieces, repair non-manifold edges and vertices, close holes up to 300 edges), registers them and adds the
results as new layers. The user's layers are never modified.

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

from pathlib import Path

import numpy as np

from meshreg.errors import InputError
from meshreg.options import Options

from .._common import register_arrays, require

pymeshlab = require("pymeshlab", "meshlab")

PREPARE_SCRIPT = Path(__file__).with_name("prepare_scan.mlx")
LAYER_NAMES = {
    "first": "meshreg first (coloured)",
    "second": "meshreg second (coloured)",
    "registered": "meshreg registered second",
}


def _layer(ms, mesh_id: int, prepare: bool) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and faces of a layer; with ``prepare``, of a prepared copy (the copy is then removed)."""
    if not ms.mesh_id_exists(mesh_id):
        raise InputError(f"the MeshSet has no mesh with id {mesh_id}")
    ms.set_current_mesh(mesh_id)
    if prepare:
        ms.generate_copy_of_current_mesh()
        ms.load_filter_script(str(PREPARE_SCRIPT))
        ms.apply_filter_script()
        ms.clear_filter_script()
    mesh = ms.current_mesh()
    arrays = np.array(mesh.vertex_matrix(), dtype=float), np.array(mesh.face_matrix(), dtype=np.int64)
    if prepare:
        ms.delete_current_mesh()
    return arrays


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
        First run ``prepare_scan.mlx`` on copies of both layers (raw scans -> disks).
    options : meshreg.Options, optional
        Mesh preparation and registration settings.

    Returns
    -------
    dict
        ``energy`` (E), ``distance`` (sqrt E), ``transformation`` (4 x 4 similarity taking the first into
        the second's frame), ``registration`` (the meshreg Registration) and ``layers`` (ids of the new
        layers "meshreg first (coloured)", "meshreg second (coloured)" and "meshreg registered second") and
        ``cleanup`` (what meshreg's own cleanup still had to do to each mesh).
    """
    first, second = _layer(ms, first_id, prepare), _layer(ms, second_id, prepare)
    mr, c1, c2, (rv, rf, rc) = register_arrays(first, second, options)
    layers = {
        "first": _add(ms, LAYER_NAMES["first"], *first, c1),
        "second": _add(ms, LAYER_NAMES["second"], *second, c2),
        "registered": _add(ms, LAYER_NAMES["registered"], rv, rf, rc),
    }
    return {
        "energy": mr.result.energy,
        "distance": mr.result.distance,
        "transformation": mr.result.transform,
        "registration": mr.result,
        "layers": layers,
        "cleanup": {k: mr.info[k]["cleanup"] for k in ("first", "second")},
    }
