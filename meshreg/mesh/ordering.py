"""Orders of unknowns: a space-filling curve through points (memory locality), and a fill-reducing order of a sparse
matrix, approximate minimum degree (Amestoy, Davis and Duff 1996).

SuperLU's own minimum degree ordering (``permc_spec="MMD_AT_PLUS_A"``) took about 2.7 of the 4.5 s that the LU of
a 1M-triangle mesh's Laplacian cost; this ordering takes a fraction of that for about the same fill, and the LU in
its order (``permc_spec="NATURAL"``) then costs the numeric factorization alone. The algorithm works on the quotient
graph (eliminated pivots become elements, indistinguishable variables merge into supervariables, degrees are
bounded from above by the approximate external degree) and ends with a postorder of the assembly tree, which keeps
each subtree's unknowns together.
"""

from __future__ import annotations

import numba
import numpy as np
import scipy.sparse as sp

# an unknown coupled to more than max(DENSE_MIN, DENSE_FACTOR sqrt(n)) others is ordered last, outside the quotient
# graph (SuiteSparse AMD's default rule): a hub of 22,500 couplings in a 300 x 300 grid took the ordering from 0.05 s
# to 0.9 s
DENSE_MIN = 16
DENSE_FACTOR = 10.0
MORTON_BITS = 21  # bits per axis of the Morton (Z-order) code: 3 x 21 fill a 64-bit key


@numba.njit(cache=True, nogil=True)
def _morton_keys(points, low, scale):
    """Morton keys (n,) of points (n, 3): each coordinate quantized to MORTON_BITS bits, their bits interleaved."""
    top = float(2**MORTON_BITS - 1)
    keys = np.empty(points.shape[0], np.uint64)
    for i in range(points.shape[0]):
        key = np.uint64(0)
        for axis in range(3):
            cell = np.uint64(min(max((points[i, axis] - low[axis]) * scale, 0.0), top))
            for b in range(MORTON_BITS):
                key |= ((cell >> np.uint64(b)) & np.uint64(1)) << np.uint64(3 * b + axis)
        keys[i] = key
    return keys


def spatial_order(points: np.ndarray) -> np.ndarray:
    """The points (n, 3) in Morton (Z-curve) order (n,): neighbours in space get nearby positions, so kernels that
    visit a mesh's vertices in this order find their neighbours' data in cache.

    For the interior block of a 1M-triangle terrain mesh whose vertices came in random order, numbering the rows
    this way cut the assembly, the minimum degree order and the permutation from 2.0 s to 1.4 s (CPU time).
    """
    points = np.ascontiguousarray(points, dtype=float)
    if len(points) == 0:
        return np.zeros(0, np.int64)
    low = points.min(axis=0)
    span = float((points.max(axis=0) - low).max())
    scale = (2**MORTON_BITS - 1) / span if span > 0 else 0.0
    return np.argsort(_morton_keys(points, low, scale), kind="stable")


@numba.njit(cache=True)
def _flip(i):
    return -i - 2


@numba.njit(cache=True, nogil=True)
def _symmetric_pattern(indptr, indices, n):
    """The pattern of A + A^T without the diagonal, as CSC arrays (column pointers, row indices; the rows array
    is longer than its used part), from A's CSC (or CSR) arrays; duplicates merged."""
    count = np.zeros(n, np.int64)
    for j in range(n):
        for p in range(indptr[j], indptr[j + 1]):
            i = indices[p]
            if i != j:
                count[i] += 1
                count[j] += 1
    start = np.zeros(n + 1, np.int64)
    for j in range(n):
        start[j + 1] = start[j] + count[j]
    rows, fill = np.empty(start[n], np.int64), start[:-1].copy()
    for j in range(n):
        for p in range(indptr[j], indptr[j + 1]):
            i = indices[p]
            if i != j:
                rows[fill[j]] = i
                fill[j] += 1
                rows[fill[i]] = j
                fill[i] += 1
    mark, size = np.full(n, -1, np.int64), 0
    ptr = np.zeros(n + 1, np.int64)
    for j in range(n):
        for p in range(start[j], start[j + 1]):
            i = rows[p]
            if mark[i] != j:
                mark[i] = j
                rows[size] = i
                size += 1
        ptr[j + 1] = size
    return ptr, rows


@numba.njit(cache=True, nogil=True)
def _postorder(parent, nv, n):
    """Postorder (n,) of the assembly tree: ``parent`` of every node (-1 for a root), elements (nv > 0) ordered
    after the variables merged into them."""
    head, following = np.full(n, -1, np.int64), np.full(n, -1, np.int64)
    for j in range(n - 1, -1, -1):
        if nv[j] <= 0 and parent[j] >= 0:
            following[j], head[parent[j]] = head[parent[j]], j
    for e in range(n - 1, -1, -1):
        if nv[e] > 0 and parent[e] >= 0:
            following[e], head[parent[e]] = head[parent[e]], e
    order, stack, k = np.empty(n, np.int64), np.empty(n, np.int64), 0
    for root in range(n):
        if parent[root] != -1:
            continue
        top, stack[0] = 0, root
        while top >= 0:
            p = stack[top]
            i = head[p]
            if i == -1:
                top -= 1
                order[k] = p
                k += 1
            else:
                head[p] = following[i]
                top += 1
                stack[top] = i
    return order[:k]


@numba.njit(cache=True)
def _collect_garbage(pe, iw, length, n, cnz):
    """Compact the live lists of the workspace ``iw`` to its front; the new end of the used part."""
    for j in range(n):
        p = pe[j]
        if p >= 0:
            pe[j] = iw[p]
            iw[p] = _flip(j)
    q = p = 0
    while p < cnz:
        j = _flip(iw[p])
        p += 1
        if j >= 0:
            iw[q] = pe[j]
            pe[j] = q
            q += 1
            for _ in range(length[j] - 1):
                iw[q] = iw[p]
                q += 1
                p += 1
    return q


@numba.njit(cache=True, inline="always")
def _unlink(i, degree, head, nxt, last):
    """Take variable i out of its degree list."""
    if nxt[i] != -1:
        last[nxt[i]] = last[i]
    if last[i] != -1:
        nxt[last[i]] = nxt[i]
    else:
        head[degree[i]] = nxt[i]


@numba.njit(cache=True, inline="always")
def _new_element(k, cnz, graph, iw, lists, held):
    """Turn pivot k into the element Lk: the variables of k's elements and of k's own list, each flagged by a
    negative nv, written at the end of the used workspace (or in place when k has no elements); k's elements are
    absorbed. Returns |Lk| (counting supervariable sizes), where Lk starts and ends in ``iw``, and the new end."""
    pe, length, nv, w, elen, degree = graph
    head, nxt, last, _ = lists
    elenk, p = elen[k], pe[k]
    dk, nv[k] = 0, -nv[k]
    pk1 = p if elenk == 0 else cnz
    pk2 = pk1
    for k1 in range(elenk + 1):
        if k1 == elenk:
            e, pj, ln = k, p, length[k] - elenk
        else:
            e = iw[p]
            p += 1
            pj, ln = pe[e], length[e]
        for q in range(pj, pj + ln):
            i = iw[q]
            nvi = nv[i]
            if nvi <= 0:
                continue
            dk += nvi
            nv[i] = -nvi
            iw[pk2] = i
            pk2 += 1
            if not held[i]:
                _unlink(i, degree, head, nxt, last)
        if e != k:
            pe[e], w[e] = _flip(k), 0
    if elenk != 0:
        cnz = pk2
    degree[k], pe[k], length[k], elen[k] = dk, pk1, pk2 - pk1, -2
    return dk, pk1, pk2, cnz


@numba.njit(cache=True, inline="always")
def _set_differences(pk1, pk2, mark, graph, iw):
    """w[e] - mark = |Le \\ Lk| for every element e next to a variable of Lk (iw[pk1: pk2])."""
    pe, _, nv, w, elen, degree = graph
    for pk in range(pk1, pk2):
        i = iw[pk]
        eln = elen[i]
        if eln <= 0:
            continue
        nvi = -nv[i]
        for p in range(pe[i], pe[i] + eln):
            e = iw[p]
            if w[e] >= mark:
                w[e] -= nvi
            elif w[e] != 0:
                w[e] = degree[e] + mark - nvi


@numba.njit(cache=True, inline="always")
def _update_degrees(k, pk1, pk2, mark, dk, nvk, nel, graph, iw, lists, held):
    """Bound the external degree of every variable of Lk, absorb the elements inside Lk, prune its list (k first)
    and hash it; a variable with no neighbour outside Lk is eliminated with k (mass elimination).
    Returns the updated |Lk|, the size of k and the count of eliminated variables."""
    pe, length, nv, w, elen, degree = graph
    _, nxt, last, hhead = lists
    n = len(pe)
    for pk in range(pk1, pk2):
        i = iw[pk]
        p1 = pe[i]
        p2, pn, h, d = p1 + elen[i] - 1, p1, 0, 0
        for p in range(p1, p2 + 1):
            e = iw[p]
            if w[e] != 0:
                dext = w[e] - mark
                if dext > 0:
                    d += dext
                    iw[pn] = e
                    pn += 1
                    h += e
                else:
                    pe[e], w[e] = _flip(k), 0  # aggressive absorption
        elen[i] = pn - p1 + 1
        p3 = pn
        for p in range(p2 + 1, p1 + length[i]):
            j = iw[p]
            if nv[j] > 0:
                d += nv[j]
                iw[pn] = j
                pn += 1
                h += j
        if d == 0 and not held[i]:
            pe[i] = _flip(k)
            nvi = -nv[i]
            dk, nvk, nel = dk - nvi, nvk + nvi, nel + nvi
            nv[i], elen[i] = 0, -1
        else:
            degree[i] = min(degree[i], d)
            iw[pn] = iw[p3]
            iw[p3] = iw[p1]
            iw[p1] = k
            length[i] = pn - p1 + 1
            h %= n
            nxt[i], hhead[h], last[i] = hhead[h], i, h
    return dk, nvk, nel


@numba.njit(cache=True, inline="always")
def _merge_supervariables(pk1, pk2, mark, graph, iw, lists, held):
    """Merge the variables of Lk whose lists are equal (same hash bucket, same entries) into supervariables.
    Returns the next mark."""
    pe, length, nv, w, elen, _ = graph
    _, nxt, last, hhead = lists
    for pk in range(pk1, pk2):
        i = iw[pk]
        if nv[i] >= 0:
            continue
        h = last[i]
        i = hhead[h]
        hhead[h] = -1
        while i != -1 and nxt[i] != -1:
            ln, eln = length[i], elen[i]
            for p in range(pe[i] + 1, pe[i] + ln):
                w[iw[p]] = mark
            jlast, j = i, nxt[i]
            while j != -1:
                same = length[j] == ln and elen[j] == eln and held[j] == held[i]
                p = pe[j] + 1
                while same and p < pe[j] + ln:
                    same = w[iw[p]] == mark
                    p += 1
                if same:
                    pe[j] = _flip(i)
                    nv[i] += nv[j]
                    nv[j], elen[j] = 0, -1
                    j = nxt[j]
                    nxt[jlast] = j
                else:
                    jlast, j = j, nxt[j]
            i = nxt[i]
            mark += 1
    return mark


@numba.njit(cache=True, inline="always")
def _finalize(k, pk1, pk2, dk, nvk, left, mindeg, graph, iw, lists, held):
    """Put the variables of Lk back in the degree lists with their new degrees and compact Lk to them.
    Returns the new minimum degree and the end of Lk."""
    pe, length, nv, w, _, degree = graph
    head, nxt, last, _ = lists
    p = pk1
    for pk in range(pk1, pk2):
        i = iw[pk]
        nvi = -nv[i]
        if nvi <= 0:
            continue
        nv[i] = nvi
        d = min(degree[i] + dk - nvi, left - nvi)
        if not held[i]:
            if head[d] != -1:
                last[head[d]] = i
            nxt[i], last[i], head[d] = head[d], -1, i
            mindeg = min(mindeg, d)
        degree[i] = d
        iw[p] = i
        p += 1
    nv[k] = nvk
    length[k] = p - pk1
    if length[k] == 0:
        pe[k], w[k] = -1, 0
    return mindeg, p


@numba.njit(cache=True, nogil=True)
def _amd(ptr, iw, cnz, stop, held):
    """Approximate minimum degree on the quotient graph whose adjacency lists are iw[ptr[i]: ptr[i + 1]] (no
    diagonal); returns the parent of every node in the assembly tree (-1 at roots), nv (> 0 for the elements, the
    pivots) and True; or False when ``iw`` has too little room after the lists or another thread set ``stop[0]``
    (checked at every pivot). The ``held`` (n,) unknowns are eliminated after all others: they are never pivots,
    never merged with unknowns not held nor eliminated with a pivot, and the order stops when only they are left
    (they come back as roots, -1; all False: the plain order). Names follow the published
    algorithm: elen (elements in a list), nv (supervariable size, negated while in the new element Lk), w
    (set-difference counters against ``mark``, 64-bit: the marks grow past 32 bits on large graphs). The lists are of
    ``iw``'s integer type (32-bit halves the memory traffic)."""
    n, kind = len(ptr) - 1, iw.dtype
    length = ptr[1:] - ptr[:-1]
    graph = (ptr[:-1].copy(), length, np.ones(n, kind), np.ones(n, np.int64), np.zeros(n, kind), length.copy())
    pe, _, nv, w, elen, degree = graph
    lists = (np.full(n, -1, kind), np.full(n, -1, kind), np.full(n, -1, kind), np.full(n, -1, kind))
    head, nxt, last, _ = lists
    mark, nel, mindeg, lemax = 2, 0, 0, 0
    for i in range(n):
        d = degree[i]
        if held[i]:  # in no degree list; with no neighbours no list either (pe -1: a root, never compacted)
            if d == 0:
                pe[i] = -1
            continue
        if d == 0:  # no neighbours: eliminated at once
            elen[i], pe[i], w[i] = -2, -1, 0
            nel += 1
        else:
            if head[d] != -1:
                last[head[d]] = i
            nxt[i], head[d] = head[d], i
    target = n - np.sum(held)
    while nel < target:
        if stop[0]:
            return np.full(n, -1, np.int64), nv, False
        while head[mindeg] == -1:
            mindeg += 1
        k = head[mindeg]
        _unlink(k, degree, head, nxt, last)
        elenk, nvk = elen[k], nv[k]
        nel += nvk
        if elenk > 0 and cnz + mindeg >= len(iw):
            cnz = _collect_garbage(pe, iw, length, n, cnz)
            if cnz + mindeg >= len(iw):
                return np.full(n, -1, np.int64), nv, False
        dk, pk1, pk2, cnz = _new_element(k, cnz, graph, iw, lists, held)
        _set_differences(pk1, pk2, mark, graph, iw)
        dk, nvk, nel = _update_degrees(k, pk1, pk2, mark, dk, nvk, nel, graph, iw, lists, held)
        degree[k] = dk
        lemax = max(lemax, dk)
        mark = _merge_supervariables(pk1, pk2, mark + lemax + 1, graph, iw, lists, held)
        mindeg, end = _finalize(k, pk1, pk2, dk, nvk, n - nel, mindeg, graph, iw, lists, held)
        if elenk != 0:
            cnz = end
    parent = np.empty(n, np.int64)
    for i in range(n):
        parent[i] = _flip(pe[i]) if pe[i] < -1 else -1
    return parent, nv, True


class Abandoned(Exception):
    """An ordering or analysis stopped because another thread set its ``stop`` flag (the work was no longer
    wanted: see :class:`meshreg.mesh.early.EarlyAnalysis`)."""


def minimum_degree(a: sp.spmatrix) -> np.ndarray:
    """Approximate minimum degree order (n,) of a square sparse matrix's symmetrized pattern A + A^T: the
    unknowns in the order to eliminate them, for a sparse LU or Cholesky factorization with little fill.

    Unknowns coupled to more than max(DENSE_MIN, DENSE_FACTOR sqrt(n)) others (a hub: the centre of a filled
    hole's fan, a global constraint) are left out of the ordering and put last, as SuiteSparse's AMD does: each
    would otherwise be revisited at every elimination next to it.

    Examples
    --------
    An arrow matrix, one unknown coupled to all others: eliminated first it would fill the whole matrix; minimum
    degree keeps it for last.

    >>> import numpy as np
    >>> import scipy.sparse as sp
    >>> arrow = 10 * np.eye(6)
    >>> arrow[0, 1:] = arrow[1:, 0] = 1
    >>> int(minimum_degree(sp.csc_matrix(arrow))[-1])
    0
    """
    a = sp.csc_matrix(a)
    n = a.shape[0]
    if a.shape != (n, n):
        raise ValueError("minimum_degree needs a square matrix")
    return symmetric_minimum_degree(a, *symmetric_pattern(a))


def dense_unknowns(ptr: np.ndarray) -> np.ndarray:
    """Whether each unknown (n,) of a pattern (column pointers ``ptr`` (n + 1,), no diagonal) is coupled to more
    than max(DENSE_MIN, DENSE_FACTOR sqrt(n)) others: a hub, which :func:`minimum_degree` orders last."""
    n = len(ptr) - 1
    return np.diff(ptr) > max(DENSE_MIN, DENSE_FACTOR * np.sqrt(n))


def symmetric_pattern(a: sp.csc_matrix) -> tuple[np.ndarray, np.ndarray]:
    """The pattern of A + A^T without its diagonal for a square CSC (or CSR) matrix: column pointers (n + 1,) and
    row indices (longer than their used part), each column's rows in the order that :func:`minimum_degree` breaks
    its ties by."""
    return _symmetric_pattern(a.indptr.astype(np.int64), a.indices.astype(np.int64), a.shape[0])


def symmetric_minimum_degree(
    a: sp.csc_matrix, pe: np.ndarray, rows: np.ndarray, stop: np.ndarray | None = None
) -> np.ndarray:
    """:func:`minimum_degree` of a matrix whose :func:`symmetric_pattern` is computed already (a symbolic analysis
    needs it too).

    Parameters
    ----------
    a : csc_matrix (n, n)
        The matrix (its submatrices are ordered again when it has hubs).
    pe, rows : ndarray (n + 1,), ndarray
        Its :func:`symmetric_pattern`.
    stop : ndarray (1,) of bool, optional
        Set by another thread to abandon the ordering (:class:`Abandoned` is raised when the minimum degree
        reaches its next pivot, or after it).

    Returns
    -------
    ndarray (n,)
        The unknowns in the order to eliminate them.
    """
    n = a.shape[0]
    if n == 0:
        return np.zeros(0, np.int64)
    degree = np.diff(pe)
    dense = dense_unknowns(pe)
    if dense.any():
        kept = np.flatnonzero(~dense)
        hubs = np.flatnonzero(dense)
        sub = sp.csc_matrix(a[kept][:, kept])
        order = symmetric_minimum_degree(sub, *symmetric_pattern(sub), stop)
        return np.concatenate([kept[order], hubs[np.argsort(degree[hubs], kind="stable")]])
    stop = np.zeros(1, np.bool_) if stop is None else stop
    order = constrained_minimum_degree(pe, rows, np.zeros(n, np.bool_), stop)
    if stop[0]:
        raise Abandoned("minimum_degree: abandoned by another thread")
    if len(order) != n:
        raise AssertionError("minimum_degree: the assembly tree does not reach every unknown")
    return order


def constrained_minimum_degree(ptr: np.ndarray, rows: np.ndarray, held: np.ndarray, stop: np.ndarray) -> np.ndarray:
    """Approximate minimum degree order of the unknowns not ``held`` (k,), for a symmetric pattern whose ``held``
    unknowns are eliminated after all others (a part between separators: :mod:`meshreg.mesh.dissection`).

    Parameters
    ----------
    ptr, rows : ndarray (n + 1,), ndarray
        The pattern without its diagonal, symmetric (held unknowns included: their couplings count in the others'
        degrees).
    held : ndarray (n,) of bool
        The unknowns held for last: never pivots, never merged with the others (none: :func:`minimum_degree`).
    stop : ndarray (1,) of bool
        Set by another thread to abandon the order (the unknowns then come back in no useful order).
    """
    n = len(ptr) - 1
    cnz = int(ptr[n])
    # room after the pattern: the quotient graph never needs more than the pattern and n more entries (each new
    # element's list is at most as long as the lists it absorbs, plus garbage collection); cs_amd's 1.2 cnz + 2n
    room = cnz + cnz // 5 + 2 * n
    kind = np.int32 if room < np.iinfo(np.int32).max else np.int64  # the same order, less memory traffic
    iw = np.empty(room, kind)
    iw[:cnz] = rows[:cnz]
    parent, nv, done = _amd(ptr.astype(kind, copy=False), iw, cnz, stop, held)
    if not done and not stop[0]:
        raise AssertionError("constrained_minimum_degree: the quotient graph outgrew its workspace")
    order = _postorder(parent, nv, n)
    return order[~held[order]]
