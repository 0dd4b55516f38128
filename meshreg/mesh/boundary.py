"""Intrinsic quantities of a mesh's boundary: what bending the surface does not change.

The turning of the boundary *within the surface* at a boundary vertex (its discrete geodesic curvature) is pi minus
the sum of the triangle angles at that vertex; triangle angles depend on edge lengths only, so an isometric bend
keeps it, while the turning of the boundary as a curve in space (the angle between consecutive boundary edges) also
counts how the surface curves. Arc length along the boundary is intrinsic too. Corners are chosen from these.
"""

from __future__ import annotations

import numpy as np

from .graph import face_normals

SHARP_TURN = np.pi / 3  # a boundary vertex turning (within the surface) by more than this counts as a clear corner
# the turning at a scale (:func:`scaled_turning`) is measured between chords reaching this many boundary edge lengths
# (their median) along the loop either way, at most a sixteenth of its length: vertex noise of 0.1% / 0.3% / 0.5% of
# the size made single vertices turn by 80-110 degrees (next to short boundary edges), and the corners found from them
# were right in 17 / 5 / 1 of 36 remeshed terrains (flat or rolled by 60 degrees; 1k-10k points); at this scale in all
CORNER_REACH = 3.0


def angle_sums(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Sum of the angles (radians) of the triangles at each vertex, shape (n,).

    Parameters
    ----------
    vertices : ndarray (n, 3)
    faces : ndarray (m, 3)
    """
    v, f = np.asarray(vertices, dtype=float), np.asarray(faces, dtype=np.int64)
    total = np.zeros(len(v))
    for k in range(3):
        a, b, c = f[:, k], f[:, (k + 1) % 3], f[:, (k + 2) % 3]
        e1, e2 = v[b] - v[a], v[c] - v[a]
        sin = np.linalg.norm(np.cross(e1, e2), axis=1)
        total += np.bincount(a, weights=np.arctan2(sin, np.sum(e1 * e2, axis=1)), minlength=len(v))
    return total


def geodesic_turning(vertices: np.ndarray, faces: np.ndarray, loop: np.ndarray) -> np.ndarray:
    """Turning of a boundary loop within the surface at each of its vertices (radians, shape (b,)): pi minus the
    angle the triangles make there. Positive where the surface is locally convex (a square's corner: pi / 2);
    the same on any isometric bend of the surface.

    Examples
    --------
    >>> v = np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]])
    >>> f = np.array([[0, 1, 2], [0, 2, 3]])
    >>> np.degrees(geodesic_turning(v, f, np.arange(4))).round(6).tolist()
    [90.0, 90.0, 90.0, 90.0]
    """
    loop = np.asarray(loop)
    return np.pi - angle_sums(vertices, _loop_faces(faces, loop, len(vertices)))[loop]


def _loop_faces(faces: np.ndarray, loop: np.ndarray, n: int) -> np.ndarray:
    """The faces (k, 3) with a corner on the ``loop`` (of a mesh of ``n`` vertices): all the loop's turning uses."""
    faces = np.asarray(faces, dtype=np.int64)
    on_loop = np.zeros(n, dtype=bool)
    on_loop[loop] = True
    return faces[on_loop[faces].any(axis=1)]


def scaled_turning(vertices: np.ndarray, faces: np.ndarray, loop: np.ndarray) -> np.ndarray:
    """Turning of a boundary loop at a scale, at each of its vertices (radians, shape (b,)): the angle between the
    chords from the points CORNER_REACH boundary edge lengths (their median, at most a sixteenth of the loop's
    length) before and after the vertex along the loop, seen along the surface's normal there (the faces' normals
    summed over the same stretch of the loop). Positive where the surface is locally convex, as
    :func:`geodesic_turning`; at a square's corner pi / 2; noise of the vertices, which makes single boundary vertices
    turn by tens of degrees, moves it by about the noise over the reach.

    Examples
    --------
    >>> v = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0], [2, 1, 0], [2, 2, 0], [1, 2, 0], [0, 2, 0], [0, 1, 0]])
    >>> f = np.array([[0, 1, 7], [1, 2, 3], [1, 3, 7], [3, 4, 5], [3, 5, 7], [5, 6, 7]])
    >>> np.degrees(scaled_turning(v, f, np.arange(8))).round(6).tolist()
    [90.0, 0.0, 90.0, 0.0, 90.0, 0.0, 90.0, 0.0]
    """
    loop = np.asarray(loop)
    near = _loop_faces(faces, loop, len(vertices))
    x = np.asarray(vertices, dtype=float)[loop]
    seg = np.linalg.norm(np.roll(x, -1, axis=0) - x, axis=1)
    arc = np.concatenate([[0.0], np.cumsum(seg)])
    reach = min(CORNER_REACH * float(np.median(seg)), arc[-1] / 16)
    closed = np.vstack([x, x[:1]])
    before, after = (
        np.stack([np.interp(np.mod(arc[:-1] + d, arc[-1]), arc, closed[:, k]) for k in range(3)], axis=-1)
        for d in (-reach, reach)
    )
    normal = _stretch_sums(_loop_normals(vertices, near, loop), arc, reach)
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)
    u, w = x - before, after - x
    u -= np.sum(u * normal, axis=1, keepdims=True) * normal
    w -= np.sum(w * normal, axis=1, keepdims=True) * normal
    turn = np.arctan2(np.sum(np.cross(u, w) * normal, axis=1), np.sum(u * w, axis=1))
    return turn * _loop_direction(near, loop)


def _loop_normals(vertices: np.ndarray, faces: np.ndarray, loop: np.ndarray) -> np.ndarray:
    """Sum of the (area-weighted) normals of ``faces`` at each vertex of the loop, shape (b, 3)."""
    n = face_normals(vertices, faces)
    corners, at = np.unique(faces.ravel(), return_inverse=True)  # the faces at the loop: few vertices
    sums = np.stack([np.bincount(at, np.repeat(n[:, k], 3), minlength=len(corners)) for k in range(3)], axis=-1)
    place = np.minimum(np.searchsorted(corners, loop), len(corners) - 1)
    return np.where((corners[place] == loop)[:, None], sums[place], 0.0)  # a loop vertex in no face: no normal


def _stretch_sums(values: np.ndarray, arc: np.ndarray, reach: float) -> np.ndarray:
    """For each loop vertex, the sum of ``values`` (b, k) over the loop's vertices within ``reach`` of it along the
    loop (arc: the loop's cumulative length, b + 1 entries, the loop closed)."""
    length = arc[-1]
    at = np.concatenate([arc[:-1] - length, arc[:-1], arc[:-1] + length])  # three turns: no wrapping to handle
    total = np.concatenate([np.zeros((1, values.shape[1])), np.cumsum(np.tile(values, (3, 1)), axis=0)])
    lo = np.searchsorted(at, arc[:-1] + length - reach, side="left")
    hi = np.searchsorted(at, arc[:-1] + length + reach, side="right")
    return total[hi] - total[lo]


def _loop_direction(faces: np.ndarray, loop: np.ndarray) -> float:
    """1.0 when the loop runs as its faces (``faces``: those at the loop) run along their boundary sides, by most of
    its sides (then the surface lies to the left seen along the normal, and convex corners turn positively), else
    -1.0."""
    n = int(max(faces.max(initial=0), loop.max(initial=0))) + 1
    sides = (faces * n + np.roll(faces, -1, axis=1)).ravel()  # each face's sides, directed as the face runs
    along = loop * n + np.roll(loop, -1)
    return 1.0 if np.isin(along, sides).sum() >= np.isin(np.roll(loop, -1) * n + loop, sides).sum() else -1.0


def sharp_corners(
    vertices: np.ndarray, faces: np.ndarray, loop: np.ndarray, cut_bases: np.ndarray | None = None
) -> np.ndarray | None:
    """Loop positions (4,), increasing, of the boundary's four clear corners (geodesic turning above SHARP_TURN),
    or None when it does not have exactly four.

    ``cut_bases`` (k, 2), the vertex ids at the ends of the bases of boundary ears that cleanup removed
    (:attr:`meshreg.mesh.topology.DiskMesh.ear_feet`): a corner whose ear was removed turns at both ends of the
    cut, by about the corner's turn in all, so when both ends of one base turn clearly, only the sharper counts (a
    held-out triangular sheet, apex angle 53 degrees, got "four clear corners", two of them 0.025 of its size apart,
    and its match was 13% of its size wrong).

    Noise of the vertices makes single boundary vertices turn clearly on straight stretches (a held-out terrain with
    noise of 0.1% of its size: two of its "four clear corners" on the middle of sides, and its match 24% of its size
    wrong at 0.3%), so when some vertex turns clearly the turning at a scale (:func:`scaled_turning`) is looked at
    too: when it turns clearly on exactly four stretches of the loop and the clear vertices are not one on each,
    the corners are the vertices turning most at that scale, one per stretch."""
    loop = np.asarray(loop)
    faces = _loop_faces(faces, loop, len(vertices))  # once: the rest reads these only
    turning = geodesic_turning(vertices, faces, loop)
    sharp = np.flatnonzero(turning > SHARP_TURN)
    if not len(sharp):
        return None
    if cut_bases is not None and len(cut_bases) and 1 < len(sharp) < len(loop):
        sharp = _one_per_cut(sharp, turning, loop, cut_bases)
    found = sharp if len(sharp) == 4 else None
    scaled = scaled_turning(vertices, faces, loop)
    stretches = _stretches(scaled > SHARP_TURN)
    if len(stretches) != 4 or (found is not None and _one_on_each(found, stretches, len(loop))):
        return found
    return np.sort([int(s[np.argmax(scaled[s])]) for s in stretches])


def _stretches(clear: np.ndarray) -> list[np.ndarray]:
    """The maximal runs of True in ``clear`` (b,) around the loop, as loop positions in its order; none when every
    or no position is True."""
    if clear.all() or not clear.any():
        return []
    order = np.roll(np.arange(len(clear)), -int(np.argmin(clear)))  # from a position that is not clear
    ends = np.flatnonzero(np.diff(np.concatenate([[0], clear[order].astype(np.int8), [0]])))
    return [order[a:b] for a, b in zip(ends[::2], ends[1::2], strict=True)]


def _one_on_each(positions: np.ndarray, stretches: list[np.ndarray], b: int) -> bool:
    """Whether the loop ``positions`` lie one on each of the ``stretches`` (a loop of ``b`` vertices)."""
    owner = np.full(b, -1)
    for k, stretch in enumerate(stretches):
        owner[stretch] = k
    return sorted(owner[positions].tolist()) == list(range(len(stretches)))


def _one_per_cut(sharp: np.ndarray, turning: np.ndarray, loop: np.ndarray, cut_bases: np.ndarray) -> np.ndarray:
    """The clear turns ``sharp`` (loop positions, increasing) less the less sharp one of each pair of neighbours on
    the loop that are the two ends of one cut base (:func:`sharp_corners`)."""
    cuts = {frozenset(pair) for pair in np.asarray(cut_bases).tolist()}
    keep = np.ones(len(sharp), dtype=bool)
    for k, (i, j) in enumerate(zip(sharp.tolist(), np.roll(sharp, -1).tolist(), strict=True)):
        if (i + 1) % len(loop) == j and frozenset((int(loop[i]), int(loop[j]))) in cuts:
            keep[k if turning[i] < turning[j] else (k + 1) % len(sharp)] = False
    return sharp[keep]
