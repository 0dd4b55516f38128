"""The registration pipeline: DP-surface-min, gradient descent and Kabsch, and its result.

Modes
-----
``"dp"``
    DP-surface-min alone (h = (gamma(r), t)), alternated with Kabsch.
``"gd"``
    Descent from R = I and h = id, alternated with Kabsch (the paper's "without DP" runs). A
    descent from the identity settles in the nearest local minimum, which is far from the best one
    when the surfaces have different numbers of folds, and which one it is depends on the path. So
    up to three paths are run and the one ending at the lower E is kept (``params["gd_path"]``):
    the plain descent in the basis KL = ``basis``; the same after a coarser basis KL = ``start_basis``;
    and that through a Gaussian scale space of both surfaces (``smoothing``, :mod:`meshreg.scale`).
``"dp+gd"``
    The paper's method: DP-surface-min, then descent from its R and h, alternated with Kabsch.
``"auto"`` (default)
    Starts (a symmetry of the square for the second surface and a rotation) ranked by a coarse DP
    (:func:`meshreg.search.best_start`); from each start close to the best (``start_margin``,
    ``max_starts``), DP along r and along t (the transposed problem), alternated and composed, then the
    basis descent; the start with the lowest E is refined.

Descent has two stages, each alternated with Kabsch (Steps 2-3 of the paper's outline):
the paper's descent in the Riseth basis (``solver="gauss-newton"``, the gradient preconditioned by
the Gauss-Newton metric, or ``solver="gradient"``, the paper's steepest descent), then, unless
``refine="none"``, a Gauss-Newton refinement in which every grid node of h moves on its own
(:func:`meshreg.fields.node_basis`). The refinement is meshreg's addition: the sine basis cannot
follow reparametrizations like r^0.8 near a side, which left E = 2e-4 to 4e-4 on the paper's
same-shape pairs; with it they reach E < 1e-9. ``refine="none", solver="gradient", smoothing=(),
start_basis=5`` is the paper's procedure as published.

References
----------
Bernal & Lawrence, Section 4 (Simplified Outline of Optimization Procedure, Steps 1-4).
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Callable

import numpy as np

from .descent import DescentParams, descend, gauss_newton
from .diffeo import compose, enforce_boundary, is_valid, jacobian_determinant
from .dp import DEFAULT_DP_ROUNDS, DEFAULT_WINDOW, dp_surface_min
from .fields import bspline_basis, node_basis, riseth_basis
from .errors import InputError
from .grid import GridSurface, read_grid
from .objective import Objective
from .rotation import kabsch
from .scale import level_nodes, smoothed
from .spline import GridInterpolator
from .search import Start, apply_symmetry, best_start, symmetry_map

MODES = ("auto", "dp", "gd", "dp+gd")
DEFAULT_MODE = "auto"
SOLVERS = ("gauss-newton", "gradient")
REFINEMENTS = ("nodes", "none")
# grids with more than DP_FULL_NODES nodes along the DP direction use the coarse-to-fine strip DP, its
# coarse level having about DP_STRIP_NODES nodes
DP_FULL_NODES = 200
DP_STRIP_NODES = 50
START_BLENDS = (0.0, 1e-3, 1e-2, 0.1, 0.5)  # blends toward the identity tried for an invalid descent start
START_MIN_DET = 1e-3  # smallest det J (per cell; its mean is 1) of a descent start
# a symmetry of the square other than the identity must beat it by this fraction (coarse DP energy)
SYMMETRY_MARGIN = 0.05
# auto: starts whose coarse energy is within DEFAULT_START_MARGIN of the best are registered in full (at most
# DEFAULT_MAX_STARTS)
DEFAULT_MAX_STARTS = 3
DEFAULT_START_MARGIN = 0.5
# coarse-to-fine refinement: cubic B-spline fields on 12 and 24 knots per axis, then every node
REFINE_KNOTS = (12, 24)
# the descent and the B-spline refinement run on at most this many nodes per axis
COARSE_NODES = 101
DEFAULT_ROUNDS = 10
DEFAULT_ROUND_TOL = 1e-4

Progress = Callable[[str, int, float], None]


@dataclass(frozen=True)
class Registration:
    """The result of registering two surfaces.

    Attributes
    ----------
    rotation : ndarray, shape (3, 3)
        R, applied to the first surface (det +1).
    h : ndarray, shape (M, N, 2)
        h(r_i, t_j) in [0, 1]^2 at the first surface's nodes; the registered second surface is c2 o h.
    energy : float
        E(h, R) = int int |R q1 - (q2, h)|^2 with both surfaces at area 1 (the squared distance).
    energy_dp : float
        E after the DP stage (NaN when the mode has none).
    energy_history : ndarray, shape (K,)
        E after every accepted descent step and Kabsch step, starting from the initial E (in mode
        "gd", of the path kept; a scale-space path starts at E of the original pair at the end of the
        smoothed levels).
    r : ndarray, shape (M,)
    t : ndarray, shape (N,)
        The first surface's partitions.
    mode : str
    params : dict
        Every parameter that produced the result.
    timings : dict
        Seconds per stage (``search``, ``dp``, ``gd``, ``smoothing`` (mode "gd": the smoothed levels),
        ``refine``, ``total``).
    symmetry : int
        Index into :data:`meshreg.search.SQUARE_SYMMETRIES` of the symmetry of the square applied
        to the second surface first (0: none). h includes it: h = sigma o h', with h' the
        orientation-preserving reparametrization found for the symmetric copy, so h itself
        reverses orientation when sigma does.
    """

    rotation: np.ndarray
    h: np.ndarray
    energy: float
    energy_dp: float
    energy_history: np.ndarray
    r: np.ndarray
    t: np.ndarray
    mode: str
    params: dict = field(default_factory=dict)
    timings: dict = field(default_factory=dict)
    symmetry: int = 0

    @property
    def distance(self) -> float:
        """The elastic shape distance sqrt(E)."""
        return float(np.sqrt(max(self.energy, 0.0)))

    def apply(self, points: np.ndarray) -> np.ndarray:
        """Rotate points (..., 3) of the first surface by R."""
        return np.asarray(points) @ self.rotation.T

    def save(self, path, **extra) -> None:
        """Write the result to ``path`` (``.npz``; keys as in architecture.md), plus ``extra`` arrays."""
        np.savez(
            path,
            **extra,
            R=self.rotation,
            h=self.h,
            energy=self.energy,
            distance=self.distance,
            energy_dp=self.energy_dp,
            energy_history=self.energy_history,
            r=self.r,
            t=self.t,
            mode=self.mode,
            params=json.dumps(self.params),
            timings=json.dumps(self.timings),
            symmetry=self.symmetry,
        )

    @classmethod
    def load(cls, path) -> "Registration":
        """Read a result written by :meth:`save`."""
        try:
            with np.load(path, allow_pickle=False) as data:
                return cls(
                    rotation=data["R"],
                    h=data["h"],
                    energy=float(data["energy"]),
                    energy_dp=float(data["energy_dp"]),
                    energy_history=data["energy_history"],
                    r=data["r"],
                    t=data["t"],
                    mode=str(data["mode"]),
                    params=json.loads(str(data["params"])),
                    timings=json.loads(str(data["timings"])),
                    symmetry=int(data["symmetry"]) if "symmetry" in data else 0,
                )
        except (OSError, KeyError, ValueError) as err:
            raise InputError(f"{path}: not a meshreg result file ({err})") from None


def as_surface(surface) -> GridSurface:
    """A GridSurface from a GridSurface, an (M, N, 3) array, or a grid file path."""
    if isinstance(surface, GridSurface):
        return surface
    if isinstance(surface, (str, Path)):
        return read_grid(surface)
    return GridSurface.from_array(surface)


def register(
    first,
    second,
    mode: str = DEFAULT_MODE,
    *,
    window: int = DEFAULT_WINDOW,
    dp_rounds: int = DEFAULT_DP_ROUNDS,
    solver: str = "gauss-newton",
    refine: str = "nodes",
    max_rounds: int = DEFAULT_ROUNDS,
    round_tol: float = DEFAULT_ROUND_TOL,
    descent: DescentParams | None = None,
    search: bool = True,
    symmetries: bool = True,
    max_starts: int = DEFAULT_MAX_STARTS,
    start_margin: float = DEFAULT_START_MARGIN,
    callback: Progress | None = None,
    **descent_params,
) -> Registration:
    """Register two grid surfaces: rotate the first, reparametrize the second.

    Parameters
    ----------
    first, second : GridSurface, ndarray (M, N, 3) or path
        The surfaces; grid sizes may differ. Both are scaled to area 1.
    mode : {"auto", "dp", "gd", "dp+gd"}
        See the module docstring. Default "auto".
    window : int
        DP window W (steps (dk, dl) with 1 <= dk, dl <= W). Default 10.
    dp_rounds : int
        Most DP + Kabsch rounds (and most r/t passes in "auto"). Default 10.
    solver : {"gauss-newton", "gradient"}
        Descent direction in the Riseth basis. Default "gauss-newton".
    refine : {"nodes", "none"}
        Node-wise Gauss-Newton refinement after the basis descent. Default "nodes".
    max_rounds : int
        Most descent + Kabsch rounds per stage (Step 3 of the outline). Default 10.
    round_tol : float
        Rounds stop when the Kabsch step after a descent lowers E by less than ``round_tol * E``.
        Default 1e-4.
    search : bool
        In "auto": rank starting rotations (Kabsch at the identity, the cube's 24 rotations, the
        principal axes) by a coarse DP before the DP stage (:func:`meshreg.search.best_start`).
        Default True.
    symmetries : bool
        In "auto" with ``search``: also try the 8 symmetries of the square as a first
        reparametrization of the second surface. Default True.
    max_starts, start_margin : int, float
        In "auto" with ``search``: the best-ranked start and every other whose coarse DP energy is within
        ``start_margin`` (relative) of it, at most ``max_starts`` in all, are each registered in full; the
        lowest E wins (a start ranked higher keeps a near tie, within 5%). The coarse ranking alone picked
        the wrong one of two close starts on nearly symmetric meshes (E 0.014 where the runner-up gave
        0.0044). Defaults 3 and 0.5; ``max_starts=1`` registers the best-ranked start only.
    descent : DescentParams, optional
        Descent parameters; keyword arguments named like its fields (``basis``, ``rel_tol``, ...)
        override single fields.
    callback : callable, optional
        ``callback(stage, iteration, E)`` after every accepted step (stage "dp", "gd", "refine"
        or "kabsch").

    Returns
    -------
    Registration

    Examples
    --------
    >>> from meshreg.samples import paper_pairs
    >>> pair = paper_pairs(31, 31)[0]
    >>> result = register(pair.first, pair.second, mode="dp")
    >>> result.energy < 0.01
    True
    """
    for name, value, allowed in (("mode", mode, MODES), ("solver", solver, SOLVERS), ("refine", refine, REFINEMENTS)):
        if value not in allowed:
            raise InputError(f"unknown {name} {value!r}: choose one of {', '.join(allowed)}")
    if window < 1:
        raise InputError("window must be a positive integer")
    if max_starts < 1 or not start_margin >= 0:
        raise InputError("max_starts must be at least 1 and start_margin at least 0")
    try:
        descent = DescentParams(**{**asdict(descent or DescentParams()), **descent_params})
    except TypeError as err:
        raise InputError(f"unknown parameter: {err}") from None
    if not all(np.isfinite(s) and s > 0 for s in descent.smoothing):
        raise InputError(f"smoothing must be positive standard deviations, got {descent.smoothing}")
    start = time.perf_counter()
    first, second = as_surface(first), as_surface(second)
    second_area = second.area()
    timings = {}
    starts = [Start(0, None, float("nan"))]
    if mode == "auto" and search:
        tic = time.perf_counter()
        starts = _close_starts(best_start(first, second, symmetries=symmetries), max_starts, start_margin)
        timings["search"] = time.perf_counter() - tic
    notify = callback or (lambda stage, iteration, e: None)
    settings = (mode, window, dp_rounds, descent, solver, refine, max_rounds, round_tol, notify)
    runs = [_solve(first, apply_symmetry(second, s.symmetry), second_area, s.rotation, settings, timings) for s in starts]
    # the lowest E after the basis descent wins, near ties (within SYMMETRY_MARGIN) going to the better-ranked
    # start; only the winner is refined (on the paper's pairs and nearly symmetric meshes the order of the starts
    # by this E was the order by their refined E, but for near ties)
    lowest = min(run["energy"] for run in runs)
    chosen = next(k for k, run in enumerate(runs) if run["energy"] <= (1.0 + SYMMETRY_MARGIN) * lowest + descent.abs_tol)
    _polish(runs[chosen])
    run, symmetry = runs[chosen], starts[chosen].symmetry
    objective, rotation, energy = run["objective"], run["rotation"], run["energy"]
    h = symmetry_map(symmetry, run["h"])
    timings["total"] = time.perf_counter() - start
    params = {
        "mode": mode,
        "window": window,
        "dp_rounds": dp_rounds,
        "solver": solver,
        "refine": refine,
        "max_rounds": max_rounds,
        "round_tol": round_tol,
        **asdict(descent),
        "smoothing": list(descent.smoothing),  # a list, as it reads back from result.npz's JSON
        "search": search,
        "symmetries": symmetries,
        "gd_path": run["gd_path"],
        "max_starts": max_starts,
        "start_margin": start_margin,
        "starts": [{"symmetry": st.symmetry, "coarse_energy": None if np.isnan(st.energy) else float(st.energy),
                    "energy": float(r["energy"]), "refined": r is run}
                   for st, r in zip(starts, runs)],
        "grid_first": list(objective.first.shape),
        "grid_second": list(objective.second.shape),
    }
    return Registration(
        rotation=rotation,
        h=h,
        energy=energy,
        energy_dp=run["energy_dp"],
        energy_history=np.array(run["history"]),
        r=objective.r,
        t=objective.t,
        mode=mode,
        params=params,
        timings=timings,
        symmetry=symmetry,
    )


def _close_starts(starts: list[Start], max_starts: int, margin: float) -> list[Start]:
    """The ranked starts worth a full registration: the best, then those whose coarse energy is within
    ``margin`` of it (at most ``max_starts``). The identity symmetry goes first when it is within
    SYMMETRY_MARGIN of the best (ties, as on surfaces with a mirror symmetry, keep the given parametrization)."""
    best = starts[0]
    identity = next(s for s in starts if s.symmetry == 0)
    if identity.energy <= (1.0 + SYMMETRY_MARGIN) * best.energy:
        starts = [identity] + [s for s in starts if s is not identity]
    close = [s for s in starts if s.energy <= (1.0 + margin) * best.energy or s is starts[0]]
    return close[:max_starts]


def _solve(first: GridSurface, second: GridSurface, second_area: float, start_rotation, settings, timings: dict) -> dict:
    """The DP stage and the basis descent of one registration (``second`` already under its start's symmetry).

    Mode "gd" runs its paths to the end here; otherwise :func:`_polish` runs the refinement. Stage times are
    added to ``timings``. Returns a dict with objective, rotation, h (in ``second``'s parametrization; on
    the work grid until polished), energy, energy_dp, history, gd_path and the descent driver (None once
    nothing is left to do).
    """
    mode, window, dp_rounds, descent, solver, refine, max_rounds, round_tol, notify = settings
    objective = Objective(first, second, second_area)
    run = {"objective": objective, "rotation": np.eye(3), "h": objective.identity.copy(), "energy_dp": float("nan"),
           "history": [], "gd_path": None, "drive": None}
    if mode != "gd":
        tic = time.perf_counter()
        run["rotation"], run["h"], run["energy_dp"] = _dp_stage(objective, window, dp_rounds, mode == "auto", start_rotation)
        run["history"].append(run["energy_dp"])
        notify("dp", 0, run["energy_dp"])
        timings["dp"] = timings.get("dp", 0.0) + time.perf_counter() - tic
    if mode == "dp":
        run["energy"] = objective.energy(run["rotation"], run["h"])
        return run
    # descent on a grid of at most COARSE_NODES nodes per axis, then node refinement on the full grid
    work, nodes = _coarse_objective(objective, first, second, second_area)
    drive = _Descent(objective, work, descent, solver, refine, max_rounds, round_tol, notify, timings)
    if mode == "gd":
        paths = _gd_paths(descent)
        ends = [drive.from_identity(first, second, path["smoothing"], path["bases"]) for path in paths]
        energies = [objective.energy(R, hh) for R, hh, _ in ends]
        best = int(np.argmin(energies))
        run["rotation"], run["h"], run["history"] = ends[best]
        run["gd_path"], run["energy"] = paths[best], energies[best]
        return run
    h_start = _valid_start(objective, run["h"])[np.ix_(*nodes)]
    run["rotation"], run["h"] = drive.descend(run["rotation"], h_start, [descent.basis], run["history"])
    run["energy"] = work.energy(run["rotation"], run["h"])
    run["drive"] = drive
    return run


def _polish(run: dict) -> dict:
    """The refinement of a :func:`_solve` run (nothing when it is finished); ``run`` updated and returned."""
    if run["drive"] is not None:
        run["rotation"], run["h"] = run["drive"].polish(run["rotation"], run["h"], run["history"])
        run["energy"] = run["objective"].energy(run["rotation"], run["h"])
        run["drive"] = None
    run["history"] = run["history"] or [run["energy"]]
    return run


def _coarse_objective(objective: Objective, first: GridSurface, second: GridSurface, second_area: float):
    """The objective on every f-th node of the first grid (at most COARSE_NODES per axis) and the node indices."""
    m, n = objective.first.shape
    ir = np.unique(np.r_[np.arange(0, m, -(-(m - 1) // (COARSE_NODES - 1))), m - 1])
    it = np.unique(np.r_[np.arange(0, n, -(-(n - 1) // (COARSE_NODES - 1))), n - 1])
    if len(ir) == m and len(it) == n:
        return objective, (ir, it)
    coarse = GridSurface(first.points[np.ix_(ir, it)], first.r[ir], first.t[it])
    return Objective(coarse, second, second_area), (ir, it)


def _upsample(h: np.ndarray, coarse: Objective, fine: Objective) -> np.ndarray:
    """h from the coarse grid's nodes to the fine grid's (bicubic), sides kept exact."""
    value = GridInterpolator(h, coarse.r, coarse.t)(fine.identity[..., 0], fine.identity[..., 1])[0]
    return enforce_boundary(value)


class _Descent:
    """Steps 2-3 of the outline on one pair: the basis descent, then the refinement levels, each alternated
    with Kabsch; ``timings`` adds up the seconds per stage over every call."""

    def __init__(self, objective, work, params, solver, refine, max_rounds, round_tol, notify, timings: dict):
        self.objective, self.work, self.params = objective, work, params
        self.step = descend if solver == "gradient" else gauss_newton
        self.refine, self.rounds, self.notify = refine, (max_rounds, round_tol), notify
        self.timings = timings

    def _clock(self, stage: str, tic: float) -> None:
        self.timings[stage] = self.timings.get(stage, 0.0) + time.perf_counter() - tic

    @staticmethod
    def _track(stage, history, notify):
        return lambda i, e: (history.append(e), notify(stage, i, e))

    def _bases(self, target, rotation, h, bases, history, notify):
        """Descend on ``target`` in the Riseth bases with KL in ``bases``, one after the other."""
        for kl in bases:
            basis = riseth_basis(kl, target.r, target.t)
            stage = lambda o, R, hh, p, cb, b=basis: self.step(o, R, hh, p, b, cb)  # noqa: E731
            track = self._track("gd", history, notify)
            rotation, h = _alternate(target, rotation, h, stage, self.params, *self.rounds, history, track, notify)
        return rotation, h

    def run(self, rotation, h, bases, history):
        """:meth:`descend`, then :meth:`polish`."""
        rotation, h = self.descend(rotation, h, bases, history)
        return self.polish(rotation, h, history)

    def descend(self, rotation, h, bases, history):
        """Descend from (R, h) on the work grid (h at its nodes) in the Riseth bases KL in ``bases``.

        E is appended to ``history`` when the work grid is the full grid. Returns R and h on the work grid.
        """
        tic = time.perf_counter()
        work_history = history if self.work is self.objective else []
        rotation, h = self._bases(self.work, rotation, h, bases, work_history, self.notify)
        self._clock("gd", tic)
        return rotation, h

    def polish(self, rotation, h, history):
        """The refinement levels from (R, h) on the work grid; E on the full grid appended to ``history``.

        Returns R and h at the full grid's nodes.
        """
        objective, work = self.objective, self.work
        tic = time.perf_counter()
        if self.refine == "nodes":
            work_history = history if work is objective else []
            for k in REFINE_KNOTS:
                if k < min(work.first.shape) // 2:
                    rotation, h = self._refine(work, bspline_basis(k, work.r, work.t), False, rotation, h, work_history)
        if work is not objective:
            h = _upsample(h, work, objective)
            history.append(objective.energy(rotation, h))
        if self.refine == "nodes":
            rotation, h = self._refine(objective, node_basis(objective.r, objective.t), True, rotation, h, history)
            self._clock("refine", tic)
        return rotation, h

    def _refine(self, target, fields, additive, rotation, h, history):
        """One refinement level: Gauss-Newton in ``fields`` on ``target``, alternated with Kabsch."""
        descent = self.params
        stage = lambda o, R, hh, p, cb: gauss_newton(o, R, hh, p, fields, cb, additive=additive)  # noqa: E731
        cap = descent.refine_iterations if target is self.work else descent.fine_iterations
        params = replace(descent, max_iterations=min(descent.max_iterations, cap), rel_tol=descent.refine_rel_tol)
        return _alternate(target, rotation, h, stage, params, *self.rounds, history, self._track("refine", history, self.notify), self.notify)

    def from_identity(self, first: GridSurface, second: GridSurface, sigmas, bases):
        """Mode "gd": from R = I and h = id through the smoothed pairs ``sigmas``, then :meth:`run`.

        Each level starts from the previous level's R and h and descends in the Riseth bases with KL in
        ``bases``, one after the other.

        Returns
        -------
        rotation, h, history
        """
        rotation, h, previous = np.eye(3), None, None
        tic = time.perf_counter()
        relabel = lambda stage, i, e: self.notify("smoothing", i, e)  # noqa: E731
        for sigma in sigmas:
            n = level_nodes(sigma, COARSE_NODES)
            level = Objective(smoothed(first, sigma, n), smoothed(second, sigma, n))
            h = _carried(h, previous, level)
            rotation, h = self._bases(level, rotation, h, bases, [], relabel)
            previous = level
        if sigmas:
            self._clock("smoothing", tic)
        history = []
        rotation, h = self.run(rotation, _carried(h, previous, self.work), bases, history)
        return rotation, h, history


def _carried(h, previous: Objective | None, target: Objective) -> np.ndarray:
    """A descent start on ``target``: h from ``previous``'s grid upsampled and made valid, or the identity
    when there is no h yet."""
    if h is None:
        return target.identity.copy()
    return _valid_start(target, _upsample(h, previous, target))


def _gd_paths(descent: DescentParams) -> list[dict]:
    """The descent paths of mode "gd": the plain descent in KL = ``basis``; the same after KL = ``start_basis``;
    and that through the scale space ``smoothing``. The last two only when their parameters ask for them."""
    paths = [{"smoothing": [], "bases": [descent.basis]}]
    if descent.start_basis < descent.basis:
        paths.append({"smoothing": [], "bases": [descent.start_basis, descent.basis]})
    if descent.smoothing:
        paths.append({"smoothing": list(descent.smoothing), "bases": paths[-1]["bases"]})
    return paths


def _dp_along(objective: Objective, rotation, h, window, dp_rounds, along_t: bool):
    """One DP-surface-min pass on (q1, (q2, h)) along r or t; returns R, h o (gamma step), E."""
    q1, q2 = objective.q1, objective.second_on_first_grid(h)
    r, t = objective.r, objective.t
    if along_t:
        q1, q2, r, t = q1.transpose(1, 0, 2), q2.transpose(1, 0, 2), t, r
    coarsen = len(r) // DP_STRIP_NODES if len(r) > DP_FULL_NODES else 1
    result = dp_surface_min(q1, q2, r, r, t, window=window, max_rounds=dp_rounds, rotation=rotation, coarsen=coarsen)
    step = objective.identity.copy()
    if along_t:
        step[..., 1] = result.gamma[None, :]
    else:
        step[..., 0] = result.gamma[:, None]
    h = step if h is None else compose(h, objective.r, objective.t, step)
    return result.rotation, h, objective.energy(result.rotation, h)


def _valid_start(objective: Objective, h: np.ndarray) -> np.ndarray:
    """h itself when every cell keeps det J >= START_MIN_DET, else the least blend (1 - eps) h + eps id that does.

    The descent needs an orientation-preserving start: a DP path that is flat in places (gamma' = 0) gives
    cells of zero area, where no step can be accepted.
    """
    for eps in START_BLENDS:
        blended = (1.0 - eps) * h + eps * objective.identity
        if is_valid(blended) and jacobian_determinant(blended, objective.r, objective.t).min() >= START_MIN_DET:
            return blended
    return objective.identity.copy()


def _dp_stage(objective: Objective, window: int, dp_rounds: int, both: bool, rotation=None):
    """DP-surface-min along r (the paper); with ``both``, alternate passes along t and r while E drops.

    The DP starts from ``rotation``, or from Kabsch at the identity when it is None.
    """
    rotation, h, energy = _dp_along(objective, rotation, None, window, dp_rounds, along_t=False)
    if both:
        for p in range(2 * dp_rounds):
            new_rotation, new_h, new_energy = _dp_along(objective, rotation, h, window, dp_rounds, along_t=p % 2 == 0)
            if not is_valid(new_h):  # composing the two directions' steps can collapse cells: keep the last valid h
                break
            if new_energy >= energy * (1 - DEFAULT_ROUND_TOL):
                if new_energy < energy:
                    rotation, h, energy = new_rotation, new_h, new_energy
                break
            rotation, h, energy = new_rotation, new_h, new_energy
    return rotation, h, energy


def _alternate(objective, rotation, h, stage, params, max_rounds, round_tol, history, on_step, notify):
    """Steps 2-3 of the outline: descent in h, then Kabsch in R, until Kabsch stops helping."""
    if not history:
        history.append(objective.energy(rotation, h))
    for _ in range(max_rounds):
        state = stage(objective, rotation, h, params, on_step)
        h = state.h
        if state.rotation is not None:
            rotation = state.rotation
        new_rotation = kabsch(objective.best_rotation_covariance(h))
        new_energy = objective.energy(new_rotation, h)
        if new_energy < state.energy:
            rotation = new_rotation
            history.append(new_energy)
            notify("kabsch", 0, new_energy)
        energy = min(new_energy, state.energy)
        # Step 3: another round only when Kabsch lowered E by much (E_L = E after the descent)
        if energy <= params.zero_energy or state.energy - energy < round_tol * state.energy + params.abs_tol:
            break
    return rotation, h


def register_symmetric(first, second, mode: str = DEFAULT_MODE, **params) -> tuple[Registration, Registration]:
    """Register both ways: (first rotated, second reparametrized) and (second rotated, first reparametrized).

    E is not symmetric in its arguments once discretized and minimized locally; the two energies
    show how far from symmetric it is for a pair. Parameters as for :func:`register`.

    Returns
    -------
    forward, backward : Registration
    """
    first, second = as_surface(first), as_surface(second)
    return register(first, second, mode, **params), register(second, first, mode, **params)
