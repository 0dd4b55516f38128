"""Map a disk mesh to the unit square: boundary on the sides by arc length, interior by a Laplacian solve.

Weights: mean-value (Floater 2003) by default, which keep the map bijective for a convex boundary;
cotangent weights (libigl's harmonic map) as an option (they can flip triangles on scans).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..errors import InputError
from .topology import DiskMesh

SHARP_TURN = np.pi / 3  # a boundary vertex turning by more than this counts as a clear corner


def _turning(vertices, loop):
    p = vertices[loop]
    a, b = p - np.roll(p, 1, axis=0), np.roll(p, -1, axis=0) - p
    cos = np.sum(a * b, axis=1) / np.maximum(np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1), 1e-300)
    return np.arccos(np.clip(cos, -1, 1))


def choose_corners(disk: DiskMesh, corners=None, start: int | None = None) -> np.ndarray:
    """Positions in the boundary loop of the four corners (increasing).

    ``corners``: vertex ids given by the user. Else the four sharpest turns when the boundary has
    four clear corners (turn > 60 degrees), else quarter arc lengths from ``start`` (a vertex id,
    default the loop's first vertex).
    """
    loop = disk.boundary
    if corners is not None:
        pos = [int(np.flatnonzero(loop == c)[0]) if np.any(loop == c) else -1 for c in corners]
        if len(pos) != 4 or min(pos) < 0:
            raise InputError("corners must be 4 vertex ids on the boundary loop")
        return np.sort(pos)
    turn = _turning(disk.vertices, loop)
    sharp = np.flatnonzero(turn > SHARP_TURN)
    if len(sharp) == 4:
        return np.sort(sharp)
    seg = np.linalg.norm(disk.vertices[np.roll(loop, -1)] - disk.vertices[loop], axis=1)
    s0 = 0 if start is None else int(np.flatnonzero(loop == start)[0])
    arc = np.concatenate([[0], np.cumsum(np.roll(seg, -s0))])[:-1]
    pos = [(s0 + int(np.argmin(np.abs(arc - q * seg.sum())))) % len(loop) for q in (0, 0.25, 0.5, 0.75)]
    if len(set(pos)) < 4:
        raise InputError("the boundary has fewer than 4 vertices: it cannot be mapped to a square")
    return np.array(pos)


def _boundary_uv(disk: DiskMesh, corner_pos: np.ndarray) -> np.ndarray:
    loop = disk.boundary
    n = len(loop)
    seg = np.linalg.norm(disk.vertices[np.roll(loop, -1)] - disk.vertices[loop], axis=1)
    square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    uv = np.empty((n, 2))
    start = corner_pos[0]
    order = np.roll(np.arange(n), -start)
    rel = (corner_pos - start) % n
    for side in range(4):
        a, b = rel[side], rel[side + 1] if side < 3 else n
        idx = order[a:b]
        lengths = np.concatenate([[0], np.cumsum(seg[idx])])
        frac = lengths[:-1] / lengths[-1]
        uv[idx] = square[side] + frac[:, None] * (square[(side + 1) % 4] - square[side])
    return uv


def _weights(v, f, kind):
    rows, cols, vals = [], [], []
    for k in range(3):
        i, j, l = f[:, k], f[:, (k + 1) % 3], f[:, (k + 2) % 3]
        eij, eil = v[j] - v[i], v[l] - v[i]
        if kind == "mean-value":
            nij, nil = np.linalg.norm(eij, axis=1), np.linalg.norm(eil, axis=1)
            angle = np.arccos(np.clip(np.sum(eij * eil, 1) / (nij * nil), -1, 1))
            t = np.tan(angle / 2)
            rows += [i, i]; cols += [j, l]; vals += [t / nij, t / nil]  # noqa: E702
        else:  # cotangent of the angle at i weights the opposite edge (j, l)
            cot = np.sum(eij * eil, 1) / np.maximum(np.linalg.norm(np.cross(eij, eil), axis=1), 1e-300)
            rows += [j, l]; cols += [l, j]; vals += [0.5 * cot, 0.5 * cot]  # noqa: E702
    n = len(v)
    return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n))


def parametrize(disk: DiskMesh, *, corners=None, start: int | None = None, weights: str = "mean-value"):
    """uv in [0, 1]^2 for every vertex of a disk mesh.

    Returns
    -------
    uv : ndarray (n, 2)
    info : dict
        ``corners`` (vertex ids), ``flipped`` and ``degenerate`` (triangle counts after mapping).
    """
    if weights not in ("mean-value", "cotangent"):
        raise InputError("weights must be 'mean-value' or 'cotangent'")
    pos = choose_corners(disk, corners, start)
    v, f, loop = disk.vertices, disk.faces, disk.boundary
    uv = np.zeros((len(v), 2))
    uv[loop] = _boundary_uv(disk, pos)
    w = _weights(v, f, weights)
    lap = sp.diags(np.asarray(w.sum(axis=1)).ravel()) - w
    interior = np.setdiff1d(np.arange(len(v)), loop)
    if len(interior):
        a = lap[interior][:, interior].tocsc()
        b = -lap[interior][:, loop] @ uv[loop]
        uv[interior] = spla.splu(a).solve(np.ascontiguousarray(b))
    d1, d2 = uv[f[:, 1]] - uv[f[:, 0]], uv[f[:, 2]] - uv[f[:, 0]]
    signed = d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]
    info = {"corners": loop[pos].tolist(), "flipped": int(np.sum(signed < 0)), "degenerate": int(np.sum(np.abs(signed) < 1e-14))}
    return np.clip(uv, 0.0, 1.0), info
