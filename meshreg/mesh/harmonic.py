"""Map a disk mesh to the unit square: boundary on the sides by arc length, interior by a Laplacian solve.

Weights: mean-value (Floater 2003) by default, which keep the map bijective for a convex boundary;
cotangent weights (libigl's harmonic map) as an option (they can flip triangles on scans).
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from functools import cached_property
from typing import TYPE_CHECKING

import numba
import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..errors import InputError
from .boundary import sharp_corners
from .frontal import Analysis, MultifrontalLU, analyse, ordered_in_space
from .graph import side_lengths, turn_counts
from .locate import uv_triangle
from .ordering import spatial_order
from .pages import small_pages
from .topology import DiskMesh, loop_segments, triangle_areas

if TYPE_CHECKING:
    from .early import EarlyAnalysis

# the fallback SuperLU's relaxed supernode size and panel width (its defaults: 5 and 10). In the minimum degree order
# of a mesh Laplacian's interior block, every pair from (1, 4) to (8, 8) factorized a 100k- (1M-) triangle terrain
# mesh within the noise, 0.08-0.11 s (1.5-2.0 s) on a shared machine; small ones keep the factors' memory small.
LU_RELAX = 1
LU_PANEL = 4


def _principal_extremes(disk: DiskMesh) -> np.ndarray:
    """Loop positions of the boundary vertices reaching furthest along +-e1 and +-e2, the surface's two
    main principal directions (area-weighted): the same surface points whatever the pose, scale,
    triangulation or loop start, up to the order (a symmetry of the square)."""
    v, f = disk.vertices, disk.faces
    centres = v[f].mean(axis=1)
    area = triangle_areas(v, f)
    mean = area @ centres / area.sum()
    d = centres - mean
    _, vecs = np.linalg.eigh((d * area[:, None]).T @ d)
    proj = (v[disk.boundary] - mean) @ vecs[:, [2, 1]]
    return np.unique([proj[:, 0].argmax(), proj[:, 1].argmax(), proj[:, 0].argmin(), proj[:, 1].argmin()])


def disk_corners(disk: DiskMesh) -> np.ndarray | None:
    """Loop positions (4,) of the boundary's four clear corners (turns within the surface above 60 degrees; a corner
    whose ear cleanup removed counted once), or None (:func:`~meshreg.mesh.boundary.sharp_corners`)."""
    bases = None if disk.ear_feet is None else disk.ear_feet.base
    return sharp_corners(disk.vertices, disk.faces, disk.boundary, bases)


def has_sharp_corners(disk: DiskMesh) -> bool:
    """Whether the boundary has exactly four clear corners (:func:`disk_corners`)."""
    return disk_corners(disk) is not None


def given_corners(disk: DiskMesh, corners) -> tuple[np.ndarray, bool]:
    """Loop positions (4,) of four corner vertex ids (of this disk) in the order of the loop from the first, which
    becomes (0, 0) of the square, and whether they were given against the loop's direction.

    Given along the loop (counterclockwise seen from the side the faces' normals point to), corner k becomes the
    k-th corner of the square, (0, 0), (1, 0), (1, 1), (0, 1); given the other way round, the second and the fourth
    trade places, which is the square's diagonal symmetry (u, v) -> (v, u): a pair with one mesh's corners given
    each way is matched through it.

    Raises
    ------
    InputError
        Not four distinct boundary vertices, or not in their order around the boundary.
    """
    loop = disk.boundary
    pos = np.array([int(np.flatnonzero(loop == c)[0]) if np.any(loop == c) else -1 for c in corners])
    if len(pos) != 4 or pos.min() < 0 or len(set(pos.tolist())) < 4:
        raise InputError("corners must be 4 distinct vertex ids on the boundary loop")
    rel = (pos - pos[0]) % len(loop)
    if np.all(np.diff(rel) > 0):
        return pos, False
    if np.all(np.diff(rel[1:]) < 0):
        return pos[[0, 3, 2, 1]], True
    raise InputError("corners must be given in their order around the boundary (either way round)")


def choose_corners(disk: DiskMesh, corners=None, start: int | None = None) -> np.ndarray:
    """Positions in the boundary loop of the four corners, in the loop's order from the one that becomes (0, 0).

    In order of precedence: ``corners``, four vertex ids given by the user (see :func:`given_corners`: the first
    becomes (0, 0)); quarter arc lengths from ``start`` (a boundary vertex id) when it is given; the four sharpest
    turns when the boundary has exactly four clear corners (turns within the surface, its geodesic curvature,
    above 60 degrees: bending the surface does not change them); else the boundary vertices reaching furthest
    along the surface's two main principal directions (both ways), which do not depend on the pose, the
    triangulation or where the loop starts; quarter arc lengths from there if two of those coincide.
    """
    loop = disk.boundary
    if corners is not None:
        return given_corners(disk, corners)[0]
    if len(loop) < 4:
        raise InputError("the boundary has fewer than 4 vertices: it cannot be mapped to a square")
    if start is None:
        sharp = disk_corners(disk)
        if sharp is not None:
            return sharp
        extremes = _principal_extremes(disk)
        if len(extremes) == 4:
            return extremes
        s0 = int(extremes[0])
    else:
        if not np.any(loop == start):
            raise InputError(f"start vertex {start} is not on the boundary loop")
        s0 = int(np.flatnonzero(loop == start)[0])
    return quarter_corners(disk, arc_fraction(disk, s0))


def _boundary_uv(disk: DiskMesh, corner_pos: np.ndarray) -> np.ndarray:
    loop = disk.boundary
    n = len(loop)
    seg = loop_segments(disk.vertices, loop)
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


@numba.njit(cache=True, nogil=True)
def _corner_weights(v, f, t, k, cotangent):
    """The two weights of corner k of face t: mean-value tan(angle at i / 2) / |e_ij| and / |e_il| on the edges
    (i, j) and (i, l), or half the cotangent of the angle at i on the opposite edge (j, l), both ways. Returns
    (row, column, value) of each: i, j, l being the corner and the next two of the face. The half-angle tangent is
    |e_ij x e_il| / (|e_ij| |e_il| + e_ij . e_il), or (|e_ij| |e_il| - e_ij . e_il) / |e_ij x e_il| at obtuse corners
    (no cancellation either way): no arccos and tan (the 1M-triangle mesh's weights in 0.13-0.2 s against 0.28 s),
    and accurate at corners near 0 and 180 degrees, where arccos of a cosine rounded to 1 gave 0, and of one near -1
    at most 1.6e16."""
    i, j, l = f[t, k], f[t, (k + 1) % 3], f[t, (k + 2) % 3]
    x1, y1, z1 = v[j, 0] - v[i, 0], v[j, 1] - v[i, 1], v[j, 2] - v[i, 2]
    x2, y2, z2 = v[l, 0] - v[i, 0], v[l, 1] - v[i, 1], v[l, 2] - v[i, 2]
    dot = x1 * x2 + y1 * y2 + z1 * z2
    if cotangent:
        cx, cy, cz = y1 * z2 - z1 * y2, z1 * x2 - x1 * z2, x1 * y2 - y1 * x2
        half = 0.5 * dot / max(np.sqrt(cx * cx + cy * cy + cz * cz), 1e-300)
        return j, l, half, l, j, half
    nij, nil = np.sqrt(x1 * x1 + y1 * y1 + z1 * z1), np.sqrt(x2 * x2 + y2 * y2 + z2 * z2)
    cx, cy, cz = y1 * z2 - z1 * y2, z1 * x2 - x1 * z2, x1 * y2 - y1 * x2
    cross = np.sqrt(cx * cx + cy * cy + cz * cz)
    if dot >= 0.0:  # |a x b| / (|a| |b| + a . b), and for obtuse corners the form without cancellation
        tan = cross / max(nij * nil + dot, 1e-300)
    else:
        tan = (nij * nil - dot) / max(cross, 1e-300)
    return i, j, tan / nij, i, l, tan / nil


@numba.njit(cache=True, nogil=True)
def _row_buckets(v, f, place, ni, cotangent):
    """The edge weights (:func:`_corner_weights`) of the ``ni`` interior rows, each row's in a bucket: start (ni +
    1,), and the column (its ``place``) and value of each weight, in the order of the faces, their corners and the
    two weights of a corner (rows of the boundary loop are neither computed nor kept). O(m): the faces are read twice,
    to count and to fill, with no list of all the weights in between."""
    m = f.shape[0]
    start = np.zeros(ni + 1, np.int64)
    for t in range(m):
        for k in range(3):
            if cotangent:
                for r in (place[f[t, (k + 1) % 3]], place[f[t, (k + 2) % 3]]):
                    if r < ni:
                        start[r + 1] += 1
            elif place[f[t, k]] < ni:
                start[place[f[t, k]] + 1] += 2
    for r in range(ni):
        start[r + 1] += start[r]
    bucket_col, bucket_val, fill = np.empty(start[ni], np.int64), np.empty(start[ni]), start[:-1].copy()
    for t in range(m):
        for k in range(3):
            if cotangent and place[f[t, (k + 1) % 3]] >= ni and place[f[t, (k + 2) % 3]] >= ni:
                continue  # both weights in rows of the boundary loop
            if not cotangent and place[f[t, k]] >= ni:
                continue
            r1, c1, w1, r2, c2, w2 = _corner_weights(v, f, t, k, cotangent)
            for row, col, w in ((r1, c1, w1), (r2, c2, w2)):
                r = place[row]
                if r < ni:
                    bucket_col[fill[r]], bucket_val[fill[r]] = place[col], w
                    fill[r] += 1
    return start, bucket_col, bucket_val


@numba.njit(cache=True, nogil=True)
def _assemble(start, bucket_col, bucket_val, n, ni):
    """CSR arrays (indptr, indices, data) of the interior block and of the coupling to the loop of the Laplacian
    diag(W 1) - W, from each interior row's bucket of weights (:func:`_row_buckets`: columns are places, the
    ``ni`` interior vertices first, then the loop; duplicates add up; ``n`` vertices in all). O(n + nnz): each
    bucket is read in sequence and merged by a marker."""
    mark = np.full(n, -1, np.int64)
    ptr = (np.zeros(ni + 1, np.int64), np.zeros(ni + 1, np.int64))
    ind = (np.empty(start[ni] + ni, np.int64), np.empty(start[ni], np.int64))
    val = (np.empty(start[ni] + ni), np.empty(start[ni]))
    for r in range(ni):
        size = (ptr[0][r] + 1, ptr[1][r])
        ind[0][size[0] - 1], val[0][size[0] - 1], mark[r] = r, 0.0, size[0] - 1  # the diagonal first
        total = 0.0
        for p in range(start[r], start[r + 1]):
            c, w = bucket_col[p], bucket_val[p]
            total += w
            side = 0 if c < ni else 1
            if mark[c] < 0:
                mark[c] = size[side]
                ind[side][size[side]], val[side][size[side]] = c - side * ni, 0.0
                size = (size[0] + 1, size[1]) if side == 0 else (size[0], size[1] + 1)
            val[side][mark[c]] -= w
        val[0][ptr[0][r]] += total
        ptr[0][r + 1], ptr[1][r + 1] = size
        mark[r] = -1
        for p in range(start[r], start[r + 1]):
            mark[bucket_col[p]] = -1
    # the coupling copied: a slice would keep its whole buffer (a weight per face corner, 48 MB at 1M triangles) alive
    # for the map's life; the block's rows serve the LU only, and a copy would raise the front end's peak memory
    coupling = (ptr[1], ind[1][: ptr[1][ni]].copy(), val[1][: ptr[1][ni]].copy())
    return ptr[0], ind[0][: ptr[0][ni]], val[0][: ptr[0][ni]], *coupling


def laplacian_blocks(disk: DiskMesh, interior: np.ndarray, weights: str) -> tuple[sp.csc_matrix, sp.csr_matrix]:
    """The rows of the mesh Laplacian L = diag(W 1) - W at the interior vertices, split into the interior block
    (i, i), CSC, and the coupling to the boundary loop (i, b), CSR, in the order of ``interior`` and of the loop."""
    rows, coupling = _laplacian_rows(disk, interior, weights)
    return rows.tocsc(), coupling


def _laplacian_rows(disk: DiskMesh, interior: np.ndarray, weights: str) -> tuple[sp.csr_matrix, sp.csr_matrix]:
    """:func:`laplacian_blocks` with the interior block by rows, as assembled (each row's diagonal first)."""
    v, f, loop = disk.vertices, disk.faces, disk.boundary
    ni = len(interior)
    buckets = _row_buckets(
        np.ascontiguousarray(v, dtype=float),
        np.ascontiguousarray(f, dtype=np.int64),
        _places(disk, interior),
        ni,
        weights == "cotangent",
    )
    bptr, bind, bval, cptr, cind, cval = _assemble(*buckets, len(v), ni)
    block = sp.csr_matrix((bval, bind, bptr), shape=(ni, ni))
    return block, sp.csr_matrix((cval, cind, cptr), shape=(ni, len(loop)))


def _places(disk: DiskMesh, interior: np.ndarray) -> np.ndarray:
    """Row and column (n,) of each vertex in the Laplacian's blocks: the interior first, then the loop."""
    place = np.empty(len(disk.vertices), dtype=np.int64)
    place[interior] = np.arange(len(interior))
    place[disk.boundary] = len(interior) + np.arange(len(disk.boundary))
    return place


@numba.njit(cache=True, nogil=True)
def _face_pattern(f, place, ni):
    """CSR arrays (indptr, indices) of the interior block's pattern without its diagonal: the edges of the faces
    ``f`` (m, 3) between interior vertices (``place`` < ni), both ways, each once."""
    start = np.zeros(ni + 1, np.int64)
    for t in range(f.shape[0]):
        for k in range(3):
            a, b = place[f[t, k]], place[f[t, (k + 1) % 3]]
            if a < ni and b < ni:
                start[a + 1] += 1
                start[b + 1] += 1
    for r in range(ni):
        start[r + 1] += start[r]
    cols, fill = np.empty(start[ni], np.int64), start[:-1].copy()
    for t in range(f.shape[0]):
        for k in range(3):
            a, b = place[f[t, k]], place[f[t, (k + 1) % 3]]
            if a < ni and b < ni:
                cols[fill[a]], cols[fill[b]] = b, a
                fill[a] += 1
                fill[b] += 1
    ptr, mark, size = np.zeros(ni + 1, np.int64), np.full(ni, -1, np.int64), 0
    for r in range(ni):
        for p in range(start[r], start[r + 1]):
            if mark[cols[p]] != r:
                mark[cols[p]] = r
                cols[size] = cols[p]
                size += 1
        ptr[r + 1] = size
    return ptr, cols[:size].copy()  # the buffer held every edge twice


def interior_pattern(disk: DiskMesh, interior: np.ndarray) -> sp.csr_matrix:
    """The pattern (ones, (ni, ni)) of the Laplacian's interior block off its diagonal from the faces alone: the
    edges between interior vertices, whichever the weights (both put a weight on every edge, both ways)."""
    return face_pattern(disk.faces, _places(disk, interior), len(interior))


def face_pattern(faces: np.ndarray, place: np.ndarray, ni: int) -> sp.csr_matrix:
    """The pattern (ones, (ni, ni)) of the edges of ``faces`` (m, 3) between the vertices whose ``place`` (n,) is
    below ``ni``, at those places: :func:`interior_pattern` with every place given."""
    ptr, cols = _face_pattern(np.ascontiguousarray(faces, dtype=np.int64), place, ni)
    return sp.csr_matrix((np.ones(len(cols), dtype=np.int8), cols, ptr), shape=(ni, ni))


def interior_in_space_order(vertices: np.ndarray, on_boundary: np.ndarray) -> np.ndarray:
    """The vertices (n, 3) not ``on_boundary`` (bool, (n,)), as indices in space order (:func:`spatial_order`): the
    unknowns of the map, numbered so that the assembly and the ordering stay in cache."""
    order = spatial_order(vertices)
    return order[~on_boundary[order]]


def quarter_corners(disk: DiskMesh, start: float) -> np.ndarray:
    """Loop positions (increasing) of the corners at quarter arc lengths from the point at arc-length
    fraction ``start`` in [0, 1) of the boundary loop (measured from its first vertex)."""
    seg = loop_segments(disk.vertices, disk.boundary)
    arc = np.concatenate([[0.0], np.cumsum(seg)[:-1]]) / seg.sum()
    targets = (start + np.array([0.0, 0.25, 0.5, 0.75])) % 1.0
    gap = np.abs(arc[None, :] - targets[:, None])
    pos = np.argmin(np.minimum(gap, 1.0 - gap), axis=1)
    if len(set(pos.tolist())) < 4:
        raise InputError("the boundary has fewer than 4 distinct quarter points: it cannot be mapped to a square")
    return np.sort(pos)


def arc_fraction(disk: DiskMesh, position: int) -> float:
    """Arc-length fraction in [0, 1) of the boundary loop at loop position ``position``."""
    seg = loop_segments(disk.vertices, disk.boundary)
    return float(seg[:position].sum() / seg.sum())


# a triangle's share of the square's area over its share of the surface's, floored here before its logarithm: a
# triangle collapsed onto a side of the square (beyond a boundary chord whose two ends share that side) counts as
# squeezed 10^8 times
SQUEEZE_FLOOR = 1e-8


@numba.njit(cache=True)
def _compression(areas, uv, f, floor):
    m = f.shape[0]
    square = np.empty(m)
    for t in range(m):
        square[t] = abs(uv_triangle(uv, f, t)[6])
    total, covered = areas.sum(), square.sum()
    if total <= 0.0 or covered <= 0.0:
        return np.inf
    out = 0.0
    for t in range(m):
        if areas[t] > 0.0:
            share = max(square[t] * total / (covered * areas[t]), floor)
            out += areas[t] * min(np.log(share), 0.0) ** 2
    return out / total


def compression(disk: DiskMesh, uv: np.ndarray, areas: np.ndarray | None = None) -> float:
    """How much a map of the disk to the square squeezes the surface: the area-weighted mean over the triangles of
    min(0, log s)^2, s a triangle's share of the square's area over its share of the surface's (at least
    SQUEEZE_FLOOR). 0 when no triangle's share shrinks; corners placed so that a boundary chord's two ends share a
    side of the square collapse the part of the surface beyond it, which this counts heavily.

    Parameters
    ----------
    disk : DiskMesh
    uv : ndarray (n, 2)
        The map, one point of the square per vertex of ``disk``.
    areas : ndarray (m,), optional
        The triangles' areas (:func:`~meshreg.mesh.graph.triangle_areas`), when the caller compares many maps of one
        disk; computed here otherwise.
    """
    if areas is None:
        areas = triangle_areas(disk.vertices, disk.faces)
    faces = np.ascontiguousarray(disk.faces, dtype=np.int64)
    return float(_compression(areas, np.ascontiguousarray(uv, dtype=float), faces, SQUEEZE_FLOOR))


def edge_length(faces: np.ndarray, uv: np.ndarray) -> float:
    """Median length of a mesh's edges on the square (its resolution there), for faces (m, 3) and uv (n, 2): over
    the three sides of every triangle (an inner edge counts twice)."""
    return float(np.median(side_lengths(uv, faces)))


class Factorization:
    """Sparse LU of A in an approximate minimum degree order of A + A^T; :meth:`solve`
    solves A x = b.

    The multifrontal LU (:class:`~meshreg.mesh.frontal.MultifrontalLU`: supernodes, dense fronts through BLAS,
    independent subtrees in two threads) keeps the diagonal as pivot. Where a pivot is zero or the factors are not
    finite, SuperLU factorizes in the same order and pivots within columns (``diag_pivot_thresh=0`` keeps the
    diagonal wherever it is nonzero); an exactly singular matrix raises SuperLU's RuntimeError. ``rows``, A by rows
    when the caller has it, spares the LU a conversion.
    """

    def __init__(self, a: sp.csc_matrix, analysis: Analysis | None = None, rows: sp.csr_matrix | None = None):
        a = sp.csc_matrix(a)
        analysis = analyse(a) if analysis is None else analysis
        try:
            self._lu = MultifrontalLU(a, analysis, rows)
        except ZeroDivisionError:
            self._lu = _SuperLU(a, analysis.order)

    def solve(self, b: np.ndarray) -> np.ndarray:
        """x (n,) or (n, k) with A x = b."""
        return self._lu.solve(b)


class _SuperLU:
    """SuperLU's LU of A in a given order (permc_spec NATURAL), pivoting within columns where the diagonal is 0."""

    def __init__(self, a: sp.csc_matrix, order: np.ndarray):
        self.order = order
        self.lu = spla.splu(
            a[order][:, order].tocsc(),
            permc_spec="NATURAL",
            diag_pivot_thresh=0.0,
            relax=LU_RELAX,
            panel_size=LU_PANEL,
            options={"SymmetricMode": True},
        )

    def solve(self, b: np.ndarray) -> np.ndarray:
        x = np.empty_like(b, dtype=float)
        x[self.order] = self.lu.solve(np.ascontiguousarray(b[self.order], dtype=float))
        return x


def factorize(a: sp.csc_matrix, analysis: Analysis | None = None) -> Factorization:
    """Sparse LU of a Laplacian-like matrix (the interior block of a mesh Laplacian; an ARAP system).

    Both weightings give a matrix that needs no pivoting (mean-value: an M-matrix; cotangent: symmetric
    positive definite), so the factorization keeps the diagonal in an approximate minimum degree order of
    A^T + A (:class:`Factorization`: the multifrontal LU); a zero pivot hands the matrix to SuperLU, which pivots
    within columns. ``analysis`` (:func:`~meshreg.mesh.frontal.analyse` of a pattern holding A's) serves every
    matrix of one pattern.
    """
    return Factorization(a, analysis)


class HarmonicMap:
    """The factorized Laplacian of a disk mesh: maps any placement of the corners on its boundary to uv.

    One sparse LU serves every corner placement (the corner search solves once per placement); it is computed at
    the first placement, so a map that is never asked for (a pair registered by its common region) costs nothing.

    Parameters
    ----------
    disk : DiskMesh
    weights : {"mean-value", "cotangent"}
        Mean-value (Floater) weights, positive, keep the map bijective onto the convex square;
        cotangent weights (libigl's harmonic map) can flip triangles on scans.
    name : str
        What an error calls the mesh.
    early : EarlyAnalysis, optional
        The LU's symbolic analysis begun before the disk's cleanup (:mod:`meshreg.mesh.early`).
    """

    def __init__(
        self, disk: DiskMesh, weights: str = "mean-value", name: str = "the mesh", early: EarlyAnalysis | None = None
    ):
        if weights not in ("mean-value", "cotangent"):
            raise InputError("weights must be 'mean-value' or 'cotangent'")
        self.disk = disk
        self.weights = weights
        self.name = name  # what an error calls the mesh (its file, or "first mesh")
        self._blocks = None
        self._early = early

    @cached_property
    def interior(self) -> np.ndarray:
        """The interior vertices (the unknowns, (ni,)) in space order (:func:`spatial_order`): the assembly and
        the ordering then stay in cache. Found at the first use, like the LU."""
        on_boundary = np.zeros(len(self.disk.vertices), dtype=bool)
        on_boundary[self.disk.boundary] = True
        return interior_in_space_order(self.disk.vertices, on_boundary)

    def assemble(self) -> tuple[sp.csc_matrix, sp.csr_matrix]:
        """The Laplacian's interior block (i, i), CSC, and its coupling to the boundary loop (i, b), CSR
        (:func:`laplacian_blocks`), assembled at the first call and kept."""
        if self._blocks is None:
            rows, coupling = _laplacian_rows(self.disk, self.interior, self.weights)
            self._blocks = rows.tocsc(), coupling, rows
        return self._blocks[:2]

    def _pattern(self) -> sp.csr_matrix:
        """The interior block's pattern (:func:`interior_pattern`)."""
        return interior_pattern(self.disk, self.interior)

    def _analysis(self, points: np.ndarray | None) -> Analysis:
        """The symbolic analysis of the interior block's LU (:func:`~meshreg.mesh.frontal.analyse`; large meshes
        are ordered by their interior vertices' ``points``, :meth:`_points`: :mod:`meshreg.mesh.dissection`)."""
        return analyse(self._pattern(), symmetric=True, points=points)

    def _points(self) -> np.ndarray | None:
        """The interior vertices' places (ni, 3) when the analysis orders the interior block by them (a large
        mesh: :func:`~meshreg.mesh.frontal.ordered_in_space`), else None (no copy made)."""
        return self.disk.vertices[self.interior] if ordered_in_space(len(self.interior)) else None

    @cached_property
    def _system(self):
        """The Laplacian's coupling of the interior to the boundary, and the LU of its interior block (None
        without interior vertices), computed at the first use (:meth:`_factorized`)."""
        with small_pages(len(self.disk.vertices)):  # large meshes' arrays: see meshreg.mesh.pages
            return self._factorized()

    def _factorized(self):
        """:attr:`_system`. The LU's ordering and symbolic analysis need only the faces: a second thread computes
        them while this one computes the weights, unless an :class:`~meshreg.mesh.early.EarlyAnalysis` began them
        before the cleanup (kept when the disk is the mesh it analysed)."""
        early = self._early
        try:
            if not len(self.interior):
                return self.assemble()[1], None
            points = self._points()
            claimed = early is not None and early.claim(self.disk.faces, self.interior, points)
            with ThreadPoolExecutor(1) as pool:
                job = None if claimed else pool.submit(self._analysis, points)
                block, coupling = self.assemble()
                pattern = early.analysis() if claimed else job.result()
        finally:
            if early is not None:
                early.abandon()  # whatever no map took (nothing, when the analysis was claimed)
        try:
            lu = Factorization(block, pattern, rows=self._blocks[2])
            self._blocks = self._blocks[:2]  # the rows served the LU only
            return coupling, lu
        except RuntimeError as err:  # SuperLU: "Factor is exactly singular"
            other = "cotangent" if self.weights == "mean-value" else "mean-value"
            raise InputError(
                f"{self.name}: its Laplacian ({self.weights} weights) is singular ({err}): the weights vanish or "
                "cancel at some vertices, as next to triangles of almost no area beside large ones (or obtuse ones, "
                f"with cotangent weights); remove the slivers, or try the other weights (--weights {other}, "
                f"Options(weights='{other}'))"
            ) from None

    def __call__(self, corner_pos: np.ndarray):
        """uv (n, 2) in [0, 1]^2 with the corners at loop positions ``corner_pos`` (4, in loop order from
        the one that goes to (0, 0), wrapping around the loop's end), and an
        info dict: ``corners`` (ids in the mesh as given, -1 for a corner the input does not have: a cut point of a
        trimmed disk), ``flipped`` and ``degenerate`` (triangle counts after mapping)."""
        disk = self.disk
        f, loop = disk.faces, disk.boundary
        uv = np.zeros((len(disk.vertices), 2))
        uv[loop] = _boundary_uv(disk, corner_pos)
        coupling, lu = self._system
        if lu is not None:
            uv[self.interior] = lu.solve(-(coupling @ uv[loop]))
        _, negative, degenerate = turn_counts(uv, f)
        info = {"corners": disk.source_of(loop[corner_pos]).tolist(), "flipped": negative, "degenerate": degenerate}
        return np.clip(uv, 0.0, 1.0), info


def parametrize(disk: DiskMesh, *, corners=None, start: int | None = None, weights: str = "mean-value"):
    """uv in [0, 1]^2 for every vertex of a disk mesh (corners by :func:`choose_corners`).

    Returns
    -------
    uv : ndarray (n, 2)
    info : dict
        ``corners`` (ids in the mesh as given), ``flipped`` and ``degenerate`` (triangle counts after mapping).

    Examples
    --------
    >>> from meshreg.mesh.samples import random_disk_mesh
    >>> from meshreg.mesh.topology import prepare_disk
    >>> from meshreg.samples import bump
    >>> v, f, _ = random_disk_mesh(bump(), 200, seed=0)
    >>> uv, info = parametrize(prepare_disk(v, f))
    >>> info["flipped"], bool(uv.min() >= 0 and uv.max() <= 1)
    (0, True)
    """
    return HarmonicMap(disk, weights)(choose_corners(disk, corners, start))
