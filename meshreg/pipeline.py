"""The registration pipeline behind ``meshreg.register``: the rotation R of the first surface and the
reparametrization h of the second.

Modes (a table, :data:`SOLVE`, of functions each returning a :class:`~meshreg.schedule.Candidate`):

``"dp"``
    DP-surface-min alone (h = (gamma(r), t)), alternated with Kabsch.
``"gd"``
    Descent from R = I and h = id, alternated with Kabsch (the paper's "without DP" runs). A descent from the
    identity settles in the nearest local minimum, which is far from the best one when the surfaces have
    different numbers of folds, and which one it is depends on the path; so up to three paths are run and the
    one ending at the lower E is kept (``params["gd_path"]``): the plain descent in KL = ``basis``; the same
    after the coarser KL = ``start_basis``; and that through a Gaussian scale space (``smoothing``).
``"dp+gd"``
    The paper's method: DP-surface-min, then the descent from its R and h.
``"auto"`` (default)
    Starts (a symmetry of the square for the second surface and a rotation) ranked by a coarse DP
    (:func:`meshreg.search.best_start`); from each start close to the best (``max_starts``,
    ``advanced.start_margin``), DP along r and along t (the transposed problem), alternated and composed,
    then the basis descent; the start with the lowest E is refined. E is blind to the sign of a surface, so
    every candidate is also judged by its coordinate residual (:mod:`meshreg.residual`): a match of the first
    surface with the mirror image of the second is never returned. The correspondences as good as the chosen
    one that a symmetry of either surface allows are listed in ``result.alternatives``
    (:mod:`meshreg.alternatives`).

On grids (and meshes outside the bending path) in every mode but "dp", with ``refine="nodes"``, an answer that
fits the normals of one shape while its points are still apart (a nearly flat sheet, whose E hardly changes as h
slides) is refined once more with tighter stopping rules (:mod:`meshreg.stalled`).

The descent and refinement schedule is in :mod:`meshreg.schedule`; ``refine="none", solver="gradient",
smoothing=(), start_basis=5`` is the paper's procedure as published (Bernal & Lawrence, Section 4, Simplified
Outline of Optimization Procedure, Steps 1-4). See docs/method.md.
"""

from __future__ import annotations

import time
from dataclasses import replace
from functools import partial

import numpy as np

from .alternatives import find_alternatives
from .choice import choose, choose_unmirrored, close_starts, mirror_record, ranked_starts, spare_starts
from .correspondence import Side
from .errors import InputError
from .grid import GridSurface
from .objective import Objective
from .options import Advanced, Options
from .result import Registration
from .rotation import similarity
from .schedule import Candidate, Descent, Log, Progress, dp_stage, gd_paths, valid_start, work_objective
from .search import Start, apply_symmetry, symmetry_map
from .stalled import polish_stalled
from .surfaces import Mesh, as_input

DEFAULTS = Options()


def register(
    first,
    second,
    mode: str = DEFAULTS.mode,
    *,
    window: int = DEFAULTS.window,
    basis: int = DEFAULTS.basis,
    solver: str = DEFAULTS.solver,
    refine: str = DEFAULTS.refine,
    search: bool = DEFAULTS.search,
    symmetries: bool = DEFAULTS.symmetries,
    keep_orientation: bool = DEFAULTS.keep_orientation,
    max_starts: int = DEFAULTS.max_starts,
    symmetry: int | None = DEFAULTS.symmetry,
    start_basis: int = DEFAULTS.start_basis,
    smoothing: tuple[float, ...] = DEFAULTS.smoothing,
    resolution: int = DEFAULTS.resolution,
    weights: str = DEFAULTS.weights,
    antialias: int = DEFAULTS.antialias,
    mesh_blur: float = DEFAULTS.mesh_blur,
    cleanup: bool = DEFAULTS.cleanup,
    corners1: tuple[int, int, int, int] | None = DEFAULTS.corners1,
    corners2: tuple[int, int, int, int] | None = DEFAULTS.corners2,
    corner_search: int = DEFAULTS.corner_search,
    overlap: str = DEFAULTS.overlap,
    bend_window: float = DEFAULTS.bend_window,
    force: bool = DEFAULTS.force,
    advanced: Advanced | None = None,
    callback: Progress | None = None,
) -> Registration:
    """Register two surfaces: rotate the first, reparametrize the second.

    Parameters
    ----------
    first, second : grid or mesh
        Two grids (GridSurface, ndarray (M, N, 3), grid file) or two disk-topology meshes (mesh file,
        ``trimesh.Trimesh``, Open3D ``TriangleMesh``, ``(vertices, faces)``); grid sizes and vertex counts may
        differ. Both are scaled to area 1.
    mode, window, basis, solver, refine, search, symmetries, keep_orientation, max_starts, start_basis, smoothing
        How to register: see :class:`meshreg.options.Options` (defaults: mode "auto", window 10, basis 5, ...).
    symmetry : int, optional
        Pins the symmetry of the square applied to the second surface (an index of
        :data:`meshreg.search.SQUARE_SYMMETRIES`, as in ``result.symmetry`` and ``result.alternatives``).
    resolution, weights, antialias, mesh_blur, cleanup, corners1, corners2, corner_search, overlap, bend_window
        How meshes are prepared and registered (cleanup, map to the square, resampling, overlap; the windows within
        which E_w lets them bend, :mod:`meshreg.bending`): see :class:`~.options.Options`.
    force : bool
        Lift the limits on grid size, DP window, basis and corner search of :mod:`meshreg.limits`.
    advanced : Advanced, optional
        The rare numerics (tolerances, iteration caps); see :class:`meshreg.options.Advanced`.
    callback : callable, optional
        ``callback(stage, iteration, E)`` after every accepted step (stage "dp", "gd", "refine", "kabsch",
        "smoothing", "polish" or "alternatives").

    Returns
    -------
    Registration
        R, h, E, the coordinate residual and the equally good alternatives, and the correspondence
        (``correspondence``, ``vertex_pairs``, ``transform``, ``distances``, ``fitness``, ``inlier_rmse``).

    Raises
    ------
    InputError
        Bad surfaces or parameters, or a grid or window beyond the limits (see :mod:`meshreg.limits`), before
        any computation.

    Examples
    --------
    >>> from meshreg.samples import paper_pairs
    >>> pair = paper_pairs(31, 31)[0]
    >>> result = register(pair.first, pair.second, mode="dp")
    >>> result.energy < 0.01
    True
    """
    options = Options(
        mode=mode,
        window=window,
        basis=basis,
        solver=solver,
        refine=refine,
        search=search,
        symmetries=symmetries,
        keep_orientation=keep_orientation,
        max_starts=max_starts,
        symmetry=symmetry,
        start_basis=start_basis,
        smoothing=smoothing,
        resolution=resolution,
        weights=weights,
        antialias=antialias,
        mesh_blur=mesh_blur,
        cleanup=cleanup,
        corners1=corners1,
        corners2=corners2,
        corner_search=corner_search,
        overlap=overlap,
        bend_window=bend_window,
        force=force,
        advanced=Advanced() if advanced is None else advanced,
    )
    return register_with(first, second, options, callback)


def register_with(first, second, options: Options, callback: Progress | None = None) -> Registration:
    """:func:`register` with every setting in one :class:`~.options.Options` (the CLI, the adapters and the distance
    matrix call this); ``first``, ``second``: two grids or two meshes in any form :func:`~.surfaces.as_input` takes."""
    if not isinstance(options, Options):
        raise InputError(f"options must be a meshreg.Options, got {type(options).__name__}")
    if callback is not None and not callable(callback):
        raise InputError(f"callback must be a function of (stage, iteration, energy), got {type(callback).__name__}")
    a, b = as_input(first, "first"), as_input(second, "second")
    if isinstance(a, Mesh) != isinstance(b, Mesh):
        raise InputError("give two meshes or two grids, not one of each")
    if isinstance(a, Mesh):
        from .mesh.correspond import register_meshes

        return register_meshes(a, b, options, callback).result
    if options.corners1 is not None or options.corners2 is not None:
        raise InputError(
            "corners1 and corners2 are vertex ids of meshes; a grid's corners are its own: give symmetry= (0-7) to "
            "fix which corner of the second grid matches which of the first"
        )
    return replace(register_grids(a, b, options, callback), first=Side.from_grid(a), second=Side.from_grid(b))


def register_grids(first: GridSurface, second: GridSurface, options: Options, callback: Progress | None = None):
    """The registration of two grid surfaces (the core of :func:`register_with`; no :class:`Side` attached)."""
    start = time.perf_counter()
    options.check_grids(first.shape, second.shape)
    timings = {}
    area = second.area()
    searched = options.mode == "auto" and options.search
    ranked, mirror = ranked_starts(first, second, options, timings)
    starts = close_starts(ranked, options.max_starts, options.advanced.start_margin) if searched else ranked
    solve = SOLVE[options.mode]

    def run(s: Start) -> Candidate:
        return solve(first, apply_symmetry(second, s.symmetry), area, s.rotation, options, Log(callback, timings))

    candidates = [run(s) for s in starts]
    if searched:
        chosen, residual = choose_unmirrored(candidates, starts, spare_starts(ranked, starts), run, options)
    else:
        chosen = choose(candidates, options)
        candidates[chosen].polish()
        residual = candidates[chosen].residual()
    best, symmetry = candidates[chosen], starts[chosen].symmetry
    residual, stalled = polish_stalled(best, residual, options, timings, callback)
    alternatives = []
    if options.mode == "auto":
        with Log(callback, timings).clock("alternatives"):
            alternatives = find_alternatives(first, second, area, symmetry, best, residual, options, Log(callback))
    timings["total"] = time.perf_counter() - start
    params = _params(options, best, starts, candidates, mirror_record(mirror, starts[chosen], residual.plus), stalled)
    h = symmetry_map(symmetry, best.h)
    return Registration(
        rotation=best.rotation,
        h=h,
        energy=best.energy,
        energy_dp=best.energy_dp,
        energy_history=np.array(best.log.energies),
        energy_stages=tuple(best.log.stages),
        r=best.objective.r,
        t=best.objective.t,
        mode=options.mode,
        params=params,
        timings=timings,
        symmetry=symmetry,
        transform=similarity(best.rotation, first.points, second.at(h)),
        residual=residual.plus,
        residual_mirrored=residual.minus,
        alternatives=[a.as_dict(best.rotation) for a in alternatives],
    )


def _params(
    options: Options, best: Candidate, starts: list[Start], candidates: list[Candidate], mirror, stalled: dict | None
) -> dict:
    """Every parameter of a registration, what its search saw and what the polish of a stalled answer did
    (:func:`~meshreg.stalled.polish_stalled`; None when it did not run) (``result.params``)."""
    return {
        **options.as_dict(),
        "gd_path": best.gd_path,
        "starts": [
            {
                "symmetry": s.symmetry,
                "coarse_energy": None if np.isnan(s.energy) else float(s.energy),
                "energy": float(c.energy),
                "residual": c.residual().plus,
                "refined": c.pending is None,
                "chosen": c is best,
            }
            for s, c in zip(starts, candidates, strict=True)
        ],
        "mirror": mirror,
        "stalled_polish": stalled,
        "grid_first": list(best.objective.first.shape),
        "grid_second": list(best.objective.second.shape),
    }


def _dp_only(first: GridSurface, second: GridSurface, area: float, rotation, options: Options, log: Log) -> Candidate:
    """Mode "dp": DP-surface-min along r, alternated with Kabsch."""
    objective = Objective(first, second, area)
    with log.clock("dp"):
        rotation, h, energy_dp = dp_stage(objective, options, both=False, rotation=rotation)
        log.step("dp", 0, energy_dp)
    energy, residual = objective.evaluate(rotation, h)
    return Candidate(objective, rotation, h, energy, log, energy_dp=energy_dp, measured=residual)


def _dp_then_descent(
    first: GridSurface, second: GridSurface, area: float, rotation, options: Options, log: Log, both: bool
) -> Candidate:
    """Modes "dp+gd" (``both`` False) and "auto" (``both``: DP along r and t): the DP stage and the basis descent
    from its R and h, both on the work grid; the refinement is left pending."""
    objective = Objective(first, second, area)
    drive = Descent(objective, options, *work_objective(objective, first, second, area))
    with log.clock("dp"):
        rotation, h, _ = dp_stage(drive.work, options, both=both, rotation=rotation)
        log.step("dp", 0, energy_dp := drive.full_energy(rotation, h))
    start = valid_start(drive.work, h, options.advanced.max_stretch)
    rotation, h = drive.descend_from_start(rotation, start, log)
    energy, measured = drive.work.evaluate(rotation, h)
    return Candidate(objective, rotation, h, energy, log, energy_dp=energy_dp, pending=drive, measured=measured)


def _descent_paths(
    first: GridSurface, second: GridSurface, area: float, rotation, options: Options, log: Log
) -> Candidate:
    """Mode "gd": each path of :func:`~meshreg.schedule.gd_paths` from R = I, h = id, refined; the lowest E kept."""
    objective = Objective(first, second, area)
    drive = Descent(objective, options, *work_objective(objective, first, second, area))
    ends = []
    for path in gd_paths(options):
        path_log = Log(log.callback, log.timings)
        rotation, h = drive.from_identity(first, second, path, path_log)
        energy, measured = objective.evaluate(rotation, h)
        ends.append(Candidate(objective, rotation, h, energy, path_log, gd_path=path, measured=measured))
    return min(ends, key=lambda c: c.energy)


SOLVE = {
    "dp": _dp_only,
    "gd": _descent_paths,
    "dp+gd": partial(_dp_then_descent, both=False),
    "auto": partial(_dp_then_descent, both=True),
}


def register_symmetric(first, second, mode: str = DEFAULTS.mode, **settings) -> tuple[Registration, Registration]:
    """Register both ways: (first rotated, second reparametrized) and (second rotated, first reparametrized).

    E is not symmetric in its arguments once discretized and minimized locally; the two energies show how far
    from symmetric it is for a pair. Settings as for :func:`register`.

    Returns
    -------
    forward, backward : Registration
    """
    first, second = as_input(first, "first"), as_input(second, "second")
    return register(first, second, mode, **settings), register(second, first, mode, **settings)
