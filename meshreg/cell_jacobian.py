"""The Jacobian of the cell residuals of a grid with respect to its node displacements, and its normal matrix.

Each cell's 3 residuals depend on the 2 components of its 4 corner nodes, so J (3 cells x 2 nodes) is kept as
per-cell 3 x 8 blocks, and J^T J couples each node with its 8 neighbours (a 9-point stencil of 2 x 2 blocks).
The CSR pattern of J^T J is built directly from that stencil and the per-cell products are added into its data
in one numba pass (no sorting of keys, no (cells, 8, 8) temporary: at 401 x 401 the pattern took 1.4 s to build
by sorting).
"""

from __future__ import annotations

from functools import lru_cache

import numba
import numpy as np
import scipy.sparse as sp

CORNERS = ((0, 0), (1, 0), (0, 1), (1, 1))  # (di, dj) of a cell's corners, in the order of its 8 columns
DENSE_CHUNK = 1024  # cells per block of J @ fields in CellJacobian.normal_dense (a few MB, reused)
PATTERN_CACHE = 4  # grid sizes whose J^T J pattern is kept (a work grid, a full grid, a mesh resolution, ...)


@numba.njit(cache=True)
def _stencil_pattern(m, n):
    """indptr, indices of the 9-point stencil of 2 x 2 blocks on an M x N grid (unknown 2 (i N + j) + c)."""
    size = 2 * m * n
    indptr = np.zeros(size + 1, np.int32)
    for i in range(m):
        for j in range(n):
            width = (min(i + 1, m - 1) - max(i - 1, 0) + 1) * (min(j + 1, n - 1) - max(j - 1, 0) + 1) * 2
            for c in range(2):
                row = 2 * (i * n + j) + c
                indptr[row + 1] = indptr[row] + width
    indices = np.empty(indptr[size], np.int32)
    for i in range(m):
        for j in range(n):
            for c in range(2):
                k = indptr[2 * (i * n + j) + c]
                for i2 in range(max(i - 1, 0), min(i + 1, m - 1) + 1):
                    for j2 in range(max(j - 1, 0), min(j + 1, n - 1) + 1):
                        for c2 in range(2):
                            indices[k] = 2 * (i2 * n + j2) + c2
                            k += 1
    return indptr, indices


@numba.njit(cache=True)
def _upper_triangle(indptr, indices):
    """Positions (in the data) of the entries on and above the diagonal of a CSR pattern, and their indptr."""
    size = len(indptr) - 1
    upper = np.empty(len(indices), np.int64)
    upper_indptr = np.zeros(size + 1, np.int32)
    count = 0
    for row in range(size):
        for k in range(indptr[row], indptr[row + 1]):
            if indices[k] >= row:
                upper[count] = k
                count += 1
        upper_indptr[row + 1] = count
    return upper[:count], upper_indptr


@numba.njit(cache=True)
def _gram_data(blocks, m, n, indptr):
    """The CSR data of J^T J on the pattern of :func:`_stencil_pattern`, from per-cell blocks (cells, 3, 8)."""
    data = np.zeros(indptr[-1])
    for cell in range(blocks.shape[0]):
        i, j = cell // (n - 1), cell % (n - 1)
        for ca in range(4):  # corner ca = (i + ca % 2, j + ca // 2), columns 2 ca and 2 ca + 1
            ia, ja = i + ca % 2, j + ca // 2
            width = (min(ja + 1, n - 1) - max(ja - 1, 0) + 1) * 2  # entries per neighbour row of the stencil
            row = 2 * (ia * n + ja)
            for cb in range(4):
                offset = (i + cb % 2 - max(ia - 1, 0)) * width + (j + cb // 2 - max(ja - 1, 0)) * 2
                for c in range(2):
                    start = indptr[row + c] + offset
                    for d in range(2):
                        s = 0.0
                        for k in range(blocks.shape[1]):
                            s += blocks[cell, k, 2 * ca + c] * blocks[cell, k, 2 * cb + d]
                        data[start + d] += s
    return data


@numba.njit(cache=True)
def _times_dense(blocks, cols, fields, lo, hi, extra, out):
    """out = [J @ fields, extra] for J given by per-cell blocks (cells, 3, 8) on the unknowns ``cols`` (cells, 8);
    row u of ``fields`` is zero outside the columns [lo[u], hi[u])."""
    nf = fields.shape[1]
    for cell in range(blocks.shape[0]):
        row = 3 * cell
        for k in range(3):
            for f in range(nf):
                out[row + k, f] = 0.0
            for e in range(extra.shape[1]):
                out[row + k, nf + e] = extra[row + k, e]
        for a in range(8):  # each row of fields read once for the cell's 3 rows
            w0, w1, w2 = blocks[cell, 0, a], blocks[cell, 1, a], blocks[cell, 2, a]
            source = cols[cell, a]
            for f in range(lo[source], hi[source]):
                x = fields[source, f]
                out[row, f] += w0 * x
                out[row + 1, f] += w1 * x
                out[row + 2, f] += w2 * x


@numba.njit(cache=True)
def _transpose_times(blocks, cols, x, out):
    """out += J^T x for J given by per-cell blocks (cells, 3, 8) on the unknowns ``cols``; x (3 cells, k)."""
    for cell in range(blocks.shape[0]):
        for a in range(8):
            target = cols[cell, a]
            for k in range(3):
                w = blocks[cell, k, a]
                for j in range(x.shape[1]):
                    out[target, j] += w * x[3 * cell + k, j]


@lru_cache(maxsize=PATTERN_CACHE)
def gram_pattern(m: int, n: int) -> GramPattern:
    """The :class:`GramPattern` of an M x N grid, built once per grid size and process."""
    return GramPattern(m, n)


class GramPattern:
    """Index maps of an M x N grid: each cell's 8 node unknowns (``cols``, (cells, 8)), the CSR pattern of J^T J
    (``indptr``, ``indices``) and of its upper triangle (``upper_indptr``, ``upper_indices``; ``upper``: where
    its entries are in the full pattern's data)."""

    def __init__(self, m: int, n: int):
        nodes = np.arange(m * n).reshape(m, n)
        corner_nodes = np.stack([nodes[di : m - 1 + di, dj : n - 1 + dj] for di, dj in CORNERS], axis=-1)
        self.cols = (corner_nodes[..., None] * 2 + np.arange(2)).reshape(-1, 8)
        self.indptr, self.indices = _stencil_pattern(m, n)
        self.shape = (m, n)
        self.size = 2 * m * n
        self.upper, self.upper_indptr = _upper_triangle(self.indptr, self.indices)
        self.upper_indices = self.indices[self.upper]


class CellJacobian:
    """Jacobian of the cell residuals with respect to node displacements, as per-cell blocks (cells, 3, 8)."""

    def __init__(self, blocks: np.ndarray, pattern: GramPattern):
        self.blocks = blocks
        self.pattern = pattern
        self.shape = (3 * blocks.shape[0], pattern.size)

    def matrix(self) -> sp.csr_matrix:
        """The Jacobian as a sparse matrix (rows cell * 3 + component)."""
        cells = self.blocks.shape[0]
        rows = np.repeat(np.arange(3 * cells), 8)
        cols = np.repeat(self.pattern.cols, 3, axis=0).ravel()
        return sp.csr_matrix((self.blocks.ravel(), (rows, cols)), shape=self.shape)

    def normal_dense(
        self, fields: np.ndarray, extra: np.ndarray, res: np.ndarray, ranges=None
    ) -> tuple[np.ndarray, np.ndarray]:
        """K^T K and K^T res for ``K = [J @ fields, extra]`` (3 cells, F + E): dense fields (2 M N, F), extra columns
        (3 cells, E), residuals res (3 cells,); ``ranges`` (lo, hi), optional: row u of ``fields`` is zero outside
        the columns [lo[u], hi[u]) (which are then skipped).

        K is formed DENSE_CHUNK cells at a time in one reused buffer: the whole of K (27 MB for 110 fields on a
        101 x 101 grid) cost more in first-touch page faults than in arithmetic.
        """
        width = fields.shape[1] + extra.shape[1]
        if ranges is None:
            ranges = (np.zeros(len(fields), np.int64), np.full(len(fields), fields.shape[1], np.int64))
        lo, hi = (np.asarray(x, dtype=np.int64) for x in ranges)
        fields, extra = np.ascontiguousarray(fields), np.ascontiguousarray(extra)
        buffer = np.empty((3 * DENSE_CHUNK, width))
        normal, rhs = np.zeros((width, width)), np.zeros(width)
        cols = self.pattern.cols
        for start in range(0, self.blocks.shape[0], DENSE_CHUNK):
            stop = min(start + DENSE_CHUNK, self.blocks.shape[0])
            part = buffer[: 3 * (stop - start)]
            _times_dense(self.blocks[start:stop], cols[start:stop], fields, lo, hi, extra[3 * start : 3 * stop], part)
            normal += part.T @ part
            rhs += part.T @ res[3 * start : 3 * stop]
        return normal, rhs

    def rmatvec(self, x: np.ndarray) -> np.ndarray:
        """J^T x for x of shape (3 cells,) or (3 cells, k)."""
        out = np.zeros((self.pattern.size, x.size // self.shape[0]))
        _transpose_times(self.blocks, self.pattern.cols, np.ascontiguousarray(x).reshape(self.shape[0], -1), out)
        return out.reshape((self.pattern.size,) + x.shape[1:])

    def gram(self, upper: bool = False) -> sp.csr_matrix:
        """J^T J, assembled from the per-cell 8 x 8 products; with ``upper``, only its upper triangle (the
        diagonal first in each row)."""
        m, n = self.pattern.shape
        data = _gram_data(np.ascontiguousarray(self.blocks), m, n, self.pattern.indptr)
        pattern = self.pattern
        if upper:
            data, indices, indptr = data[pattern.upper], pattern.upper_indices, pattern.upper_indptr
        else:
            indices, indptr = pattern.indices, pattern.indptr
        return sp.csr_matrix((data, indices, indptr), shape=(pattern.size,) * 2)
