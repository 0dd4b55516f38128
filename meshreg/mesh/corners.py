"""Corners of a disk mesh's boundary on the square, and the search for the second mesh's corner placement.

A boundary with four clear turns (a scanned sheet, a terrain tile) has natural corners: turns within the surface,
which bending does not change. A smooth boundary (a round crop of a scan) has none, and two meshes of one surface
would get their corners at different places, which no reparametrization that keeps the corners can undo:
:func:`search_corners` tries placements of the second mesh's corners and ranks them by E_w at the parametrizations'
own correspondence (:func:`meshreg.bending.symmetry_energies`: local rotations absorb bending).
"""

from __future__ import annotations

import numpy as np

from ..bending import (
    CHOICE_GRID,
    METRIC_VETO,
    RESIDUAL_FLOOR,
    choice_symmetries,
    coarse,
    preferred,
    symmetry_energies,
)
from ..errors import InputError
from ..grid import GridSurface
from ..options import Options
from ..search import ORIENTATION_PRESERVING, SQUARE_SYMMETRIES
from .early import EarlyAnalysis
from .harmonic import (
    HarmonicMap,
    arc_fraction,
    choose_corners,
    compression,
    given_corners,
    has_sharp_corners,
    quarter_corners,
)
from .resample import resample_grid
from .topology import DiskMesh, prepare_disk, triangle_areas

# when the best trial placement does not fit the points (residual at least RESIDUAL_FLOOR), the trial within this
# factor of its E_w that fits them best (coordinate residual below RESIDUAL_FLOOR) may sit beside a narrow minimum
# the trials stepped over: it is refined too (the five-lobed star over a saddle: E_w 2.2 times the best, residual
# 0.052 against 0.256, and 0.015 of the boundary from a placement at 1.28 times the best E_w with residual 0.027, the
# right one; a four-lobed rim under a cubic: 1.36 times the best, residual 0.085 against 0.112, refined to E_w 0.0051
# and residual 0.022 against the half-turned match's 0.0043 and 0.19)
FITTING_REACH = 3.0
PLACEMENT_HALVINGS = 4  # halving steps around the best trial: the pair's corner search, a round boundary's own start
OWN_TRIALS = 8  # trial starts of a round boundary's own corner placement, over a quarter of it (:func:`own_start`)
SQUEEZE_GAIN = 0.5  # ... which moves off choose_corners' start only to a map squeezing the surface less than this much
# a chosen placement whose match fits the points within this coordinate residual (area 1) is one surface, nearly
# unbent: its placement is then moved to where the points fit best (:func:`_snug`)
SNUG_RESIDUAL = 0.05
SNUG_HALVINGS = 6  # halving steps of that move, from half the trials' spacing
SWAP = SQUARE_SYMMETRIES.index((True, False, False))  # (u, v) -> (v, u): corners given each way round


def placement_starts(disk: DiskMesh, trials: int, span: float = 0.25, start: float | None = None) -> np.ndarray:
    """Arc-length fractions (trials,) of the trial corner placements of a disk: quarter arc lengths from
    ``trials`` starts spaced by ``span / trials`` of its boundary, the first at ``start`` (by default the point
    where :func:`~meshreg.mesh.harmonic.choose_corners` would start). A quarter of the boundary (``span`` 0.25)
    covers every placement when the square's quarter turns are tried too; else the whole boundary (``span`` 1)."""
    if start is None:
        start = arc_fraction(disk, int(choose_corners(disk)[0]))
    return start + span / trials * np.arange(trials)


def own_start(hmap: HarmonicMap) -> float:
    """Arc-length fraction in [0, 1) where a round boundary's own corner placement starts: where
    :func:`~meshreg.mesh.harmonic.choose_corners` would start, unless another start squeezes the surface less
    than SQUEEZE_GAIN as much (:func:`~meshreg.mesh.harmonic.compression`); the best of OWN_TRIALS starts spread over a
    quarter of the boundary from there, then PLACEMENT_HALVINGS halving steps around the best.

    A placement that puts both ends of a boundary chord on one side of the square collapses the surface beyond the
    chord: on a face-scan crop, E against a remeshed copy ranged from 0.0056 to 0.063 with the first mesh's start
    (the correspondence right at every start), and the boundary loop's numbering picked the start. A boundary
    without such chords (a cap) keeps choose_corners' start, which two meshes of one surface share: where the
    relief cannot tell placements apart, the pair's corner search matches them only there."""
    disk = hmap.disk
    areas = triangle_areas(disk.vertices, disk.faces)

    def squeeze(start):
        try:
            return compression(disk, hmap(quarter_corners(disk, start % 1.0))[0], areas)
        except InputError:  # fewer than 4 distinct quarter points from this start
            return np.inf

    tried = _lowest(squeeze, placement_starts(disk, OWN_TRIALS), 0.25 / OWN_TRIALS)
    best = min(tried, key=lambda x: x[1])
    return best[0] if best[1] < SQUEEZE_GAIN * tried[0][1] else tried[0][0]


def _lowest(rank, starts: np.ndarray, step: float, best=None) -> list[tuple[float, object]]:
    """(start mod 1, rank) of every start tried: ``starts``, then :func:`_halvings` around the best so far.
    ``best(ranks)``: the index of the best of a list of ranks (default: the lowest)."""
    tried = [(float(start) % 1.0, rank(start)) for start in starts]
    return tried + _halvings(rank, tried, step, best)


def _halvings(rank, tried: list, step: float, best=None, count: int = PLACEMENT_HALVINGS) -> list[tuple[float, object]]:
    """(start mod 1, rank) of ``count`` pairs of steps, from ``step`` / 2 and halving, each pair around the best
    start of ``tried`` (start, rank) and the steps before it (``best`` as for :func:`_lowest`)."""
    best = best or (lambda ranks: int(np.argmin(ranks)))
    tried, given = list(tried), len(tried)
    for _ in range(count):
        centre, step = tried[best([r for _, r in tried])][0], step / 2
        tried += [((centre + d) % 1.0, rank(centre + d)) for d in (-step, step)]
    return tried[given:]


def placement_corners(hmap: HarmonicMap, trials: int) -> list[np.ndarray]:
    """Corner loop positions (4,) of each trial placement of :func:`placement_starts` from the disk's own start
    (:func:`own_start`); the first is the placement a round-boundary mesh uses as the first surface of a pair."""
    disk = hmap.disk
    return [quarter_corners(disk, start % 1.0) for start in placement_starts(disk, trials, start=own_start(hmap))]


def placement_rank(
    coarse1: GridSurface, grid: GridSurface, window: float, symmetries
) -> tuple[float, float, int, float]:
    """(E_w, coordinate residual, symmetry, metric residual) of one corner placement of the second surface,
    ``grid``, against the first's ``coarse1``: its preferred symmetry of the square (:func:`_best` of
    :func:`meshreg.bending.symmetry_energies` over ``symmetries`` at h = the symmetry, windows of ``window``),
    mirrored matches aside, with its E_w, residual and metric residual; (inf, inf, 0, inf)
    when every match is mirrored (ranked last)."""
    fair = [
        (e, r, k, m) for k, e, mirrored, r, m in symmetry_energies(coarse1, grid, window, symmetries) if not mirrored
    ]
    return fair[_best(fair)] if fair else (np.inf, np.inf, 0, np.inf)


def best_placement(first: GridSurface, placements: list[GridSurface], options: Options) -> list[tuple[int, int, float]]:
    """The second surface's corner placements (each a grid) ranked against ``first`` as :func:`search_corners`
    ranks its trials (:func:`placement_rank`, with the symmetries and choice window of ``options``): (placement
    index, its preferred symmetry of the square, that match's coordinate residual) of the best (:func:`_best`), then
    of a placement that fits the points better than it (:func:`_fitting`), if there is one.

    A collection's placements are fixed trials, with no halving steps between them, and its pairs are registered by
    E, which cannot see that a match fits the normals but not the points: the caller may need the second entry and
    the symmetries (:func:`meshreg.batch.registered_pair`)."""
    symmetries = choice_symmetries(options, options.symmetry)
    coarse1 = coarse(first)
    ranks = [placement_rank(coarse1, g, options.advanced.choice_window, symmetries) for g in placements]
    best = _best(ranks)
    fitting = _fitting(list(enumerate(ranks)))
    found = [best] + ([] if fitting is None else [fitting[0]])
    return [(k, int(ranks[k][2]), float(ranks[k][1])) for k in found]


def corner_positions(disks: list[DiskMesh], maps: list[HarmonicMap], options: Options):
    """Corner loop positions (4,) of both meshes of a pair: given ids (``options.corners1/2``, the first of each
    at (0, 0)), four clear turns on both, or else the first's own placement (:func:`placement_corners`, even where
    the first alone has four clear turns) and a search of the second's (:func:`search_corners`).

    Returns
    -------
    positions : list of two ndarray (4,)
    tried : list or None
        The (start, E_w) pairs of the second's placements tried (None without a search).
    symmetry : int or None
        With corners given for both meshes, the symmetry of the square that matches corner k of the first with
        corner k of the second: the identity, or the diagonal one when one mesh's corners were given along its
        boundary and the other's against it (:func:`~meshreg.mesh.harmonic.given_corners`); else None.
    other : ndarray (4,) or None
        Another placement of the second's corners to register as well (:func:`search_corners`), or None.
    """
    given = (options.corners1, options.corners2)
    pos, backwards = [], []
    for disk, ids in zip(disks, given, strict=True):
        if ids is None:
            pos.append(choose_corners(disk))
            backwards.append(None)
        else:
            corners, reverse = given_corners(disk, disk.input_ids(ids))
            pos.append(corners)
            backwards.append(reverse)
    symmetry = None if None in backwards else (SWAP if backwards[0] != backwards[1] else 0)
    search = options.corner_search > 0 and given == (None, None) and not all(has_sharp_corners(d) for d in disks)
    if not search:
        return pos, None, symmetry, None
    # four clear turns on one mesh only are no corners of the surface (dents of a jagged rim, bunched in a tenth of it):
    # both meshes are placed at quarter arc lengths, which the search can match
    pos[0] = placement_corners(maps[0], 1)[0]
    pos[1], tried, other = search_corners(maps[0], pos[0], maps[1], options)
    return pos, tried, symmetry, other


def search_corners(
    first: HarmonicMap, corners1: np.ndarray, second: HarmonicMap, options: Options
) -> tuple[np.ndarray, list, np.ndarray | None]:
    """Corners of the second mesh that best match the first's: the ``options.corner_search`` placements of
    :func:`placement_starts` from the second's own start (:func:`own_start`; four times as many, over the whole
    boundary, when the square's quarter turns are not tried: ``search`` or ``symmetries`` off, or a pinned
    ``symmetry``), then PLACEMENT_HALVINGS halving steps around the best, each ranked by E_w over the symmetries of
    the square at h = the symmetry, mirrored matches aside (:func:`meshreg.bending.symmetry_energies`, windows of
    ``options.advanced.choice_window``, on CHOICE_GRID x CHOICE_GRID grids): the lowest, unless one nearly as low
    fits the points far better (:func:`meshreg.bending.preferred`, which also picks the best placement). When the
    best trial does not fit the points, the trial that fits them best within reach (:func:`_fitting`) gets
    PLACEMENT_HALVINGS halving steps of its own: the right placement's minimum of E_w can be narrower than the
    trials' spacing.

    A smooth boundary (a round crop) has no natural corners: two meshes of one surface get corners at
    different places, and no reparametrization that keeps the corners can undo that. This finds them; E_w
    compares normals under rotations that vary over the square, so a bent copy is placed like an unbent one.

    Returns the second's corner loop positions (4,), the (start, E_w) pairs tried (E_w of each placement's
    preferred symmetry; the chosen placement need not have the lowest) and the corners of the placement
    :func:`_snug` moved it to, where they differ (else None): the caller registers both and keeps the answer
    :func:`meshreg.bending.preferred` prefers by E and residual (the lower E, unless it alone does not fit the points).
    """
    n, trials = CHOICE_GRID, options.corner_search
    symmetries = choice_symmetries(options, options.symmetry)
    span = 0.25 if set(ORIENTATION_PRESERVING) <= set(symmetries) else 1.0
    window, disk1, disk2 = options.advanced.choice_window, first.disk, second.disk
    aa = options.antialias
    coarse1 = resample_grid(disk1.vertices, disk1.faces, first(corners1)[0], n, n, aa)

    def rank(start, among=symmetries):
        grid = resample_grid(disk2.vertices, disk2.faces, second(quarter_corners(disk2, start % 1.0))[0], n, n, aa)
        return placement_rank(coarse1, grid, window, among)

    count = round(trials * span / 0.25)  # the same spacing, 1 / (4 trials) of the boundary, over the span
    tried = _lowest(rank, placement_starts(disk2, count, span, own_start(second)), 0.25 / trials, _best)
    fitting = _fitting(tried[:count])
    if fitting is not None:  # a narrow minimum of E_w between the trials, where the points fit: refined too
        tried += _halvings(rank, [fitting], 0.25 / trials, _best)
    chosen = tried[_best([r for _, r in tried])]
    snug, moves = _snug(rank, chosen, 0.25 / trials)
    corners, other = quarter_corners(disk2, chosen[0] % 1.0), quarter_corners(disk2, snug % 1.0)
    tried += moves
    return corners, [(start, float(r[0])) for start, r in tried], None if np.array_equal(other, corners) else other


def _snug(rank, chosen: tuple[float, tuple], step: float) -> tuple[float, list]:
    """The start of the ``chosen`` placement (start, (E_w, residual, symmetry)) moved to where its match fits the
    points best, and the (start, rank) tried on the way: when its coordinate residual is below SNUG_RESIDUAL (one
    surface, nearly unbent), SNUG_HALVINGS halving steps from ``step`` / 2 around it, each placement ranked by the
    residual of the chosen symmetry's match (``rank(start, symmetries)``: :func:`placement_rank`); else the start as
    chosen.

    E_w absorbs a turn of the placement along the boundary into its local rotations where the surface is nearly
    round about its middle (a cap, a cone, a torus patch: the lowest E_w 2-6 degrees off the right placement on
    held-out disk-rim meshes), and the registration cannot undo it: the corners stay where they were placed. The
    points pin the placement of one unbent surface sharply."""
    start, (_, residual, symmetry, *_) = chosen
    if not residual < SNUG_RESIDUAL:
        return start, []

    def fits(ranks):  # index of the rank with the lowest residual
        return int(np.argmin([r[1] for r in ranks]))

    moves = _halvings(lambda s: rank(s, [symmetry]), [chosen], step, fits, SNUG_HALVINGS)
    tried = [chosen, *moves]
    return tried[fits([r for _, r in tried])][0], moves


def _fitting(tried: list[tuple[float, tuple]]) -> tuple[float, tuple] | None:
    """The entry (start, (E_w, residual, symmetry, metric residual)) of ``tried`` that fits the points best when the
    best start's (:func:`_best`) coordinate residual is at least RESIDUAL_FLOOR (it does not fit the points), its own
    is below RESIDUAL_FLOOR (it does), its E_w within FITTING_REACH times the best's and its metric residual within
    METRIC_VETO times the best's (a bent pair's right placement does not fit the points:
    :func:`meshreg.bending.preferred`); else None."""
    ranks = np.array([r for _, r in tried], dtype=float)
    energy, residual, _, metric = ranks[_best(ranks)]
    if not residual >= RESIDUAL_FLOOR:  # the best fits the points (or is NaN): nothing to refine
        return None
    near = (ranks[:, 0] <= FITTING_REACH * energy) & (ranks[:, 1] < RESIDUAL_FLOOR)
    near &= ranks[:, 3] <= METRIC_VETO * metric
    return tried[int(np.argmin(np.where(near, ranks[:, 1], np.inf)))] if near.any() else None


def _best(ranks: list[tuple]) -> int:
    """Index of the best of (E_w, coordinate residual, symmetry, metric residual) ranks:
    :func:`meshreg.bending.preferred`, with the metric residuals."""
    return preferred([r[0] for r in ranks], [r[1] for r in ranks], [r[3] for r in ranks])


def mesh_grids(vertices: np.ndarray, faces: np.ndarray, options: Options, arcs: bool = False):
    """One mesh, on its own, to grid surfaces: clean, map to the square, resample on grids of
    ``options.resolution`` nodes per axis (``options.cleanup``, ``options.weights``, ``options.antialias``).

    With four clear corners (or ``options.corner_search=0``), one grid (corners by
    :func:`~meshreg.mesh.harmonic.choose_corners`); else one grid per trial corner placement of
    :func:`placement_starts` (one LU serves them all), the first of which is the mesh's own placement when
    it is the first surface of a pair; a pair ranks the second's placements by :func:`best_placement`. With
    ``arcs``, a mesh with four clear corners has the grids of its trial placements after its corner grid (a
    collection with round-boundary meshes places it like them in their pairs).

    Returns the list of GridSurfaces and an info dict (cleanup report, corners, flipped and degenerate counts, and
    ``searched``: "round" for trial placements, "turned" for four clear corners, else None).
    """
    with EarlyAnalysis() as early:  # the LU's analysis begun while the mesh is cleaned
        disk = prepare_disk(vertices, faces, cleanup=options.cleanup, checked=early.begin)
        hmap = HarmonicMap(disk, options.weights, early=early)
        searched = None
        if options.corner_search > 0:
            searched = "turned" if has_sharp_corners(disk) else "round"
        placements = [choose_corners(disk)] if searched != "round" else []
        if searched == "round" or (searched == "turned" and arcs):
            placements += placement_corners(hmap, options.corner_search)
        maps = [hmap(corners) for corners in placements]
    n = options.resolution
    grids = [resample_grid(disk.vertices, disk.faces, uv, n, n, options.antialias) for uv, _ in maps]
    return grids, {**maps[0][1], "cleanup": disk.report, "searched": searched}
