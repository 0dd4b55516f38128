"""Sparse LU by the multifrontal method: the factorization of a mesh Laplacian's interior block (and of the ARAP
systems of the warp) in a fill-reducing order, with the dense work done by BLAS.

The unknowns are eliminated in the order of :func:`~meshreg.mesh.ordering.minimum_degree`, postordered along the
elimination tree. Columns with nested structure are grouped into supernodes (relaxed: a few explicit zeros are
allowed when they save small fronts); each supernode's frontal matrix gathers the matrix entries of its columns and
its children's update matrices, is factorized in place (no pivoting: the systems are M-matrices or symmetric
positive definite) and passes its Schur complement up the tree. Large fronts are factorized in column panels whose
trailing update is one matrix product. Independent subtrees are factorized in two threads (the work is numba code
that releases the GIL); the top of the tree after them.

SuperLU, used before (``scipy.sparse.linalg.splu`` in the same order), spent 1.6-2.0 s on the interior block of a
1M-triangle terrain mesh (500,000 unknowns): it factorizes column by column (supernodes of 1 were its fastest
setting), without BLAS; this factorization 0.76-0.92 s in two threads (docs/benchmarks.md). A matrix with a zero or
non-finite pivot in this order is handed to SuperLU, which pivots within columns.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from functools import cache, cached_property

import numba
import numpy as np
import scipy.sparse as sp
from threadpoolctl import ThreadpoolController

from .dissection import DISSECT_LEAF, dissected_order
from .ordering import Abandoned, _postorder, dense_unknowns, symmetric_minimum_degree, symmetric_pattern

PANEL = 32  # columns per panel of a large front's factorization (its trailing update is one matrix product)
UPDATE_ROWS = 256  # rows of a large front's update per matrix product (bounds the product's scratch)
# columns of the right factor per matrix product of the update block: bounds the copy's scratch (the whole right
# factor, ns times the update columns, grows with the square of the front)
UPDATE_COLUMNS = 512
BLOCKED_MIN = 48  # fronts of at least this many rows (and 8 pivots) are factorized in panels, smaller ones entry-wise
# relaxed supernodes: a child supernode merges into its parent (adjacent columns) when the merged one has at most
# RELAX_SIZES[k] columns and explicit zeros make at most RELAX_ZEROS[k] of its entries (the last size: any)
RELAX_SIZES = (4, 16, 48)
RELAX_ZEROS = (1.0, 0.2, 0.02, 0.01)
THREADS = 2  # subtrees of the elimination tree factorized side by side
THREADS_MIN = 100_000  # unknowns below which one thread factorizes (at 50k, two were no faster than one)
# BLAS threads per matrix product of a front: the fronts are split between our own threads (OpenBLAS's default of
# two made a 60k-unknown planar block 25% slower, a 3D grid's 7.6 times)
BLAS_THREADS = 1
SCHEDULE_SPLITS = 64  # subtrees split at most this often when looking for the best balance of the threads


@numba.njit(cache=True, nogil=True)
def _inverse(order):
    """The inverse (n,) of a permutation (n,)."""
    inv = np.empty(len(order), np.int64)
    for k in range(len(order)):
        inv[order[k]] = k
    return inv


@numba.njit(cache=True, nogil=True)
def _etree(ptr, rows, order, inv):
    """Elimination tree (parent of each column, -1 at a root) of the symmetric pattern (ptr, rows) in ``order``."""
    n = len(order)
    parent = np.full(n, -1, np.int64)
    ancestor = np.full(n, -1, np.int64)
    for k in range(n):
        col = order[k]
        for p in range(ptr[col], ptr[col + 1]):
            i = inv[rows[p]]
            while i != -1 and i < k:
                above = ancestor[i]
                ancestor[i] = k
                if above == -1:
                    parent[i] = k
                i = above
    return parent


@numba.njit(cache=True, nogil=True)
def _relabel(parent, post):
    """The tree ``parent`` with node post[k] renamed k."""
    inv = _inverse(post)
    out = np.empty(len(parent), np.int64)
    for k in range(len(post)):
        p = parent[post[k]]
        out[k] = -1 if p == -1 else inv[p]
    return out


@numba.njit(cache=True, nogil=True)
def _column_counts(ptr, rows, order, inv, parent):
    """Entries below the diagonal in each column of L (the row subtrees of the elimination tree)."""
    n = len(order)
    count = np.zeros(n, np.int64)
    mark = np.full(n, -1, np.int64)
    for i in range(n):
        mark[i] = i
        col = order[i]
        for p in range(ptr[col], ptr[col + 1]):
            j = inv[rows[p]]
            while j != -1 and j < i and mark[j] != i:
                count[j] += 1
                mark[j] = i
                j = parent[j]
    return count


@numba.njit(cache=True)
def _merges(columns, real, nu):
    """Whether a supernode of ``columns`` with ``real`` true entries and ``nu`` update rows stays relaxed."""
    stored = columns * (columns + nu) - columns * (columns - 1) // 2
    zeros = stored - real
    for k in range(len(RELAX_SIZES)):
        if columns <= RELAX_SIZES[k]:
            return zeros <= RELAX_ZEROS[k] * stored
    return zeros <= RELAX_ZEROS[-1] * stored


@numba.njit(cache=True, nogil=True)
def _supernodes(parent, count):
    """First column of each (relaxed) supernode, (nsup + 1,) ending with n: fundamental supernodes (a chain of
    only children whose columns nest), then each merged into its parent when it is the parent's last child and
    :func:`_merges` allows."""
    n = len(parent)
    children = np.zeros(n, np.int64)
    for j in range(n):
        if parent[j] != -1:
            children[parent[j]] += 1
    first = np.empty(n + 1, np.int64)
    nsup, real, f = 0, 0, 0
    while f < n:
        end = f + 1
        while end < n and parent[end - 1] == end and count[end - 1] == count[end] + 1 and children[end] == 1:
            end += 1
        own = 0
        for k in range(f, end):
            own += count[k] + 1
        if nsup > 0 and parent[f - 1] == f and _merges(end - first[nsup - 1], real + own, count[end - 1]):
            real += own
        else:
            first[nsup] = f
            nsup += 1
            real = own
        f = end
    first[nsup] = n
    return first[: nsup + 1].copy()


@numba.njit(cache=True, inline="always")
def _add_row(flat, k, i, last, mark, s):
    """Appends row i to supernode s's update rows flat[..k] when it comes after the supernode's columns (``last``)
    and is not there yet (``mark``); the array grows when full. Returns the array and its new length."""
    if i < last or mark[i] == s:
        return flat, k
    mark[i] = s
    if k >= len(flat):
        grown = np.empty(2 * len(flat) + 16, np.int64)
        grown[:k] = flat[:k]
        flat = grown
    flat[k] = i
    return flat, k + 1


@numba.njit(cache=True, nogil=True)
def _structure(ptr, rows, order, inv, first, parent):
    """Each supernode's update rows (flat, with offsets (nsup + 1,): rows after its columns in its front), its
    parent supernode (-1 at a root) and its children as linked lists (head, following; in increasing order)."""
    nsup, n = len(first) - 1, len(order)
    owner = np.empty(n, np.int64)
    for s in range(nsup):
        owner[first[s] : first[s + 1]] = s
    sparent = np.full(nsup, -1, np.int64)
    head, following = np.full(nsup, -1, np.int64), np.full(nsup, -1, np.int64)
    for s in range(nsup - 1, -1, -1):
        p = parent[first[s + 1] - 1]
        if p != -1:
            sparent[s] = owner[p]
            following[s], head[owner[p]] = head[owner[p]], s
    mark = np.full(n, -1, np.int64)
    flat, off = np.empty(len(rows) + n, np.int64), np.zeros(nsup + 1, np.int64)
    k = 0
    for s in range(nsup):
        last = first[s + 1]
        for j in range(first[s], last):
            col = order[j]
            for p in range(ptr[col], ptr[col + 1]):
                flat, k = _add_row(flat, k, inv[rows[p]], last, mark, s)
        c = head[s]
        while c != -1:
            for q in range(off[c], off[c + 1]):
                flat, k = _add_row(flat, k, flat[q], last, mark, s)
            c = following[c]
        off[s + 1] = k
    return flat[:k].copy(), off, sparent, head, following


@numba.njit(cache=True, error_model="numpy")
def _entrywise_lu(front, m, ns):
    """Partial LU in place of the first ns pivots of a front (m * m, row-major)."""
    for k in range(ns):
        pivot_row = k * m
        pivot = front[pivot_row + k]
        for i in range(k + 1, m):
            row = i * m
            factor = front[row + k] / pivot
            front[row + k] = factor
            if factor != 0.0:
                for j in range(k + 1, m):
                    front[row + j] -= factor * front[pivot_row + j]


@numba.njit(cache=True, error_model="numpy")
def _subtract_product(front, inner, rows, columns, work):
    """front[rows, columns] -= front[rows, inner] @ front[inner, columns] (front (m, m); ``inner``, ``rows``,
    ``columns`` as (start, stop)) by matrix products of at most UPDATE_ROWS rows and UPDATE_COLUMNS columns, each block
    of the right factor copied once (``work``: scratch of at least (inner + UPDATE_ROWS) * UPDATE_COLUMNS +
    UPDATE_ROWS * inner entries)."""
    c0, c1 = inner
    r0, r1 = rows
    width = c1 - c0
    if width == 0 or r1 <= r0:
        return
    for b0 in range(columns[0], columns[1], UPDATE_COLUMNS):
        b1 = min(b0 + UPDATE_COLUMNS, columns[1])
        span = b1 - b0
        right = work[: width * span].reshape((width, span))
        right[:] = front[c0:c1, b0:b1]
        used = width * span
        for a0 in range(r0, r1, UPDATE_ROWS):
            a1 = min(a0 + UPDATE_ROWS, r1)
            left = work[used : used + (a1 - a0) * width].reshape((a1 - a0, width))
            product = work[used + (a1 - a0) * width : used + (a1 - a0) * (width + span)].reshape((a1 - a0, span))
            left[:] = front[a0:a1, c0:c1]
            np.dot(left, right, product)
            for i in range(a1 - a0):
                for j in range(span):
                    front[a0 + i, b0 + j] -= product[i, j]


@numba.njit(cache=True, error_model="numpy")
def _panel_lu(front, m, ns, work):
    """Partial LU in place of the first ns pivots of a front (m, m): column panels of PANEL pivots, each factorized
    entry-wise, its rows of U by forward substitution, and the pivot rows and columns after it updated by matrix
    products; the update block (rows and columns from ns on, most of the work) then by one product of inner size
    ns, L21 U12, instead of ns / PANEL thin ones (a dense front of 1000 rows and 255 pivots: 14% less time;
    ``work``: scratch of :func:`_subtract_product`)."""
    for k0 in range(0, ns, PANEL):
        k1 = min(k0 + PANEL, ns)
        for k in range(k0, k1):
            pivot = front[k, k]
            for i in range(k + 1, m):
                factor = front[i, k] / pivot
                front[i, k] = factor
                if factor != 0.0:
                    for j in range(k + 1, k1):
                        front[i, j] -= factor * front[k, j]
        if k1 == m:
            return
        for k in range(k0, k1):
            for i in range(k + 1, k1):
                factor = front[i, k]
                if factor != 0.0:
                    for j in range(k1, m):
                        front[i, j] -= factor * front[k, j]
        _subtract_product(front, (k0, k1), (k1, m), (k1, ns), work)  # the pivot columns left, on every row
        _subtract_product(front, (k0, k1), (k1, ns), (ns, m), work)  # the pivot rows left, on the update columns
    _subtract_product(front, (0, ns), (ns, m), (ns, m), work)


@numba.njit(cache=True)
def _assemble_front(front, m, s, csc, csr, order, inv, first, loc):
    """The matrix entries of supernode s's columns (rows from its first column on) and rows (columns after it);
    False when an entry falls outside the front (loc < 0: not in the analysed pattern)."""
    f, last = first[s], first[s + 1]
    for j in range(f, last):
        col, cj = order[j], j - f
        for p in range(csc[0][col], csc[0][col + 1]):
            i = inv[csc[1][p]]
            if i >= f:
                if loc[i] < 0:
                    return False
                front[loc[i] * m + cj] += csc[2][p]
        for p in range(csr[0][col], csr[0][col + 1]):
            i = inv[csr[1][p]]
            if i >= last:
                if loc[i] < 0:
                    return False
                front[cj * m + loc[i]] += csr[2][p]
    return True


@numba.njit(cache=True)
def _extend_add(front, m, update, nc, rows, loc, rel):
    """Adds a child's update matrix (nc * nc, on its update rows) into the front at the rows' places."""
    for a in range(nc):
        rel[a] = loc[rows[a]]
    for a in range(nc):
        target, source = rel[a] * m, a * nc
        for b in range(nc):
            front[target + rel[b]] += update[source + b]


@numba.njit(cache=True)
def _store(front, m, ns, nu, s, factors, offsets):
    """Copies the factorized front's diagonal block (LU packed), L21 and U12 into the factors."""
    diag, lower, upper = factors
    d, lu = offsets[0][s], offsets[1][s]
    for a in range(ns):
        for b in range(ns):
            diag[d + a * ns + b] = front[a * m + b]
    for a in range(nu):
        for b in range(ns):
            lower[lu + a * ns + b] = front[(ns + a) * m + b]
    for a in range(ns):
        for b in range(nu):
            upper[lu + a * nu + b] = front[a * m + ns + b]


@numba.njit(cache=True, inline="always")
def _room(stack, need):
    """The stack of update matrices, grown (by a quarter, or to ``need``) when shorter than ``need`` entries: a
    guard, since the stack is allocated at the size :func:`_stack_need` counts (a count that fell short would
    otherwise write past its end: numba does not check bounds)."""
    if need <= len(stack):
        return stack
    grown = np.empty(max(len(stack) + len(stack) // 4, need))
    grown[: len(stack)] = stack
    return grown


@numba.njit(cache=True, nogil=True)
def _stack_need(seq, off, head, following, ext_off):
    """The most entries (at least 1) that :func:`_factor_sequence` holds at once on its stack of update matrices
    for ``seq``: each supernode pops its children's (those with ext_off < 0) and pushes its own (nu^2 entries)
    unless it leaves it in ``ext``."""
    sizes = np.zeros(len(seq) + 1, np.int64)
    depth, held, most = 0, 0, 1
    for s in seq:
        c = head[s]
        while c != -1:
            if ext_off[c] < 0:
                depth -= 1
                held -= sizes[depth]
            c = following[c]
        nu = off[s + 1] - off[s]
        if nu > 0 and ext_off[s] < 0:
            sizes[depth] = nu * nu
            depth += 1
            held += nu * nu
            most = max(most, held)
    return most


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _factor_sequence(csc, csr, order, inv, first, tree, seq, ext_off, ext, factors, offsets):
    """Factorizes the supernodes ``seq`` (increasing; each one's children either in ``seq`` before it or with
    their update matrix in ``ext`` at ``ext_off``); a supernode with ext_off >= 0 leaves its update there, the
    others on a stack that its parent in ``seq`` reads. Its scratch fits the largest front of ``seq``."""
    flat, off, head, following = tree
    n = len(order)
    mmax = max([first[s + 1] - first[s] + off[s + 1] - off[s] for s in seq]) if len(seq) else 0
    buffer, rel, loc = np.empty(mmax * mmax), np.empty(mmax, np.int64), np.full(n, -1, np.int64)
    work = np.empty((UPDATE_ROWS + UPDATE_COLUMNS) * (mmax + UPDATE_ROWS))  # _subtract_product's scratch
    # the stack starts at the size it will reach: grown on the way, each copy left its old block as a hole in the
    # heap (32 MB of the 1M-triangle front end's peak)
    stack = np.empty(_stack_need(seq, off, head, following, ext_off))
    tops, depth = np.zeros(len(seq) + 1, np.int64), 0
    for s in seq:
        f, last = first[s], first[s + 1]
        ns, nu = last - f, off[s + 1] - off[s]
        m = ns + nu
        front = buffer[: m * m]
        front[:] = 0.0
        for j in range(f, last):
            loc[j] = j - f
        for q in range(nu):
            loc[flat[off[s] + q]] = ns + q
        if not _assemble_front(front, m, s, csc, csr, order, inv, first, loc):
            return False
        stacked = 0
        c = head[s]
        while c != -1:
            stacked += ext_off[c] < 0
            c = following[c]
        depth -= stacked
        t, c = depth, head[s]
        while c != -1:
            nc = off[c + 1] - off[c]
            rows = flat[off[c] : off[c + 1]]
            if ext_off[c] >= 0:
                _extend_add(front, m, ext[ext_off[c] : ext_off[c] + nc * nc], nc, rows, loc, rel)
            else:
                _extend_add(front, m, stack[tops[t] : tops[t] + nc * nc], nc, rows, loc, rel)
                t += 1
            c = following[c]
        if m >= BLOCKED_MIN and ns >= 8:
            _panel_lu(front.reshape((m, m)), m, ns, work)
        else:
            _entrywise_lu(front, m, ns)
        _store(front, m, ns, nu, s, factors, offsets)
        loc[f:last] = -1
        for q in range(nu):
            loc[flat[off[s] + q]] = -1
        if nu == 0:
            continue
        if ext_off[s] >= 0:
            target = ext[ext_off[s] : ext_off[s] + nu * nu]
        else:
            stack = _room(stack, tops[depth] + nu * nu)
            target = stack[tops[depth] : tops[depth] + nu * nu]
            tops[depth + 1] = tops[depth] + nu * nu
            depth += 1
        for a in range(nu):
            source = (ns + a) * m + ns
            target[a * nu : (a + 1) * nu] = front[source : source + nu]
    return True


@numba.njit(cache=True, inline="always", error_model="numpy")
def _pivot_rows(s, first, factors, offsets, b):
    """Supernode s's part of the forward solve within its own rows (its unit lower diagonal block)."""
    f, ns, d = first[s], first[s + 1] - first[s], offsets[0][s]
    for a in range(ns):
        for q in range(a):
            w = factors[0][d + a * ns + q]
            for r in range(b.shape[1]):
                b[f + a, r] -= w * b[f + q, r]


@numba.njit(cache=True, inline="always", error_model="numpy")
def _update_rows(s, first, flat, off, factors, offsets, b, held, want):
    """Supernode s's part of the forward solve on its update rows i whose ``held[i]`` is ``want``."""
    f, ns, lu = first[s], first[s + 1] - first[s], offsets[1][s]
    for a in range(off[s + 1] - off[s]):
        i = flat[off[s] + a]
        if held[i] == want:
            for q in range(ns):
                w = factors[1][lu + a * ns + q]
                for r in range(b.shape[1]):
                    b[i, r] -= w * b[f + q, r]


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _forward(seq, first, flat, off, factors, offsets, b, held):
    """Solves L y = b in place (b (n, k) in the factor's order) over the supernodes ``seq``, in their order, except
    on the rows i where ``held[i]`` (left for :func:`_forward_held`)."""
    for s in seq:
        _pivot_rows(s, first, factors, offsets, b)
        _update_rows(s, first, flat, off, factors, offsets, b, held, False)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _forward_held(top, first, flat, off, factors, offsets, b, held):
    """After :func:`_forward` of the threads' subtrees: the forward solve on the ``held`` rows (the top's), every
    supernode in order, the ``top`` ones (a mask over the supernodes) whole. Each row gets the operations of the
    serial solve in the serial order, so the bits are the same."""
    for s in range(len(first) - 1):
        if top[s]:
            _pivot_rows(s, first, factors, offsets, b)
        _update_rows(s, first, flat, off, factors, offsets, b, held, True)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _backward(seq, first, flat, off, factors, offsets, b):
    """Solves U x = y in place over the supernodes ``seq``, last to first (each after its ancestors)."""
    diag, upper = factors[0], factors[2]
    k = b.shape[1]
    for t in range(len(seq) - 1, -1, -1):
        s = seq[t]
        f, ns, nu = first[s], first[s + 1] - first[s], off[s + 1] - off[s]
        d, lu = offsets[0][s], offsets[1][s]
        for a in range(ns - 1, -1, -1):
            for q in range(nu):
                w = upper[lu + a * nu + q]
                i = flat[off[s] + q]
                for r in range(k):
                    b[f + a, r] -= w * b[i, r]
            for q in range(a + 1, ns):
                w = diag[d + a * ns + q]
                for r in range(k):
                    b[f + a, r] -= w * b[f + q, r]
            pivot = diag[d + a * ns + a]
            for r in range(k):
                b[f + a, r] /= pivot


@numba.njit(cache=True)
def _pivots_nonzero(diag, first, start):
    """Whether every pivot (the diagonal of each supernode's packed LU block) is nonzero."""
    for s in range(len(first) - 1):
        ns = first[s + 1] - first[s]
        for a in range(ns):
            if diag[start[s] + a * ns + a] == 0.0:
                return False
    return True


@numba.njit(cache=True)
def _all_finite(values):
    for v in values:
        if not np.isfinite(v):
            return False
    return True


def _work(first, off) -> np.ndarray:
    """Floating-point operations (roughly) of each supernode's front: its partial LU, the update, the assembly."""
    ns = np.diff(first).astype(float)
    nu = np.diff(off).astype(float)
    return 2 / 3 * ns**3 + 2 * ns**2 * nu + 2 * ns * nu**2 + (ns + nu) ** 2


@numba.njit(cache=True, nogil=True)
def _subtrees(sparent, work):
    """Each supernode's subtree: its work and its number of supernodes (children come before parents)."""
    total, size = work.copy(), np.ones(len(work), np.int64)
    for s in range(len(work)):
        if sparent[s] != -1:
            total[sparent[s]] += total[s]
            size[sparent[s]] += size[s]
    return total, size


def _balance(candidates, total, threads):
    """The candidates' subtrees given to the least loaded thread, largest first: (bins of roots, largest load)."""
    loads, bins = [0.0] * threads, [[] for _ in range(threads)]
    for s in sorted(candidates, key=lambda s: -total[s]):
        k = int(np.argmin(loads))
        loads[k] += total[s]
        bins[k].append(s)
    return bins, max(loads)


def _schedule(first, off, sparent, threads, splits=SCHEDULE_SPLITS):
    """Subtrees for the threads and the top of the tree for after them.

    Returns ``bins`` (one increasing array of supernodes per thread), ``top`` (the rest, increasing) and
    ``roots`` (the subtrees' roots, whose update matrices pass from the threads to the top).
    Starting from the roots, the largest subtree is split into its children (its root joins the top), up to
    ``splits`` times; of these, the cut with the least estimated time (the top's work plus the most loaded thread's)
    is kept.
    """
    work = _work(first, off)
    total, size = _subtrees(sparent, work)
    by_parent = np.argsort(sparent, kind="stable")
    starts = np.searchsorted(sparent[by_parent], np.arange(len(work) + 1))
    candidates, top = [int(s) for s in np.flatnonzero(sparent == -1)], []
    best = (np.inf, None, None)
    for _ in range(splits + 1):
        bins, load = _balance(candidates, total, threads)
        estimate = load + sum(work[s] for s in top)
        if estimate < best[0]:
            best = (estimate, bins, list(top))
        largest = max(candidates, key=lambda s: total[s])
        kids = by_parent[starts[largest] : starts[largest + 1]]
        if len(kids) == 0:
            break
        candidates.remove(largest)
        top.append(largest)
        candidates += [int(c) for c in kids]
    _, bins, top = best
    ranges = [[np.arange(s - size[s] + 1, s + 1) for s in b] for b in bins]
    seqs = [np.sort(np.concatenate(r)) if r else np.zeros(0, np.int64) for r in ranges]
    roots = np.array([s for b in bins for s in b], np.int64)
    return seqs, np.sort(np.array(top, np.int64)), roots


@dataclass(frozen=True)
class Analysis:
    """The symbolic part of a multifrontal LU, which depends on the matrix's pattern alone (:func:`analyse`).

    Attributes
    ----------
    n : int
        Unknowns.
    order : ndarray (n,)
        The elimination order (postordered along the elimination tree); ``inv`` its inverse.
    first : ndarray (nsup + 1,)
        First column (in ``order``) of each supernode, ending with n.
    flat, off : ndarray
        Each supernode's update rows, flat[off[s]:off[s + 1]].
    head, following : ndarray (nsup,)
        Each supernode's children as linked lists.
    schedule : tuple
        The threads' subtrees, the top of the tree and the subtrees' roots (:func:`_schedule`).
    """

    n: int
    order: np.ndarray
    inv: np.ndarray
    first: np.ndarray
    flat: np.ndarray
    off: np.ndarray
    head: np.ndarray
    following: np.ndarray
    schedule: tuple


def ordered_in_space(n: int) -> bool:
    """Whether :func:`analyse` orders a pattern of ``n`` unknowns by their places in space when it is given them
    (:func:`~meshreg.mesh.dissection.dissected_order`, for more than DISSECT_LEAF unknowns)."""
    return n > DISSECT_LEAF


def analyse(
    pattern: sp.spmatrix,
    threads: int = THREADS,
    stop: np.ndarray | None = None,
    symmetric: bool = False,
    points: np.ndarray | None = None,
) -> Analysis:
    """The symbolic analysis of a multifrontal LU of any matrix whose entries lie within ``pattern`` (n, n) (the
    pattern of A + A^T is used): the order (:func:`~meshreg.mesh.ordering.minimum_degree`), the elimination tree,
    the supernodes and their fronts' rows, and the threads' subtrees (one thread under THREADS_MIN unknowns). It
    needs no values, so it can run while the values are computed. ``stop`` (1,) of bool: another thread sets it to
    abandon the analysis (:class:`~meshreg.mesh.ordering.Abandoned`, raised at the ordering's next pivot or after
    the ordering). ``symmetric``: the pattern is symmetric, without diagonal or repeated entries (the edges of a
    mesh, :func:`~meshreg.mesh.harmonic.face_pattern`); its sorted CSC is then the pattern of A + A^T that
    :func:`~meshreg.mesh.ordering.symmetric_pattern` would build, entry for entry (0.1-0.16 s at 1M triangles).
    ``points`` (n, 3): the unknowns' places in space (a mesh's interior vertices); given, a pattern of more than
    DISSECT_LEAF unknowns without hubs is ordered by :func:`~meshreg.mesh.dissection.dissected_order` (nested
    dissection by planes: at 1M triangles about half the time of the minimum degree order, and a little less fill)."""
    pattern = sp.csc_matrix(pattern)
    n = pattern.shape[0]
    if pattern.shape != (n, n):
        raise ValueError("analyse needs a square pattern")
    if symmetric:
        pattern.sort_indices()
        ptr, rows = pattern.indptr.astype(np.int64), pattern.indices.astype(np.int64)
    else:
        ptr, rows = symmetric_pattern(pattern)
    if points is None or not ordered_in_space(n) or dense_unknowns(ptr).any():
        order = symmetric_minimum_degree(pattern, ptr, rows, stop)
    else:
        order = dissected_order(points, ptr, rows, stop, leaf=DISSECT_LEAF)
    parent = _etree(ptr, rows, order, _inverse(order))
    post = _postorder(parent, np.ones(n, np.int64), n)
    order, parent = order[post], _relabel(parent, post)
    inv = _inverse(order)
    first = _supernodes(parent, _column_counts(ptr, rows, order, inv, parent))
    if stop is not None and stop[0]:
        raise Abandoned("analyse: abandoned by another thread")
    flat, off, sparent, head, following = _structure(ptr, rows, order, inv, first, parent)
    if threads > 1 and n >= max(THREADS_MIN, 1):
        schedule = _schedule(first, off, sparent, threads)
    else:
        schedule = ([], np.arange(len(first) - 1), np.zeros(0, np.int64))
    return Analysis(n, order, inv, first, flat, off, head, following, schedule)


@cache
def _blas() -> ThreadpoolController:
    """The process's BLAS libraries, found once (threadpoolctl's ``threadpool_limits`` looks them up again at every
    call: 2-10 ms each). Those loaded at the first factorization: numpy's and scipy's, which this module's imports
    load already."""
    return ThreadpoolController()


class MultifrontalLU:
    """The LU factors of a sparse square matrix that needs no pivoting (an M-matrix, a symmetric positive definite
    matrix), by the multifrontal method; :meth:`solve` solves A x = b.

    Parameters
    ----------
    a : sparse matrix (n, n)
        Its pattern should be (nearly) symmetric: the fronts follow the pattern of A + A^T.
    analysis : Analysis, optional
        The symbolic analysis (:func:`analyse`) of a pattern that holds A's; of A itself by default.
    rows : csr_matrix (n, n), optional
        A again, by rows (its column indices in any order), when the caller has it: spares converting A (0.14 s
        for the interior block of a 1M-triangle mesh, after the analysis, on the front end's critical path).

    Raises
    ------
    ZeroDivisionError
        When a pivot is zero or the factors are not finite (the caller may pivot: :class:`Factorization`).
    ValueError
        When A has entries outside the analysed pattern, or its shape is not the analysis's.

    Examples
    --------
    >>> import numpy as np
    >>> import scipy.sparse as sp
    >>> a = sp.diags([-1.0, 2.5, -1.0], [-1, 0, 1], shape=(50, 50)).tocsc()
    >>> x = MultifrontalLU(a).solve(np.ones(50))
    >>> bool(np.allclose(a @ x, 1.0))
    True
    """

    def __init__(self, a: sp.spmatrix, analysis: Analysis | None = None, rows: sp.csr_matrix | None = None):
        a = sp.csc_matrix(a, dtype=float)
        self.analysis = analysis = analyse(a) if analysis is None else analysis
        if a.shape != (analysis.n, analysis.n):
            raise ValueError(f"a matrix of shape {a.shape} for an analysis of {analysis.n} unknowns")
        csc = (a.indptr, a.indices, a.data)
        rows_major = a.tocsr() if rows is None else sp.csr_matrix(rows, dtype=float)
        if rows_major.shape != a.shape or rows_major.nnz != a.nnz:
            raise ValueError(f"rows {rows_major.shape}, {rows_major.nnz} entries, are not A {a.shape}, {a.nnz}")
        csr = (rows_major.indptr, rows_major.indices, rows_major.data)
        first, off = analysis.first, analysis.off
        ns, nu = np.diff(first), np.diff(off)
        self.offsets = (np.r_[0, np.cumsum(ns * ns)], np.r_[0, np.cumsum(ns * nu)])
        self.factors = (np.empty(self.offsets[0][-1]), np.empty(self.offsets[1][-1]), np.empty(self.offsets[1][-1]))
        tree = (analysis.flat, off, analysis.head, analysis.following)
        common = (csc, csr, analysis.order, analysis.inv, first, tree)
        bins, top, roots = analysis.schedule
        ext_off = np.full(len(ns), -1, np.int64)
        ext_off[roots] = np.r_[0, np.cumsum(nu[roots] ** 2)][:-1]
        ext = np.empty(int((nu[roots] ** 2).sum()))
        run = [(b, ext_off, ext, self.factors, self.offsets) for b in bins]
        with _blas().limit(limits=BLAS_THREADS, user_api="blas"):
            self._factorize(common, run, top, ext_off, ext)
        finite = all(_all_finite(part) for part in self.factors)
        if not (finite and _pivots_nonzero(self.factors[0], first, self.offsets[0])):
            raise ZeroDivisionError("a zero or non-finite pivot in the multifrontal LU")

    def _factorize(self, common, run, top, ext_off, ext):
        """The threads' subtrees side by side, then the top of the tree."""
        if run:
            with ThreadPoolExecutor(len(run) - 1 or 1) as pool:
                pending = [pool.submit(_factor_sequence, *common, *r) for r in run[1:]]
                fits = [_factor_sequence(*common, *run[0])] + [job.result() for job in pending]
            if not all(fits):
                raise ValueError("the matrix has entries outside the analysed pattern")
        if not _factor_sequence(*common, top, ext_off, ext, self.factors, self.offsets):
            raise ValueError("the matrix has entries outside the analysed pattern")

    def solve(self, b: np.ndarray) -> np.ndarray:
        """x (n,) or (n, k) with A x = b."""
        b = np.asarray(b, dtype=float)
        an = self.analysis
        work = np.ascontiguousarray((b[:, None] if b.ndim == 1 else b)[an.order])
        tree = (an.first, an.flat, an.off, self.factors, self.offsets)
        bins = an.schedule[0]
        if bins:
            self._threaded_solve(bins, tree, work)
        else:
            every = np.arange(len(an.first) - 1)
            _forward(every, *tree, work, np.zeros(len(work), np.bool_))
            _backward(every, *tree, work)
        x = np.empty_like(work)
        x[an.order] = work
        return x.reshape(b.shape)

    @cached_property
    def _held(self) -> tuple[np.ndarray, np.ndarray]:
        """Masks of the top of the tree (:attr:`Analysis.schedule`): over the supernodes (nsup,) and over the rows
        in the factor's order (n,)."""
        an = self.analysis
        top = np.zeros(len(an.first) - 1, np.bool_)
        top[an.schedule[1]] = True
        return top, np.repeat(top, np.diff(an.first))

    def _threaded_solve(self, bins: list, tree: tuple, work: np.ndarray) -> None:
        """L U x = b in place (``work`` (n, k), the factor's order) with the threads' subtrees side by side, to the
        same bits as one thread: forward, each subtree on its own rows (the rows of the top, which two subtrees may
        share, held back), then every supernode's part on the top's rows in order; back, the top, then each subtree
        (which reads the rows above it and writes its own)."""
        top, held = self._held
        with ThreadPoolExecutor(max(len(bins) - 1, 1)) as pool:
            pending = [pool.submit(_forward, seq, *tree, work, held) for seq in bins[1:]]
            _forward(bins[0], *tree, work, held)
            for job in pending:
                job.result()
            _forward_held(top, *tree, work, held)
            _backward(self.analysis.schedule[1], *tree, work)
            pending = [pool.submit(_backward, seq, *tree, work) for seq in bins[1:]]
            _backward(bins[0], *tree, work)
            for job in pending:
                job.result()
