"""Every setting of a registration, in one typed, validated object, and the table the command line is built from.

:class:`Options` holds what a user sets (the mode, the DP window, the basis, the mesh preparation) and
:class:`Advanced` the rare numerics (tolerances, iteration caps). Both are frozen dataclasses checked once, when
they are made: an invalid value raises :class:`~meshreg.errors.InputError` naming the valid range. The same
object travels from the command line (or the API, the adapters, the distance matrix) to the solvers.

:data:`meshreg.flags.FLAGS` is the command line's view of these fields: one row per flag, from which the argparse
options are built and read back, so the flags cannot drift from the fields. Adding an option is one field here plus
one row in :data:`meshreg.flags.FLAGS` (and, for a registration option, a keyword of :func:`meshreg.register`).

Examples
--------
>>> opts = Options(mode="dp+gd", window=8)
>>> opts.window, opts.advanced.max_rounds
(8, 10)
>>> Options(window=0)
Traceback (most recent call last):
...
meshreg.errors.InputError: window must be an integer from 1 to ..., got 0
"""

from __future__ import annotations

import math
import re
from dataclasses import asdict, dataclass, field, fields, replace

from .errors import InputError
from .limits import check_grids, check_static

MODES = ("auto", "dp", "gd", "dp+gd")
SOLVERS = ("gauss-newton", "gradient")
REFINEMENTS = ("nodes", "none")
WEIGHTS = ("mean-value", "cotangent")
OVERLAPS = ("auto", "off")
MAX_BASIS = 40  # KL beyond this gives 2 (KL + 2 KL^2) > 6000 fields: more than any grid here resolves
MAX_WINDOW = 10_000
MESH_BLUR_DEFAULT = 2.0  # Options.mesh_blur


@dataclass(frozen=True)
class StepParams:
    """Numerics of one descent round (:func:`meshreg.descent.descend`, :func:`meshreg.descent.gauss_newton`).

    Attributes
    ----------
    basis : int
        KL of the Riseth basis (2 (KL + 2 KL^2) fields) when no basis is given. Default 5 (110 fields).
    max_iterations : int
        Most iterations per round (between two Kabsch steps). Default 200.
    rel_tol, abs_tol : float
        A round stops when an iteration lowers E by less than ``rel_tol * E + abs_tol``. Defaults 1e-3, 1e-9.
    grad_tol : float
        A round stops when the L^2 norm of the gradient is below this. Default 1e-10.
    zero_energy : float
        E at or below this counts as zero: stop. Default 1e-10.
    step_fraction : float
        The step starts at this fraction of the det / Gale-Nikaido bound. Default 0.5.
    max_backtracks : int
        Most halvings of the step (or increases of the damping) in one iteration. Default 30.
    damping : float
        Initial Levenberg-Marquardt damping of the Gauss-Newton solver. Default 1e-3.
    cg_iterations : int
        Most conjugate-gradient iterations of a Gauss-Newton step in a local basis. Default 100.
    max_stretch : float
        Modes "auto" and "dp+gd": no descent step may stretch an edge of the first grid by more than this factor
        both in the square and on the surfaces (:meth:`meshreg.objective.Objective.stretch`). Default 10
        (docs/method.md, "Stretch bound").
    """

    basis: int = 5
    max_iterations: int = 200
    rel_tol: float = 1e-3
    abs_tol: float = 1e-9
    grad_tol: float = 1e-10
    zero_energy: float = 1e-10
    step_fraction: float = 0.5
    max_backtracks: int = 30
    damping: float = 1e-3
    cg_iterations: int = 100
    max_stretch: float = 10.0


@dataclass(frozen=True)
class Advanced:
    """The rare numerics of a registration (defaults suit grids of 21 to 401 nodes per axis).

    Attributes
    ----------
    dp_rounds : int
        Most DP + Kabsch rounds of a DP pass; in mode "auto" also half the most passes along t and r that follow the
        first pass along r. Default 10.
    dp_radius : int
        Mode "auto", grids of at most 200 nodes along the DP's direction: the passes along r and t after the first
        pass each way search only within this many nodes of the identity path (h is aligned by then), and the
        whole table again when a path reaches the edge of that band; 0 searches the whole table in every pass.
        Default 20 (twice the default window): on the paper's pairs every path is the one of the whole table; on
        pairs of different shapes whose passes creep on for 10-20 alternations each pass costs about half.
    max_rounds : int
        Most descent + Kabsch rounds per stage (Step 3 of the paper's outline). Default 10.
    round_tol : float
        Rounds stop when the Kabsch step after a descent lowers E by less than ``round_tol * E``. Default 1e-4.
    start_margin : float
        Mode "auto": starts whose coarse DP energy is within this fraction of the best one are registered in
        full (at most ``Options.max_starts``). Default 0.5.
    max_iterations, rel_tol, abs_tol, grad_tol, zero_energy, step_fraction, max_backtracks, damping, cg_iterations,
    max_stretch
        Numerics of each descent round: see :class:`StepParams`. ``abs_tol`` defaults to 1e-9 because E itself
        is only accurate to about 1e-9 on 101 x 101 grids (the exact h of the paper's same-shape pairs gives
        E = 4e-10 to 2e-9).
    refine_iterations : int
        Most iterations per round of each refinement level (cubic B-spline bases of 12 and 24 functions per axis,
        and the node basis). Default 10.
    fine_iterations : int
        On grids above 101 nodes per axis, most node-refinement iterations per round on the full grid, after the
        whole schedule on the coarse work grid (its node level included). Default 5.
    fine_rel_tol : float
        ``rel_tol`` and ``round_tol`` of that node level on the full grid: its rounds stop at the first Gauss-Newton
        step that lowers E by less than this fraction, and another round follows only when Kabsch lowers E by more
        (Gauss-Newton moves R too: on a terrain pair at 401 x 401 Kabsch gained 0.02% after each round, and four
        rounds of one step each took 4 s). Default 0.05: at 401 x 401 one step costs about as much as the whole
        101 x 101 schedule, and on the paper's sine 2-3 pair the second step gained 0.8%; same-shape pairs, whose E
        falls by orders of magnitude per step, are not affected.
    fine_cg_iterations : int
        Most conjugate-gradient iterations of a Gauss-Newton step of that node level (``cg_iterations`` elsewhere).
        Default 30: the start carried from the coarse grid is already close, so the step is a local correction.
    fine_stretch_masks : int
        That node level: a step that stretches some edges beyond the bound is not refused whole; the move is
        dropped at those edges' nodes, up to this many times (:func:`meshreg.descent.gauss_newton`). Default 3.
    stuck_stretch_masks : int
        Modes "auto" and "dp+gd", Gauss-Newton: when the descent from a DP answer accepts no step at all (every step
        that lowers E breaks the stretch bound: the DP path lies on it) and that start is the one chosen for
        refinement, it first descends again with a step's move dropped at the offending edges' nodes up to this many
        times instead of the step being refused, its steps charged for the area they hide (``fine_area_charge``), for
        at most ``stuck_iterations`` steps in ``stuck_rounds`` rounds; the DP answer is kept when that ends on the
        mirror image of the second surface. The refinement levels then run as for any start. 0 = off: such a start
        keeps its DP answer. Default 3. On the 190 pairs of ``benchmarks/bench_matrix.py``'s ``collection(20, 101)``
        (43 answers were DP answers with 0), with the defaults: mean E 0.878 -> 0.850, median 0.881 -> 0.866, 46 pairs
        more than 1% lower (up to 60%; the 11 checked on 401 x 401 samplings lower there too), none higher; the
        matrix (jobs=2) at 1.72, 1.45, 1.58, 1.78 pairs/s against 1.52, 1.57, 1.54, 1.72 with 0, alternating. Paper
        pairs: same-shape ones identical; sine2-3 g1/g2 0.3074 -> 0.3054 (but 0.3444 -> 0.3463 measured on 401 x
        401), sine2-4 g2 0.5145 -> 0.5135 (401: 0.5296 -> 0.5251). Masking every stuck candidate (191 of 502), not
        only the chosen one, and refining with masks too, the mean reached 0.826 but the matrix took 1.7x as long;
        the chosen one alone, masked without a cap, 0.844 at 0.87-0.91x the pairs/s; without the mirror check
        collection pair 1-19 ended 7.9% higher.
    stuck_iterations : int
        Most Gauss-Newton steps per round of that masked descent. Default 3 (a plain descent after 3 masked steps
        accepted a step from 1 of 191 stuck candidates: the answer stays on the bound, so none follows).
    stuck_rounds : int
        Most rounds (descent, then Kabsch) of that masked descent. Default 1.
    fine_area_charge : float
        That node level: a step must lower E + k (1 - A), A the share of the second surface's area that the chords
        of the cells carry (:meth:`meshreg.objective.Objective.carried_area`; 1 in the continuum for every h), k this
        charge. The stretch bound alone does not stop a fine grid from hiding folds of the second surface in its
        cells: on sine2-4 g1 at 201 x 201 one node step lowered E there from 0.514 to 0.495 by losing 2.6% of the
        area, and raised E on 401 x 401 from 0.520 to 0.553; on sine2-4 g2 a step losing 1.3% of the area for a
        1.65% drop of E still raised E on 401 x 401 (0.530 to 0.539), so k = 1 (E + 1 - A = 2 - 2 <R q1, (q2, h)>)
        is not enough. Default 2: a step must lower E by more than twice the area it hides. 0 switches it off.
    refine_rel_tol : float
        ``rel_tol`` of the refinement levels. Default 1e-2: on the paper's different-shape pairs the levels
        otherwise spend two thirds of their time on 0.2% steps; same-shape pairs, whose E falls by orders of
        magnitude, are not affected.
    choice_window : float
        Meshes with ``Options.bend_window`` > 0: width (side lengths of the square) of the windows of E_w that
        ranks the symmetries of the square and the corner placements of round boundaries
        (:mod:`meshreg.bending`). Wider windows see larger relief (more telling) but charge more of the bending.
        Default 0.1: on the benchmark's pairs (docs/bending.md) the right symmetry's E_w is below the next one's by
        a factor of 1.23 (fold) to 31 (remeshed sheet); with 0.2 the fold's factor is 1.09.
    refine_triangles : float
        Meshes with ``Options.bend_window`` > 0: the refinement levels run only at scales (B-spline knot
        spacing; grid spacing for the node level) of at least this many triangles (the mean of both meshes'
        median edge lengths on the square). Finer, h fits the difference between two triangulations of one
        surface rather than the correspondence. Default 6: sheets of 2500 vertices are not refined (refining
        raised their error by 10 to 40%), a dense face scan (15000 and 47000 vertices) is refined to B-spline
        knots 0.048 apart (its error fell from 0.005 to 0.002); docs/bending.md.
    ambiguity : float
        Mode "auto": another correspondence counts as equally good (``result.alternatives``) when its distance
        sqrt(E) and its coordinate residual (both lengths on area-1 surfaces) exceed the chosen one's by at most
        this. Default 0.01 (1% of sqrt(area)): the refined symmetric twins of the answer on meshes of symmetric
        sheets with two random triangulations came within 0.006 in distance and 0.0015 in residual (exact
        twins on exactly sampled grids are equal), while the best twin of a terrain against its mirror image,
        a different shape, was 0.24 further.
    overlap_quick : float
        Meshes with ``Options.overlap`` "auto": before the feature search for a pose (FPFH + RANSAC), the meshes
        are taken to cover the same region (overlap regime "full", registered whole, then held to the pose if the
        answer does not fit the points: docs/overlap.md) when, at the pose of their principal axes refined by ICP,
        at most this fraction of each one's area (2000 random points spread evenly) lies beyond the other's rim and
        90% of the rest coincides with the other mesh (:func:`meshreg.mesh.overlap.same_region`). At most 0.02
        (the tolerance of the full check); 0 = always the feature search. Default 0.01: two random triangulations
        of one terrain patch leave 0.04% and 0.002% beyond the rims, a crop of 3% is not mistaken for the whole.
        Saves 1-1.5 s on two 100k-triangle meshes.
    processes : int
        Processes one registration may keep busy at once. With 2, a pair of meshes (together at least
        ``meshreg.mesh.correspond.FORK_FACES`` triangles) gets its corners and maps to the square computed in a
        forked child while the caller checks the overlap (:class:`meshreg.forked.Forked`: on Linux, when a core is
        idle, not inside a daemonic process nor while other Python threads run; the answer is the serial one). 1 =
        all in the calling process. Default 2. The distance matrix runs its pairs with 1 (its workers already keep
        every core busy).
    """

    dp_rounds: int = 10
    dp_radius: int = 20
    max_rounds: int = 10
    round_tol: float = 1e-4
    start_margin: float = 0.5
    max_iterations: int = StepParams.max_iterations
    rel_tol: float = StepParams.rel_tol
    abs_tol: float = StepParams.abs_tol
    grad_tol: float = StepParams.grad_tol
    zero_energy: float = StepParams.zero_energy
    step_fraction: float = StepParams.step_fraction
    max_backtracks: int = StepParams.max_backtracks
    damping: float = StepParams.damping
    cg_iterations: int = StepParams.cg_iterations
    max_stretch: float = StepParams.max_stretch
    refine_iterations: int = 10
    fine_iterations: int = 5
    fine_rel_tol: float = 0.05
    fine_cg_iterations: int = 30
    fine_stretch_masks: int = 3
    stuck_stretch_masks: int = 3
    stuck_iterations: int = 3
    stuck_rounds: int = 1
    fine_area_charge: float = 2.0
    refine_rel_tol: float = 1e-2
    choice_window: float = 0.1
    refine_triangles: float = 6.0
    ambiguity: float = 0.01
    overlap_quick: float = 0.01
    processes: int = 2

    def __post_init__(self):
        _integer("dp_radius", self.dp_radius, 0, 1_000_000)
        for name in (
            "dp_rounds",
            "max_rounds",
            "max_iterations",
            "max_backtracks",
            "cg_iterations",
            "refine_iterations",
            "fine_iterations",
            "fine_cg_iterations",
        ):
            _integer(name, getattr(self, name), 1, 1_000_000)
        _integer("fine_stretch_masks", self.fine_stretch_masks, 0, 1_000_000)
        _integer("stuck_stretch_masks", self.stuck_stretch_masks, 0, 1_000_000)
        _integer("stuck_iterations", self.stuck_iterations, 1, 1_000_000)
        _integer("stuck_rounds", self.stuck_rounds, 1, 1_000_000)
        _integer("processes", self.processes, 1, 2)
        for name in (
            "round_tol",
            "rel_tol",
            "abs_tol",
            "grad_tol",
            "zero_energy",
            "refine_rel_tol",
            "fine_rel_tol",
            "fine_area_charge",
            "damping",
            "start_margin",
            "ambiguity",
        ):
            _number(name, getattr(self, name), 0.0, math.inf)
        _number("step_fraction", self.step_fraction, 0.0, 1.0, low_open=True)
        _number("choice_window", self.choice_window, 0.0, 1.0, low_open=True)
        _number("refine_triangles", self.refine_triangles, 0.0, math.inf)
        _number("overlap_quick", self.overlap_quick, 0.0, 0.02)
        _number("max_stretch", self.max_stretch, 1.0, math.inf)

    def steps(self, basis: int, **changes) -> StepParams:
        """The :class:`StepParams` of a descent round in the basis KL = ``basis`` (``changes`` override fields)."""
        names = [f.name for f in fields(StepParams) if f.name != "basis"]
        return StepParams(basis=basis, **{**{n: getattr(self, n) for n in names}, **changes})


@dataclass(frozen=True)
class Options:
    """Every setting of a registration; validated when made.

    Attributes
    ----------
    mode : {"auto", "dp", "gd", "dp+gd"}
        How to register (see :mod:`meshreg.pipeline`). Default "auto".
    window : int
        DP window W: steps (dk, dl) with 1 <= dk, dl <= W. Default 10.
    basis : int
        KL of the Riseth basis of the descent (2 (KL + 2 KL^2) fields). Default 5 (110 fields).
    solver : {"gauss-newton", "gradient"}
        Direction of the basis descent: Gauss-Newton (moves R and h together) or the paper's steepest
        descent. Default "gauss-newton".
    refine : {"nodes", "none"}
        After the basis descent, refine in B-spline bases and then node by node. Default "nodes".
    search : bool
        Mode "auto": rank starting rotations and symmetries of the square by a coarse DP. Default True.
    symmetries : bool
        Mode "auto" with ``search``: also try the 8 symmetries of the square on the second surface. Default True.
    keep_orientation : bool
        Mode "auto" with ``symmetries``: try only the 4 symmetries that keep orientation (the rotations of the
        square), so that the front side of each surface stays its front side: for meshes whose faces are wound
        consistently (a cohort from one pipeline), half the start search is then saved, and a member is never
        matched back to front. Default False (a mesh wound the other way, or a grid with r and t swapped, is
        matched too; matches on the mirror image are rejected by the residual either way).
    max_starts : int
        Mode "auto": most ranked starts registered in full (see ``Advanced.start_margin``). Default 3.
    symmetry : int or None
        Pin the symmetry of the square applied to the second surface first: an index of
        :data:`meshreg.search.SQUARE_SYMMETRIES` (0-7, as in ``result.symmetry`` and ``result.alternatives``).
        Mode "auto" then searches rotations for it alone; other modes register the second surface under it.
        Default None: mode "auto" searches all 8, the other modes use the identity (0).
    start_basis : int
        Mode "gd": a second descent path starts in the coarser basis KL = ``start_basis``; ``>= basis`` turns
        it off. Default 3.
    smoothing : tuple of float
        Mode "gd": a third path descends through both surfaces blurred by Gaussians of these standard
        deviations (side lengths of the square, largest first; one number is one level); () turns it off.
        Default (0.1,).
    resolution : int
        Meshes are resampled on ``resolution`` x ``resolution`` grids. Default 101.
    weights : {"mean-value", "cotangent"}
        Laplacian weights of the map of a mesh to the square. Default "mean-value" (bijective).
    antialias : int
        Meshes: each grid node is the hat-weighted mean of the mesh around it, sampled ``antialias`` times
        finer than the grid (1: the mesh's point at the node). Default 3: point samples alias a scan's noise into
        E (a face-scan crop against a remeshed copy: E 0.026 at 101 x 101, 0.014 anti-aliased, where no further
        refinement went below 0.025).
    mesh_blur : float
        Meshes in mode "auto" with ``bend_window`` > 0, registered whole, when the two maps to the square nearly
        agree (their own correspondence fits the blurred points within :data:`meshreg.bending.BLUR_FIT_RESIDUAL`:
        one surface, unbent or slightly bent): both grids are blurred by a Gaussian whose standard deviation is
        this many median edge lengths (on the square) of the coarser mesh (:func:`meshreg.mesh.resample.blur_grid`),
        when that is at least half a grid spacing. Below the size of its triangles a mesh's normals are the facets
        of its triangulation, not the surface's, and E matches two triangulations' facets rather than the surface:
        on random triangulations of one terrain (150 to 8000 triangles) the answers were 0.08-2.2% of the size off
        where the two maps agreed within 0.1-0.35%, blurred 0.02-0.43%. Bent pairs, pairs whose maps disagree,
        other modes, partial overlaps and collections are not blurred (blurring made those worse, and it lowers the
        distance between different coarse shapes: 300 against 500 vertices, E about half the smooth shapes' E).
        Default 2; 0 turns it off. E is then the blurred grids' E (near 0 for one surface, where the facets gave
        1e-3 to 1e-2); ``result.params`` records the standard deviation used (``mesh_blur_sigma``, side lengths of
        the square; 0 when not blurred).
    cleanup : bool
        Repair meshes (holes, pieces, pinched vertices, ears) instead of refusing them. Default True.
    corners1, corners2 : tuple of 4 int or None
        Corner vertex ids of each mesh's boundary (ids in the mesh as given), in their order around the boundary
        (either way round): the first becomes (0, 0) of the square, and given for both meshes, corner k of one
        is matched with corner k of the other. Default: chosen (the boundary's four clear turns within the
        surface, else a search; see :mod:`meshreg.mesh.corners`).
    corner_search : int
        Trial corner placements of the second mesh when the boundaries have no four clear corners; 0 turns
        the search off. Default 8.
    overlap : {"auto", "off"}
        Meshes: "auto" finds where the two overlap (:mod:`meshreg.mesh.overlap`); when they cover different
        regions (two scans, two crops), only the common region is registered and vertices outside it get no match.
        "off" always registers the whole meshes. Default "auto" (a no-op for meshes that cover the same region).
    bend_window : float
        Meshes in mode "auto": the correspondence starts from the two maps to the square (which bending does not
        change) and descends E_w, E with a rotation of its own for every window of this width (side lengths of
        the square): bending over longer lengths is not charged, so the descent does not slide a bent surface's
        correspondence (:mod:`meshreg.bending`, docs/bending.md). Smaller: sharper creases kept (a fold), less
        of the relief's long-range shape used (a stretch). 0 minimizes E itself, as for grids (the paper's
        method; the registration then also runs the DP stage and the refinement levels). Default 0.05. The
        reported E is E itself either way.
    force : bool
        Lift the limits of :mod:`meshreg.limits` on what a run may cost (grid nodes, the DP window's time, the
        corner search, worker processes) knowingly. Default False.
    advanced : Advanced
        The rare numerics.
    """

    mode: str = "auto"
    window: int = 10
    basis: int = 5
    solver: str = "gauss-newton"
    refine: str = "nodes"
    search: bool = True
    symmetries: bool = True
    keep_orientation: bool = False
    max_starts: int = 3
    symmetry: int | None = None
    start_basis: int = 3
    smoothing: tuple[float, ...] = (0.1,)
    resolution: int = 101
    weights: str = "mean-value"
    antialias: int = 3
    mesh_blur: float = MESH_BLUR_DEFAULT
    cleanup: bool = True
    corners1: tuple[int, int, int, int] | None = None
    corners2: tuple[int, int, int, int] | None = None
    corner_search: int = 8
    overlap: str = "auto"
    bend_window: float = 0.05
    force: bool = False
    advanced: Advanced = field(default_factory=Advanced)

    def __post_init__(self):
        for name, allowed in (
            ("mode", MODES),
            ("solver", SOLVERS),
            ("refine", REFINEMENTS),
            ("weights", WEIGHTS),
            ("overlap", OVERLAPS),
        ):
            if getattr(self, name) not in allowed:
                raise InputError(f"unknown {name} {getattr(self, name)!r}: choose one of {', '.join(allowed)}")
        for name in ("search", "symmetries", "keep_orientation", "cleanup", "force"):
            if not isinstance(getattr(self, name), bool):
                raise InputError(f"{name} must be True or False, got {getattr(self, name)!r}")
        _integer("window", self.window, 1, MAX_WINDOW)
        _integer("basis", self.basis, 1, MAX_BASIS)
        _integer("start_basis", self.start_basis, 1, MAX_BASIS)
        _integer("max_starts", self.max_starts, 1, 8)
        if self.symmetry is not None:
            _integer("symmetry", self.symmetry, 0, 7)
            object.__setattr__(self, "symmetry", int(self.symmetry))
        _integer("antialias", self.antialias, 1, 16)
        _number("mesh_blur", self.mesh_blur, 0.0, 100.0)
        _integer("resolution", self.resolution, 3, 100_000)
        _integer("corner_search", self.corner_search, 0, 1000)
        _number("bend_window", self.bend_window, 0.0, 1.0)
        given = self.smoothing
        listed = hasattr(given, "__iter__") and not isinstance(given, (str, bytes))
        smoothing = (given,) if _real(given) else tuple(given) if listed else (None,)
        if not all(_real(s) and 0 < s <= 1 for s in smoothing):
            raise InputError(f"smoothing must be standard deviations in (0, 1] (side lengths), got {self.smoothing!r}")
        object.__setattr__(self, "smoothing", tuple(float(s) for s in smoothing))
        for name in ("corners1", "corners2"):
            value = getattr(self, name)
            if value is not None:
                ok = hasattr(value, "__len__") and not isinstance(value, str) and len(value) == 4
                ok = ok and len({int(v) for v in value if _is_int(v)}) == 4
                if not ok or not all(_is_int(v) and v >= 0 for v in value):
                    raise InputError(
                        f"{name} must be four different vertex ids (integers from 0, one per corner), got {value}"
                    )
                object.__setattr__(self, name, tuple(int(v) for v in value))
        if not isinstance(self.advanced, Advanced):
            raise InputError(f"advanced must be a meshreg.Advanced, got {type(self.advanced).__name__}")
        check_static(self)

    def replace(self, **changes) -> Options:
        """A copy with some fields changed (validated again)."""
        return replace(self, **changes)

    def steps(self, basis: int | None = None, **changes) -> StepParams:
        """:class:`StepParams` of the descent rounds (basis KL = ``basis``, default ``self.basis``)."""
        return self.advanced.steps(self.basis if basis is None else basis, **changes)

    def check_grids(self, *shapes: tuple[int, int]) -> None:
        """Refuse grids (M, N) (the first grid first) too large for the limits of :mod:`meshreg.limits`, or for
        the DP window on them, unless ``force`` (InputError with the estimate and the limit)."""
        check_grids(self, *shapes)

    def as_dict(self) -> dict:
        """Every field, the advanced ones included, as one flat JSON-ready dict."""
        out = {f.name: getattr(self, f.name) for f in fields(self) if f.name != "advanced"}
        out["smoothing"] = list(self.smoothing)
        for name in ("corners1", "corners2"):
            out[name] = None if out[name] is None else list(out[name])
        return {**out, **asdict(self.advanced)}


SCHEDULER_SCHEMES = ("tcp", "tls", "ucx", "ws", "wss")
_ADDRESS = re.compile(
    r"^(?:(?P<scheme>[a-z]+)://)?(?P<host>\[[0-9a-fA-F:.]+\]|[A-Za-z0-9_.-]+):(?P<port>[0-9]{1,5})/?$"
)


def check_scheduler(address: str) -> str:
    """A dask.distributed scheduler address ``[scheme://]host:port`` (scheme one of SCHEDULER_SCHEMES), or
    InputError before any connection is tried."""
    match = _ADDRESS.match(address) if isinstance(address, str) else None
    if not match or (match["scheme"] or "tcp") not in SCHEDULER_SCHEMES or not 0 < int(match["port"]) < 65536:
        raise InputError(
            "--scheduler must be a Dask scheduler address like tcp://host:8786 "
            f"(schemes {', '.join(SCHEDULER_SCHEMES)}), got {address!r}"
        )
    return address


def _is_int(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) or type(value).__name__.startswith(("int", "uint"))


def _integer(name: str, value, low: int, high: int) -> None:
    if not _is_int(value) or not low <= value <= high:
        raise InputError(f"{name} must be an integer from {low} to {high}, got {value!r}")


def _real(value) -> bool:
    """A finite int or float (not a bool)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _number(name: str, value, low: float, high: float, low_open: bool = False) -> None:
    ok = _real(value)
    if not ok or value < low or (low_open and value == low) or value > high:
        bound = f"({low}" if low_open else f"[{low}"
        raise InputError(f"{name} must be a finite number in {bound}, {high}], got {value!r}")
