"""Gaussian smoothing along the first axis of an array, to the bit as ``scipy.ndimage.gaussian_filter1d`` computes
it (the same normalized kernel, the same sums of symmetric pairs from the outermost in), without importing
scipy.ndimage and scipy.special (0.05 s at every start).
"""

from __future__ import annotations

import numpy as np


def gaussian_kernel(sigma: float, truncate: float) -> np.ndarray:
    """The normalized Gaussian weights (2 r + 1,) of standard deviation ``sigma`` (samples) out to r =
    int(truncate * sigma + 0.5) samples each side."""
    radius = int(truncate * float(sigma) + 0.5)
    x = np.arange(-radius, radius + 1)
    weights = np.exp(-0.5 / (float(sigma) * float(sigma)) * x**2)
    return weights / weights.sum()


def gaussian_filter1d(values: np.ndarray, sigma: float, mode: str = "nearest", truncate: float = 4.0) -> np.ndarray:
    """``values`` (n, ...) smoothed along axis 0 by a Gaussian of standard deviation ``sigma`` (samples).

    Parameters
    ----------
    values : ndarray (n, ...)
    sigma : float
        Standard deviation, in samples (> 0).
    mode : {"nearest", "constant"}
        Beyond the ends: the end samples repeated, or zeros.
    truncate : float
        The kernel's reach in standard deviations.

    Returns
    -------
    ndarray, float64, the shape of ``values``.

    Examples
    --------
    >>> gaussian_filter1d(np.array([0.0, 0.0, 1.0, 0.0, 0.0]), 1.0, truncate=1.0).round(3).tolist()
    [0.0, 0.274, 0.452, 0.274, 0.0]
    """
    if mode not in ("nearest", "constant"):
        raise ValueError(f"mode must be 'nearest' or 'constant', not {mode!r}")
    weights = gaussian_kernel(sigma, truncate)
    radius = len(weights) // 2
    values = np.asarray(values, dtype=float)
    n = len(values)
    ends = [(radius, radius)] + [(0, 0)] * (values.ndim - 1)
    padded = np.pad(values, ends, mode="edge" if mode == "nearest" else "constant")
    out = padded[radius : radius + n] * weights[radius]
    for d in range(radius, 0, -1):
        out += (padded[radius - d : radius - d + n] + padded[radius + d : radius + d + n]) * weights[radius - d]
    return out
