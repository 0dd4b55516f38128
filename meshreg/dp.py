"""DP-surface-min: dynamic programming over reparametrizations h(r, t) = (gamma(r), t).

With h restricted to act along r, E(R, h) becomes the elastic distance between two curves in
R^(3(N-1)) (the columns of q), which dynamic programming minimizes exactly over piecewise-linear
gamma whose pieces join grid nodes with steps (dk, dl), 1 <= dk, dl <= W, gcd(dk, dl) = 1.
The DP alternates with Kabsch-Umeyama, starting from Kabsch at the identity gamma.

Specification: docs/dp.md (exact edge costs over merged breakpoints; constant terms of
E are dropped so the DP maximizes the cross term ``sum len sqrt(m) trace(R C[a][b])``).

References
----------
Bernal & Lawrence, Section 4, Step 1 of the outline (Procedure DP-surface-min).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from math import gcd

import numba
import numpy as np

from .rotation import kabsch

DEFAULT_WINDOW = 10
DEFAULT_DP_ROUNDS = 10
DEFAULT_DP_TOL = 1e-9
_SETUP = object()  # the key under which a ``seen`` dict of dp_surface_min keeps its problem's set-up
# partitions whose intervals all equal their mean to this relative tolerance are uniform: the DP then takes each
# edge's pieces from a table made once per step (:func:`uniform_pieces`); equal to the general edge walk to rounding
UNIFORM_TOL = 1e-12


def steps(window: int) -> np.ndarray:
    """Allowed DP steps (dk, dl), 1 <= dk, dl <= window, gcd(dk, dl) = 1; shape (S, 2)."""
    return np.array(
        [(a, b) for a in range(1, window + 1) for b in range(1, window + 1) if gcd(a, b) == 1], dtype=np.int64
    )


@numba.njit(cache=True)
def _edge_cross(r1, s2, k0, l0, k, l, g):
    """sqrt(m) * sum over pieces of len * g[a, b] for the straight edge (k0, l0) -> (k, l)."""
    x0 = r1[k0]
    y0 = s2[l0]
    slope = (s2[l] - y0) / (r1[k] - x0)
    a = k0
    b = l0
    x = x0
    total = 0.0
    while a < k and b < l:
        xa = r1[a + 1]
        xb = x0 + (s2[b + 1] - y0) / slope
        tol = 1e-12 * (1.0 + abs(xa))
        if xa < xb - tol:
            total += (xa - x) * g[a, b]
            x = xa
            a += 1
        elif xb < xa - tol:
            total += (xb - x) * g[a, b]
            x = xb
            b += 1
        else:
            total += (xa - x) * g[a, b]
            x = xa
            a += 1
            b += 1
    return np.sqrt(slope) * total


@numba.njit(cache=True)
def _edge_covariance(r1, s2, k0, l0, k, l, c, out):
    """Add sqrt(m) * sum len * C[a, b] (3x3) of the edge (k0, l0) -> (k, l) to ``out``."""
    x0 = r1[k0]
    y0 = s2[l0]
    slope = (s2[l] - y0) / (r1[k] - x0)
    sq = np.sqrt(slope)
    a = k0
    b = l0
    x = x0
    while a < k and b < l:
        xa = r1[a + 1]
        xb = x0 + (s2[b + 1] - y0) / slope
        tol = 1e-12 * (1.0 + abs(xa))
        if xa < xb - tol:
            end = xa
            da, db = 1, 0
        elif xb < xa - tol:
            end = xb
            da, db = 0, 1
        else:
            end = xa
            da, db = 1, 1
        out += (end - x) * sq * c[a, b]
        x = end
        a += da
        b += db


@numba.njit(cache=True)
def _dp_table(r1, s2, g, step, lo, hi):
    """Maximize the cross term over monotone paths (0,0) -> (A,B); returns (value, predecessor)."""
    na = r1.shape[0]
    nb = s2.shape[0]
    best = np.full((na, nb), -np.inf)
    pred = np.full((na, nb), -1, dtype=np.int64)
    best[0, 0] = 0.0
    for k in range(1, na):
        for l in range(max(lo[k], 1), hi[k] + 1):
            top = -np.inf
            arg = -1
            for s in range(step.shape[0]):
                k0 = k - step[s, 0]
                l0 = l - step[s, 1]
                if k0 < 0 or l0 < 0:
                    continue
                prev = best[k0, l0]
                if prev == -np.inf:
                    continue
                val = prev + _edge_cross(r1, s2, k0, l0, k, l, g)
                if val > top:
                    top = val
                    arg = s
            best[k, l] = top
            pred[k, l] = arg
    return best, pred


def uniform_pieces(step: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The pieces of every step's edge when both partitions are uniform: they depend on the step alone.

    The edge (k0, l0) -> (k0 + dk, l0 + dl) crosses the lines of the first partition at k0 + 1, ..., and those of
    the second at k0 + b dk / dl (in units of the first partition's spacing); with gcd(dk, dl) = 1 no two crossings
    inside the edge coincide, so it has dk + dl - 1 pieces.

    Returns
    -------
    first : ndarray (S + 1,)
        Step s owns pieces ``first[s]:first[s + 1]``.
    da, db : ndarray of int
        Each piece's cell, relative to (k0, l0).
    length : ndarray
        Each piece's length along r, in units of the first partition's spacing.
    """
    first, da, db, length = [0], [], [], []
    for dk, dl in step:
        cuts = np.unique(np.r_[np.arange(dk + 1), np.arange(dl + 1) * dk / dl])
        middle = 0.5 * (cuts[1:] + cuts[:-1])
        da += list(np.floor(middle).astype(np.int64))
        db += list(np.floor(middle * dl / dk).astype(np.int64))
        length += list(np.diff(cuts))
        first.append(len(length))
    return np.array(first), np.array(da, dtype=np.int64), np.array(db, dtype=np.int64), np.array(length)


def uniform_spacing(r: np.ndarray) -> float | None:
    """The spacing of a uniform partition (every interval equal to UNIFORM_TOL, relative), else None."""
    d = np.diff(r)
    mean = (r[-1] - r[0]) / len(d)
    return float(mean) if np.all(np.abs(d - mean) <= UNIFORM_TOL * mean) else None


@numba.njit(cache=True)
def _dp_table_uniform(g, step, lo, hi, first, da, db, length, weight):
    """:func:`_dp_table` on uniform partitions: each edge's cross term is ``weight[s]`` times the sum of its
    pieces' lengths times g of their cells (:func:`uniform_pieces`), without locating its breakpoints; for one k
    and one step, the edges to every l of the row are summed together (contiguous in g: vectorized)."""
    na, nb = g.shape[0] + 1, g.shape[1] + 1
    best = np.full((na, nb), -np.inf)
    pred = np.full((na, nb), -1, dtype=np.int64)
    best[0, 0] = 0.0
    edge = np.empty(nb)
    for k in range(1, na):
        start, stop = max(lo[k], 1), hi[k] + 1
        top = best[k]
        arg = pred[k]
        for s in range(step.shape[0]):
            k0 = k - step[s, 0]
            dl = step[s, 1]
            begin = max(start, dl)
            if k0 < 0 or begin >= stop:
                continue
            edge[begin:stop] = 0.0
            p, end = first[s], first[s + 1]
            while p + 3 < end:  # four pieces per pass over the row, each added in turn (the same sums)
                row0, row1, row2, row3 = g[k0 + da[p]], g[k0 + da[p + 1]], g[k0 + da[p + 2]], g[k0 + da[p + 3]]
                s0, s1, s2, s3 = db[p] - dl, db[p + 1] - dl, db[p + 2] - dl, db[p + 3] - dl
                w0, w1, w2, w3 = length[p], length[p + 1], length[p + 2], length[p + 3]
                for l in range(begin, stop):
                    e = edge[l] + w0 * row0[l + s0]
                    e = e + w1 * row1[l + s1]
                    e = e + w2 * row2[l + s2]
                    edge[l] = e + w3 * row3[l + s3]
                p += 4
            while p < end:
                row0, s0, w0 = g[k0 + da[p]], db[p] - dl, length[p]
                for l in range(begin, stop):
                    edge[l] += w0 * row0[l + s0]
                p += 1
            previous = best[k0]
            for l in range(begin, stop):
                val = previous[l - dl] + weight[s] * edge[l]
                if val > top[l]:
                    top[l] = val
                    arg[l] = s
    return best, pred


def _backtrack(pred: np.ndarray, step: np.ndarray) -> np.ndarray:
    """The optimal path's nodes (P, 2), (0, 0) first, from the predecessor table."""
    if pred[-1, -1] < 0:
        raise RuntimeError("DP found no path to the end node: widen the window or the strip")
    return _walk_back(pred, step)


@numba.njit(cache=True)
def _walk_back(pred, step):
    k, l = pred.shape[0] - 1, pred.shape[1] - 1
    reverse = np.empty((k + l + 1, 2), dtype=np.int64)
    count = 0
    while True:
        reverse[count, 0], reverse[count, 1] = k, l
        count += 1
        if k == 0 and l == 0:
            break
        s = pred[k, l]
        k, l = k - step[s, 0], l - step[s, 1]
    return reverse[:count][::-1].copy()


def _setup(q1, q2, r1, r2, t, window: int, strip):
    """What every round of one DP problem uses: the covariances C[a, b], the sum of both row norms, the steps, the
    strip's bounds and the table function."""
    dt = np.diff(t)
    c = column_covariances(q1, q2, dt)
    norms = float(np.sum(np.diff(r1)[:, None] * dt * np.sum(q1**2, -1)))
    norms += float(np.sum(np.diff(r2)[:, None] * dt * np.sum(q2**2, -1)))
    step = steps(min(window, max(len(r1), len(r2)) - 1))  # wider steps leave the table: the same DP, bounded cost
    lo, hi = strip if strip is not None else strip_bounds(len(r1), len(r2), None, 0)
    return c, norms, step, lo, hi, _table_function(r1, r2, step)


def _table_function(r1: np.ndarray, r2: np.ndarray, step: np.ndarray):
    """``table(g, lo, hi) -> (value, predecessor)``: the DP table of these partitions and steps, by the
    uniform-partition kernel when both partitions are uniform, else by the general edge walk."""
    h1, h2 = uniform_spacing(r1), uniform_spacing(r2)
    if h1 is None or h2 is None:
        return lambda g, lo, hi: _dp_table(r1, r2, g, step, lo, hi)
    first, da, db, length = _pieces(step.tobytes(), len(step))
    weight = h1 * np.sqrt(step[:, 1] * h2 / (step[:, 0] * h1))
    return lambda g, lo, hi: _dp_table_uniform(g, step, lo, hi, first, da, db, length, weight)


@functools.lru_cache(maxsize=16)
def _pieces(key: bytes, count: int):
    """:func:`uniform_pieces` of the steps given as bytes (made once per window and process)."""
    return uniform_pieces(np.frombuffer(key, dtype=np.int64).reshape(count, 2))


@numba.njit(cache=True)
def _path_covariance(r1, s2, path, c):
    out = np.zeros((3, 3))
    for p in range(path.shape[0] - 1):
        _edge_covariance(r1, s2, path[p, 0], path[p, 1], path[p + 1, 0], path[p + 1, 1], c, out)
    return out


def column_covariances(q1: np.ndarray, q2: np.ndarray, dt: np.ndarray) -> np.ndarray:
    """C[a, b] = sum_j dt_j q1[a, j] q2[b, j]^T, shape (A, B, 3, 3)."""
    a, n, _ = q1.shape
    b = q2.shape[0]
    x = (q1 * dt[None, :, None]).transpose(0, 2, 1).reshape(a * 3, n)
    y = q2.transpose(1, 0, 2).reshape(n, b * 3)
    return (x @ y).reshape(a, 3, b, 3).transpose(0, 2, 1, 3)


@dataclass(frozen=True)
class DPResult:
    """Outcome of :func:`dp_surface_min`.

    Attributes
    ----------
    rotation : ndarray, shape (3, 3)
    path : ndarray, shape (P, 2)
        Node indices (k, l) of the optimal path, (0, 0) to (A, B).
    gamma : ndarray, shape (A + 1,)
        gamma at the first surface's r nodes (piecewise linear through the path, strictly increasing).
    energy : float
        E(R, gamma) of the discretized problem (the DP's own value).
    history : tuple of float
        E after each round (DP for the current R, then Kabsch for that gamma).
    """

    rotation: np.ndarray
    path: np.ndarray
    gamma: np.ndarray
    energy: float
    history: tuple


def _coarsen(q: np.ndarray, r: np.ndarray, t: np.ndarray, factor: int):
    """Merge cells ``factor`` at a time along r by adding their vector areas; returns (q, r, node indices)."""
    idx = np.unique(np.r_[np.arange(0, len(r), factor), len(r) - 1])
    area = np.outer(np.diff(r), np.diff(t))[..., None]
    n = q * np.linalg.norm(q, axis=-1, keepdims=True) * area  # vector area per cell
    merged = np.add.reduceat(n, idx[:-1], axis=0)
    v = merged / np.outer(np.diff(r[idx]), np.diff(t))[..., None]
    norm = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.sqrt(np.maximum(norm, 1e-300)), r[idx], idx


def strip_bounds(na: int, nb: int, path: np.ndarray | None, radius: int) -> tuple[np.ndarray, np.ndarray]:
    """For each k the range [lo, hi] of l allowed in the DP table.

    Without a path, the whole table. With a path (node indices on a grid of na x nb nodes), the
    l's within ``radius`` nodes of the path's l at k, so the DP costs O(na * radius * W^2).
    """
    if path is None:
        return np.zeros(na, dtype=np.int64), np.full(na, nb - 1, dtype=np.int64)
    centre = np.interp(np.arange(na), path[:, 0], path[:, 1])
    lo = np.clip(np.floor(centre) - radius, 0, nb - 1).astype(np.int64)
    hi = np.clip(np.ceil(centre) + radius, 0, nb - 1).astype(np.int64)
    return lo, hi


def dp_surface_min(
    q1: np.ndarray,
    q2: np.ndarray,
    r1: np.ndarray,
    r2: np.ndarray,
    t: np.ndarray,
    *,
    window: int = DEFAULT_WINDOW,
    rotation: np.ndarray | None = None,
    max_rounds: int = DEFAULT_DP_ROUNDS,
    tol: float = DEFAULT_DP_TOL,
    strip: tuple[np.ndarray, np.ndarray] | None = None,
    coarsen: int = 1,
    seen: dict | None = None,
) -> DPResult:
    """DP-surface-min: alternate DP over gamma with Kabsch-Umeyama over R.

    Parameters
    ----------
    q1 : ndarray, shape (A, N-1, 3)
        Shape function of the first surface per cell (rotated by R).
    q2 : ndarray, shape (B, N-1, 3)
        Shape function of the second surface per cell (reparametrized by gamma).
    r1 : ndarray, shape (A + 1,)
        r partition of the first surface.
    r2 : ndarray, shape (B + 1,)
        r partition of the second surface.
    t : ndarray, shape (N,)
        Common t partition.
    window : int
        W, the largest step (dk, dl) component. Default 10 (63 steps). Steps longer than the grid are never
        used: W is capped at the nodes per axis minus 1 (same result; :mod:`meshreg.limits` checks the time).
    rotation : ndarray, shape (3, 3), optional
        Starting R. Default: Kabsch at the identity gamma (needs A == B); R = I if A != B.
    max_rounds : int
        Most DP + Kabsch rounds.
    tol : float
        Stop when a round lowers E by less than ``tol``.
    strip : (lo, hi), optional
        Per-k bounds on l (see :func:`strip_bounds`).
    coarsen : int
        When > 1, first solve on cells merged ``coarsen`` at a time along r, then only within
        ``2 * coarsen`` nodes of that path (coarse-to-fine: cost linear in A instead of A * B).
    seen : dict, optional
        Results of earlier calls on the same problem (q1, q2, partitions, window, rounds, strip) from other
        starting rotations, by the path of their first round; filled by this call. After its first round a
        call depends on nothing but that path, so a start whose first path was seen before returns that result
        (the same numbers) without its further rounds: the start search tries 29 rotations per symmetry of the
        square, and many lead to one path. Without a strip it also keeps the problem's set-up (covariances, steps,
        table function), made by the first call.

    Returns
    -------
    DPResult
    """
    if window < 1:
        raise ValueError("window must be at least 1")
    if coarsen > 1 and strip is None:
        (cq1, cr1, idx1), (cq2, cr2, idx2) = _coarsen(q1, r1, t, coarsen), _coarsen(q2, r2, t, coarsen)
        coarse = dp_surface_min(cq1, cq2, cr1, cr2, t, window=window, rotation=rotation, max_rounds=max_rounds, tol=tol)
        fine_path = np.stack([idx1[coarse.path[:, 0]], idx2[coarse.path[:, 1]]], axis=-1)
        strip = strip_bounds(len(r1), len(r2), fine_path, 2 * coarsen)
        rotation = coarse.rotation
    shared = seen is not None and strip is None  # the set-up depends on the problem alone: made once per ``seen``
    setup = seen.get(_SETUP) if shared else None
    if setup is None:
        setup = _setup(q1, q2, r1, r2, t, window, strip)
        if shared:
            seen[_SETUP] = setup
    c, norms, step, lo, hi, table = setup
    if rotation is None:
        if q1.shape[0] == q2.shape[0]:
            diagonal = np.arange(q1.shape[0])
            rotation = kabsch(np.einsum("a,akl->kl", np.diff(r1), c[diagonal, diagonal]))
        else:
            rotation = np.eye(3)
    best = None
    history = []
    first_path = None
    for _ in range(max_rounds):
        g = np.einsum("kl,ablk->ab", rotation, c)
        _, pred = table(g, lo, hi)
        path = _backtrack(pred, step)
        if first_path is None:
            first_path = path.tobytes()
            if seen is not None and first_path in seen:
                return seen[first_path]
        h = _path_covariance(r1, r2, path, c)
        new_rotation = kabsch(h)
        e = norms - 2.0 * float(np.trace(new_rotation @ h))
        history.append(e)
        if best is not None and e > best.energy - tol:
            break
        gamma = np.interp(r1, r1[path[:, 0]], r2[path[:, 1]])
        best = DPResult(new_rotation, path, gamma, e, tuple(history))
        rotation = new_rotation
    result = DPResult(best.rotation, best.path, best.gamma, best.energy, tuple(history))
    if seen is not None:
        seen[first_path] = result
    return result
