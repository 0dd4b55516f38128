"""A second refinement pass for a stalled answer: E at the level of one shape, the points still off.

The refinement's stopping rules are relative: a level stops when a step lowers E by less than a fraction of E
(``Advanced.refine_rel_tol``, ``round_tol``). That suits pairs whose E falls by orders of magnitude per step, but not
a nearly flat sheet: q is constant on a flat sheet, so sliding h within a sheet of relief eps changes E only by about
eps^2, and the descent stops while the points are still a few percent apart (a held-out sheet of 1% relief against a
warped copy of itself: E 1.7e-5 where the exact answer has E ~ 1e-12, points 4.6% off on 41 x 41 nodes;
docs/heldout.md). Tighter rules for every pair would slow them all, so they are applied only to such an answer:
after the choice, when the answer has E below :data:`meshreg.choice.SAME_SHAPE_ENERGY` and a coordinate residual
above :data:`STALLED_RESIDUAL`, the refinement runs once more from it on the full grid, in the B-spline levels of
:data:`POLISH_KNOTS` and then the node level, with :data:`POLISH_ITERATIONS` and :data:`POLISH_REL_TOL` in place of
``Advanced.refine_iterations`` and ``refine_rel_tol``. Its answer is kept only when it lowers E, brings the residual
down to at most :data:`POLISH_KEEP_RESIDUAL` of what it was, and is not on the mirror image of the second surface.
Either way ``result.params["stalled_polish"]`` records what it did and ``result.timings["stalled_polish"]`` its
seconds; where it does not run, nothing changes.
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from .choice import normals_only
from .options import Options
from .residual import Residual
from .schedule import Candidate, Descent, Log, Progress

# an answer is stalled when E < SAME_SHAPE_ENERGY and its coordinate residual (on area 1) is above this. Measured
# with benchmarks/bench_heldout.py (docs/heldout.md): the right answers among the 13 held-out surfaces' 4 cases had
# residuals of at most 0.0047 on 41 x 41 and 0.0026 on 101 x 101 nodes, the paper's same-shape pairs at most 0.0005
# on 61 x 61; the stalled nearly flat sheet 0.070 (41 x 41) and 0.029 (101 x 101). The ridge under the power warp on
# 41 x 41 (points 1.1% off, its exact answer has a higher E on the grid: docs/heldout.md) has 0.015 and is left alone
STALLED_RESIDUAL = 0.02
# cubic B-spline functions per axis of the polish's levels before the node level (only those below half the grid's
# nodes per axis run: 8, 12, 16 on 41 x 41). A finer ladder than REFINE_KNOTS: on the nearly flat sheet at 101 x 101
# the levels 12, 24 and the nodes stopped at points 0.61% off, this ladder at 0.39% (1.8 s), 8 to 48 at 0.20% (21 s)
POLISH_KNOTS = (8, 12, 16, 24, 32)
# most Gauss-Newton steps per round of each polish level (Advanced.refine_iterations: 10); on the nearly flat sheet at
# 41 x 41 the ladder stopped at points 0.30% off with 20, 0.17% with 40 and with 80
POLISH_ITERATIONS = 40
# a polish round stops at a step that lowers E by less than this fraction (Advanced.refine_rel_tol: 1e-2). On the
# nearly flat sheet at 41 x 41 the ladder stopped at points 0.73% off with 1e-2, at 0.17% with 1e-3 and with 1e-4
# (1e-4 made the ridge's rejected polish below take 9 s instead of 4). The rounds' rules (Advanced.max_rounds,
# round_tol) stay as they are: 30 rounds and a round_tol of 1e-6 changed nothing
POLISH_REL_TOL = 1e-3
# the polished answer is kept only when its residual is at most this fraction of the stalled one's (and E is lower):
# E alone can fall by fitting the normals better while the points stay where they were. The nearly flat sheet went
# from 0.070 to 0.0039 (41 x 41) and 0.029 to 0.0081 (101 x 101); the held-out tanh ridge on 101 x 101 (a local
# minimum across the ridge, not a stalled descent) from E 7.5e-4 to 6e-6 but residual 0.0325 to 0.0288 only, its
# points 2.4% -> 2.0% off on average but 9.3% -> 13.1% at most (0.89 of its residual). Half until the twenty-first
# session: a ridge of two flat sides (|r - 0.4 - 0.15 t^2| rounded over 0.03) under smooth warps on 61 x 61 against
# 65 x 57 nodes had polishes to 0.58-0.61 of the residual rejected, though they lowered the points' mean error by 42-43%
# and their largest by 15-17% (tests/test_stalled.py; two of a helper's 64 held-out pairs likewise, docs/heldout.md);
# benchmarks/bench_heldout.py (41 and 101 nodes, and 120 random pairs) gave the same answers with 0.5 and 0.75
POLISH_KEEP_RESIDUAL = 0.75


def is_stalled(energy: float, residual: Residual) -> bool:
    """Whether an answer of E ``energy`` and coordinate ``residual`` fits the normals of one shape with its points
    further apart than STALLED_RESIDUAL (:func:`meshreg.choice.normals_only` at that bound)."""
    return normals_only(energy, residual, STALLED_RESIDUAL)


def polish_options(options: Options) -> Options:
    """``options`` with the polish's stopping rules (POLISH_ITERATIONS, POLISH_REL_TOL) in place of the refinement
    levels' (``Advanced.refine_iterations``, ``refine_rel_tol``)."""
    advanced = replace(options.advanced, refine_iterations=POLISH_ITERATIONS, refine_rel_tol=POLISH_REL_TOL)
    return options.replace(advanced=advanced)


def polish_stalled(
    candidate: Candidate, residual: Residual, options: Options, timings: dict, callback: Progress | None = None
) -> tuple[Residual, dict | None]:
    """Polish the chosen, refined ``candidate`` when it is stalled (:func:`is_stalled`) and its mode refines (not
    "dp", ``refine`` "nodes").

    The refinement levels of POLISH_KNOTS and the node level run on the full grid from the candidate's R and h with
    the polish's stopping rules (:func:`polish_options`). The candidate takes the polished R, h, E and residual
    only when E is lower, the residual at most POLISH_KEEP_RESIDUAL times what it was and the match not mirrored;
    its log then gains the polish's energies (stage "polish"). ``timings["stalled_polish"]`` gets the seconds
    spent.

    Parameters
    ----------
    candidate : Candidate
        The chosen answer, refined (R and h on the full grid).
    residual : Residual
        Its residual.
    options : Options
    timings : dict
        Seconds per stage of the registration.
    callback : callable, optional
        Progress, reported under stage "polish".

    Returns
    -------
    (Residual, dict or None)
        The answer's residual, and what the polish did (None when it did not run): E and residual before and
        after, whether the polished answer was kept, the POLISH_KEEP_RESIDUAL that decided it, seconds.
    """
    if options.mode == "dp" or options.refine != "nodes" or not is_stalled(candidate.energy, residual):
        return residual, None
    tic = time.perf_counter()
    objective = candidate.objective
    nodes = (np.arange(objective.first.shape[0]), np.arange(objective.first.shape[1]))
    drive = Descent(objective, polish_options(options), objective, nodes, knots=POLISH_KNOTS)
    trial = Log(callback, {}, stage="polish")
    rotation, h = drive.polish(candidate.rotation, candidate.h, trial)
    energy, found = objective.evaluate(rotation, h)
    record = {
        "energy_before": float(candidate.energy),
        "energy_after": float(energy),
        "residual_before": residual.plus,
        "residual_after": found.plus,
        "kept": bool(
            energy < candidate.energy and found.plus <= POLISH_KEEP_RESIDUAL * residual.plus and not found.mirrored
        ),
        "keep_residual": POLISH_KEEP_RESIDUAL,
    }
    if record["kept"]:
        _take(candidate, rotation, h, energy, found, trial)
        residual = found
    timings["stalled_polish"] = record["seconds"] = time.perf_counter() - tic
    return residual, record


def _take(candidate: Candidate, rotation: np.ndarray, h: np.ndarray, energy: float, found: Residual, trial: Log):
    """The polished R, h, E and residual into ``candidate``, the polish's energies (``trial``) into its log under
    stage "polish" (Kabsch steps stay "kabsch"; the trial's starting E, the candidate's last, is left out)."""
    candidate.rotation, candidate.h, candidate.energy, candidate.measured = rotation, h, energy, found
    for e, stage in zip(trial.energies, trial.stages, strict=True):
        if stage != "start":
            candidate.log.keep("kabsch" if stage == "kabsch" else "polish", e)
