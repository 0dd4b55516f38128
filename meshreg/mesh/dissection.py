"""A fill-reducing order for large mesh Laplacians: nested dissection by planes, minimum degree inside the parts.

The approximate minimum degree order (:mod:`meshreg.mesh.ordering`) of a 1M-triangle mesh's interior block (500k
unknowns) took 0.75-0.95 s, 20 times its time on a 100k-triangle mesh (50k unknowns, whose quotient graph stays in
the processor's cache). Here the unknowns are cut in two by the plane through their median across their principal
axis, and a smallest set of vertices touching every edge across the plane (a minimum vertex cover of those edges,
from a maximum matching: Koenig's theorem) is the separator, eliminated after both sides. The sides are cut again
until no part holds more than DISSECT_LEAF unknowns; each part is then ordered by minimum degree with the separator
vertices next to it held for last (a constrained minimum degree, as CHOLMOD orders the parts between METIS's
separators), and the separators follow, the deepest first. On that 1M-triangle mesh: 0.43 s, and factors of
289 MB and 9.95 GFlop against 294 MB and 11.5 GFlop (docs/benchmarks.md).

The cut needs the unknowns' places in space (the vertices' coordinates), not a graph partitioner: on a disk mesh a
plane through the middle crosses it along a curve of about sqrt(n) vertices. A cut whose separator would hold more
than SEPARATOR_FACTOR sqrt(m) of a part's m unknowns (a sheet rolled up so that the plane crosses it several times)
is not made; that part is ordered whole.
"""

from __future__ import annotations

import numba
import numpy as np

from .ordering import Abandoned, constrained_minimum_degree

DISSECT_LEAF = 65_000  # parts of more unknowns are cut in two (500k unknowns: three levels, eight parts)
SEPARATOR_FACTOR = 3.0  # a cut is made only when its separator holds at most this times sqrt(unknowns of the part)


@numba.njit(cache=True, nogil=True)
def _principal_axis(points, members):
    """The unit direction (3,) of largest spread of the points (n, 3) numbered in ``members`` (m,)."""
    mean, cov = np.zeros(3), np.zeros((3, 3))
    for i in members:
        for a in range(3):
            mean[a] += points[i, a]
    mean /= len(members)
    for i in members:
        for a in range(3):
            for b in range(a + 1):
                cov[a, b] += (points[i, a] - mean[a]) * (points[i, b] - mean[b])
    for a in range(3):
        for b in range(a):
            cov[b, a] = cov[a, b]
    return np.linalg.eigh(cov)[1][:, 2]


@numba.njit(cache=True, nogil=True)
def _crossing(ptr, rows, members, part, level, side, slot):
    """The edges from side ``side`` of a part to side ``side + 1`` (``part``): as lists of the vertices of each side
    that such an edge touches (left (a,), right (b,)) and the left ones' neighbours on the right (CSR over local
    numbers: pointers (a + 1,), indices). ``slot`` (n,) is -1 everywhere and is left so."""
    left, right = [], []
    for i in members:
        if part[i] != side:
            continue
        touches = False
        for p in range(ptr[i], ptr[i + 1]):
            j = rows[p]
            if level[j] < 0 and part[j] == side + 1:
                touches = True
                if slot[j] < 0:
                    slot[j] = len(right)
                    right.append(j)
        if touches:
            left.append(i)
    adjacency_ptr = np.zeros(len(left) + 1, np.int64)
    adjacency = []
    for a in range(len(left)):
        i = left[a]
        for p in range(ptr[i], ptr[i + 1]):
            j = rows[p]
            if level[j] < 0 and part[j] == side + 1:
                adjacency.append(slot[j])
        adjacency_ptr[a + 1] = len(adjacency)
    right_ids = np.array(right, np.int64)
    slot[right_ids] = -1
    return np.array(left, np.int64), right_ids, adjacency_ptr, np.array(adjacency, np.int64)


@numba.njit(cache=True, nogil=True)
def _matching(adjacency_ptr, adjacency, nright):
    """A maximum matching of a bipartite graph (left vertices' neighbours on the right, CSR) by augmenting paths:
    each left vertex's partner (-1: none) and each right vertex's."""
    nleft = len(adjacency_ptr) - 1
    mate_left, mate_right = np.full(nleft, -1, np.int64), np.full(nright, -1, np.int64)
    seen = np.full(nright, -1, np.int64)
    stack, edge, via = np.empty(nleft, np.int64), np.empty(nleft, np.int64), np.empty(nleft, np.int64)
    for root in range(nleft):
        top, stack[0], edge[0] = 0, root, adjacency_ptr[root]
        while top >= 0:
            x = stack[top]
            if edge[top] == adjacency_ptr[x + 1]:
                top -= 1
                continue
            y = adjacency[edge[top]]
            edge[top] += 1
            if seen[y] == root:
                continue
            seen[y] = root
            if mate_right[y] < 0:  # augment: each left vertex on the path takes the right vertex it went through
                via[top] = y
                for t in range(top, -1, -1):
                    mate_left[stack[t]], mate_right[via[t]] = via[t], stack[t]
                break
            via[top] = y
            top += 1
            stack[top], edge[top] = mate_right[y], adjacency_ptr[mate_right[y]]
    return mate_left, mate_right


@numba.njit(cache=True, nogil=True)
def _cover(adjacency_ptr, adjacency, nright):
    """A minimum vertex cover of a bipartite graph (Koenig: from a maximum matching, the left vertices that no
    alternating path from an unmatched left vertex reaches, and the right vertices that one reaches): masks of
    the left (a,) and right (b,) vertices in it."""
    mate_left, mate_right = _matching(adjacency_ptr, adjacency, nright)
    nleft = len(mate_left)
    reached_left, reached_right = np.zeros(nleft, np.bool_), np.zeros(nright, np.bool_)
    queue = [x for x in range(nleft) if mate_left[x] < 0]
    for x in queue:
        reached_left[x] = True
    while len(queue):
        x = queue.pop()
        for p in range(adjacency_ptr[x], adjacency_ptr[x + 1]):
            y = adjacency[p]
            if not reached_right[y]:
                reached_right[y] = True
                z = mate_right[y]
                if z >= 0 and not reached_left[z]:
                    reached_left[z] = True
                    queue.append(z)
    return ~reached_left, reached_right


@numba.njit(cache=True, nogil=True)
def _cut(points, ptr, rows, members, part, level, new, depth, factor, slot):
    """Cut the part of unknowns ``members`` (m,) in two by the plane through their median across their principal
    axis: its sides become parts ``new`` and ``new + 1`` (``part``), and a smallest set of vertices that touches
    every edge between them its separator (``level`` = ``depth``). Returns False, changing nothing, when the
    separator would hold more than ``factor`` sqrt(m) unknowns or leave a side empty."""
    m, old = len(members), part[members[0]]
    axis = _principal_axis(points, members)
    place = np.empty(m)
    for k in range(m):
        i = members[k]
        place[k] = points[i, 0] * axis[0] + points[i, 1] * axis[1] + points[i, 2] * axis[2]
    middle = np.median(place)
    sizes = np.zeros(2, np.int64)
    for k in range(m):
        side = 0 if place[k] < middle else 1
        part[members[k]] = new + side
        sizes[side] += 1
    left, right, adjacency_ptr, adjacency = _crossing(ptr, rows, members, part, level, new, slot)
    on_left, on_right = _cover(adjacency_ptr, adjacency, len(right))
    taken = np.array([on_left.sum(), on_right.sum()])
    if taken.sum() > factor * np.sqrt(m) or sizes[0] == taken[0] or sizes[1] == taken[1]:
        part[members] = old
        return False
    level[left[on_left]] = depth
    level[right[on_right]] = depth
    return True


@numba.njit(cache=True, nogil=True)
def _dissect(points, ptr, rows, leaf, factor):
    """Cut the unknowns until no part holds more than ``leaf`` (or a cut is refused): each unknown's part (n,)
    (meaningful where ``level`` < 0), each separator vertex's depth ``level`` (n,) (-1 off the separators)."""
    n = len(ptr) - 1
    part, level, slot = np.zeros(n, np.int64), np.full(n, -1, np.int64), np.full(n, -1, np.int64)
    pending, depths, parts = [0], [0], 1
    while len(pending):
        p, depth = pending.pop(), depths.pop()
        members = np.flatnonzero((part == p) & (level < 0))
        if len(members) > leaf and _cut(points, ptr, rows, members, part, level, parts, depth, factor, slot):
            pending += [parts, parts + 1]
            depths += [depth + 1, depth + 1]
            parts += 2
    return part, level


@numba.njit(cache=True, nogil=True)
def _with_held(ptr, rows, members, level, place):
    """The pattern (pointers, rows; int32) among a part's unknowns ``members`` and the separator vertices next to
    them (numbered after the members), those held for last (a mask), and the unknowns in that numbering.
    ``place`` (n,) is -1 everywhere and is left so."""
    count = 0
    for i in members:
        place[i] = count
        count += 1
    held = []
    for i in members:
        for p in range(ptr[i], ptr[i + 1]):
            j = rows[p]
            if level[j] >= 0 and place[j] < 0:
                place[j] = count
                count += 1
                held.append(j)
    local = np.concatenate((members, np.array(held, np.int64)))
    sub_ptr = np.zeros(count + 1, np.int32)
    for a in range(count):
        i = local[a]
        for p in range(ptr[i], ptr[i + 1]):
            if place[rows[p]] >= 0:
                sub_ptr[a + 1] += 1
    for a in range(count):
        sub_ptr[a + 1] += sub_ptr[a]
    sub_rows = np.empty(sub_ptr[count], np.int32)
    for a in range(count):
        q = sub_ptr[a]
        for p in range(ptr[local[a]], ptr[local[a] + 1]):
            b = place[rows[p]]
            if b >= 0:
                sub_rows[q] = b
                q += 1
    place[local] = -1
    last = np.zeros(count, np.bool_)
    last[len(members) :] = True
    return sub_ptr, sub_rows, last, local


def dissected_order(
    points: np.ndarray,
    ptr: np.ndarray,
    rows: np.ndarray,
    stop: np.ndarray | None = None,
    leaf: int = DISSECT_LEAF,
    factor: float = SEPARATOR_FACTOR,
) -> np.ndarray:
    """A fill-reducing elimination order (n,) of a symmetric pattern whose unknowns have places in space.

    Parameters
    ----------
    points : ndarray (n, 3)
        Each unknown's place (a mesh's interior vertices).
    ptr, rows : ndarray (n + 1,), ndarray
        The pattern without its diagonal (:func:`~meshreg.mesh.ordering.symmetric_pattern`), symmetric.
    stop : ndarray (1,) of bool, optional
        Set by another thread to abandon the order (:class:`~meshreg.mesh.ordering.Abandoned`).
    leaf : int
        Parts of more unknowns are cut in two (DISSECT_LEAF); with n <= ``leaf`` this is the minimum degree order
        (:func:`~meshreg.mesh.ordering.minimum_degree`) of a pattern without hubs, which that function orders last.
    factor : float
        A cut whose separator would hold more than ``factor`` sqrt(m) of a part's m unknowns is not made
        (SEPARATOR_FACTOR).

    Examples
    --------
    The Laplacian of a 60 x 60 grid cut into parts of at most 1000 unknowns: its first separator, the 60 unknowns
    of a middle column, comes last.

    >>> import numpy as np
    >>> import scipy.sparse as sp
    >>> from meshreg.mesh.ordering import symmetric_pattern
    >>> line = sp.diags([1.0, 1.0], [-1, 1], shape=(60, 60))
    >>> grid = (sp.kron(sp.identity(60), line) + sp.kron(line, sp.identity(60))).tocsc()
    >>> x, y = np.meshgrid(np.arange(60.0), np.arange(60.0) / 2)
    >>> points = np.column_stack([x.ravel(), y.ravel(), np.zeros(3600)])
    >>> order = dissected_order(points, *symmetric_pattern(grid), leaf=1000)
    >>> np.unique(points[order[-60:], 0]).tolist()
    [29.0]
    """
    n = len(ptr) - 1
    stop = np.zeros(1, np.bool_) if stop is None else stop
    ptr = np.ascontiguousarray(ptr, np.int64)
    part, level = _dissect(np.ascontiguousarray(points, float), ptr, rows, leaf, factor)
    place, orders = np.full(n, -1, np.int64), []
    inside = level < 0
    for p in np.unique(part[inside]):
        sub_ptr, sub_rows, last, local = _with_held(ptr, rows, np.flatnonzero(inside & (part == p)), level, place)
        orders.append(local[constrained_minimum_degree(sub_ptr, sub_rows, last, stop)])
        if stop[0]:
            raise Abandoned("dissected_order: abandoned by another thread")
    separators = np.flatnonzero(~inside)
    separators = separators[np.argsort(-level[separators], kind="stable")]
    return np.concatenate([*orders, separators])
