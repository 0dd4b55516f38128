"""Bases of vector fields on the unit square that are tangent to its sides.

A field v = (v1, v2) is tangent to the sides when v1(0, t) = v1(1, t) = 0 and v2(r, 0) = v2(r, 1) = 0;
then id + v maps each side to itself. Both bases here are separable: the first components are
``a1(r) C1 b1(t)^T`` and the second ``a2(r) C2 b2(t)^T`` for coefficient matrices C1, C2, so that
projections, syntheses and Jacobians are small matrix products.

* :func:`riseth_basis`: the paper's L^2-orthonormal basis (sines times Fourier modes), truncated at
  KL: 2 (KL + 2 KL^2) fields, 110 for KL = 5.
* :func:`bspline_basis`: cubic B-splines on n uniform knots per axis (local support), for the
  coarse-to-fine refinement that the global sine basis cannot resolve (e.g. a reparametrization
  like r^0.8 whose slope blows up at a side).

References
----------
Bernal & Lawrence, Section 4 (the basis B of Riseth).
"""

from __future__ import annotations

from collections import OrderedDict
from functools import wraps

import numba
import numpy as np
import scipy.sparse as sp

from .spline import bspline_table

BASIS_CACHE = 8  # bases kept per process, by kind, size and grid (every start and level asks for the same few)


def _kept(make):
    """``make(*args)`` (sizes and the partitions r, t) with its last BASIS_CACHE results kept: a basis and its field
    matrix are built once per process and grid, not once per descent round (a basis is not modified once made)."""
    kept = OrderedDict()

    @wraps(make)
    def cached(*args):
        key = tuple(a.tobytes() if isinstance(a, np.ndarray) else a for a in args)
        if key not in kept:
            kept[key] = make(*args)
            if len(kept) > BASIS_CACHE:
                kept.popitem(last=False)
        kept.move_to_end(key)
        return kept[key]

    return cached


class TensorBasis:
    """Fields ``(a1 C1 b1^T, a2 C2 b2^T)`` at grid nodes, with derivative factors ``da*``, ``db*``.

    Parameters
    ----------
    first : tuple of 4 ndarrays
        (a1 (M, p1), da1, b1 (N, s1), db1): factors of the first components.
    second : tuple of 4 ndarrays
        (a2 (M, p2), da2, b2 (N, s2), db2): factors of the second components.
    sparse : bool
        Whether :meth:`matrix` returns a sparse matrix (local bases).
    """

    def __init__(self, first, second, sparse: bool = False):
        self.a1, self.da1, self.b1, self.db1 = first
        self.a2, self.da2, self.b2, self.db2 = second
        self.sparse = sparse
        self.selection = None  # set when every field moves one node value: the rows of matrix() it keeps
        self._matrix = None
        self._row_ranges = None
        self.shape1 = (self.a1.shape[1], self.b1.shape[1])
        self.shape2 = (self.a2.shape[1], self.b2.shape[1])
        self.size = self.shape1[0] * self.shape1[1] + self.shape2[0] * self.shape2[1]

    def split(self, coef: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """A coefficient vector (size,) as the matrices C1, C2."""
        n1 = self.shape1[0] * self.shape1[1]
        return coef[:n1].reshape(self.shape1), coef[n1:].reshape(self.shape2)

    def project(self, density: np.ndarray) -> np.ndarray:
        """Sums ``sum_nodes G . w_i`` for every field w_i, from G of shape (M, N, 2); shape (size,)."""
        c1 = self.a1.T @ density[..., 0] @ self.b1
        c2 = self.a2.T @ density[..., 1] @ self.b2
        return np.concatenate([c1.ravel(), c2.ravel()])

    def synthesize(self, coef: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The field sum c_i w_i at the nodes (M, N, 2) and its Jacobian (M, N, 2, 2)."""
        c1, c2 = self.split(coef)
        v1 = self.a1 @ c1 @ self.b1.T
        v2 = self.a2 @ c2 @ self.b2.T
        jac = np.empty(v1.shape + (2, 2))
        jac[..., 0, 0] = self.da1 @ c1 @ self.b1.T
        jac[..., 0, 1] = self.a1 @ c1 @ self.db1.T
        jac[..., 1, 0] = self.da2 @ c2 @ self.b2.T
        jac[..., 1, 1] = self.a2 @ c2 @ self.db2.T
        return np.stack([v1, v2], axis=-1), jac

    def matrix(self):
        """The fields as columns of a (2 M N, size) matrix; row (i N + j) 2 + c is component c at node (i, j).

        Built on the first call and kept (every Gauss-Newton round in the basis asks for it); do not modify it.
        """
        if self._matrix is None:
            self._matrix = self._build_matrix()
        return self._matrix

    def row_ranges(self) -> tuple[np.ndarray, np.ndarray]:
        """Per row of :meth:`matrix` (a node value), the range [lo, hi) of the fields that may be non-zero there: the
        fields of its component (the first and the second components' fields are separate columns)."""
        if self._row_ranges is None:
            m, n = self.a1.shape[0], self.b1.shape[0]
            n1 = self.shape1[0] * self.shape1[1]
            self._row_ranges = (np.tile([0, n1], m * n), np.tile([n1, self.size], m * n))
        return self._row_ranges

    def normal_matrix(self, gram: sp.csr_matrix, n: int, out: np.ndarray | None = None) -> np.ndarray:
        """W^T G W, dense (size, size), for the fields W (:meth:`matrix`) and a matrix G on the node values of an
        M x n grid that couples each node only with its 8 neighbours (J^T J of the cell residuals,
        :meth:`meshreg.cell_jacobian.CellJacobian.gram`). With ``out`` (size, size), e.g. a corner of a larger normal
        matrix, it is written there (and returned) instead of into a new array.

        The fields are separable, so the sum over pairs of nodes is done one axis at a time, over the non-zero
        entries of the factors (:func:`_tensor_gram`): for the cubic B-spline bases about 10 times faster than the
        sparse products ``W^T (G W)``, the same matrix to rounding.
        """
        factors = [(self.a1, self.b1), (self.a2, self.b2)]
        offsets = np.cumsum([0, self.shape1[0] * self.shape1[1], self.shape2[0] * self.shape2[1]])
        if out is None:
            out = np.zeros((self.size, self.size))
        else:
            out[:] = 0.0
        for c, (a, b) in enumerate(factors):
            for d, (a2, b2) in enumerate(factors):
                if d < c:
                    continue
                block = out[offsets[c] : offsets[c + 1], offsets[d] : offsets[d + 1]]
                _tensor_gram(
                    gram.data,
                    gram.indices,
                    gram.indptr,
                    n,
                    c,
                    d,
                    *_nonzero(a),
                    *_nonzero(b),
                    *_nonzero(a2),
                    *_nonzero(b2),
                    block,
                )
        upper = out[: offsets[1], offsets[1] :]
        out[offsets[1] :, : offsets[1]] = upper.T
        return out

    def _build_matrix(self):
        m, n = self.a1.shape[0], self.b1.shape[0]
        if self.sparse:
            k1 = sp.kron(sp.csr_matrix(self.a1), sp.csr_matrix(self.b1), format="csr")
            k2 = sp.kron(sp.csr_matrix(self.a2), sp.csr_matrix(self.b2), format="csr")
            z1 = sp.csr_matrix((m * n, k2.shape[1]))
            z2 = sp.csr_matrix((m * n, k1.shape[1]))
            stacked = sp.vstack([sp.hstack([k1, z1]), sp.hstack([z2, k2])], format="csr")
            order = np.arange(2 * m * n).reshape(2, m * n).T.ravel()
            return stacked[order]
        out = np.zeros((m * n, 2, self.size))
        n1 = self.shape1[0] * self.shape1[1]
        out[:, 0, :n1] = np.kron(self.a1, self.b1)
        out[:, 1, n1:] = np.kron(self.a2, self.b2)
        return out.reshape(2 * m * n, self.size)


def _nonzero(factor: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A factor (nodes, functions) and, per node, the range [lo, hi) of functions not zero there."""
    nonzero = factor != 0.0
    lo = np.where(nonzero.any(axis=1), nonzero.argmax(axis=1), 0)
    hi = np.where(nonzero.any(axis=1), factor.shape[1] - nonzero[:, ::-1].argmax(axis=1), 0)
    return np.ascontiguousarray(factor), lo.astype(np.int64), hi.astype(np.int64)


@numba.njit(cache=True)
def _tensor_gram(data, indices, indptr, n, c, d, a, alo, ahi, b, blo, bhi, a2, a2lo, a2hi, b2, b2lo, b2hi, out):
    """out[(p, s), (p2, s2)] += sum over entries G[(i, j, c), (i2, j2, d)] of G a[i, p] b[j, s] a2[i2, p2] b2[j2, s2].

    For each node row i and neighbour row i2 the sum over j is done first (into x, (s, s2)), then spread over
    (p, p2): the cost is that of the non-zero factor entries, not of every pair of fields.
    """
    m = len(indptr) // (2 * n)
    ns, ns2 = b.shape[1], b2.shape[1]
    x = np.zeros((3, ns, ns2))
    lo = np.empty((3, ns), np.int64)
    hi = np.empty((3, ns), np.int64)
    for i in range(m):
        x[:] = 0.0
        lo[:] = ns2
        hi[:] = 0
        for j in range(n):
            row = 2 * (i * n + j) + c
            for k in range(indptr[row], indptr[row + 1]):
                col = indices[k]
                if col % 2 != d:
                    continue
                node = col // 2
                i2, j2 = node // n, node % n
                g = data[k]
                di = i2 - i + 1
                for s in range(blo[j], bhi[j]):
                    gb = g * b[j, s]
                    lo[di, s] = min(lo[di, s], b2lo[j2])
                    hi[di, s] = max(hi[di, s], b2hi[j2])
                    for s2 in range(b2lo[j2], b2hi[j2]):
                        x[di, s, s2] += gb * b2[j2, s2]
        for di in range(3):
            i2 = i + di - 1
            if i2 < 0 or i2 >= m:
                continue
            for p in range(alo[i], ahi[i]):
                for p2 in range(a2lo[i2], a2hi[i2]):
                    w = a[i, p] * a2[i2, p2]
                    for s in range(ns):
                        base = p * ns
                        for s2 in range(lo[di, s], hi[di, s]):
                            out[base + s, p2 * ns2 + s2] += w * x[di, s, s2]


def _sines(x: np.ndarray, kl: int):
    k = np.pi * np.arange(1, kl + 1)
    return np.sqrt(2) * np.sin(np.outer(x, k)), np.sqrt(2) * k * np.cos(np.outer(x, k))


def _fourier(x: np.ndarray, kl: int):
    w = 2 * np.pi * np.arange(1, kl + 1)
    c, s = np.cos(np.outer(x, w)), np.sin(np.outer(x, w))
    values = np.hstack([np.ones((len(x), 1)), np.sqrt(2) * c, np.sqrt(2) * s])
    derivs = np.hstack([np.zeros((len(x), 1)), -np.sqrt(2) * w * s, np.sqrt(2) * w * c])
    return values, derivs


@_kept
def riseth_basis(kl: int, r: np.ndarray, t: np.ndarray) -> TensorBasis:
    """The paper's basis truncated at KL: first components sqrt2 sin(pi k r) psi_l(t), second sqrt2 sin(pi k t)
    psi_l(r).

    psi_l ranges over 1, sqrt2 cos(2 pi l x), sqrt2 sin(2 pi l x), l = 1..KL.

    Examples
    --------
    >>> import numpy as np
    >>> riseth_basis(5, np.linspace(0, 1, 11), np.linspace(0, 1, 11)).size
    110
    """
    if kl < 1:
        raise ValueError("the basis size KL must be at least 1")
    sr, dsr = _sines(r, kl)
    st, dst = _sines(t, kl)
    fr, dfr = _fourier(r, kl)
    ft, dft = _fourier(t, kl)
    return TensorBasis((sr, dsr, ft, dft), (fr, dfr, st, dst))


def _bsplines(x: np.ndarray, n: int):
    """n clamped uniform cubic B-splines on [0, 1] at x, and their derivatives: (len(x), n) each."""
    interior = np.linspace(0.0, 1.0, n - 2)
    return bspline_table(np.concatenate([[0.0] * 3, interior, [1.0] * 3]), 3, np.asarray(x, dtype=float))


@_kept
def bspline_basis(n: int, r: np.ndarray, t: np.ndarray) -> TensorBasis:
    """Cubic B-spline fields with n functions per axis (n >= 4): 2 n (n - 2) fields.

    The first and last B-spline (the only ones non-zero at 0 and 1) are left out along the axis
    where the component must vanish.
    """
    if n < 4:
        raise ValueError("a B-spline basis needs at least 4 functions per axis")
    br, dbr = _bsplines(r, n)
    bt, dbt = _bsplines(t, n)
    inner = slice(1, n - 1)
    return TensorBasis((br[:, inner], dbr[:, inner], bt, dbt), (br, dbr, bt[:, inner], dbt[:, inner]), sparse=True)


@_kept
def node_basis(r: np.ndarray, t: np.ndarray) -> TensorBasis:
    """One field per free node value: moving one node of h along r (inner r nodes) or t (inner t nodes).

    The finest basis there is on the grid (2 M N - 2 M - 2 N fields); derivatives are those of
    the piecewise-linear interpolant (np.gradient).
    """
    ir, it = np.eye(len(r)), np.eye(len(t))
    dr, dt = np.gradient(ir, r, axis=0), np.gradient(it, t, axis=0)
    inner_r, inner_t = slice(1, len(r) - 1), slice(1, len(t) - 1)
    basis = TensorBasis((ir[:, inner_r], dr[:, inner_r], it, dt), (ir, dr, it[:, inner_t], dt[:, inner_t]), sparse=True)
    fields = basis.matrix().tocoo()
    basis.selection = fields.row[np.argsort(fields.col)]
    return basis
