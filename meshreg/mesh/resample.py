"""Resample a parametrized mesh on a grid over the unit square (barycentric interpolation, numba), anti-aliased.

A node that takes the mesh's point at its place (a point sample) sees whatever detail lies there, below the grid's
resolution too: on a range scan, the scanner's noise, which E then counts (normals are derivatives and amplify
it). So by default each node is the mean of the mesh around it weighted by the node's hat function (the
piecewise-linear basis function of the grid), computed from point samples ``antialias`` times finer; across the
sides of the square the samples are reflected through the side node (odd reflection), so that sides and corners
stay exact and planes stay planes. On pymeshlab's face-scan crop against a remeshed copy
(``benchmarks/bench_face.py``) this took E at 101 x 101 from 0.026, where more refinement no longer helped, to
0.014.
"""

from __future__ import annotations

import numba
import numpy as np

from ..errors import InputError
from ..gaussian import gaussian_filter1d
from ..grid import GridSurface
from .locate import barycentric, uv_triangle

DEFAULT_GRID = 101
DEFAULT_ANTIALIAS = 3  # as Options.antialias
GAUSS_TAIL = 4.0  # blur_grid's kernel reaches this many standard deviations each way
# Options.mesh_blur is applied when its standard deviation is at least this many grid spacings (below, the anti-aliased
# resampling's own average over about one spacing is as wide): at the default mesh_blur on 101 x 101 grids, meshes of
# more than about 150,000 vertices spread evenly over the surface are not blurred
MIN_BLUR = 0.5


@numba.njit(cache=True)
def _node_range(nodes, low, high):
    """First node >= low and first node > high of uniformly spaced increasing nodes (as np.searchsorted with
    side left and right), from the spacing and then checked against the nodes themselves: no binary search."""
    if not low <= high:  # NaN corners: no node
        return 0, 0
    last, step = nodes.shape[0] - 1, (nodes[-1] - nodes[0]) / max(nodes.shape[0] - 1, 1)
    i0 = min(max(int(np.floor((low - nodes[0]) / step)), 0), last + 1)
    while i0 > 0 and nodes[i0 - 1] >= low:
        i0 -= 1
    while i0 <= last and nodes[i0] < low:
        i0 += 1
    i1 = min(max(int(np.floor((high - nodes[0]) / step)), 0), last + 1)
    while i1 > 0 and nodes[i1 - 1] > high:
        i1 -= 1
    while i1 <= last and nodes[i1] <= high:
        i1 += 1
    return i0, i1


@numba.njit(cache=True)
def _rasterize(uv, faces, values, r, t, out, hit, tol):
    m, n = r.shape[0], t.shape[0]
    for f in range(faces.shape[0]):
        ax, ay, bx, by, cx, cy, det = uv_triangle(uv, faces, f)
        if abs(det) < 1e-300:
            continue
        i0, i1 = _node_range(r, min(ax, bx, cx) - tol, max(ax, bx, cx) + tol)
        j0, j1 = _node_range(t, min(ay, by, cy) - tol, max(ay, by, cy) + tol)
        for i in range(i0, min(i1, m)):
            for j in range(j0, min(j1, n)):
                px, py = r[i], t[j]
                l0, l1, l2 = barycentric(ax, ay, bx, by, cx, cy, det, px, py)
                worst = min(l0, l1, l2)
                if worst >= -tol and worst > hit[i, j]:
                    hit[i, j] = worst
                    a, b, c = faces[f, 0], faces[f, 1], faces[f, 2]
                    for k in range(values.shape[1]):
                        out[i, j, k] = l0 * values[a, k] + l1 * values[b, k] + l2 * values[c, k]


def resample_grid(
    vertices: np.ndarray,
    faces: np.ndarray,
    uv: np.ndarray,
    m: int = DEFAULT_GRID,
    n: int = DEFAULT_GRID,
    antialias: int = DEFAULT_ANTIALIAS,
) -> GridSurface:
    """The mesh on a uniform m x n grid of its uv square.

    Parameters
    ----------
    vertices : ndarray, shape (k, 3)
    faces : ndarray, shape (f, 3)
    uv : ndarray, shape (k, 2)
        Each vertex's place on the square.
    m, n : int
        Grid nodes along r and t. Default 101.
    antialias : int
        Each node is the hat-weighted mean of point samples on a grid this many times finer (1: the point
        sample at the node itself). Default 3.

    A point sample is the barycentric interpolation of the triangle that contains it (with a small
    tolerance so that samples on the square's edges are never missed; of several candidates the one
    the sample lies deepest inside wins).
    """
    fine = _point_samples(vertices, faces, uv, antialias * (m - 1) + 1, antialias * (n - 1) + 1)
    if antialias > 1:
        fine = _hat_mean(_hat_mean(fine, antialias, 0), antialias, 1)[::antialias, ::antialias]
    return GridSurface.from_array(fine, np.linspace(0, 1, m), np.linspace(0, 1, n))


def _point_samples(vertices: np.ndarray, faces: np.ndarray, uv: np.ndarray, m: int, n: int) -> np.ndarray:
    """The mesh at the nodes of a uniform m x n grid of its uv square, shape (m, n, 3)."""
    r, t = np.linspace(0, 1, m), np.linspace(0, 1, n)
    out = np.zeros((m, n, 3))
    hit = np.full((m, n), -np.inf)
    _rasterize(
        np.ascontiguousarray(uv, dtype=float),
        np.ascontiguousarray(faces, dtype=np.int64),
        np.ascontiguousarray(vertices, dtype=float),
        r,
        t,
        out,
        hit,
        1e-9,
    )
    missing = int(np.sum(hit == -np.inf))
    if missing:
        raise InputError(f"{missing} grid nodes fall in no triangle of the parametrization (it has folds or gaps)")
    return out


def _odd_padded(v: np.ndarray, k: int) -> np.ndarray:
    """``v`` with k samples added beyond each end of axis 0, reflected oddly through the end sample (2 v_0 - v_i)."""
    return np.concatenate([2 * v[:1] - v[k:0:-1], v, 2 * v[-1:] - v[-2 : -k - 2 : -1]])


def _hat_mean(values: np.ndarray, k: int, axis: int) -> np.ndarray:
    """Means of ``values`` along ``axis`` weighted by the hat function of half-width k samples (1, 2, .., k, ..,
    2, 1), the samples beyond each end reflected oddly through the end sample (2 v_0 - v_i): linear data is
    kept exactly, and the end samples are kept."""
    v = np.moveaxis(values, axis, 0)
    weights = np.r_[np.arange(1, k + 1), np.arange(k - 1, 0, -1)] / float(k * k)
    padded = _odd_padded(v, k - 1)
    out = sum(w * padded[i : i + len(v)] for i, w in enumerate(weights))
    return np.moveaxis(out, 0, axis)


def blur_sigma(edge: float, mesh_blur: float, nodes: int) -> float:
    """The standard deviation (side lengths of the square) of the Gaussian that blurs the grids of a mesh whose
    median edge on the square is ``edge`` (:func:`meshreg.mesh.harmonic.edge_length`; of a pair, the coarser one's):
    ``mesh_blur`` (``Options.mesh_blur``) times it, or 0 when that is below MIN_BLUR spacings of a grid of ``nodes``
    nodes per axis."""
    sigma = mesh_blur * edge
    return float(sigma) if sigma * (nodes - 1) >= MIN_BLUR else 0.0


def blur_grid(grid: GridSurface, sigma: float) -> GridSurface:
    """``grid`` blurred by a Gaussian of standard deviation ``sigma`` (nodes, the same along both axes: the grid's
    nodes are taken as equally spaced) along both axes, the nodes beyond the sides reflected oddly through the side
    nodes, repeatedly where the kernel reaches beyond the opposite side (planes stay planes; the sides move only with
    the curve of the surface across them). Its nodes' parameters are kept.

    Examples
    --------
    >>> r = np.linspace(0, 1, 11)
    >>> u, v = np.meshgrid(r, r, indexing="ij")
    >>> plane = GridSurface.from_array(np.stack([u, v, 0.3 * u - v], -1), r, r)
    >>> bool(np.allclose(blur_grid(plane, 2.0).points, plane.points))
    True
    """
    points = grid.points
    for axis in (0, 1):
        v = np.moveaxis(points, axis, 0)
        k = int(np.ceil(GAUSS_TAIL * sigma))
        padded = np.pad(v, [(k, k)] + [(0, 0)] * (v.ndim - 1), mode="reflect", reflect_type="odd")
        v = gaussian_filter1d(padded, sigma, "constant", GAUSS_TAIL)[k : k + len(v)]
        points = np.moveaxis(v, 0, axis)
    return GridSurface.from_array(points, grid.r, grid.t)
