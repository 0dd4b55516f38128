"""Gaussian scale space of a grid surface: the surface smoothed over the parameter square.

A descent from the identity settles in the nearest local minimum of E, which for surfaces with
different numbers of folds (the paper's sine 2 against sine 4) is far from the best one. Smoothing
both surfaces first removes small folds, so a descent on the smoothed pair makes the large moves, and
descents on less smoothed pairs, each from the previous one's R and h, bring back the detail
(graduated optimization). Smoothing blurs in parameter space, which is not invariant under
reparametrization, so the last level is always the original pair.
"""

from __future__ import annotations

import numpy as np

from .gaussian import gaussian_filter1d
from .grid import GridSurface

NODES_PER_SIGMA = 5  # grid spacing of a smoothed level: sigma / NODES_PER_SIGMA
MIN_LEVEL_NODES = 11


def level_nodes(sigma: float, limit: int) -> int:
    """Nodes per axis for a surface smoothed with ``sigma``: enough to sample it, at most ``limit``."""
    return int(min(limit, max(MIN_LEVEL_NODES, np.ceil(NODES_PER_SIGMA / sigma) + 1)))


def smoothed(surface: GridSurface, sigma: float, nodes: int) -> GridSurface:
    """The surface on a uniform ``nodes`` x ``nodes`` grid, blurred by a Gaussian in (r, t).

    Parameters
    ----------
    surface : GridSurface
    sigma : float
        Standard deviation of the Gaussian, in units of the unit square (0.1 = a tenth of a side).
    nodes : int
        Nodes per axis of the result.

    Returns
    -------
    GridSurface
        Each coordinate filtered along r, then t. Beyond each side the surface is continued by point
        reflection (c(-r) = 2 c(0) - c(r)), so that sides stay in place and planes stay planes.

    Examples
    --------
    >>> from meshreg.samples import sine
    >>> r = t = np.linspace(0, 1, 41)
    >>> flat = GridSurface(sine(4)(*np.meshgrid(r, t, indexing="ij")), r, t)
    >>> wave = np.ptp(smoothed(flat, 0.1, 41).points[..., 0])
    >>> bool(wave < 0.5 * np.ptp(flat.points[..., 0]))
    True
    """
    uniform = surface.resampled(nodes, nodes)
    points = uniform.points
    for axis in (0, 1):
        points = _blur(points, sigma * (nodes - 1), axis)
    return GridSurface(points, uniform.r, uniform.t)


def _blur(points: np.ndarray, sigma_nodes: float, axis: int) -> np.ndarray:
    """Gaussian filter along ``axis`` with the array continued by point reflection at both ends."""
    pad = min(int(np.ceil(4 * sigma_nodes)), points.shape[axis] - 1)
    a = np.moveaxis(points, axis, 0)
    head = 2 * a[:1] - a[pad:0:-1]
    tail = 2 * a[-1:] - a[-2 : -pad - 2 : -1]
    extended = np.concatenate([head, a, tail])
    blurred = gaussian_filter1d(extended, sigma_nodes, "nearest", 4.0)
    return np.moveaxis(blurred[pad : pad + a.shape[0]], 0, axis)
