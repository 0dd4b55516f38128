"""Equally good correspondences of a symmetric shape: the ambiguity report of mode "auto".

When the first surface has a symmetry, a symmetry tau of the square with ``c1 o tau = S c1`` for a rotation S
(a sheet with two equal bumps and a half turn, a centred bump and its quarter turns), the chosen answer (R, h)
has a twin (R S, h o tau) with the same E and the same coordinate residual: another correspondence, just as
right. A symmetry sigma of the second surface, ``c2 o sigma = S c2``, gives the twin (S R, sigma o h) the same
way. No energy can prefer one of them; the user has to know and choose (``Options.symmetry``). When S is a
reflection instead, the twin reaches the same E on the mirror image of the other surface (its residual says so,
:mod:`meshreg.residual`) and is not an alternative.

So the symmetries of each surface are found first (:func:`self_symmetries`: a proper rotation brings it onto
itself reparametrized by tau, within :data:`SELF_SYMMETRY`); a surface without any costs nothing more. Each twin
of the chosen answer under them (R by Kabsch) is judged: mirrored, it is dropped; with its distance sqrt(E) and
residual at most ``Advanced.ambiguity`` above the chosen ones it is an alternative; otherwise (the surface
symmetric as a shape but not in its parametrization, as a mesh mapped to the square is) it is refined as the
chosen candidate was and judged again.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .diffeo import enforce_boundary
from .grid import GridSurface
from .objective import Objective
from .options import Options
from .residual import Residual, node_weights
from .rotation import angle_between, kabsch
from .schedule import Candidate, Descent, Log, valid_start, work_objective
from .search import SQUARE_SYMMETRIES, apply_symmetry, compose_symmetries, inverse_symmetry, symmetry_map
from .spline import GridInterpolator

SELF_SYMMETRY = 0.03  # a surface is symmetric under tau when S c - c o tau has RMS at most this (area 1, centred)
SELF_SYMMETRY_GRID = 41  # ... measured on this many nodes per axis
SAME_ANSWER = 2.0  # degrees: twins of one symmetry whose rotations are closer are one correspondence


@dataclass(frozen=True)
class Alternative:
    """An equally good correspondence: the symmetry of the square it applies to the second surface first (as
    :attr:`meshreg.Registration.symmetry`), its rotation, E and coordinate residual."""

    symmetry: int
    rotation: np.ndarray
    energy: float
    residual: float

    def as_dict(self, chosen_rotation: np.ndarray) -> dict:
        """JSON-ready: symmetry, angle (degrees) of its rotation from the chosen one, E, residual, rotation."""
        return {
            "symmetry": self.symmetry,
            "angle": angle_between(self.rotation, chosen_rotation),
            "energy": float(self.energy),
            "residual": float(self.residual),
            "rotation": self.rotation.tolist(),
        }


def self_symmetries(surface: GridSurface) -> list[int]:
    """The symmetries tau of the square (identity aside) under which a rotation S brings the surface onto itself
    reparametrized by tau: area-weighted RMS of ``S c - c o tau`` (area 1, both centred) at most SELF_SYMMETRY,
    on SELF_SYMMETRY_GRID nodes per axis. Measured on meshes of symmetric sheets mapped to the square (two random
    triangulations): 0.008-0.013 for their symmetries; 0.06 and more for every other tau of 35 surfaces (the sample
    sheets, the distance-matrix benchmark's 20 surfaces, sheet meshes, the face scan)."""
    n = SELF_SYMMETRY_GRID
    coarse = surface.scaled().resampled(n, n)
    w = node_weights(coarse.points)[..., None]
    p = coarse.points - np.sum(w * coarse.points, axis=(0, 1))
    found = []
    for tau in range(1, len(SQUARE_SYMMETRIES)):
        q = apply_symmetry(coarse, tau).points
        q = q - np.sum(w * q, axis=(0, 1))
        rotation = kabsch(np.einsum("ijk,ijl->kl", w * p, q))
        if np.sqrt(np.sum(w * (p @ rotation.T - q) ** 2)) <= SELF_SYMMETRY:
            found.append(tau)
    return found


def equally_good(energy: float, residual: float, chosen_energy: float, chosen_residual: float, options) -> bool:
    """Whether (E, residual) is as good as the chosen answer's: its distance sqrt(E) and its residual (both
    lengths on area-1 surfaces) exceed the chosen ones by at most ``Advanced.ambiguity``."""
    tol = options.advanced.ambiguity
    close = np.sqrt(max(energy, 0.0)) <= np.sqrt(max(chosen_energy, 0.0)) + tol
    return bool(close and residual <= chosen_residual + tol)


def find_alternatives(
    first: GridSurface,
    second: GridSurface,
    area: float,
    symmetry: int,
    chosen: Candidate,
    residual: Residual,
    options: Options,
    log: Log,
    refine_margin: float = np.inf,
) -> list[Alternative]:
    """The correspondences as good as the chosen one that differ from it by a symmetry of either surface.

    Parameters
    ----------
    first, second : GridSurface
        The surfaces as given (the second before any symmetry of the square).
    area : float
        The second surface's area (the Objective's scale).
    symmetry : int
        The symmetry of the square of the chosen answer.
    chosen : Candidate
        The chosen answer, refined: ``chosen.objective`` registers ``first`` with ``second`` under ``symmetry``
        and ``chosen.h`` is on its full grid.
    residual : Residual
        The chosen answer's coordinate residual.
    options : Options
    log : Log
        Progress reports of the refinements (stage "alternatives").
    refine_margin : float
        A twin that is not equally good as it stands is refined (the refinement levels, on E) and judged again,
        unless its residual exceeds the chosen one's by more than this (area-1 length; default: always refined).

    Returns
    -------
    list of Alternative
        Sorted by E; one per symmetry of the square (what ``Options.symmetry`` can pin: of two twins under one
        symmetry, the lower E).
    """
    objective = chosen.objective
    h = symmetry_map(symmetry, chosen.h)  # the answer's h, the symmetry included
    at = GridInterpolator(h, objective.r, objective.t)
    # (sigma, tau): the twin sigma o h o tau
    twins = [(0, tau) for tau in self_symmetries(first)] + [(s, 0) for s in self_symmetries(second)]
    found = []
    for left, right in twins:
        uv = symmetry_map(right, objective.identity)
        image = symmetry_map(left, at(uv[..., 0], uv[..., 1])[0])
        k = compose_symmetries(left, compose_symmetries(symmetry, right))
        rotation, energy, twin_residual = objective.judge(symmetry_map(inverse_symmetry(symmetry), image))
        if twin_residual.mirrored or _listed(found, k, rotation):
            continue
        if not equally_good(energy, twin_residual.plus, chosen.energy, residual.plus, options):
            if twin_residual.plus > residual.plus + refine_margin:
                continue
            start = symmetry_map(inverse_symmetry(k), image)  # orientation preserving on the copy under k
            rotation, energy, twin_residual = _refined(
                first, apply_symmetry(second, k), area, rotation, start, options, log
            )
            if twin_residual.mirrored or not equally_good(
                energy, twin_residual.plus, chosen.energy, residual.plus, options
            ):
                continue
        _add(found, Alternative(k, rotation, float(energy), twin_residual.plus))
    return sorted(found, key=lambda a: a.energy)


def _add(found: list[Alternative], alternative: Alternative) -> None:
    """List ``alternative`` once per symmetry (what ``Options.symmetry`` can pin): of two twins under one symmetry,
    the lower E. Two whose rotations differ by more than SAME_ANSWER were listed twice, and the note said "the others
    4 (180 deg), 4 (180 deg)" (a held-out square terrain meshed with 8 boundary vertices)."""
    same = next((i for i, a in enumerate(found) if a.symmetry == alternative.symmetry), None)
    if same is None:
        found.append(alternative)
    elif alternative.energy < found[same].energy:
        found[same] = alternative


def _listed(found: list[Alternative], symmetry: int, rotation: np.ndarray) -> bool:
    """Whether the correspondence (symmetry, rotation) is among ``found`` already."""
    return any(a.symmetry == symmetry and angle_between(a.rotation, rotation) < SAME_ANSWER for a in found)


def _refined(first: GridSurface, second: GridSurface, area: float, rotation, h, options: Options, log: Log):
    """The refinement levels of the chosen candidate run from (R, h) (h at the full grid's nodes, orientation
    preserving) on ``first`` and ``second``; returns R, E and the residual."""
    objective = Objective(first, second, area)
    drive = Descent(objective, options, *work_objective(objective, first, second, area))
    start = valid_start(drive.work, drive.restrict(enforce_boundary(h.copy())))
    scratch = Log(log.callback, {}, "alternatives")
    candidate = Candidate(objective, rotation, start, float("nan"), scratch, pending=drive).polish()
    return candidate.rotation, candidate.energy, candidate.residual()
