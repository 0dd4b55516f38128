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
    placed, pose = _placed_second(trimmed2, carry2, target, overlap)
    positions = placed.vertices
    corners = choose_corners(trimmed1)
    uv1, corner_info = HarmonicMap(trimmed1, options.weights)(corners)
    closest, _, triangle, weights = target.project(positions)
    uv2 = _on_the_rim(trimmed2, positions, target.at(uv1, triangle, weights), trimmed1, corners, overlap.edge)
    grid1 = resample_grid(trimmed1.vertices, trimmed1.faces, uv1, options.resolution, options.resolution)
    grid2 = _second_at_nodes(grid1, placed, trimmed2)
    objective = Objective(grid1, grid2)
    h = identity(grid1.r, grid1.t)
    rotation, transform = _rotation_and_transform(objective, h, pose, grid1, grid2)
    energy, residual = objective.evaluate(rotation, h)
    infos = {name: dict(info) for name, info in infos.items()}
    for name, disk in (("first", trimmed1), ("second", trimmed2)):
        infos[name]["overlap"] = disk.report
    infos["first"].update(corner_info)
    infos["second"].update(_layout_report(uv2, trimmed2.faces))
    infos["overlap"] = {**overlap.summary(), "unused": _unused_settings(options)}
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
        params={**options.as_dict(), "overlap_regime": overlap.regime, "snapped": False, "mesh_blur_sigma": 0.0},
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


def _unused_settings(options: Options) -> list[str]:
    """The settings given for a whole-mesh registration that a registration of the common region does not use: it
    takes its corners from the trimmed first mesh, and its pose and matches from the overlap check."""
    unused = [
        f"{name} {getattr(options, name)}" for name in ("corners1", "corners2") if getattr(options, name) is not None
    ]
    if options.mode != "auto":
        unused.append(f"mode {options.mode!r}")
    if options.symmetry is not None:
        unused.append(f"symmetry {options.symmetry}")
    return unused


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


def _placed_second(trimmed2: DiskMesh, carry2, target: Surface, overlap: Overlap) -> tuple[Surface, np.ndarray | None]:
    """The trimmed second mesh in the first's frame, and the pose (4, 4) that put it there: by ICP onto the trimmed
    first (``target``) from the overlap's alignment for a rigid overlap; else (an elastic one) its vertices carried
    (``carry2``, sparse (k, n)) from the overlap's warped positions, and no pose."""
    if overlap.regime != "rigid":
        return Surface(carry2 @ overlap.positions, trimmed2.faces), None
    own = Surface(trimmed2.vertices, trimmed2.faces)
    pose, _ = icp(
        Cloud(own.vertices, own.normals), target, overlap.alignment.matrix, iterations=REFINE_ITERATIONS, exact=True
    )
    return own.moved(pose), pose


def _second_at_nodes(grid1: GridSurface, placed: Surface, trimmed2: DiskMesh) -> GridSurface:
    """The second at the first's nodes: the point of the trimmed second whose place in the first's frame
    (``placed``) is closest to each node of ``grid1``, on grid1's (r, t)."""
    _, _, triangle, weights = placed.project(grid1.points.reshape(-1, 3))
    points = placed.at(trimmed2.vertices, triangle, weights).reshape(*grid1.points.shape[:2], 3)
    return GridSurface.from_array(points, grid1.r, grid1.t)


def _rotation_and_transform(objective: Objective, h: np.ndarray, pose: np.ndarray | None, grid1, grid2):
    """R (3, 3) and the similarity (4, 4) taking the first grid onto the second: for a warp (no ``pose``) the
    rotation that minimizes E at h and the similarity fitted to the grids' matches; for the same surface the ICP
    pose's inverse, and its rotation part."""
    if pose is None:
        rotation = kabsch(objective.best_rotation_covariance(h))
        return rotation, similarity(rotation, grid1.points, grid2.points)
    transform = np.linalg.inv(pose)
    return transform[:3, :3] / np.cbrt(np.linalg.det(transform[:3, :3])), transform


def _layout_report(uv: np.ndarray, faces: np.ndarray) -> dict:
    """Triangles of a layout on the square turned against most of the others ("flipped") and of about zero area
    ("degenerate"), as :class:`~meshreg.mesh.harmonic.HarmonicMap` reports them."""
    positive, negative, degenerate = turn_counts(uv, faces)
    return {"flipped": min(positive, negative), "degenerate": degenerate}
