"""The stages of one registration and their order: the DP stage, the basis descent and the refinement levels.

Every stage alternates with Kabsch (Steps 2-3 of the paper's outline: descend in h, then find the best R for
that h, until Kabsch stops helping). The DP stage of modes "dp+gd" and "auto" and the descent run on a work grid
of at most :data:`COARSE_NODES` nodes per axis; the refinement levels are cubic B-spline bases of
:data:`REFINE_KNOTS` functions per axis on the work grid, then every node of the full grid. Mode "gd" adds
smoothed copies of both surfaces before all that (:mod:`meshreg.scale`). Each change of level goes through
:func:`carry`: h is upsampled bicubically to the next grid and made a valid start there.

:class:`Log` gathers what a run reports: the energies of the full grid after every accepted step, the
progress callback and the seconds per stage.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from contextlib import contextmanager
from dataclasses import dataclass, field
from functools import partial

import numpy as np

from .descent import descend, gauss_newton
from .diffeo import compose, enforce_boundary, jacobian_determinant
from .dp import dp_surface_min, strip_bounds
from .fields import bspline_basis, node_basis, riseth_basis
from .grid import GridSurface
from .objective import Objective
from .options import Options, StepParams
from .residual import Residual
from .rotation import kabsch
from .scale import level_nodes, smoothed
from .spline import GridInterpolator

# grids with more than DP_FULL_NODES nodes along the DP direction use the coarse-to-fine strip DP, its coarse
# level having about DP_STRIP_NODES nodes
DP_FULL_NODES = 200
DP_STRIP_NODES = 50
START_BLENDS = (0.0, 1e-3, 1e-2, 0.1, 0.5)  # blends toward the identity tried for an invalid descent start
START_MIN_DET = 1e-3  # smallest det J (per cell; its mean is 1) of a descent start
REFINE_KNOTS = (12, 24)  # cubic B-spline functions per axis of the refinement levels, before the node level
COARSE_NODES = 101  # the descent and the B-spline levels run on at most this many nodes per axis
DP_ROUND_TOL = 1e-4  # the DP stage of mode "auto" alternates directions while E drops by more than this fraction

Progress = Callable[[str, int, float], None]


class Log:
    """What one candidate registration reports: its energies, the progress callback and stage timings.

    Parameters
    ----------
    callback : callable, optional
        ``callback(stage, iteration, E)`` after every accepted step.
    timings : dict, optional
        Seconds per stage, shared with the logs made by :meth:`scratch` (and by other candidates).
    stage : str, optional
        Report every step under this stage name instead of its own.
    """

    def __init__(self, callback: Progress | None = None, timings: dict | None = None, stage: str | None = None):
        self.energies: list[float] = []
        self.stages: list[str] = []  # the stage of each kept energy
        self.callback = callback
        self.timings = {} if timings is None else timings
        self._stage = stage

    def step(self, stage: str, iteration: int, energy: float) -> None:
        """An accepted step: keep E and report it."""
        self.keep(stage, energy)
        if self.callback is not None:
            self.callback(self._stage or stage, iteration, energy)

    def keep(self, stage: str, energy: float) -> None:
        """Keep E (of the full grid) without reporting it: a level's starting point."""
        self.energies.append(energy)
        self.stages.append(stage)

    def scratch(self, stage: str | None = None) -> Log:
        """A log for work off the full grid: reports and timings go on, its energies are not kept here."""
        return Log(self.callback, self.timings, stage or self._stage)

    @contextmanager
    def clock(self, stage: str):
        """Add the seconds spent in the block to ``timings[stage]``."""
        tic = time.perf_counter()
        try:
            yield
        finally:
            self.timings[stage] = self.timings.get(stage, 0.0) + time.perf_counter() - tic


@dataclass
class Candidate:
    """One registration in progress: R and h (on the work grid until :meth:`Descent.polish`), E and its log."""

    objective: Objective
    rotation: np.ndarray
    h: np.ndarray
    energy: float
    log: Log
    energy_dp: float = float("nan")
    gd_path: dict | None = None
    pending: Descent | None = field(default=None, repr=False)  # the refinement still to run
    measured: Residual | None = field(default=None, repr=False)  # the residual of R and h, once computed

    def residual(self) -> Residual:
        """The coordinate residual of R and h on the grid h lives on (the work grid until :meth:`polish`)."""
        if self.measured is None:
            objective = self.objective if self.pending is None else self.pending.work
            self.measured = objective.residual(self.rotation, self.h)
        return self.measured

    def polish(self) -> Candidate:
        """Run the pending refinement (nothing when there is none); returns self."""
        if self.pending is not None:
            self.rotation, self.h = self.pending.polish(self.rotation, self.h, self.log)
            self.energy, self.measured = self.objective.evaluate(self.rotation, self.h)
            self.pending = None
        if not self.log.energies:
            self.log.keep("start", self.energy)
        return self


def valid_start(objective: Objective, h: np.ndarray, max_stretch: float = np.inf) -> np.ndarray:
    """h itself when every cell keeps det J >= START_MIN_DET and no cell edge is lengthened by more than
    ``max_stretch``, else the least blend (1 - eps) h + eps id that does.

    The descent needs an orientation-preserving start: a DP path that is flat in places (gamma' = 0) gives
    cells of zero area, where no step can be accepted; and a start beyond the stretch bound of the descent
    (:meth:`~meshreg.objective.Objective.stretch`) where no step is accepted either.
    """
    r, t = objective.r, objective.t
    for eps in START_BLENDS:
        blended = (1.0 - eps) * h + eps * objective.identity
        if objective.admissible(blended, max_stretch) and jacobian_determinant(blended, r, t).min() >= START_MIN_DET:
            return blended
    return objective.identity.copy()


def dp_stage(objective: Objective, options: Options, both: bool, rotation=None):
    """DP-surface-min along r (the paper); with ``both``, alternate passes along t and r while E drops.

    The DP starts from ``rotation``, or from Kabsch at the identity when it is None. Returns R, h, E.
    """
    rounds, radius = options.advanced.dp_rounds, options.advanced.dp_radius
    rotation, h, energy = dp_pass(objective, rotation, None, options.window, rounds, along_t=False)
    if both:
        for p in range(2 * rounds):
            # after the first pass each way, h is aligned: later passes search near the identity path
            near = radius if p >= 1 else 0
            new_rotation, new_h, new_energy = dp_pass(objective, rotation, h, options.window, rounds, p % 2 == 0, near)
            # composing the two directions' steps can collapse cells, or stretch them beyond the descent's bound
            if not objective.admissible(new_h, options.advanced.max_stretch):
                break
            if new_energy >= energy * (1 - DP_ROUND_TOL):
                if new_energy < energy:
                    rotation, h, energy = new_rotation, new_h, new_energy
                break
            rotation, h, energy = new_rotation, new_h, new_energy
    return rotation, h, energy


def dp_pass(objective: Objective, rotation, h, window: int, dp_rounds: int, along_t: bool, radius: int = 0):
    """One DP-surface-min pass on (q1, (q2, h)) along r or t; returns R, h o (gamma step), E.

    With ``radius`` > 0 (and a grid small enough for the full table), the DP searches only within ``radius`` nodes
    of the identity path, and again over the whole table when its path reaches the edge of that strip.
    """
    q1, q2 = objective.q1, objective.second_on_first_grid(h)
    r, t = objective.r, objective.t
    if along_t:
        q1, q2, r, t = q1.transpose(1, 0, 2), q2.transpose(1, 0, 2), t, r
    coarsen = len(r) // DP_STRIP_NODES if len(r) > DP_FULL_NODES else 1
    solve = partial(dp_surface_min, q1, q2, r, r, t, window=window, max_rounds=dp_rounds, rotation=rotation)
    if coarsen == 1 and 0 < radius < len(r) - 1:
        diagonal = np.repeat(np.arange(len(r)), 2).reshape(-1, 2)
        lo, hi = strip_bounds(len(r), len(r), diagonal, radius)
        result = solve(strip=(lo, hi))
        rows, cols = result.path.T
        if np.any(((cols == lo[rows]) & (cols > 0)) | ((cols == hi[rows]) & (cols < len(r) - 1))):
            result = solve()
    else:
        result = solve(coarsen=coarsen)
    step = objective.identity.copy()
    if along_t:
        step[..., 1] = result.gamma[None, :]
    else:
        step[..., 0] = result.gamma[:, None]
    h = step if h is None else compose(h, objective.r, objective.t, step)
    return result.rotation, h, objective.energy(result.rotation, h)


def carry(h: np.ndarray | None, source: Objective | None, target: Objective, max_stretch: float = np.inf) -> np.ndarray:
    """A descent start on ``target``: h from ``source``'s grid upsampled (bicubic, sides exact) and made a
    valid start (:func:`valid_start`), or the identity when there is no h yet."""
    if h is None:
        return target.identity.copy()
    value = GridInterpolator(h, source.r, source.t).values(target.identity[..., 0], target.identity[..., 1])
    return valid_start(target, enforce_boundary(value), max_stretch)


def alternate(objective: Objective, rotation, h, solve, steps: StepParams, rounds: tuple, log: Log, stage: str):
    """Steps 2-3 of the outline: ``solve`` moves h (and R), then Kabsch moves R, until Kabsch stops helping.

    ``solve(objective, R, h, steps, callback=...)`` is a descent round; ``rounds`` = (most rounds, relative
    tolerance on the Kabsch step's decrease).
    """
    max_rounds, round_tol = rounds
    if not log.energies:
        log.keep("start", objective.energy(rotation, h))
    for _ in range(max_rounds):
        state = solve(objective, rotation, h, steps, callback=partial(log.step, stage))
        h = state.h
        if state.rotation is not None:
            rotation = state.rotation
        new_rotation = kabsch(objective.best_rotation_covariance(h))
        new_energy = objective.energy(new_rotation, h)
        if new_energy < state.energy:
            rotation = new_rotation
            log.step("kabsch", 0, new_energy)
        energy = min(new_energy, state.energy)
        # Step 3: another round only when Kabsch lowered E by much (E_L = E after the descent)
        if energy <= steps.zero_energy or state.energy - energy < round_tol * state.energy + steps.abs_tol:
            break
    return rotation, h


class Descent:
    """Steps 2-3 of the outline on one pair: the basis descent on the work grid, then the refinement levels.

    Parameters
    ----------
    objective : Objective
        E on the full grid of the first surface.
    options : Options
    work, nodes : Objective, (ndarray, ndarray)
        E on the work grid and its nodes' indices in the full grid (:func:`work_objective`).
    finest : float
        The refinement levels whose spacing (of the B-spline knots; of the full grid's nodes) is below this
        (side lengths of the square) are not run. Default 0: all of them.
    knots : tuple of int
        Cubic B-spline functions per axis of the refinement levels before the node level, coarsest first (those
        with at least half as many functions as the work grid has nodes per axis are left out). Default
        :data:`REFINE_KNOTS`.
    """

    def __init__(
        self,
        objective: Objective,
        options: Options,
        work: Objective,
        nodes: tuple,
        finest: float = 0.0,
        knots: tuple[int, ...] = REFINE_KNOTS,
    ):
        self.objective, self.options, self.finest, self.knots = objective, options, finest, knots
        self.work, self.nodes = work, nodes
        self.solver = descend if options.solver == "gradient" else gauss_newton
        self.rounds = (options.advanced.max_rounds, options.advanced.round_tol)
        # mode "gd" descends from the identity, not from a DP path: no stretch bound (docs/method.md, "Stretch bound")
        self.max_stretch = np.inf if options.mode == "gd" else options.advanced.max_stretch
        self.stuck = False  # the descent from the DP answer accepted no step: polish() first runs unstick()

    def full_energy(self, rotation, h: np.ndarray) -> float:
        """E on the full grid of R and h given at the work grid's nodes (h carried up when the grids differ)."""
        if self.work is self.objective:
            return self.work.energy(rotation, h)
        return self.objective.energy(rotation, carry(h, self.work, self.objective))

    def restrict(self, h: np.ndarray) -> np.ndarray:
        """h at the full grid's nodes -> h at the work grid's nodes."""
        return h[np.ix_(*self.nodes)]

    def _log(self, target: Objective, log: Log) -> Log:
        """Energies are kept for the full grid only."""
        return log if target is self.objective else log.scratch()

    def _bases(self, target: Objective, rotation, h, bases, log: Log, masks: int = 0, cap: tuple = ()):
        """Descend on ``target`` in the Riseth bases with KL in ``bases``, one after the other; with ``masks`` > 0
        (Gauss-Newton) a step's move is dropped at over-stretched edges up to that many times, and the step is
        charged for the area it hides; ``cap`` = (most iterations per round, most rounds) instead of the usual."""
        masked = {}
        if masks and self.solver is gauss_newton:
            masked = {"stretch_masks": masks, "area_charge": self.options.advanced.fine_area_charge}
        iterations, rounds = cap or (self.options.advanced.max_iterations, self.rounds[0])
        for kl in bases:
            solve = partial(self.solver, basis=riseth_basis(kl, target.r, target.t), **masked)
            steps = self.options.steps(max_stretch=self.max_stretch, max_iterations=iterations)
            rotation, h = alternate(target, rotation, h, solve, steps, (rounds, self.rounds[1]), log, "gd")
        return rotation, h

    def unstick(self, rotation, h, log: Log):
        """The basis descent again from a DP answer where it accepted no step (its path lies on the stretch bound),
        with ``Advanced.stuck_stretch_masks`` stretch masks, at most ``stuck_iterations`` steps in ``stuck_rounds``
        rounds; the DP answer is kept when the masked steps end on the mirror image of the second surface."""
        advanced = self.options.advanced
        masks, cap = advanced.stuck_stretch_masks, (advanced.stuck_iterations, advanced.stuck_rounds)
        trial = Log(log.callback, log.timings)  # its energies join the log only when its answer is kept
        trial.energies, trial.stages = list(log.energies), list(log.stages)
        with log.clock("gd"):
            moved = self._bases(self.work, rotation, h, [self.options.basis], self._log(self.work, trial), masks, cap)
        if self.work.residual(*moved).mirrored:
            return rotation, h
        log.energies, log.stages = trial.energies, trial.stages
        return moved

    def descend(self, rotation, h, bases, log: Log):
        """Descend from (R, h) on the work grid (h at its nodes) in the Riseth bases KL in ``bases``.

        Returns R and h on the work grid.
        """
        with log.clock("gd"):
            return self._bases(self.work, rotation, h, bases, self._log(self.work, log))

    def descend_from_start(self, rotation, start: np.ndarray, log: Log):
        """:meth:`descend` in KL = ``options.basis`` from a DP answer ``start``; when no step was accepted (none fit
        the stretch bound) the descent is marked stuck, so that :meth:`polish` first runs :meth:`unstick` (with
        Gauss-Newton and ``Advanced.stuck_stretch_masks`` > 0). Returns R and h on the work grid."""
        rotation, h = self.descend(rotation, start, [self.options.basis], log)
        masks = self.options.advanced.stuck_stretch_masks
        self.stuck = self.solver is gauss_newton and masks > 0 and np.array_equal(h, start)
        return rotation, h

    def polish(self, rotation, h, log: Log):
        """The refinement levels from (R, h) on the work grid; returns R and h at the full grid's nodes."""
        if self.stuck:
            self.stuck = False
            rotation, h = self.unstick(rotation, h, log)
        objective, work, refine = self.objective, self.work, self.options.refine == "nodes"
        tic = time.perf_counter()
        levels = []
        if refine:
            levels = [
                (work, bspline_basis(k, work.r, work.t), False)
                for k in self.knots
                if k < min(work.first.shape) // 2 and 1.0 / (k - 3) >= self.finest
            ]
            for target in dict.fromkeys((work, objective)):  # the node level of the work grid, then the full one's
                if min(np.diff(target.r).max(), np.diff(target.t).max()) >= self.finest:
                    levels.append((target, None, True))
        source, bound = work, self.max_stretch
        for target, fields, additive in levels:
            if target is not source:
                h, bound = self._enter(h, source, target, rotation, log)
            fields = node_basis(target.r, target.t) if fields is None else fields
            rotation, h = self._refine(target, fields, additive, rotation, h, self._log(target, log), bound)
            source = target
        if source is not objective:
            h, _ = self._enter(h, source, objective, rotation, log)
        if refine:
            log.timings["refine"] = log.timings.get("refine", 0.0) + time.perf_counter() - tic
        return rotation, h

    def _enter(self, h, source: Objective, target: Objective, rotation, log: Log) -> tuple[np.ndarray, float]:
        """:func:`carry` to another level, and the stretch bound there; E on the full grid is kept on arrival.

        The bound is ``max_stretch`` or the stretch of the carried h, whichever is larger: the bicubic upsampling
        of an h within the bound on the coarser grid can exceed it by a few percent on the finer grid's shorter
        edges (its derivative peaks between the coarse nodes), and a start beyond the bound would have to be
        blended toward the identity, losing the coarse answer. So the level starts from the coarse answer itself
        and no step stretches beyond what it already does.
        """
        h = carry(h, source, target)
        bound = self.max_stretch if target.within_stretch(h, self.max_stretch) else target.stretch(h)
        if target is self.objective:
            log.keep("full grid", self.objective.energy(rotation, h))
        return h, bound

    def _refine(self, target: Objective, fields, additive: bool, rotation, h, log: Log, max_stretch: float):
        """One refinement level: Gauss-Newton in ``fields`` on ``target`` within the stretch bound ``max_stretch``,
        alternated with Kabsch.

        The node level of a full grid finer than the work grid has its own iteration cap, tolerance (of its steps
        and of the Kabsch step that starts another round), CG iterations and stretch masks, and its steps are
        charged for the area they hide (``Advanced.fine_*``).
        """
        advanced, fine = self.options.advanced, target is not self.work
        cap = advanced.fine_iterations if fine else advanced.refine_iterations
        steps = self.options.steps(
            max_iterations=min(advanced.max_iterations, cap),
            rel_tol=advanced.fine_rel_tol if fine else advanced.refine_rel_tol,
            cg_iterations=advanced.fine_cg_iterations if fine else advanced.cg_iterations,
            max_stretch=max_stretch,
        )
        masks = advanced.fine_stretch_masks if fine and additive else 0
        charge = advanced.fine_area_charge if fine else 0.0
        solve = partial(gauss_newton, basis=fields, additive=additive, stretch_masks=masks, area_charge=charge)
        rounds = (self.rounds[0], advanced.fine_rel_tol) if fine else self.rounds
        return alternate(target, rotation, h, solve, steps, rounds, log, "refine")

    def from_identity(self, first: GridSurface, second: GridSurface, path: dict, log: Log):
        """Mode "gd": one descent path from R = I and h = id, through the smoothed pairs ``path["smoothing"]``,
        then the original pair and the refinement levels; each level descends in the Riseth bases with KL in
        ``path["bases"]``, one after the other. Returns R and h at the full grid's nodes."""
        rotation, h, previous = np.eye(3), None, None
        if path["smoothing"]:
            with log.clock("smoothing"):
                for sigma in path["smoothing"]:
                    n = level_nodes(sigma, COARSE_NODES)
                    level = Objective(smoothed(first, sigma, n), smoothed(second, sigma, n))
                    h = carry(h, previous, level, self.max_stretch)
                    rotation, h = self._bases(level, rotation, h, path["bases"], log.scratch("smoothing"))
                    previous = level
        h = carry(None, None, self.work) if previous is None else self._enter(h, previous, self.work, rotation, log)[0]
        rotation, h = self.descend(rotation, h, path["bases"], log)
        return self.polish(rotation, h, log)


def gd_paths(options: Options) -> list[dict]:
    """The descent paths of mode "gd": the plain descent in KL = ``basis``; the same after KL = ``start_basis``;
    and that through the scale space ``smoothing``. The last two only when their options ask for them."""
    paths = [{"smoothing": [], "bases": [options.basis]}]
    if options.start_basis < options.basis:
        paths.append({"smoothing": [], "bases": [options.start_basis, options.basis]})
    if options.smoothing:
        paths.append({"smoothing": list(options.smoothing), "bases": paths[-1]["bases"]})
    return paths


def work_objective(objective: Objective, first: GridSurface, second: GridSurface, second_area: float, make=Objective):
    """E on every f-th node of the first grid (at most COARSE_NODES per axis), and the nodes' indices.

    ``objective`` is E on the full grid of ``first`` and ``second``; it is returned itself when the full grid
    is small enough. ``make(first, second, second_area)`` builds the work grid's objective (default
    :class:`~meshreg.objective.Objective`).
    """
    m, n = objective.first.shape
    ir = np.unique(np.r_[np.arange(0, m, -(-(m - 1) // (COARSE_NODES - 1))), m - 1])
    it = np.unique(np.r_[np.arange(0, n, -(-(n - 1) // (COARSE_NODES - 1))), n - 1])
    if len(ir) == m and len(it) == n:
        return objective, (ir, it)
    coarse = GridSurface(first.points[np.ix_(ir, it)], first.r[ir], first.t[it])
    return make(coarse, second, second_area), (ir, it)
