"""Statistics of shapes in correspondence (aligned grids of one connectivity): the Karcher update of a template,
spread, the q-space gap of a coordinate mean, principal modes and canonical correlations. Pure numpy."""

from __future__ import annotations

import numpy as np

from .grid import GridSurface
from .srnf import cell_weights, shape_function

ROUNDING_MODES = 10.0  # singular values of a PCA below this many roundings count as 0 (principal_modes)


def karcher_update(aligned: np.ndarray, r: np.ndarray, t: np.ndarray) -> GridSurface:
    """The next template: the node-by-node mean of aligned shapes (K, M, N, 3), centred, at area 1."""
    mean = GridSurface(aligned.mean(axis=0), r, t).scaled()
    return GridSurface(mean.points - mean.points.reshape(-1, 3).mean(axis=0), r, t)


def rms_spread(shapes: np.ndarray) -> float:
    """Root mean square distance of the shapes' vertices (K, V, 3) from the mean shape's."""
    return float(np.sqrt(np.mean(np.sum((shapes - shapes.mean(axis=0)) ** 2, axis=-1))))


def karcher_gap(template: GridSurface, aligned: np.ndarray, energies: np.ndarray, floor: float = 0.0) -> float:
    """||q(T) - mean_j q(aligned_j)||^2 / mean_j E_j: the fraction of the Karcher objective that the mean of the aligned
    shape functions (the minimizer for these alignments, not a surface in general) would remove (0 when the mean E
    is at most ``floor``, where it means nothing)."""
    r, t = template.r, template.t
    w = cell_weights(r, t)[..., None]
    q_mean = np.mean([shape_function(a, r, t) for a in aligned], axis=0)
    gap = float(np.sum(w * (shape_function(template.points, r, t) - q_mean) ** 2))
    objective = float(np.mean(energies))
    return gap / objective if objective > floor else 0.0


def principal_modes(shapes: np.ndarray, count: int):
    """PCA of K shapes (K, V, 3) in correspondence.

    Returns mean (V, 3), unit modes (k, V, 3) (each signed so that its largest component is positive), variances
    (k,) (sample variances, K - 1 in the denominator), explained fractions of the total variance (k,; 0 when all
    shapes are equal) and scores (K, k), with k = min(count, K - 1). The total variance is ``variances.sum() /
    explained.sum()`` (when not 0). Singular values at the level of the coordinates' rounding count as 0 (below
    ``ROUNDING_MODES`` eps max|x| (sqrt(K) + sqrt(3 V)), about the largest singular value of a K x 3V matrix of
    independent errors of one rounding of the largest coordinate): equal shapes have no mode, not one that explains
    100% of a variance of 1e-30; shapes far from the origin (terrain in map coordinates) keep modes of micrometres.
    """
    k_shapes = len(shapes)
    x = shapes.reshape(k_shapes, -1)
    mean = x.mean(axis=0)
    u, s, vt = np.linalg.svd(x - mean, full_matrices=False)
    rounding = (
        ROUNDING_MODES * np.finfo(float).eps * np.abs(x).max(initial=0.0) * (np.sqrt(x.shape[0]) + np.sqrt(x.shape[1]))
    )
    s = np.where(s > rounding, s, 0.0)
    k = min(count, max(k_shapes - 1, 0))
    signs = np.sign(vt[np.arange(k), np.argmax(np.abs(vt[:k]), axis=1)])
    modes, scores = vt[:k] * signs[:, None], u[:, :k] * s[:k] * signs
    denominator = max(k_shapes - 1, 1)
    variances = s[:k] ** 2 / denominator
    total = float(np.sum(s**2)) / denominator
    explained = variances / total if total > 0 else np.zeros(k)
    return mean.reshape(-1, 3), modes.reshape(k, -1, 3), variances, explained, scores


def canonical_correlations(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Canonical correlations (min(p, q),) of two sets of variables x (K, p) and y (K, q), largest first: how well
    linear combinations of one (e.g. the first modes' scores) follow the other (e.g. known generating parameters)."""
    x = np.asarray(x, dtype=float).reshape(len(x), -1)
    y = np.asarray(y, dtype=float).reshape(len(y), -1)
    qx, _ = np.linalg.qr(x - x.mean(axis=0))
    qy, _ = np.linalg.qr(y - y.mean(axis=0))
    return np.clip(np.linalg.svd(qx.T @ qy, compute_uv=False), 0.0, 1.0)
