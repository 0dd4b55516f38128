"""Global search for a starting point: symmetries of the square and candidate rotations.

The descent only finds the minimum of the basin it starts in. Two things put it in the wrong basin:

* the corner of the second surface's parametrization that is (0, 0), and whether r and t are
  swapped (arbitrary for meshes mapped to the square): the 8 symmetries of the square;
* a rotation far from the one Kabsch finds at the identity correspondence.

:func:`best_start` tries every symmetry with rotation candidates (Kabsch at the identity, the 24
rotations of the cube's symmetry group, and the 4 proper alignments of the principal axes),
ranks them by DP-surface-min on coarse grids (a pass along r, then one along t for each symmetry's best), and
returns the best.

E cannot decide alone: it is blind to the sign of a surface (``q(-c) = q(c)``), so when the surface has a
mirror symmetry, an orientation-reversing symmetry of the square reaches the same E as the right start with
the aligned first surface on the point reflection of the second (see :mod:`meshreg.residual`). Each DP result
is therefore also judged by its coordinate residual: a mirrored one is never a start, only a record that a
mirror image fits (:attr:`Start.mirrored`).
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import product

import numpy as np

from .dp import dp_surface_min
from .grid import GridSurface
from .objective import Objective
from .rotation import kabsch
from .schedule import dp_pass
from .srnf import cell_normals

# (swap r and t, flip r, flip t); index 0 is the identity
SQUARE_SYMMETRIES = tuple(product((False, True), repeat=3))
# the 4 that keep orientation (an even number of swaps and flips: the rotations of the square)
ORIENTATION_PRESERVING = tuple(k for k, s in enumerate(SQUARE_SYMMETRIES) if sum(s) % 2 == 0)
DEFAULT_SEARCH_GRID = 21
DEFAULT_SEARCH_WINDOW = 6
# Kabsch alternations of each ranking DP pass
SEARCH_DP_ROUNDS = 3


def apply_symmetry(surface: GridSurface, k: int) -> GridSurface:
    """The surface reparametrized by the k-th symmetry of the square: points'[i, j] = c(sigma_k(r'_i, t'_j))."""
    swap, flip_r, flip_t = SQUARE_SYMMETRIES[k]
    p, r, t = surface.points, surface.r, surface.t
    if swap:
        p, r, t = p.transpose(1, 0, 2), t, r
    if flip_r:
        p, r = p[::-1], 1.0 - r[::-1]
    if flip_t:
        p, t = p[:, ::-1], 1.0 - t[::-1]
    return GridSurface(np.ascontiguousarray(p), r, t)


def compose_symmetries(a: int, b: int) -> int:
    """The index of sigma_a o sigma_b (first sigma_b, then sigma_a)."""
    probe = np.array([0.1, 0.3])
    target = symmetry_map(a, symmetry_map(b, probe))
    return next(k for k in range(len(SQUARE_SYMMETRIES)) if np.allclose(symmetry_map(k, probe), target))


def inverse_symmetry(k: int) -> int:
    """The index of sigma_k^-1."""
    return next(j for j in range(len(SQUARE_SYMMETRIES)) if compose_symmetries(j, k) == 0)


def symmetry_map(k: int, uv: np.ndarray) -> np.ndarray:
    """sigma_k applied to points (..., 2) of the square: where (u, v) of the symmetric copy lies on the original."""
    swap, flip_r, flip_t = SQUARE_SYMMETRIES[k]
    u, v = uv[..., 0], uv[..., 1]
    if flip_r:
        u = 1.0 - u
    if flip_t:
        v = 1.0 - v
    if swap:
        u, v = v, u
    return np.stack([u, v], axis=-1)


def cube_rotations() -> np.ndarray:
    """The 24 rotations of the cube's symmetry group (signed permutation matrices with det +1), (24, 3, 3)."""
    out = []
    for perm in ((0, 1, 2), (0, 2, 1), (1, 0, 2), (1, 2, 0), (2, 0, 1), (2, 1, 0)):
        for signs in product((1.0, -1.0), repeat=3):
            m = np.zeros((3, 3))
            m[range(3), perm] = signs
            if np.linalg.det(m) > 0:
                out.append(m)
    return np.array(out)


def _principal_axes(surface: GridSurface) -> np.ndarray:
    """Eigenvectors (columns, decreasing variance) of the area-weighted covariance of the points."""
    c = surface.points
    centres = 0.25 * (c[1:, 1:] + c[:-1, :-1] + c[1:, :-1] + c[:-1, 1:]).reshape(-1, 3)
    n = cell_normals(c).reshape(-1, 3)
    w = np.linalg.norm(n, axis=1)
    mean = (w[:, None] * centres).sum(0) / w.sum()
    d = centres - mean
    _, vecs = np.linalg.eigh((w[:, None] * d).T @ d)
    return vecs[:, ::-1]


def principal_rotations(first: GridSurface, second: GridSurface) -> np.ndarray:
    """The 4 rotations taking the first surface's principal axes onto the second's, (4, 3, 3)."""
    a, b = _principal_axes(first), _principal_axes(second)
    out = []
    for s1, s2 in product((1.0, -1.0), repeat=2):
        s = np.diag([s1, s2, s1 * s2 * np.linalg.det(a) * np.linalg.det(b)])
        out.append(b @ s @ a.T)
    return np.array(out)


def tried_symmetries(symmetries: bool, keep_orientation: bool, only: int | None = None) -> tuple[int, ...]:
    """The symmetries of the square a start search tries: ``only`` when pinned; else all 8, or the 4 that keep
    orientation (``keep_orientation``); the identity alone without ``symmetries``."""
    if only is not None:
        return (only,)
    if not symmetries:
        return (0,)
    return ORIENTATION_PRESERVING if keep_orientation else tuple(range(len(SQUARE_SYMMETRIES)))


@dataclass(frozen=True)
class Start:
    """A ranked starting point: symmetry index, rotation and the coarse DP energy.

    ``mirrored``: the DP's aligned first surface is closer to the point reflection of the second than to it
    (:class:`meshreg.residual.Residual`); such a start is never registered. ``residual``: the coordinate residual
    of the coarse DP match (:attr:`meshreg.residual.Residual.plus`; NaN where not measured).
    """

    symmetry: int
    rotation: np.ndarray
    energy: float
    mirrored: bool = False
    residual: float = float("nan")


def best_start(
    first: GridSurface,
    second: GridSurface,
    *,
    symmetries: bool = True,
    keep_orientation: bool = False,
    only: int | None = None,
    grid: int = DEFAULT_SEARCH_GRID,
    window: int = DEFAULT_SEARCH_WINDOW,
) -> list[Start]:
    """Rank (symmetry, rotation) starts by DP-surface-min on coarse grids; best first.

    Each rotation candidate gets a DP pass along r; the best of each symmetry (and its best mirrored one, if any)
    also one along t, and is ranked by the lower of the two energies (:func:`_after_t_pass`).

    Parameters
    ----------
    first, second : GridSurface
    symmetries : bool
        Try the 8 symmetries of the square (else only the identity).
    keep_orientation : bool
        With ``symmetries``, try only the 4 that keep orientation (:data:`ORIENTATION_PRESERVING`).
    only : int, optional
        Try this symmetry alone (a user's pin; overrides ``symmetries`` and ``keep_orientation``).
    grid : int
        Both surfaces are resampled on grid x grid nodes for the ranking. Default 21.
    window : int
        DP window for the ranking. Default 6.

    Returns
    -------
    list of Start
        Per symmetry its best rotation whose DP match is not mirrored, and before it its best rotation
        overall when that one is mirrored (flagged ``mirrored``); sorted by energy.
    """
    coarse1 = first.scaled().resampled(grid, grid)
    coarse2 = second.scaled().resampled(grid, grid)
    rotations = np.concatenate([cube_rotations(), principal_rotations(coarse1, coarse2)])
    starts = []
    for k in tried_symmetries(symmetries, keep_orientation, only):
        starts += _symmetry_starts(Objective(coarse1, apply_symmetry(coarse2, k)), k, rotations, window)
    return sorted(starts, key=lambda s: s.energy)


def _symmetry_starts(ob: Objective, k: int, rotations: np.ndarray, window: int) -> list[Start]:
    """The starts of symmetry ``k`` (``ob`` the coarse pair under it): a DP pass along r from Kabsch at the identity
    and from each of ``rotations``; the best whose match is not mirrored, and before it the best overall when that
    one is mirrored, each ranked after the pass along t (:func:`_after_t_pass`)."""
    q2 = ob.second_on_first_grid()
    candidates = [kabsch(ob.best_rotation_covariance(ob.identity)), *rotations]
    seen = {}
    results = [
        dp_surface_min(
            ob.q1, q2, ob.r, ob.r, ob.t, window=window, rotation=rotation, max_rounds=SEARCH_DP_ROUNDS, seen=seen
        )
        for rotation in candidates
    ]
    starts = []
    for result in sorted(results, key=lambda x: x.energy):
        h = ob.identity.copy()
        h[..., 0] = result.gamma[:, None]
        residual = ob.residual(result.rotation, h)
        if residual.mirrored and starts:
            continue  # one mirrored record per symmetry: its best
        energy = _after_t_pass(ob, result.rotation, h, window)
        starts.append(Start(k, result.rotation, energy, residual.mirrored, residual.plus))
        if not residual.mirrored:
            break
    return starts


def _after_t_pass(objective: Objective, rotation: np.ndarray, h: np.ndarray, window: int) -> float:
    """The coarse E (:meth:`Objective.energy`) of a match found along r (``rotation``, ``h``) after one more DP pass
    along t, or before it when that is lower (both measured alike: the DP's own energy, from its edge costs, differs
    from E at the same R and h, by 40% on the paper's sine 2-3 pair). A warp along t that the pass along r cannot
    undo would otherwise rank the right start low: a random terrain under a warp with a power of 1.29 along t had
    the right symmetry's coarse E at 0.217 against 0.115 for a wrong one, which ended at E 0.032 with points 4% off
    (``bench_heldout.py --random``, case 41); after the pass along t the right one ranked first and reached E 4e-9.
    On 2:1 sheets of low relief the starts that swap r and t ranked first before it (a flat rectangle's q does not
    see the swap) and the answers were 180 degrees off (cases 5, 16, 99)."""
    before = objective.energy(rotation, h)
    return min(before, dp_pass(objective, rotation, h, window, SEARCH_DP_ROUNDS, along_t=True)[2])
