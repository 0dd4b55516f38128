"""The settings of a shape atlas (:func:`meshreg.atlas`): light, so that the command line can show their defaults."""

from __future__ import annotations

from dataclasses import dataclass

from .options import Options, _integer, _number

ATLAS_RESOLUTION = 41
ATLAS_OPTIONS = Options(resolution=ATLAS_RESOLUTION, keep_orientation=True)
"""The atlas's registration defaults: :class:`~meshreg.options.Options` but for meshes resampled on 41 x 41 grids (a
2k-triangle mesh has about 32 x 32 vertices; 101 costs 2-3x the time for detail such meshes do not hold) and
``keep_orientation`` (a cohort's meshes are wound alike; mirrored matches of nearly symmetric members come within a
few percent of the right E and would put vertex k at mirrored places on different members)."""


@dataclass(frozen=True)
class AtlasSettings:
    """How the template is iterated and what the atlas keeps; validated when made.

    Attributes
    ----------
    tolerance : float
        Stop when the mean energy F to the template falls by at most this fraction of itself in one iteration (plus
        ``Options.advanced.abs_tol``, the accuracy of E). Default 0.01.
    max_iterations : int
        Most registration rounds (the first registers to the medoid). Default 8.
    modes : int
        Principal modes kept (at most the number of members minus one). Default 10.
    medoid_grid : int
        Nodes per axis of the coarse grids the medoid's distance matrix is computed on. Default 21.
    """

    tolerance: float = 0.01
    max_iterations: int = 8
    modes: int = 10
    medoid_grid: int = 21

    def __post_init__(self):
        _number("tolerance", self.tolerance, 0.0, 1.0)
        _integer("max_iterations", self.max_iterations, 1, 1000)
        _integer("modes", self.modes, 1, 100_000)
        _integer("medoid_grid", self.medoid_grid, 5, 1001)
