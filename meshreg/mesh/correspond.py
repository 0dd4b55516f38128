"""Register two disk meshes: clean, map to the square, resample, register, and attach the meshes to the result."""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from functools import cached_property

import numpy as np

from ..bending import RESIDUAL_GAIN, preferred, register_bending
from ..correspondence import Side, inverse_uv
from ..errors import InputError, RunError
from ..forked import Forked, can_fork
from ..options import Options
from ..pipeline import register_grids
from ..result import Registration, with_stage
from ..schedule import Progress
from .corners import corner_positions
from .harmonic import HarmonicMap, edge_length, given_corners
from .overlap import Overlap, rigid_match, rigid_overlap, warped_overlap
from .pages import small_pages
from .partial import register_overlap
from .resample import blur_grid, blur_sigma, resample_grid
from .snap import SETTLE_PINNING, SETTLE_SLACK, snap_rigid
from .topology import DiskMesh, prepare_disk

# Meshes of together at least this many triangles get their maps to the square in a forked child while the overlap is
# checked (``Advanced.processes``, when a core is idle). Measured (CPU seconds of the caller, serial -> forked): two
# 10k-triangle meshes 0.67 -> 0.64 (the child 0.07: hardly worth its copy-on-write faults), two 100k-triangle meshes
# 1.6 -> 1.2-1.3 (the child 0.45-0.6).
FORK_FACES = 50_000
# a pair registered whole in mode "auto" (bend_window > 0) that the overlap check found to be one surface moved
# rigidly (its pose makes the meshes coincide and the relief pins it) is held to the points: when the answer's
# coordinate residual (area 1) is above POSE_CHECK, the common region is registered at the pose as well (as a rigid
# overlap) and that answer kept if its residual is at most RESIDUAL_GAIN times the whole answer's. Meshes of random
# points whose rims are their convex hulls (sliver triangles along the rim, the square's corners cut off differently
# in each) had whole answers 88-177 degrees off with residuals 0.057-0.063 at lower E than the right match; right
# answers of same-surface pairs measured 0.001-0.016 (docs/heldout.md, seventeenth session)
POSE_CHECK = 0.01


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
        The meshes resampled on the square (as resampled: ``result`` may have registered blurred copies,
        ``result.params["mesh_blur_sigma"]``).
    result : Registration
    info : dict
        Per mesh ("first", "second"): the cleanup report, the map's flipped and degenerate triangles, corners,
        and for a searched corner placement the placements tried.
    matches : ndarray, shape (n2, 2), optional
        :attr:`matched_uv2` when it is known without inverting h (the common region of a partial pair, registered
        at h = identity); else None.
    """

    first: DiskMesh
    second: DiskMesh
    uv1: np.ndarray
    uv2: np.ndarray
    grids: tuple
    result: Registration
    info: dict
    matches: np.ndarray | None = None

    @cached_property
    def matched_uv2(self) -> np.ndarray:
        """For each vertex of the second disk (n2, 2), the point of the first's square that the registration matches
        it with (corresponding points of the two meshes share this value). Computed when first asked
        (:func:`meshreg.correspondence.inverse_uv`, about 0.03 s for 50000 vertices): :func:`meshreg.register` returns
        only the :class:`Registration`, which does not need it."""
        if self.matches is not None:
            return self.matches
        return inverse_uv(self.result.h, self.result.r, self.result.t, self.uv2)


def register_meshes(
    first, second, options: Options | None = None, callback: Progress | None = None, names=("first mesh", "second mesh")
) -> MeshRegistration:
    """Register two meshes given as (vertices (n, 3), faces (m, 3)): clean, parametrize, resample, register.

    Parameters
    ----------
    first, second : mesh
        Two disk-topology meshes: files, ``trimesh.Trimesh``, Open3D ``TriangleMesh`` or (vertices (n, 3), faces
        (m, 3)); see :func:`meshreg.surfaces.as_input`.
    options : Options, optional
        Mesh preparation (``resolution``, ``antialias``, ``cleanup``, ``weights``, ``corners1``, ``corners2``,
        ``corner_search``) and registration settings. In mode "auto" (the default) with ``bend_window`` > 0
        (default 0.05) the correspondence starts from the two maps to the square and descends E_w, which lets
        the surface bend (:func:`meshreg.bending.register_bending`); the symmetry of the square (which corner
        of the boundary became (0, 0)) is chosen, or fixed by corners given for both meshes. Other modes, or
        ``bend_window=0``, minimize E (:func:`meshreg.pipeline.register_grids`). With ``overlap="auto"`` (the
        default) meshes that cover different regions are registered only where they overlap
        (:mod:`meshreg.mesh.overlap`, :mod:`meshreg.mesh.partial`; docs/overlap.md).
    callback : callable, optional
        Progress, as for :func:`meshreg.register`.
    names : (str, str)
        What to call the meshes in error messages when they are not files (files are called by their paths).
    """
    from ..surfaces import Mesh, as_input

    if options is not None and not isinstance(options, Options):  # a dict, say: {} would pass for the defaults
        raise TypeError(f"options must be a meshreg.Options, e.g. Options(resolution=61), got {type(options).__name__}")
    options = Options() if options is None else options
    side = (options.resolution, options.resolution)
    options.check_grids(side, side)
    meshes = [as_input(mesh, name) for mesh, name in zip((first, second), names, strict=True)]
    if not all(isinstance(m, Mesh) for m in meshes):
        raise InputError("register_meshes takes two meshes")
    with small_pages(max(len(m.vertices) for m in meshes)):  # large meshes' arrays: see meshreg.mesh.pages
        return _registered_pair(meshes, options, callback)


def _registered_pair(meshes: list, options: Options, callback) -> MeshRegistration:
    """:func:`register_meshes` of two checked meshes (:class:`meshreg.surfaces.Mesh`)."""
    disks, maps, infos = _prepared(meshes, options)
    n_input = (len(meshes[0].vertices), len(meshes[1].vertices))
    if options.overlap == "off":
        return register_disks(disks, maps, n_input, infos, options, callback)
    fork = options.advanced.processes > 1 and sum(len(d.faces) for d in disks) >= FORK_FACES and can_fork()
    # the maps (Laplacians, LUs, solves) in the child, beside the overlap check: both take about as long
    with Forked(square_maps, disks, maps, options, fork=fork) as squares:
        found = rigid_overlap(disks[0], disks[1], options.advanced.overlap_quick)
        mapped = None if found.regime == "rigid" else squares.result()
    if found.regime == "rigid":
        return register_overlap(disks[0], disks[1], found, n_input, options, infos)
    whole = register_disks(disks, maps, n_input, infos, options, callback, mapped, (found.target, found.source))
    if found.regime == "deformed":
        matches = whole.result.first.at_uv(whole.matched_uv2)[0]
        found = warped_overlap(disks[0], disks[1], found, matches)
        if found.regime in ("rigid", "elastic"):
            return register_overlap(disks[0], disks[1], found, n_input, options, infos)
    whole.info["overlap"] = found.summary()
    whole.info["overlap"]["parameters"]["POSE_CHECK"] = POSE_CHECK
    timings = with_stage(whole.result.timings, "overlap", found.seconds)
    whole = replace(whole, result=replace(whole.result, info=json_ready(whole.info), timings=timings))
    return _held_to_the_pose(whole, disks, found, n_input, options, infos)


def _held_to_the_pose(
    whole: MeshRegistration, disks: list[DiskMesh], found: Overlap, n_input: tuple[int, int], options: Options, infos
) -> MeshRegistration:
    """``whole`` (the pair registered whole; ``found`` its overlap, regime "full") or, when the answer does not fit
    the points (residual above POSE_CHECK) and ``found``'s pose pins a rigid match
    (:func:`~meshreg.mesh.overlap.rigid_match`), the registration of the common region at the pose
    (:func:`~meshreg.mesh.partial.register_overlap`: regime "rigid", vertices outside the common region unmatched) if
    it fits them RESIDUAL_GAIN times better. Tried where the snap is, in mode "auto" with ``bend_window`` > 0
    (``bend_window=0`` asks for the lowest E), and not when the user fixed the corners or the symmetry.
    ``info["pose_check"]`` records which answer was kept ("pose" or "whole") and the other's E and residual, or the
    error that left the whole answer standing; ``timings["pose_check"]`` (in the total) the seconds not in the kept
    answer's own stages."""
    result, start = whole.result, time.perf_counter()
    fixed = any(value is not None for value in (options.corners1, options.corners2, options.symmetry))
    if fixed or not _bending(options) or not result.residual > POSE_CHECK:
        return whole
    rigid = rigid_match(disks[0], disks[1], found)
    if rigid is None:
        return whole
    matched_at = time.perf_counter()
    try:
        posed = register_overlap(disks[0], disks[1], rigid, n_input, options, infos)
    except (ValueError, RuntimeError) as err:  # a common region too small to map, say: the whole answer stands
        chosen, record, seconds = whole, {"error": str(err)}, time.perf_counter() - start
    else:
        keep = posed.result.residual <= RESIDUAL_GAIN * result.residual
        chosen, other = (posed, whole) if keep else (whole, posed)
        record = {"kept": "pose" if keep else "whole", "energy": other.result.energy, "residual": other.result.residual}
        registered = result.timings["total"] - found.seconds  # the whole registration, without the overlap check
        seconds = registered + matched_at - start if keep else time.perf_counter() - start
    return _with_info(chosen, {**chosen.info, "pose_check": record}, "pose_check", seconds)


def _with_info(chosen: MeshRegistration, info: dict, stage: str, seconds: float) -> MeshRegistration:
    """``chosen`` with ``info`` as its report (and its result's) and ``seconds`` recorded as ``stage`` (in the
    total): the answer kept by a comparison, with what the comparison cost."""
    timings = with_stage(chosen.result.timings, stage, seconds)
    return replace(chosen, info=info, result=replace(chosen.result, info=json_ready(info), timings=timings))


def _bending(options: Options) -> bool:
    """Whether the pair is registered by :func:`meshreg.bending.register_bending` (mode "auto", ``bend_window`` >
    0), and its answer snapped to closest points when the meshes are one rigid surface."""
    return options.mode == "auto" and options.bend_window > 0


def _prepared(meshes: list, options: Options) -> tuple[list[DiskMesh], list[HarmonicMap], dict]:
    """Both meshes (:class:`meshreg.surfaces.Mesh`) cleaned into disks, their given corners checked, their maps to
    the square set up (not yet solved), and the cleanup report per mesh ("first", "second"); an InputError names
    the mesh."""
    disks, maps, infos = [], [], {}
    for name, mesh in zip(("first", "second"), meshes, strict=True):
        try:
            disk = prepare_disk(mesh.vertices, mesh.faces, cleanup=options.cleanup)
            _check_corners(disk, options, name)
            maps.append(HarmonicMap(disk, options.weights, mesh.name))
        except InputError as err:
            raise InputError(f"{mesh.name}: {err}") from None
        disks.append(disk)
        infos[name] = {"cleanup": disk.report}
    return disks, maps, infos


def _check_corners(disk: DiskMesh, options: Options, name: str) -> None:
    """InputError naming the option when the corners given for the ``name`` ("first" or "second") mesh are not four
    distinct vertices of its boundary in their order around it: checked whichever way the pair is registered (the
    overlap's path does not use them)."""
    option = "corners1" if name == "first" else "corners2"
    ids = getattr(options, option)
    if ids is not None:
        try:
            given_corners(disk, disk.input_ids(ids))
        except InputError as err:
            raise InputError(f"{option}: {err}") from None


@dataclass
class SquareMaps:
    """Two prepared disks' corners and maps to the square (:func:`square_maps`).

    Attributes
    ----------
    uvs : [ndarray (n1, 2), ndarray (n2, 2)]
        Each disk vertex's place on the square.
    reports : [dict, dict]
        Each map's report (:meth:`meshreg.mesh.harmonic.HarmonicMap.__call__`).
    tried : list or None
        The second disk's corner placements tried by a search (:func:`meshreg.mesh.corners.corner_positions`).
    symmetry : int or None
        The symmetry of the square that corners given for both disks fix.
    other : (ndarray (n2, 2), dict) or None
        The second disk's map and its report under another corner placement that the search found (registered
        too; the final answers are compared by :func:`meshreg.bending.preferred` on E and residual), or None.
    """

    uvs: list
    reports: list
    tried: list | None
    symmetry: int | None
    other: tuple | None = None


def square_maps(disks: list[DiskMesh], maps: list[HarmonicMap], options: Options) -> SquareMaps:
    """Both disks' corners and maps to the square (the first part of :func:`register_disks`)."""
    positions, tried, symmetry, other = corner_positions(disks, maps, options)
    uvs, reports = zip(*(m(p) for m, p in zip(maps, positions, strict=True)), strict=True)
    return SquareMaps(list(uvs), list(reports), tried, symmetry, None if other is None else maps[1](other))


def register_disks(
    disks: list[DiskMesh],
    maps: list[HarmonicMap],
    n_input: tuple[int, int],
    infos: dict,
    options: Options,
    callback,
    squares: SquareMaps | None = None,
    surfaces: tuple | None = None,
) -> MeshRegistration:
    """Register two prepared disks whole (the path of :func:`register_meshes` without the overlap): corners and
    harmonic maps (:func:`square_maps`), grids, :func:`meshreg.bending.register_bending` or
    :func:`meshreg.pipeline.register_grids`, the snap; when the corner search moved the second's placement to where
    the points fit (``squares.other``), that placement is registered too and one answer kept (:func:`_placement_kept`).

    Parameters
    ----------
    disks : [DiskMesh, DiskMesh]
    maps : [HarmonicMap, HarmonicMap]
        Their Laplacians (factorized at their first use).
    n_input : (int, int)
        Vertex counts of the meshes as given.
    infos : dict
        The preparation report per mesh ("first", "second"), completed here.
    squares : SquareMaps, optional
        :func:`square_maps` of the disks when already computed (else computed here).
    surfaces : (Surface, Surface), optional
        The disks as :class:`~meshreg.mesh.surface.Surface` objects, when already built (for the snap).
    """
    infos = {name: dict(info) for name, info in infos.items()}
    squares = square_maps(disks, maps, options) if squares is None else squares
    symmetry, uvs = squares.symmetry, squares.uvs
    if symmetry is not None and options.symmetry not in (None, symmetry):
        raise InputError(
            f"the corners given for both meshes fix the symmetry of the square to {symmetry}, not the pinned "
            f"{options.symmetry}: give corners or a symmetry, not both"
        )
    if squares.tried is not None:
        infos["second"]["corner_search"] = squares.tried
    for name, report in zip(("first", "second"), squares.reports, strict=True):
        infos[name].update(report)
    pinned = options.symmetry if symmetry is None else symmetry
    start = time.perf_counter()
    whole = _registered(disks, uvs, n_input, infos, options, callback, pinned, surfaces)
    if squares.other is None:
        return whole
    moved = {**infos, "second": {**infos["second"], **squares.other[1]}}
    uvs = [uvs[0], squares.other[0]]
    return _placement_kept(
        whole, lambda: _registered(disks, uvs, n_input, moved, options, callback, pinned, surfaces), start
    )


def _placement_kept(whole: MeshRegistration, register_moved, start: float) -> MeshRegistration:
    """``whole`` (registered from the search's chosen corner placement since ``start``, a perf_counter time) or the
    registration ``register_moved()`` of the placement :func:`~meshreg.mesh.corners._snug` moved it to, whichever
    :func:`meshreg.bending.preferred` prefers by final E and residual. ``info["second"]["other_placement"]`` records
    the other answer's E and residual, whether the moved placement was kept, and the other registration's seconds
    (``timings["other_placement"]``, added to the total); or the error that left the moved placement without an
    answer (``whole`` stands)."""
    first = time.perf_counter() - start
    try:
        moved = register_moved()
    except (InputError, RunError) as err:  # every match mirrored there, say: the chosen placement's answer stands
        record = {"error": str(err)}
        answers, kept, seconds = (whole,), 0, time.perf_counter() - start - first
    else:
        answers = (whole, moved)
        kept = preferred([a.result.energy for a in answers], [a.result.residual for a in answers])
        left = answers[1 - kept].result
        seconds = (first, time.perf_counter() - start - first)[1 - kept]
        record = {"energy": left.energy, "residual": left.residual, "kept": bool(kept), "seconds": seconds}
    chosen = answers[kept]
    info = {**chosen.info, "second": {**chosen.info["second"], "other_placement": record}}
    return _with_info(chosen, info, "other_placement", seconds)


def _registered(disks, uvs, n_input, infos, options: Options, callback, pinned, surfaces) -> MeshRegistration:
    """The disks resampled from their maps ``uvs``, registered by :func:`meshreg.bending.register_bending` (mode
    "auto" with ``bend_window`` > 0) or :func:`meshreg.pipeline.register_grids` under the ``pinned`` symmetry (if
    any), and snapped (:func:`meshreg.mesh.snap.snap_rigid`); ``infos`` becomes the result's preparation report.
    The bending path first tries the snap on the parametrizations' own correspondence of an unbent pair (its
    ``settle``, with SETTLE_SLACK and SETTLE_PINNING): one rigid surface that pins the pose snaps to the same closest
    points from there as from the descent's answer, which is then not computed (``params["descended"]`` False)."""
    n = options.resolution
    grids = [resample_grid(d.vertices, d.faces, uv, n, n, options.antialias) for d, uv in zip(disks, uvs, strict=True)]
    sides = [Side.from_disk(d, uv, k) for d, uv, k in zip(disks, uvs, n_input, strict=True)]
    bending, blurred, sigma = _bending(options), None, 0.0

    def snapped(result: Registration, used: list, slack: float = 1.0, pinning: float = 0.0) -> MeshRegistration:
        params = {**result.params, "mesh_blur_sigma": sigma if used is not grids else 0.0}
        result = replace(result, first=sides[0], second=sides[1], info=json_ready(infos), params=params)
        whole = MeshRegistration(disks[0], disks[1], uvs[0], uvs[1], tuple(grids), result, infos)
        return snap_rigid(whole, tuple(used), bending, surfaces, slack, pinning)

    if not bending:
        return snapped(register_grids(grids[0], grids[1], options.replace(symmetry=pinned), callback), grids)
    edges = [edge_length(d.faces, uv) for d, uv in zip(disks, uvs, strict=True)]
    sigma = blur_sigma(max(edges), options.mesh_blur, n)
    blurred = [blur_grid(g, sigma * (n - 1)) for g in grids] if sigma else None
    settled = []

    def settle(result: Registration, on_blurred: bool) -> Registration | None:
        settled.append(snapped(result, blurred if on_blurred else grids, SETTLE_SLACK, SETTLE_PINNING))
        return settled[-1].result if settled[-1].result.params["snapped"] else None

    finest = options.advanced.refine_triangles * np.mean(edges)
    result = register_bending(grids[0], grids[1], options, callback, pinned, finest, blurred, settle)
    if settled and settled[-1].result is result:
        return settled[-1]
    return snapped(result, blurred if result.params["blurred"] else grids)


def json_ready(info: dict) -> dict:
    """The preparation report with numpy values made plain (it is saved as JSON in result.npz)."""
    if isinstance(info, dict):
        return {str(k): json_ready(v) for k, v in info.items()}
    if isinstance(info, (list, tuple)):
        return [json_ready(v) for v in info]
    if isinstance(info, np.ndarray):
        return info.tolist()
    return info.item() if isinstance(info, np.generic) else info
