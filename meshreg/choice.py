"""Which starts of mode "auto" are registered in full, and which candidate is the answer: the lowest E, near
ties going to the better-ranked start, never a match on the mirror image of the second surface, nor one that fits
the normals of one shape but not its points while another candidate fits both (both judged by the coordinate
residual, :mod:`meshreg.residual`)."""

from __future__ import annotations

import time

from .errors import InputError
from .grid import GridSurface
from .options import Options
from .residual import Residual
from .schedule import Candidate
from .search import Start, best_start

# a start ranked lower must beat a better-ranked one by this fraction of E to win; the identity symmetry goes
# first when its coarse energy is within this fraction of the best
SYMMETRY_MARGIN = 0.05
# the search reports that a mirror image of the second surface fits clearly better when its best coarse energy is
# below this fraction of the chosen start's
MIRROR_MARGIN = 0.5
# ... unless the answer fits the second's points within this coordinate residual (area 1): a proper rotation then
# carries the first onto the second, which is no mirror image of it. A mirror-symmetric shape has a mirrored start as
# good as the right one, and the coarse ranking can put it first by chance: a held-out face mesh against its remeshed
# copy was told that a mirror image fits better (coarse E_w 0.0012 against the chosen start's 0.0027) with an answer
# of residual 0.0033 and points right within 0.3%; a true mirror image (tests/test_symmetry.py) had 0.057
MIRROR_FIT_RESIDUAL = 0.01
# two starts whose coarse energies agree to this relative tolerance are twins: a symmetry of the surfaces maps one
# problem onto the other (measured: the twins of the paper's pairs agree to 1e-15), so only one is registered (see
# TWIN_RESIDUAL_MARGIN); the other stays a spare, and the chosen answer's symmetric twins are listed by
# meshreg.alternatives
TWIN_TOL = 1e-9
# of twins, the one whose coarse match has the clearly lower coordinate residual (by this fraction) is registered:
# E cannot tell a surface from its point reflection, so twins can be unequally right (collection pairs 0-5 and
# 0-13 of bench_matrix.py: equal E, residuals 1.06 and 1.50, 0.34 and 0.58); among equally good twins the first
TWIN_RESIDUAL_MARGIN = 0.05
# a match of normals only: E at the level of one shape (below SAME_SHAPE_ENERGY) with the points far apart (a residual
# above NORMALS_ONLY_RESIDUAL, on area 1). The SRNF does not always fix the surface: the monkey saddle z = Re (u + iv)^3
# against itself under the anti-diagonal reflection of the square has q(c o tau) = D q(c), D a half turn, and c o tau
# is congruent neither to c nor to -c; E reached 1.8e-7 there with a residual of 0.55 against and 0.55 mirrored. On
# held-out same-shape pairs (paraboloid, saddles, cap, cylinder, torus, terrains; 41 and 101 nodes) the right answers
# had E <= 2.4e-5 and residuals <= 0.009
SAME_SHAPE_ENERGY = 1e-3
NORMALS_ONLY_RESIDUAL = 0.05
# candidates above this E after the basis descent are not refined to replace a match of normals only (the right
# starts of the monkey saddles Re (u + iv)^3 and ^5 were at 0.0037 and 0.0135 before their refinement, 1.4e-8 and
# 5.9e-8 after it)
REFINE_BELOW = 100 * SAME_SHAPE_ENERGY
# when no registered candidate fits the points, at most this many spare starts are registered to find one: on a
# nearly flat sheet (relief 1% of its size) the start search ranked the right symmetry second, at twice the best's
# coarse E, outside the start margin, and the chosen one was 180 degrees off (E 1.7e-4, residual 0.13; the right
# one E 9.8e-8, residual 0.013)
NORMALS_ONLY_SPARES = 4


def ranked_starts(first: GridSurface, second: GridSurface, options: Options, timings: dict):
    """The starts of mode "auto" with ``search`` ranked best first (:func:`meshreg.search.best_start`; none on the
    mirror image of the second surface) and the best mirrored start seen, or None; in other modes the one start
    (the pinned symmetry, no rotation) and None."""
    if not (options.mode == "auto" and options.search):
        return [Start(options.symmetry or 0, None, float("nan"))], None
    tic = time.perf_counter()
    found = best_start(
        first, second, symmetries=options.symmetries, keep_orientation=options.keep_orientation, only=options.symmetry
    )
    ranked = [s for s in found if not s.mirrored]
    if not ranked:
        raise every_start_mirrored(options.symmetry)
    timings["search"] = time.perf_counter() - tic
    return ranked, next((s for s in found if s.mirrored), None)


def every_start_mirrored(symmetry: int | None) -> InputError:
    """The error when every start (under the pinned ``symmetry``, if any) is on the mirror image of the second."""
    pinned = "" if symmetry is None else f" under the pinned symmetry {symmetry}"
    return InputError(f"every start{pinned} puts the first surface on a mirror image of the second")


def every_match_mirrored(lowest_energy: float) -> InputError:
    """The error when every correspondence found, down to the last spare start, is on the mirror image."""
    return InputError(
        "every correspondence found puts the first surface on a mirror image of the second "
        f"(lowest E {lowest_energy:.3g}): are they mirror images of each other?"
    )


def choose_unmirrored(candidates: list[Candidate], starts: list[Start], spare: list[Start], run, options: Options):
    """The chosen candidate among those whose aligned first surface is not on the mirror image of the second,
    refined, and its residual. Candidates are judged after the basis descent and again once refined; when every
    one is mirrored, the ``spare`` starts are registered one by one (``candidates`` and ``starts`` grow).

    Raises
    ------
    InputError
        When no start gives a correspondence that keeps the orientation.
    """
    rejected = set()
    while True:
        fair = [k for k, c in enumerate(candidates) if k not in rejected and not c.residual().mirrored]
        if not fair:
            if not spare:
                raise every_match_mirrored(min(c.energy for c in candidates))
            starts.append(spare.pop(0))
            candidates.append(run(starts[-1]))
            continue
        chosen = fair[choose([candidates[k] for k in fair], options)]
        residual = candidates[chosen].polish().residual()
        if not residual.mirrored:
            return right_by_points(
                candidates, chosen, residual, lambda: _register_spare(candidates, starts, spare, run)
            )
        rejected.add(chosen)


def _register_spare(candidates: list[Candidate], starts: list[Start], spare: list[Start], run) -> int | None:
    """Register the best spare start (``candidates`` and ``starts`` grow); its index, or None when none is left."""
    if not spare:
        return None
    starts.append(spare.pop(0))
    candidates.append(run(starts[-1]))
    return len(candidates) - 1


def normals_only(energy: float, residual: Residual, bound: float = NORMALS_ONLY_RESIDUAL) -> bool:
    """Whether a match fits the normals of one shape (E < SAME_SHAPE_ENERGY) but not its points (residual above
    ``bound``): E cannot see that it is wrong.

    Parameters
    ----------
    energy : float
        E of the match.
    residual : Residual
        Its coordinate residual (:mod:`meshreg.residual`).
    bound : float
        The residual (area 1) above which the points do not fit. Default NORMALS_ONLY_RESIDUAL.
    """
    return energy < SAME_SHAPE_ENERGY and residual.plus > bound


def right_by_points(candidates: list[Candidate], chosen: int, residual: Residual, more=None) -> tuple[int, Residual]:
    """The chosen candidate, or one that fits both normals and points when the chosen one fits the normals only.

    When ``candidates[chosen]`` (refined, with ``residual``) matches normals only (:func:`normals_only`), every
    other candidate below REFINE_BELOW is refined, and of those that fit the normals and the points (not normals
    only, not mirrored) the one with the lowest residual replaces it. When none does, up to NORMALS_ONLY_SPARES more
    starts are registered by ``more`` (returns the new candidate's index, or None when no start is left) until one
    fits. Without one the chosen candidate stays.

    Parameters
    ----------
    candidates : list of Candidate
        The registered candidates (the others are refined here when needed; ``more`` appends to it).
    chosen : int
        Index of the chosen candidate, refined.
    residual : Residual
        Its residual.
    more : callable, optional
        Registers one more start: () -> int or None.

    Returns
    -------
    (int, Residual)
        The index of the answer and its residual.
    """
    if not normals_only(candidates[chosen].energy, residual):
        return chosen, residual
    best = _best_fit(candidates, [k for k in range(len(candidates)) if k != chosen], (chosen, residual))
    for _ in range(NORMALS_ONLY_SPARES if more is not None and best[0] == chosen else 0):
        k = more()
        if k is None:
            break
        best = _best_fit(candidates, [k], best)
        if best[0] != chosen:
            break
    return best


def _best_fit(candidates: list[Candidate], ks: list[int], best: tuple[int, Residual]) -> tuple[int, Residual]:
    """``best``, or the candidate of ``ks`` (refined when below REFINE_BELOW) that fits normals and points with a
    lower residual."""
    for k in ks:
        other = candidates[k]
        if other.energy > REFINE_BELOW:
            continue
        found = other.polish().residual()
        fits = other.energy < SAME_SHAPE_ENERGY and found.plus <= NORMALS_ONLY_RESIDUAL and not found.mirrored
        if fits and found.plus < best[1].plus:
            best = (k, found)
    return best


def spare_starts(ranked: list[Start], starts: list[Start]) -> list[Start]:
    """The ranked starts not registered yet, best first."""
    return [s for s in ranked if all(s is not t for t in starts)]


def mirror_record(mirror: Start | None, chosen: Start, residual: float = float("inf")) -> dict | None:
    """What the search saw of a mirror image: the best mirrored start's symmetry and coarse E, and whether it
    fits clearly better: its coarse E below MIRROR_MARGIN times the chosen start's, while the answer, of coordinate
    ``residual``, does not fit the second's points (above MIRROR_FIT_RESIDUAL)."""
    if mirror is None:
        return None
    return {
        "symmetry": mirror.symmetry,
        "coarse_energy": float(mirror.energy),
        "fits_better": bool(mirror.energy < MIRROR_MARGIN * chosen.energy and residual > MIRROR_FIT_RESIDUAL),
    }


def choose(candidates: list[Candidate], options: Options) -> int:
    """The lowest E after the basis descent wins, near ties (within SYMMETRY_MARGIN) going to the better-ranked
    start; only the winner is refined (on the paper's pairs and nearly symmetric meshes the order of the starts
    by this E was the order by their refined E, but for near ties)."""
    lowest = min(c.energy for c in candidates)
    bar = (1.0 + SYMMETRY_MARGIN) * lowest + options.advanced.abs_tol
    return next(k for k, c in enumerate(candidates) if c.energy <= bar)


def close_starts(starts: list[Start], max_starts: int, margin: float) -> list[Start]:
    """The ranked starts worth a full registration: the best, then those whose coarse energy is within
    ``margin`` of it (at most ``max_starts``), twins left out (a start whose coarse energy equals, within TWIN_TOL,
    that of one kept already: the same problem under a symmetry of the surfaces, or under the point reflection that
    E cannot see; of twins, the first unless another's coarse match has a clearly lower coordinate residual,
    TWIN_RESIDUAL_MARGIN, which then replaces it, even the identity put first below). The identity symmetry goes first
    when it is within SYMMETRY_MARGIN of the best (ties, as on surfaces with a mirror symmetry, keep the given
    parametrization)."""
    best = starts[0]
    identity = next((s for s in starts if s.symmetry == 0), best)
    if identity.energy <= (1.0 + SYMMETRY_MARGIN) * best.energy:
        starts = [identity] + [s for s in starts if s is not identity]
    close = []
    for s in starts:
        if s.energy > (1.0 + margin) * best.energy and s is not starts[0]:
            continue
        twin = next((i for i, k in enumerate(close) if abs(s.energy - k.energy) <= TWIN_TOL * abs(k.energy)), None)
        if twin is None:
            close.append(s)
        elif s.residual < (1.0 - TWIN_RESIDUAL_MARGIN) * close[twin].residual:
            close[twin] = s
    return close[:max_starts]
