"""Corners of a disk mesh's boundary on the square, and the search for the second mesh's corner placement.

A boundary with four clear turns (a scanned sheet, a terrain tile) has natural corners. A smooth boundary (a
round crop of a scan) has none, and two meshes of one surface would get their corners at different places,
which no reparametrization that keeps the corners can undo: :func:`search_corners` tries placements of the
second mesh's corners and ranks them by a coarse DP.
"""

from __future__ import annotations

import numpy as np

from ..grid import GridSurface
from ..options import Options
from ..search import best_start
from .harmonic import HarmonicMap, arc_fraction, choose_corners, has_sharp_corners, quarter_corners
from .resample import DEFAULT_ANTIALIAS, resample_grid
from .topology import DiskMesh, prepare_disk

CORNER_SEARCH_GRID = 21  # coarse grid on which the trial placements are ranked


def placement_starts(disk: DiskMesh, trials: int) -> np.ndarray:
    """Arc-length fractions (trials,) of the trial corner placements of a disk: quarter arc lengths from
    ``trials`` starts spaced by 1/(4 trials) of its boundary, the first at the point where
    :func:`~meshreg.mesh.harmonic.choose_corners` would start (a quarter turn is a symmetry of the square)."""
    return arc_fraction(disk, int(choose_corners(disk)[0])) + 0.25 / trials * np.arange(trials)


def placement_corners(disk: DiskMesh, trials: int) -> list[np.ndarray]:
    """Corner loop positions (4,) of each trial placement of :func:`placement_starts`; the first is the
    placement a round-boundary mesh uses as the first surface of a pair."""
    return [quarter_corners(disk, start % 1.0) for start in placement_starts(disk, trials)]


def placement_energy(coarse1, coarse2, keep_orientation: bool = False) -> float:
    """Rank of a corner placement: the best coarse DP energy over the square's symmetries (those that keep
    orientation with ``keep_orientation``) and rotations, of a match that is not mirrored
    (:func:`meshreg.search.best_start`)."""
    starts = best_start(coarse1, coarse2, keep_orientation=keep_orientation)
    return next((s.energy for s in starts if not s.mirrored), float("inf"))


def best_placement(first: GridSurface, placements: list[GridSurface], keep_orientation: bool = False) -> int:
    """Index of the second surface's corner placement (each a grid) that matches ``first`` best, by
    :func:`placement_energy` on CORNER_SEARCH_GRID x CORNER_SEARCH_GRID grids."""
    n = CORNER_SEARCH_GRID
    coarse = first.scaled().resampled(n, n)
    energies = [placement_energy(coarse, g.scaled().resampled(n, n), keep_orientation) for g in placements]
    return int(np.argmin(energies))


def corner_positions(disks: list[DiskMesh], maps: list[HarmonicMap], options: Options) -> tuple[list, list | None]:
    """Corner loop positions (4,) of both meshes of a pair: given ids (``options.corners1/2``), four clear
    turns, or the first's own placement and a search of the second's (:func:`search_corners`) when the
    boundaries are round. Returns the positions and the placements tried (None without a search)."""
    given = (options.corners1, options.corners2)
    pos = [choose_corners(d, None if c is None else d.input_ids(c)) for d, c in zip(disks, given, strict=True)]
    search = options.corner_search > 0 and given == (None, None) and not all(has_sharp_corners(d) for d in disks)
    if not search:
        return pos, None
    pos[0] = placement_corners(disks[0], 1)[0]
    pos[1], tried = search_corners(
        maps[0], pos[0], maps[1], options.corner_search, options.keep_orientation, options.antialias
    )
    return pos, tried


def search_corners(
    first: HarmonicMap,
    corners1: np.ndarray,
    second: HarmonicMap,
    trials: int = 8,
    keep_orientation: bool = False,
    antialias: int = DEFAULT_ANTIALIAS,
) -> tuple[np.ndarray, list]:
    """Corners of the second mesh that best match the first's: the ``trials`` placements of
    :func:`placement_starts`, then one halving step around the best, ranked by :func:`placement_energy`
    on 21 x 21 grids (resampled with ``antialias``, see :func:`~meshreg.mesh.resample.resample_grid`).

    A smooth boundary (a round crop) has no natural corners: two meshes of one surface get corners at
    different places, and no reparametrization that keeps the corners can undo that. This finds them.

    Returns the second's corner loop positions (4,) and the (start, energy) pairs tried.
    """
    n = CORNER_SEARCH_GRID
    disk1, disk2 = first.disk, second.disk
    coarse1 = resample_grid(disk1.vertices, disk1.faces, first(corners1)[0], n, n, antialias)

    def energy(start):
        uv = second(quarter_corners(disk2, start))[0]
        grid = resample_grid(disk2.vertices, disk2.faces, uv, n, n, antialias)
        return placement_energy(coarse1, grid, keep_orientation)

    starts = placement_starts(disk2, trials)
    tried = [(start, energy(start)) for start in starts]
    best = min(tried, key=lambda x: x[1])[0]
    tried += [(best + d, energy(best + d)) for d in (-0.125 / trials, 0.125 / trials)]
    best = min(tried, key=lambda x: x[1])[0]
    return quarter_corners(disk2, best % 1.0), tried


def mesh_grids(vertices: np.ndarray, faces: np.ndarray, options: Options):
    """One mesh, on its own, to grid surfaces: clean, map to the square, resample on grids of
    ``options.resolution`` nodes per axis (``options.cleanup``, ``options.weights``, ``options.antialias``).

    With four clear corners (or ``options.corner_search=0``), one grid (corners by
    :func:`~meshreg.mesh.harmonic.choose_corners`); else one grid per trial corner placement of
    :func:`placement_starts` (one LU serves them all), the first of which is the mesh's own placement when
    it is the first surface of a pair; a pair ranks the second's placements by :func:`placement_energy`.

    Returns the list of GridSurfaces and an info dict (cleanup report, corners, flipped and degenerate counts).
    """
    disk = prepare_disk(vertices, faces, cleanup=options.cleanup)
    hmap = HarmonicMap(disk, options.weights)
    if options.corner_search > 0 and not has_sharp_corners(disk):
        placements = placement_corners(disk, options.corner_search)
    else:
        placements = [choose_corners(disk)]
    maps = [hmap(corners) for corners in placements]
    n = options.resolution
    grids = [resample_grid(disk.vertices, disk.faces, uv, n, n, options.antialias) for uv, _ in maps]
    return grids, {**maps[0][1], "cleanup": disk.report}
