"""Registration that keeps a bent surface's correspondence: the parametrizations' own match, improved by E_w.

Two meshes of one material surface, one of them bent, get (nearly) the same harmonic map to the square when their
corners are the same material points: the map is built from lengths and angles within the surface, which bending
keeps. E, which compares normals after one rotation of the whole surface, charges the bending, and minimizing it
slides the correspondence away from the right one (on a sheet rolled by 180 degrees, E of the true map is 0.69 and
the minimum found 0.53). So for meshes (``Options.bend_window`` > 0, mode "auto"):

1. the symmetry of the square (which corner of the second's square is (0, 0), and whether r and t swap) is chosen
   by the ranking's E_w (:func:`meshreg.local_rotation.local_energy`) at h = that symmetry, in windows of
   ``advanced.choice_window``, on coarse grids: local rotations absorb the bending, the relief within a window
   decides (and a nearly as low one that fits the points far better wins: :func:`preferred`);
2. from h = the symmetry (the parametrizations' own correspondence), h descends on the descent's E_w
   (:class:`meshreg.local_rotation.LocalObjective`: each cell under its own rotation and scale) with windows of
   ``bend_window``, in the basis of the descent (KL = ``basis``), then in the refinement levels that are not
   finer than ``finest``: for meshes, ``advanced.refine_triangles`` triangles, since below a few triangles two
   meshes of one surface are different piecewise-linear surfaces and a finer h fits their difference, not the
   correspondence; several symmetries that rank within CHOICE_MARGIN of the best (at most ``max_starts``) are
   each descended and the lowest E_w wins, unless one nearly as low fits the points far better
   (:func:`preferred`);
3. E itself is reported at the answer (at its best rotation), so that energies stay comparable with every other
   registration; ``params["bend_energy"]`` holds E_w.

No DP stage: the DP minimizes E and walks away from the parametrization on bends.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from functools import cache, partial

import numpy as np

from .alternatives import find_alternatives
from .choice import every_match_mirrored, every_start_mirrored, mirror_record
from .grid import GridSurface
from .local_rotation import LocalObjective, local_energy
from .objective import Objective
from .options import Options
from .residual import Residual, metric_residual
from .result import Registration
from .rotation import similarity
from .schedule import Descent, Log, Progress, work_objective
from .search import Start, apply_symmetry, symmetry_map, tried_symmetries

CHOICE_GRID = 41  # nodes per axis of the coarse grids on which symmetries and corner placements are ranked
CHOICE_MARGIN = 0.1  # symmetries whose E_w at the start is within this fraction of the best are descended too
# E_w alone can prefer a wrong match of a nearly symmetric pair: a five-lobed star over a saddle, remeshed, turned and
# scaled, had its half-turned match (lobes on notches, coordinate residual 0.24-0.28) rank first at E_w 0.0052-0.0057,
# the right one (residual 0.021-0.027) 1.27-1.28 times that; in another remeshing (1,500 and 3,000 vertices, scaled
# 1.5x) 1.7-2.2 times (residuals 0.057-0.060 against 0.25-0.28). Among matches within RESIDUAL_TIE times the lowest
# E_w, one that fits the points (coordinate residual below RESIDUAL_FLOOR, an area-1 length, and below RESIDUAL_GAIN
# times the lowest's) is preferred (:func:`preferred`) when the lowest does not (right matches of the star measured
# 0.012-0.060; on pairs whose every placement fits, a lower residual came with a higher E: 0.00035 -> 0.00106). A
# sheet rolled half a turn has no match that fits: the right one measured 0.66, a wrong symmetry 0.13 at 1.24 times
# its E_w, and without the bound of RESIDUAL_FLOOR on the winner the tie of 3 (1.5 before) chose the wrong one
RESIDUAL_TIE = 3.0
RESIDUAL_GAIN = 0.5
RESIDUAL_FLOOR = 0.1
# a match that fits the points (residual below RESIDUAL_FLOOR) replaces the lowest E_w's that does not only if its
# metric residual (meshreg.residual.metric_residual, the surfaces' first fundamental forms compared) is at most this
# many times the lowest's: a bent pair's right match moves the points but keeps the metric (a disc rolled a quarter
# turn: the right placement at residual 0.38 and metric 0.083, a placement turned 0.15 of its rim at residual 0.04 and
# metric 0.124), while a half-turned match of a nearly symmetric shape keeps it about as well as the right one
METRIC_VETO = 1.3
# a twin of the answer (a symmetry of either surface applied to it) is refined only when its residual as it stands
# is within this of the answer's (area-1 length): measured 0.002-0.009 above on a four-fold symmetric sheet's
# remeshed copy (true twins), 0.096 and more on the folded relief sheet (a flat square's symmetries, not the fold's)
TWIN_MARGIN = 0.05
WINDOW_CELLS = 4.0  # the descent's windows are at least this many grid cells wide (a rotation is fitted in each)
# a pair whose parametrizations' own correspondence fits the points within this coordinate residual (area 1) is one
# unbent surface: its E_w fits rotations only. With a scale per cell such pairs came back 1.5-2 times worse (random
# relief sheets remeshed and moved rigidly: median errors 0.0002-0.0019 of the diameter -> 0.0003-0.0030); bent
# pairs need the scales (the benchmark's roll, fold, stretch and face pairs)
RIGID_FIT_RESIDUAL = 0.01
# blurred grids (meshes: Options.mesh_blur) stand for a pair whose blurred parametrizations' own correspondence fits the
# points within this coordinate residual (area 1): unbent pairs (random remeshed relief sheets 0.001-0.009; with vertex
# noise of 0.3% of the size, which perturbs the maps, 0.011-0.015: errors 0.0095-0.0101 -> 0.0048-0.0087) and slight
# bends (a face or terrain rolled 15-30 degrees: three of four more accurate, one 0.0024 -> 0.0027), not reliefs
# rolled 45 degrees (0.032-0.048, which blurring made 10-25% worse), the face scan whose searched corners differ (0.030,
# 4-6 times worse blurred: a blur on two squares that disagree is not one blur on the surface) nor the benchmark's bent
# pairs (0.07-0.31, 1.3-3 times worse)
BLUR_FIT_RESIDUAL = 0.02


def coarse(surface: GridSurface, n: int = CHOICE_GRID) -> GridSurface:
    """The surface at area 1 on an n x n uniform grid (for ranking)."""
    return surface.scaled().resampled(n, n)


def symmetry_energies(
    first: GridSurface, second: GridSurface, window: float, tried
) -> list[tuple[int, float, bool, float, float]]:
    """(symmetry, E_w at h = that symmetry, whether that match is mirrored, its coordinate residual, its metric
    residual) for each symmetry of the square in ``tried``, lowest E_w first. Both surfaces are ranked on
    :func:`coarse` grids with windows of ``window`` (side lengths); a match is mirrored when the first, rotated by
    Kabsch, lies on the point reflection of the second (:mod:`meshreg.residual`): E_w, like E, cannot tell them
    apart. The residual is the area-weighted RMS of R c1 - c2 at area 1 (:class:`~meshreg.residual.Residual`), the
    metric residual :func:`~meshreg.residual.metric_residual` (for :func:`preferred`)."""
    a, b = coarse(first), coarse(second)
    out = []
    for k in tried:
        copy = apply_symmetry(b, k)
        plain = Objective(a, copy, copy.area())
        residual = plain.judge(plain.identity)[2]
        energy = local_energy(a.points, copy.points, a.r, a.t, window)
        out.append((k, energy, residual.mirrored, residual.plus, metric_residual(a.points, copy.points)))
    return sorted(out, key=lambda x: x[1])


def preferred(energies, residuals, metrics=None) -> int:
    """Index of the preferred match among matches with ``energies`` (E_w, (m,)) and coordinate ``residuals`` (m,):
    the lowest E_w, unless it does not fit the points (residual at least RESIDUAL_FLOOR) and a match within
    RESIDUAL_TIE times its E_w does (residual below RESIDUAL_FLOOR and below RESIDUAL_GAIN times the lowest's); then
    the lowest residual among those within RESIDUAL_TIE. With ``metrics`` (m,), the matches' metric residuals
    (:func:`meshreg.residual.metric_residual`), only to a match whose metric residual is at most METRIC_VETO times
    the lowest E_w's: a bent pair's right match does not fit the points (the bend moves them) but keeps the metric,
    and a wrong one can fit the points better.

    >>> preferred([0.0052, 0.0066, 0.0200], [0.252, 0.024, 0.001])
    1
    >>> preferred([0.0052, 0.0066], [0.252, 0.200])
    0
    >>> preferred([0.0052, 0.0066], [0.030, 0.010])
    0
    >>> preferred([0.0655, 0.0813], [0.663, 0.132])  # a sheet rolled half a turn: neither fits the points
    0
    >>> preferred([0.0052, 0.0066], [0.252, 0.024], metrics=[0.08, 0.12])  # the lowest keeps the metric
    0

    A NaN counts as infinite (last).
    """
    energies, residuals = (np.nan_to_num(np.asarray(x, dtype=float), nan=np.inf) for x in (energies, residuals))
    best = int(np.argmin(energies))
    tied = np.flatnonzero(energies <= RESIDUAL_TIE * energies[best])
    fit = int(tied[np.argmin(residuals[tied])])
    fits = residuals[fit] < min(RESIDUAL_FLOOR, RESIDUAL_GAIN * residuals[best])
    if metrics is not None:
        metrics = np.nan_to_num(np.asarray(metrics, dtype=float), nan=np.inf)
        fits = fits and metrics[fit] <= METRIC_VETO * metrics[best]
    return fit if residuals[best] >= RESIDUAL_FLOOR and fits else best


def descent_window(first: GridSurface, bend_window: float) -> float:
    """The descent's window: ``bend_window``, widened to WINDOW_CELLS cells of the first's grid (on a 41 x 41
    grid a window of 2 cells absorbs the relief it should compare and the descent stalls)."""
    cell = max(np.diff(first.r).max(), np.diff(first.t).max())
    return float(max(bend_window, WINDOW_CELLS * cell))


def register_bending(
    first: GridSurface,
    second: GridSurface,
    options: Options,
    callback: Progress | None = None,
    symmetry: int | None = None,
    finest: float = 0.0,
    blurred: list[GridSurface] | None = None,
    settle: Callable[[Registration, bool], Registration | None] | None = None,
) -> Registration:
    """Register two grid surfaces (two meshes on their squares) from their parametrizations' own correspondence,
    descending E_w (see the module's docstring).

    Parameters
    ----------
    first, second : GridSurface
    options : Options
        ``bend_window`` (> 0), ``advanced.choice_window``, ``basis``, ``solver``, ``max_starts``, ``search``,
        ``symmetries``, ``keep_orientation`` and the descent's numerics.
    callback : callable, optional
        ``callback(stage, iteration, E_w)`` after every accepted step (stage "gd").
    symmetry : int, optional
        The symmetry of the square to use (corners given on both meshes fix it); default: chosen.
    finest : float
        Refinement levels finer than this (side lengths of the square) are not run (see
        :class:`~meshreg.schedule.Descent`): for meshes, ``advanced.refine_triangles`` times their typical edge
        length on the square (:func:`meshreg.mesh.harmonic.edge_length`). Default 0: every level.
    blurred : [GridSurface, GridSurface], optional
        Both surfaces blurred (meshes: ``Options.mesh_blur``), registered instead when the pair is one unbent surface
        (:func:`_unbent`); ``params["blurred"]`` says whether they were.
    settle : callable, optional
        ``settle(registration, blurred)``: a final answer from the parametrizations' own correspondence, or None.
        Tried before any descent when one symmetry ranks close and its start fits the points within
        RIGID_FIT_RESIDUAL (one unbent surface) and is not mirrored, with the registration at that start (h = the
        symmetry; ``blurred``: whether it is on the blurred grids); an answer it returns is returned as it is
        (meshes: the snap to closest points, :func:`meshreg.mesh.snap.snap_rigid`, whose answer for one rigid
        surface does not depend on the descent), None descends as usual. ``params["descended"]`` says which;
        ``timings["settle"]`` holds the time of a refused try.

    Returns
    -------
    Registration
        ``energy`` is E at the answer (at its best rotation); ``energy_history`` holds E_w along the descent.
    """
    start = time.perf_counter()
    timings: dict = {}
    tic = time.perf_counter()
    ranked, close, spare = _ranked_symmetries(first, second, options, symmetry)
    timings["search"] = time.perf_counter() - tic
    area = second.area()
    blurred_fit = None if blurred is None else cache(partial(_start_fit, blurred[0], blurred[1], blurred[1].area()))
    use_blurred = blurred_fit is not None and _unbent(blurred_fit, close)
    if use_blurred:
        first, second = blurred
        area = second.area()
    start_fit = blurred_fit if use_blurred else partial(_start_fit, first, second, area)
    window = descent_window(first, options.bend_window)

    def descend(k: int) -> BentRun:
        return _descend(first, start_fit(k), area, k, window, options, finest, Log(callback, timings))

    def finished(chosen: BentRun, runs: list[BentRun], descended: bool = True) -> Registration:
        alternatives = []
        if symmetry is None:
            with Log(callback, timings).clock("alternatives"):
                alternatives = find_alternatives(
                    first, second, area, chosen.symmetry, chosen, chosen.residual, options, Log(callback), TWIN_MARGIN
                )
        timings["total"] = time.perf_counter() - start
        params = _params(options, chosen, runs, ranked, window, first, second)
        params.update(blurred=use_blurred, descended=descended)
        return _registration(chosen, first, second, options, params, timings, alternatives)

    fit = start_fit(close[0]) if settle is not None and len(close) == 1 else None
    if fit is not None and not _bent(fit[2]):
        tic, kept = time.perf_counter(), dict(timings)
        run = _at_start(first, fit, area, close[0], window, Log(callback, timings))
        settled = None if run.residual.mirrored else settle(finished(run, [run], False), use_blurred)
        if settled is not None:
            return settled
        timings.clear()
        timings.update(kept, settle=time.perf_counter() - tic)  # the refused try (its alternatives and snap) apart
    chosen, runs = _unmirrored(close, spare, descend)
    return finished(chosen, runs)


def choice_symmetries(options: Options, symmetry: int | None) -> tuple[int, ...]:
    """The symmetries of the square that the E_w rankings try (:func:`meshreg.search.tried_symmetries`): the pinned
    ``symmetry``, else those of ``options`` (none but the identity with ``search`` or ``symmetries`` off)."""
    return tried_symmetries(options.search and options.symmetries, options.keep_orientation, symmetry)


def _ranked_symmetries(first: GridSurface, second: GridSurface, options: Options, symmetry: int | None):
    """The symmetries of the square tried, ranked by E_w at h = each (:func:`symmetry_energies`), the ones within
    CHOICE_MARGIN of the :func:`preferred` unmirrored one (at most ``options.max_starts``: descended first, the
    preferred one first) and the other unmirrored ones (spares, best first)."""
    ranked = symmetry_energies(first, second, options.advanced.choice_window, choice_symmetries(options, symmetry))
    fair = [(k, e, r, m) for k, e, mirrored, r, m in ranked if not mirrored]
    if not fair:
        raise every_start_mirrored(symmetry)
    energies, residuals, metrics = ([x[i] for x in fair] for i in (1, 2, 3))
    fair.insert(0, fair.pop(preferred(energies, residuals, metrics)))
    close = [k for k, e, *_ in fair if e <= (1.0 + CHOICE_MARGIN) * fair[0][1]][: options.max_starts]
    return ranked, close, [k for k, *_ in fair if k not in close]


def _registration(chosen, first: GridSurface, second: GridSurface, options: Options, params, timings, alternatives):
    """The :class:`~meshreg.result.Registration` of the ``chosen`` run (h mapped back through its symmetry)."""
    h = symmetry_map(chosen.symmetry, chosen.h)
    plain = chosen.objective
    return Registration(
        rotation=chosen.rotation,
        h=h,
        energy=chosen.energy,
        energy_dp=float("nan"),
        energy_history=np.array(chosen.log.energies),
        r=plain.r,
        t=plain.t,
        mode=options.mode,
        params=params,
        timings=timings,
        symmetry=chosen.symmetry,
        energy_stages=tuple(chosen.log.stages),
        transform=similarity(chosen.rotation, first.points, second.at(h)),
        residual=chosen.residual.plus,
        residual_mirrored=chosen.residual.minus,
        alternatives=[a.as_dict(chosen.rotation) for a in alternatives],
    )


def _params(options: Options, chosen, runs, ranked, window: float, first: GridSurface, second: GridSurface) -> dict:
    """Every parameter of a bending registration and what its choice saw (``result.params``)."""
    return {
        **options.as_dict(),
        "bend_energy": chosen.bend_energy,
        "bend_window_used": window,
        "bend_fit_residual": chosen.fit_residual,
        "bend_scaled": chosen.scaled,
        "symmetry_ranking": [
            {"symmetry": s, "choice_energy": float(e), "mirrored": m, "choice_residual": float(r)}
            for s, e, m, r, _ in ranked
        ],
        "mirror": mirror_record(*_mirror_starts(ranked, chosen.symmetry), chosen.residual.plus),
        "starts": [
            {
                "symmetry": run.symmetry,
                "bend_energy": run.bend_energy,
                "energy": run.energy,
                "residual": run.residual.plus,
                "chosen": run is chosen,
            }
            for run in runs
        ],
        "grid_first": list(first.shape),
        "grid_second": list(second.shape),
    }


def _unmirrored(close: list[int], spare: list[int], descend) -> tuple[BentRun, list[BentRun]]:
    """Descend the ``close`` symmetries; while every run ends on the mirror image of the second, the ``spare``
    ones, best ranked first. Returns the :func:`preferred` run (by E_w and the coordinate residual) of those that
    are not mirrored, and every run."""
    runs = [descend(k) for k in close]
    while all(run.residual.mirrored for run in runs):
        if not spare:
            raise every_match_mirrored(min(run.energy for run in runs))
        runs.append(descend(spare.pop(0)))
    fair = [run for run in runs if not run.residual.mirrored]
    energies, residuals = [run.bend_energy for run in fair], [run.residual.plus for run in fair]
    return fair[preferred(energies, residuals, [run.metric for run in fair])], runs


def _mirror_starts(ranked, chosen: int) -> tuple[Start | None, Start]:
    """The best mirrored entry of the E_w ranking and the chosen one, as starts for
    :func:`~meshreg.choice.mirror_record` (their ``coarse_energy`` is E_w at h = the symmetry)."""
    mirror = next((Start(k, None, e) for k, e, mirrored, *_ in ranked if mirrored), None)
    return mirror, next(Start(k, None, e) for k, e, *_ in ranked if k == chosen)


@dataclass
class BentRun:
    """One symmetry's descent of E_w: the answer on the symmetric copy's square, judged by E and the residual
    (shaped like :class:`~meshreg.schedule.Candidate` for :func:`~meshreg.alternatives.find_alternatives`)."""

    symmetry: int
    objective: Objective  # E on the first and the second under ``symmetry``
    rotation: np.ndarray
    h: np.ndarray
    energy: float
    bend_energy: float
    residual: Residual
    log: Log
    fit_residual: float  # the coordinate residual at h = the symmetry (the parametrizations' correspondence)
    metric: float  # the metric residual of the answer (meshreg.residual.metric_residual)

    @property
    def scaled(self) -> bool:
        """Whether E_w fitted a scale per cell (:func:`_descend`): the parametrizations' correspondence did not
        fit the points."""
        return _bent(self.fit_residual)


def _bent(fit_residual: float) -> bool:
    """Whether a pair whose parametrizations' correspondence has this coordinate residual is bent (above
    RIGID_FIT_RESIDUAL): its E_w then fits a scale per cell."""
    return fit_residual > RIGID_FIT_RESIDUAL


def _start_fit(first: GridSurface, second: GridSurface, area: float, k: int) -> tuple[GridSurface, Objective, float]:
    """The second under the k-th symmetry of the square, E between the first and it, and the coordinate residual of
    the parametrizations' own correspondence (at h = the symmetry, the best rotation)."""
    copy = apply_symmetry(second, k)
    plain = Objective(first, copy, area)
    return copy, plain, plain.judge(plain.identity)[2].plus


def _unbent(start_fit, symmetries: list[int]) -> bool:
    """Whether the parametrizations' own correspondence fits the points within BLUR_FIT_RESIDUAL under one of the
    ``symmetries`` (``start_fit``: :func:`_start_fit` of the blurred grids, by symmetry): one surface, unbent or
    slightly bent, whose two maps to the square nearly agree, so that a blur on either square is nearly one blur on
    the surface."""
    return any(start_fit(k)[2] <= BLUR_FIT_RESIDUAL for k in symmetries)


def _at_start(first: GridSurface, start, area: float, k: int, window: float, log: Log) -> BentRun:
    """The parametrizations' own correspondence under the k-th symmetry (``start``: its :func:`_start_fit`) as a run
    that did not descend: h = the symmetry, at its best rotation, with E_w there (the rotations-only E_w of an unbent
    pair, :func:`_descend`) as its one logged energy."""
    copy, plain, fit = start
    rotation, energy, residual = plain.judge(plain.identity)
    local = LocalObjective(first, copy, area, window=window, scaled=_bent(fit))
    bend_energy = float(local.energy(rotation, plain.identity))
    log.keep("start", bend_energy)
    metric = metric_residual(plain.first.points, plain.points(plain.identity))
    return BentRun(k, plain, rotation, plain.identity, float(energy), bend_energy, residual, log, fit, metric)


def _descend(first, start, area, k, window, options, finest, log) -> BentRun:
    """E_w descended from h = the k-th symmetry of the square (``start``: its :func:`_start_fit`): with a scale per
    cell, unless the parametrizations' own correspondence already fits the points (coordinate residual at most
    RIGID_FIT_RESIDUAL: one unbent surface), where E_w fits rotations only
    (:class:`~meshreg.local_rotation.LocalObjective`)."""
    copy, plain, fit = start
    make = partial(LocalObjective, window=window, scaled=_bent(fit))
    objective = make(first, copy, area)
    work, nodes = work_objective(objective, first, copy, area, make=make)
    drive = Descent(objective, options, work, nodes, finest)
    rotation, h = drive.descend(np.eye(3), drive.restrict(objective.identity), [options.basis], log)
    rotation, h = drive.polish(rotation, h, log)
    rotation, energy, residual = plain.judge(h)
    bend_energy = float(objective.energy(rotation, h))
    metric = metric_residual(plain.first.points, plain.points(h))
    return BentRun(k, plain, rotation, h, float(energy), bend_energy, residual, log, fit, metric)
