"""Nested dissection by planes (meshreg.mesh.dissection) and the constrained minimum degree under it, against their
definitions: separators that separate, covers that cover and are smallest, orders that are permutations and solve."""

import numpy as np
import pytest
import scipy.sparse as sp
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.sparse.csgraph import maximum_bipartite_matching

from meshreg.mesh import frontal
from meshreg.mesh.dissection import _cover, _dissect, dissected_order
from meshreg.mesh.early import EarlyAnalysis
from meshreg.mesh.frontal import MultifrontalLU, analyse
from meshreg.mesh.harmonic import HarmonicMap, _corner_weights
from meshreg.mesh.ordering import _amd, _postorder, constrained_minimum_degree, minimum_degree, symmetric_pattern
from meshreg.mesh.samples import random_disk_mesh, terrain_function
from meshreg.mesh.topology import prepare_disk


def _grid(m: int, k: int | None = None):
    """The 5-point Laplacian of an m x k grid (csc) and its nodes' places (m k, 3)."""
    k = m if k is None else k
    line = [sp.diags([-1.0, -1.0], [-1, 1], shape=(s, s)) for s in (m, k)]
    a = sp.kron(sp.identity(k), line[0]) + sp.kron(line[1], sp.identity(m)) + 4.5 * sp.identity(m * k)
    x, y = np.meshgrid(np.arange(m, dtype=float), np.arange(k, dtype=float))
    return a.tocsc(), np.column_stack([x.ravel(), y.ravel(), 0.1 * np.sin(x.ravel())])


def _factor_entries(analysis) -> int:
    size, below = np.diff(analysis.first), np.diff(analysis.off)
    return int((size * size + 2 * size * below).sum())


def test_the_separators_separate_the_parts():
    a, points = _grid(90, 70)
    ptr, rows = symmetric_pattern(a)
    part, level = _dissect(points, ptr, rows, 800, 3.0)
    assert level.max() >= 2  # several levels cut
    i, j = np.repeat(np.arange(a.shape[0]), np.diff(ptr)), rows[: ptr[-1]]
    inside = (level[i] < 0) & (level[j] < 0)
    assert np.array_equal(part[i][inside], part[j][inside])  # no edge joins two parts
    sizes = np.bincount(part[level < 0])
    assert sizes[sizes > 0].max() <= 800


def test_a_dissected_order_solves_and_fills_about_as_little_as_minimum_degree():
    a, points = _grid(120)
    ptr, rows = symmetric_pattern(a)
    order = dissected_order(points, ptr, rows, leaf=1500)
    assert np.array_equal(np.sort(order), np.arange(a.shape[0]))
    # the first cut is a straight column or row of the grid, eliminated last
    top = points[order[-120:]]
    assert len(np.unique(top[:, 0])) == 1 or len(np.unique(top[:, 1])) == 1
    plain, dissected = analyse(a), analyse(a, symmetric=False, points=points)
    assert _factor_entries(dissected) == _factor_entries(plain)  # under DISSECT_LEAF: the plain order
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(frontal, "DISSECT_LEAF", 1500)
        dissected = analyse(a, points=points)
    assert _factor_entries(dissected) <= 1.1 * _factor_entries(plain)  # less at 1M triangles: docs/benchmarks.md
    b = np.random.default_rng(0).normal(size=a.shape[0])
    x = MultifrontalLU(a, dissected).solve(b)
    assert np.linalg.norm(a @ x - b) < 1e-10 * np.linalg.norm(b)


def test_without_cuts_the_order_is_the_minimum_degree_order():
    a, points = _grid(40, 30)
    assert np.array_equal(dissected_order(points, *symmetric_pattern(a), leaf=a.shape[0]), minimum_degree(a))


def test_a_cut_whose_separator_is_too_long_is_not_made():
    """Places that say nothing of the graph (shuffled): every plane crosses about half the edges; no cut is made
    and the order is the minimum degree order of the whole."""
    a, points = _grid(60)
    shuffled = points[np.random.default_rng(1).permutation(len(points))]
    ptr, rows = symmetric_pattern(a)
    part, level = _dissect(shuffled, ptr, rows, 500, 3.0)
    assert (level < 0).all() and (part == 0).all()
    assert np.array_equal(dissected_order(shuffled, ptr, rows, leaf=500), minimum_degree(a))


def test_coincident_places_are_not_cut():
    a, _ = _grid(50)
    ptr, rows = symmetric_pattern(a)
    order = dissected_order(np.zeros((a.shape[0], 3)), ptr, rows, leaf=100)
    assert np.array_equal(order, minimum_degree(a))


def test_constrained_minimum_degree_orders_the_others_and_holds_the_rest():
    a, _ = _grid(30)
    ptr, rows = symmetric_pattern(a)
    n = a.shape[0]
    held = np.zeros(n, np.bool_)
    held[np.arange(n) % 30 == 15] = True  # a middle column
    stop = np.zeros(1, np.bool_)
    order = constrained_minimum_degree(ptr.astype(np.int32), rows.astype(np.int32), held, stop)
    assert np.array_equal(np.sort(order), np.flatnonzero(~held))
    none = constrained_minimum_degree(ptr.astype(np.int32), rows.astype(np.int32), np.zeros(n, np.bool_), stop)
    assert np.array_equal(none, minimum_degree(a))


@settings(max_examples=60, deadline=None)
@given(
    left=st.integers(1, 12),
    right=st.integers(1, 12),
    edges=st.lists(st.tuples(st.integers(0, 11), st.integers(0, 11)), min_size=1, max_size=40),
)
def test_the_cover_touches_every_edge_and_is_a_smallest(left, right, edges):
    edges = sorted({(u % left, v % right) for u, v in edges})
    u, v = np.array(edges).T
    ptr = np.searchsorted(u, np.arange(left + 1))
    on_left, on_right = _cover(ptr, v.astype(np.int64), right)
    assert (on_left[u] | on_right[v]).all()
    graph = sp.csr_matrix((np.ones(len(u)), (u, v)), shape=(left, right))
    matched = int((maximum_bipartite_matching(graph, perm_type="column") >= 0).sum())
    assert on_left.sum() + on_right.sum() == matched  # Koenig: a smallest cover is as large as a largest matching


def test_an_early_analysis_of_other_places_is_not_claimed(monkeypatch):
    monkeypatch.setattr(frontal, "DISSECT_LEAF", 300)  # the interior (about 1900 vertices) is ordered by its places
    v, f, _ = random_disk_mesh(terrain_function(), 2000, seed=6)
    disk = prepare_disk(v, f)
    interior = HarmonicMap(disk).interior
    early = EarlyAnalysis(minimum=0)
    early.begin(disk.vertices * 2.0, disk.faces)  # the same faces and interior at other places
    assert not early.claim(disk.faces, interior, disk.vertices[interior])
    early = EarlyAnalysis(minimum=0)
    early.begin(disk.vertices, disk.faces)
    assert early.claim(disk.faces, interior, disk.vertices[interior])
    early.abandon()


def test_a_stopped_dissection_raises_abandoned(monkeypatch):
    from meshreg.mesh.ordering import Abandoned

    a, points = _grid(60)
    monkeypatch.setattr(frontal, "DISSECT_LEAF", 500)
    with pytest.raises(Abandoned):
        analyse(a, stop=np.ones(1, np.bool_), points=points)


@pytest.mark.parametrize("where", [0, 1700, 3000])
def test_a_held_unknown_without_neighbours_does_not_upset_the_workspace(where):
    """An isolated held unknown has an empty list: it must not pass for a live list when the workspace is compacted
    (its pointer took over the next list's first entry). The order must not depend on the workspace's room."""
    v, f, _ = random_disk_mesh(terrain_function(), 3000, seed=1)
    edges = sp.csc_matrix((np.ones(3 * len(f)), (f.ravel(), np.roll(f, 1, axis=1).ravel())), shape=(len(v),) * 2)
    ids = np.delete(np.arange(len(v) + 1), where)  # unknown ``where`` has no couplings
    coo = edges.tocoo()
    n = len(v) + 1
    ptr, rows = symmetric_pattern(sp.csc_matrix((coo.data, (ids[coo.row], ids[coo.col])), shape=(n, n)))
    held = np.zeros(n, np.bool_)
    held[where] = True
    stop = np.zeros(1, np.bool_)
    order = constrained_minimum_degree(ptr.astype(np.int32), rows.astype(np.int32), held, stop)
    roomy = np.empty(20 * int(ptr[n]), np.int32)
    roomy[: ptr[n]] = rows[: ptr[n]]
    parent, nv, done = _amd(ptr.astype(np.int32), roomy, int(ptr[n]), stop, held)
    expected = _postorder(parent, nv, n)
    assert done and np.array_equal(order, expected[~held[expected]])
    assert np.array_equal(np.sort(order), np.flatnonzero(~held))


@pytest.mark.parametrize("scale", [1e-6, 1.0, 1e20])
@pytest.mark.parametrize("height", [1e-10, 1e-6, 0.3, 1.0, 10.0, 1e6, 1e9])
def test_mean_value_weights_hold_at_corners_near_0_and_180_degrees(height, scale):
    """The corner at (0, h, 0) of the triangle with (-1, 0, 0) and (1, 0, 0) (times ``scale``) has tan(angle / 2)
    = 1 / h exactly: its weight is 1 / (h |e|), from nearly 180 degrees (h = 1e-10; tan(arccos) gave 1.6e16) to
    nearly 0."""
    vertices = np.array([[0.0, height, 0.0], [-1.0, 0.0, 0.0], [1.0, 0.0, 0.0]]) * scale
    _, _, weight, _, _, other = _corner_weights(vertices, np.array([[0, 1, 2]]), 0, 0, False)
    expected = 1.0 / (height * scale * np.sqrt(1.0 + height**2))
    assert weight == pytest.approx(expected, rel=1e-12) and other == pytest.approx(expected, rel=1e-12)
