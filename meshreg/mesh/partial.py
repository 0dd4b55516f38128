"""Register the common region of two meshes that overlap only partly (:mod:`meshreg.mesh.overlap`).

Both meshes are trimmed to the overlap; the first's trimmed part is mapped to the square (harmonic map); each vertex
of the second's trimmed part is matched with the closest point of the first to its place in the first's frame
(the pose of the "rigid" regime refined on the trimmed parts against the triangles, or the as-rigid-as-possible
warp of the "elastic" regime), and takes that point's place on the square. So the registration is h = identity
between two layouts of one square, and every query of :class:`~meshreg.result.Registration` (correspondence,
vertex pairs, distances) works as for a whole-mesh registration; vertices outside the overlap have no match (NaN).
E is the elastic energy of the two trimmed parts under that correspondence.
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np
from scipy.spatial import cKDTree

from ..correspondence import Side
from ..diffeo import identity
from ..grid import GridSurface
from ..objective import Objective
from ..options import Options
from ..result import Registration
from ..rotation import kabsch, similarity
from .align import Cloud, icp
from .graph import turn_counts
from .harmonic import HarmonicMap, choose_corners
from .overlap import Overlap, trim
from .resample import resample_grid
from .surface import Surface
from .topology import DiskMesh

REFINE_ITERATIONS = 30  # ICP iterations of the rigid pose on the trimmed parts (exact closest points)
RIM_SNAP = 2.0  # the second's rim vertex nearest to a corner of the first takes the corner within this many edges


def register_overlap(first, second, overlap: Overlap, n_input: tuple[int, int], options: Options, infos: dict):
    """The :class:`~meshreg.mesh.correspond.MeshRegistration` of the common region of two disks.

    Parameters
    ----------
    first, second : DiskMesh
        The whole meshes after cleanup.
    overlap : Overlap
        :func:`meshreg.mesh.overlap.find_overlap` of the two, regime "rigid" or "elastic".
    n_input : (int, int)
        Vertex counts of the meshes as given.
    options : Options
    infos : dict
        The preparation report per mesh ("first", "second"); the overlap and the trimming are added.
    """
    from .correspond import MeshRegistration, json_ready

    start = time.perf_counter()
    trimmed1, _ = trim(first, overlap.first.signed)
    trimmed2, carry2 = trim(second, overlap.second.signed)
    target = Surface(trimmed1.vertices, trimmed1.faces)
    pose = None
    if overlap.regime == "rigid":
        own = Surface(trimmed2.vertices, trimmed2.faces)
        pose, _ = icp(
            Cloud(own.vertices, own.normals), target, overlap.alignment.matrix, iterations=REFINE_ITERATIONS, exact=True
        )
        placed = own.moved(pose)  # the trimmed second in the first's frame
    else:
        placed = Surface(carry2 @ overlap.positions, trimmed2.faces)
    positions = placed.vertices
    corners = choose_corners(trimmed1)
    uv1, corner_info = HarmonicMap(trimmed1, options.weights)(corners)
    closest, _, triangle, weights = target.project(positions)
    uv2 = _on_the_rim(trimmed2, positions, target.at(uv1, triangle, weights), trimmed1, corners, overlap.edge)
    n = options.resolution
    grid1 = resample_grid(trimmed1.vertices, trimmed1.faces, uv1, n, n)
    # the second at the first's nodes: the point of the trimmed second whose place in the first's frame is closest
    _, _, triangle, weights = placed.project(grid1.points.reshape(-1, 3))
    grid2 = GridSurface.from_array(
        placed.at(trimmed2.vertices, triangle, weights).reshape(n, n, 3),
        grid1.r,
        grid1.t,
    )
    objective = Objective(grid1, grid2)
    h = identity(grid1.r, grid1.t)
    if pose is None:  # a warp: the rotation that minimizes E, the similarity fitted to the matches
        rotation = kabsch(objective.best_rotation_covariance(h))
        transform = similarity(rotation, grid1.points, grid2.points)
    else:  # the same surface: the pose itself
        transform = np.linalg.inv(pose)
        rotation = transform[:3, :3] / np.cbrt(np.linalg.det(transform[:3, :3]))
    energy, residual = objective.evaluate(rotation, h)
    infos = {name: dict(info) for name, info in infos.items()}
    for name, disk in (("first", trimmed1), ("second", trimmed2)):
        infos[name]["overlap"] = disk.report
    infos["first"].update(corner_info)
    infos["second"].update(_layout_report(uv2, trimmed2.faces))
    infos["overlap"] = overlap.summary()
    seconds = time.perf_counter() - start
    result = Registration(
        rotation=rotation,
        h=h,
        energy=float(energy),
        energy_dp=float("nan"),
        energy_history=np.array([energy]),
        r=grid1.r,
        t=grid1.t,
        mode=options.mode,
        params={**options.as_dict(), "overlap_regime": overlap.regime},
        timings={"overlap": overlap.seconds, "register": seconds, "total": overlap.seconds + seconds},
        symmetry=0,
        energy_stages=("overlap",),
        transform=transform,
        residual=residual.plus,
        residual_mirrored=residual.minus,
    )
    sides = [Side.from_disk(d, uv, k) for d, uv, k in zip((trimmed1, trimmed2), (uv1, uv2), n_input, strict=True)]
    result = replace(result, first=sides[0], second=sides[1], info=json_ready(infos))
    return MeshRegistration(trimmed1, trimmed2, uv1, uv2, (grid1, grid2), result, infos, matches=uv2)


def _on_the_rim(
    disk: DiskMesh, positions: np.ndarray, uv: np.ndarray, first: DiskMesh, corners: np.ndarray, edge: float
) -> np.ndarray:
    """The second's layout (its vertices' places on the square, ``uv`` (n, 2)) with its rim on the square's sides:
    each of its rim vertices onto the nearest side, and the rim vertex nearest (at ``positions``, in the first's
    frame) to each of the first's corners onto that corner, when within RIM_SNAP edge lengths. The two trimmed
    rims are one curve, but the second's rim vertices lie between the first's, a little inside; without this the
    first's points along the rim would fall just outside the second's layout and find no match."""
    out = np.clip(uv, 0.0, 1.0)
    loop = disk.boundary
    rim = out[loop]
    gaps = np.stack([rim[:, 0], 1 - rim[:, 0], rim[:, 1], 1 - rim[:, 1]], axis=1)
    side = np.argmin(gaps, axis=1)
    rim[side == 0, 0], rim[side == 1, 0], rim[side == 2, 1], rim[side == 3, 1] = 0.0, 1.0, 0.0, 1.0
    out[loop] = rim
    square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    distance, nearest = cKDTree(positions[loop]).query(first.vertices[first.boundary[corners]])
    for k in range(4):
        if distance[k] <= RIM_SNAP * edge:
            out[loop[nearest[k]]] = square[k]
    return out


def _layout_report(uv: np.ndarray, faces: np.ndarray) -> dict:
    """Triangles of a layout on the square turned against most of the others ("flipped") and of about zero area
    ("degenerate"), as :class:`~meshreg.mesh.harmonic.HarmonicMap` reports them."""
    positive, negative, degenerate = turn_counts(uv, faces)
    return {"flipped": min(positive, negative), "degenerate": degenerate}
