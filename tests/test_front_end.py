"""The mesh front end's linear-time kernels against their plain numpy/scipy definitions."""

import importlib
import threading

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla
import trimesh
from scipy.sparse.csgraph import connected_components

from meshreg.errors import InputError
from meshreg.mesh import pages
from meshreg.mesh.graph import edge_table, face_components, neighbourhood_sums, triangle_areas, turn_counts
from meshreg.mesh.harmonic import HarmonicMap, factorize, laplacian_blocks
from meshreg.mesh.ordering import minimum_degree, spatial_order
from meshreg.mesh.resample import _node_range
from meshreg.mesh.samples import random_disk_mesh
from meshreg.mesh.topology import prepare_disk, unique_edges
from meshreg.samples import bump


def _soup(seed: int, n: int = 40, m: int = 120) -> np.ndarray:
    """Random triangles over n vertices (non-manifold edges, isolated pieces and all)."""
    rng = np.random.default_rng(seed)
    faces = np.array([rng.choice(n, 3, replace=False) for _ in range(m)])
    return np.vstack([faces, faces[:5, ::-1]])  # some edges used three or four times


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_edge_table_matches_sorting(seed):
    faces = _soup(seed)
    directed, first, inverse, counts = edge_table(faces)
    assert np.array_equal(directed[: len(faces)], faces[:, [0, 1]])
    keys = np.sort(directed, axis=1) @ [1000, 1]
    uniq, expected_inverse, expected_counts = np.unique(keys, return_inverse=True, return_counts=True)
    assert len(first) == len(uniq)
    assert np.array_equal(keys[first][inverse], keys)  # each directed edge's id names its undirected edge
    assert np.array_equal(np.sort(counts), np.sort(expected_counts))
    assert np.array_equal(counts[inverse], expected_counts[expected_inverse])
    assert np.all(first[inverse] <= np.arange(len(keys)))  # the first directed edge comes first
    assert np.array_equal(unique_edges(faces), np.stack([uniq // 1000, uniq % 1000], axis=1))


@pytest.mark.parametrize("seed", [0, 3])
def test_face_components_match_scipy(seed):
    faces = _soup(seed, n=200, m=60)
    labels, count = face_components(faces, 200)
    graph = sp.coo_matrix((np.ones(2 * len(faces)), (faces[:, [0, 1]].ravel(), faces[:, [1, 2]].ravel())), (200, 200))
    expected = connected_components(graph, directed=False)[1][faces[:, 0]]
    assert count == len(np.unique(expected))
    assert np.array_equal(labels[:, None] == labels[None, :], expected[:, None] == expected[None, :])


@pytest.mark.parametrize("seed", [0, 4])
def test_neighbourhood_sums_match_the_sparse_product_to_the_bit(seed):
    faces = np.vstack([_soup(seed), [[3, 3, 7]]])  # a repeated corner counts once
    values = np.random.default_rng(seed).normal(size=(len(faces), 3)) * 10.0 ** np.arange(-8, 8, 5.5)
    incidence = sp.csr_matrix((np.ones(faces.size), (np.repeat(np.arange(len(faces)), 3), faces.ravel())))
    sharing = incidence @ incidence.T
    sharing.data[:] = 1.0
    corners = faces.ravel()  # each vertex's triangles in increasing order, padded with -1
    by_vertex = np.argsort(corners, kind="stable")
    width = np.bincount(corners).max()
    incident = np.full((corners.max() + 1, width), -1)
    slot = np.arange(len(corners)) - np.searchsorted(corners[by_vertex], corners[by_vertex])
    incident[corners[by_vertex], slot] = by_vertex // 3
    # to the bit: the kernel follows scipy's order of summation (csr_matmat's rows, last met first)
    assert np.array_equal(neighbourhood_sums(faces, values, incident), sharing @ values)


def test_triangle_areas():
    v = np.array([[0.0, 0, 0], [2, 0, 0], [0, 3, 0], [0, 0, 4]])
    f = np.array([[0, 1, 2], [0, 1, 3], [1, 2, 3], [0, 0, 1]])
    assert np.allclose(triangle_areas(v, f), [3.0, 4.0, 0.5 * np.linalg.norm(np.cross([-2, 3, 0], [-2, 0, 4])), 0])


@pytest.mark.parametrize("weights", ["mean-value", "cotangent"])
def test_laplacian_blocks_match_dense_definition(weights):
    v, f, _ = random_disk_mesh(bump(), 60, seed=1)
    disk = prepare_disk(v, f)
    interior = HarmonicMap(disk, weights).interior
    block, coupling = laplacian_blocks(disk, interior, weights)
    n = len(disk.vertices)
    w = np.zeros((n, n))
    for a, b, c in disk.faces:
        for i, j, k in ((a, b, c), (b, c, a), (c, a, b)):
            e1, e2 = disk.vertices[j] - disk.vertices[i], disk.vertices[k] - disk.vertices[i]
            angle = np.arccos(e1 @ e2 / np.linalg.norm(e1) / np.linalg.norm(e2))
            if weights == "mean-value":
                w[i, j] += np.tan(angle / 2) / np.linalg.norm(e1)
                w[i, k] += np.tan(angle / 2) / np.linalg.norm(e2)
            else:
                w[j, k] += 0.5 / np.tan(angle)
                w[k, j] += 0.5 / np.tan(angle)
    lap = np.diag(w.sum(axis=1)) - w
    assert np.allclose(block.toarray(), lap[np.ix_(interior, interior)], rtol=1e-12, atol=1e-12)
    assert np.allclose(coupling.toarray(), lap[np.ix_(interior, disk.boundary)], rtol=1e-12, atol=1e-12)


def test_factorize_solves_in_the_given_order():
    v, f, _ = random_disk_mesh(bump(), 300, seed=2)
    disk = prepare_disk(v, f)
    block, _ = laplacian_blocks(disk, HarmonicMap(disk).interior, "mean-value")
    rhs = np.random.default_rng(0).standard_normal((block.shape[0], 2))
    assert np.allclose(factorize(block).solve(rhs), spla.spsolve(block, rhs), rtol=1e-10, atol=1e-12)
    assert np.allclose(factorize(block).solve(rhs[:, 0]), spla.spsolve(block, rhs[:, 0]), rtol=1e-10, atol=1e-12)


def _fill(matrix: sp.spmatrix, order: np.ndarray) -> int:
    """Entries of L in SuperLU's LU of the matrix in the given order (no pivoting, no further ordering)."""
    permuted = sp.csc_matrix(matrix)[order][:, order]
    return spla.splu(permuted, permc_spec="NATURAL", diag_pivot_thresh=0.0, options={"SymmetricMode": True}).L.nnz


@pytest.mark.parametrize("seed", [0, 1])
def test_minimum_degree_fills_about_as_little_as_superlus(seed):
    v, f, _ = random_disk_mesh(bump(), 3000, seed=seed)
    disk = prepare_disk(v, f)
    block, _ = laplacian_blocks(disk, HarmonicMap(disk).interior, "mean-value")
    order = minimum_degree(block)
    assert np.array_equal(np.sort(order), np.arange(block.shape[0]))
    superlu = spla.splu(sp.csc_matrix(block), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0)
    natural = _fill(block, np.arange(block.shape[0]))
    assert _fill(block, order) <= 1.1 * superlu.L.nnz
    assert _fill(block, order) < 0.5 * natural


def test_minimum_degree_lists_in_32_and_64_bits_give_one_order():
    from meshreg.mesh.ordering import _amd, symmetric_pattern

    v, f, _ = random_disk_mesh(bump(), 600, seed=2)
    disk = prepare_disk(v, f)
    block = laplacian_blocks(disk, HarmonicMap(disk).interior, "mean-value")[0]
    pe, rows = symmetric_pattern(block)
    n, cnz = block.shape[0], int(pe[-1])
    results = []
    for kind in (np.int32, np.int64):
        iw = np.empty(cnz + cnz // 5 + 2 * n, kind)
        iw[:cnz] = rows[:cnz]
        results.append(_amd(pe.astype(kind), iw, cnz, np.zeros(1, np.bool_), np.zeros(n, np.bool_)))
    assert results[0][2] and results[1][2]
    assert np.array_equal(results[0][0], results[1][0]) and np.array_equal(results[0][1], results[1][1])


def test_minimum_degree_of_odd_patterns():
    rng = np.random.default_rng(3)
    pattern = sp.random(200, 200, density=0.02, random_state=rng, format="csc")  # not symmetric, empty rows
    for matrix in (pattern, sp.eye(5), sp.csc_matrix((0, 0)), sp.csc_matrix(np.ones((30, 30)))):
        order = minimum_degree(matrix)
        assert np.array_equal(np.sort(order), np.arange(matrix.shape[0]))
    with pytest.raises(ValueError, match="square"):
        minimum_degree(sp.csc_matrix((3, 4)))


def test_minimum_degree_puts_hubs_last():
    path = sp.diags([np.ones(499), 4 * np.ones(500), np.ones(499)], [-1, 0, 1]).tolil()
    path[:, 7] = path[7, :] = 1  # unknown 7 is coupled to all: a dense row, left out of the ordering
    order = minimum_degree(path.tocsc())
    assert order[-1] == 7 and np.array_equal(np.sort(order), np.arange(500))
    assert _fill(path, order) < 3 * 500


def test_spatial_order_keeps_neighbours_close():
    rng = np.random.default_rng(4)
    points = np.c_[rng.random((4000, 2)), np.zeros(4000)]
    order = spatial_order(points)
    assert np.array_equal(np.sort(order), np.arange(4000))
    steps = np.linalg.norm(np.diff(points[order], axis=0), axis=1)
    assert np.median(steps) < 0.05 < np.median(np.linalg.norm(np.diff(points, axis=0), axis=1))
    assert np.array_equal(spatial_order(np.zeros((3, 3))), [0, 1, 2])


def test_turn_counts():
    uv = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [2.0, 0.0]])
    faces = np.array([[0, 1, 2], [0, 2, 1], [0, 1, 3]])
    assert turn_counts(uv, faces) == (1, 1, 1)


def test_node_range_is_a_binary_search():
    nodes = np.linspace(0, 1, 31)
    rng = np.random.default_rng(0)
    points = np.r_[rng.uniform(-0.2, 1.2, 300), nodes, np.nextafter(nodes, 2), np.nextafter(nodes, -2)]
    for low in points:
        for high in (low, low + 0.07, np.nextafter(low, 2)):
            assert _node_range(nodes, low, high) == (np.searchsorted(nodes, low), np.searchsorted(nodes, high, "right"))
    assert _node_range(nodes, np.nan, 0.5)[1] <= _node_range(nodes, np.nan, 0.5)[0]  # NaN corners: no node


@pytest.mark.parametrize("seed", [0, 4])
def test_rim_vertices_are_the_vertices_of_edges_one_face_uses(seed):
    from meshreg.mesh.early import _rim_vertices

    faces = _soup(seed)
    _, _, inverse, counts = edge_table(faces)
    directed = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    expected = np.zeros(40, bool)
    expected[directed[counts[inverse] == 1].ravel()] = True
    assert np.array_equal(_rim_vertices(faces.astype(np.int64), 40), expected)


def _map_with(disk_args, early):
    """uv of the mesh (vertices, faces) mapped with its own corners, cleaned with ``early`` (or without)."""
    from meshreg.mesh.harmonic import choose_corners

    disk = prepare_disk(*disk_args, checked=None if early is None else early.begin)
    return HarmonicMap(disk, early=early)(choose_corners(disk))[0]


def _no_early_thread_left():
    import threading

    for thread in threading.enumerate():  # an abandoned analysis's thread ends (its pool shuts down)
        if thread.name.startswith("meshreg-early"):
            thread.join(timeout=10)
            assert not thread.is_alive()


def test_an_analysis_begun_before_the_cleanup_gives_the_same_map_or_is_abandoned():
    """The LU's analysis begun on the mesh as given (meshreg.mesh.early) is kept when the cleanup left the mesh as it
    was, and gives the very map; when the cleanup changed the faces (a degenerate triangle dropped) or failed, it is
    abandoned and its thread stopped, and the map is the one without it."""
    from meshreg.mesh.early import EarlyAnalysis

    v, f, _ = random_disk_mesh(bump(), 3000, seed=1)
    early = EarlyAnalysis(minimum=0)
    assert np.array_equal(_map_with((v, f), early), _map_with((v, f), None))
    assert early.used
    dirty = np.vstack([f, [[f[0, 0], f[0, 1], f[0, 1]]]])  # a triangle of no area, which the cleanup drops
    early = EarlyAnalysis(minimum=0)
    assert np.array_equal(_map_with((v, dirty), early), _map_with((v, f), None))
    assert not early.used
    _no_early_thread_left()
    closed = trimesh.creation.icosphere(3)
    with pytest.raises(InputError, match="closed"), EarlyAnalysis(minimum=0) as early:
        prepare_disk(closed.vertices, closed.faces, checked=early.begin)
    _no_early_thread_left()
    small = EarlyAnalysis()  # under EARLY_MIN vertices: nothing begun
    _map_with((v, f), small)
    assert not small.used


def test_a_large_mesh_is_mapped_alike_in_either_order(monkeypatch):
    """The harmonic map of a mesh whose interior is dissected (DISSECT_LEAF lowered so that a 6000-vertex mesh is
    cut) equals the map in the minimum degree order to rounding, analysed early or not."""
    from meshreg.mesh import frontal
    from meshreg.mesh.early import EarlyAnalysis
    from meshreg.mesh.samples import terrain_function

    v, f, _ = random_disk_mesh(terrain_function(), 6000, seed=4)
    plain = _map_with((v, f), None)
    monkeypatch.setattr(frontal, "DISSECT_LEAF", 700)
    early = EarlyAnalysis(minimum=0)
    for uv in (_map_with((v, f), None), _map_with((v, f), early)):
        assert np.abs(uv - plain).max() < 1e-10
    assert early.used


def test_a_stopped_analysis_raises_abandoned():
    from meshreg.mesh.frontal import analyse
    from meshreg.mesh.ordering import Abandoned

    v, f, _ = random_disk_mesh(bump(), 500, seed=2)
    disk = prepare_disk(v, f)
    block, _ = laplacian_blocks(disk, HarmonicMap(disk).interior, "mean-value")
    with pytest.raises(Abandoned):
        analyse(block, stop=np.ones(1, np.bool_))


def test_a_mesh_edge_pattern_analysed_as_symmetric_gives_the_same_analysis():
    """analyse(symmetric=True) takes a mesh's edge pattern as the pattern of A + A^T: the same order, supernodes and
    fronts as building A + A^T from it."""
    from meshreg.mesh.frontal import analyse
    from meshreg.mesh.harmonic import interior_pattern

    v, f, _ = random_disk_mesh(bump(), 4000, seed=5)
    disk = prepare_disk(v, f)
    pattern = interior_pattern(disk, HarmonicMap(disk).interior)
    general, shortcut = analyse(pattern), analyse(pattern, symmetric=True)
    for name in ("order", "first", "flat", "off", "head", "following"):
        assert np.array_equal(getattr(general, name), getattr(shortcut, name)), name


def _advised() -> bool:
    """Whether NumPy advises huge pages for new large arrays now."""
    for name in ("numpy._core.multiarray", "numpy.core.multiarray"):
        getter = getattr(importlib.import_module(name), "_get_madvise_hugepage", None)
        if getter is not None:
            return bool(getter())
    raise AssertionError("NumPy has a switch but no getter")


@pytest.mark.skipif(pages._switch() is None, reason="NumPy without the switch")
def test_small_pages_blocks_turn_the_advice_off_until_the_last_ends():
    switch = pages._switch()
    before = switch(True)
    try:
        first, second = pages.small_pages(), pages.small_pages()
        first.__enter__()
        assert not _advised()
        entered, done = threading.Event(), threading.Event()

        def other_thread():
            with pages.small_pages():
                entered.set()
                done.wait(5)

        thread = threading.Thread(target=other_thread)
        thread.start()
        assert entered.wait(5)
        second.__enter__()
        first.__exit__(None, None, None)
        second.__exit__(None, None, None)
        assert not _advised()  # the other thread's block still runs
        done.set()
        thread.join()
        assert _advised()
        with pytest.raises(ValueError, match="inside"), pages.small_pages():
            raise ValueError("inside")
        assert _advised()
        seen = []  # the front end of a large mesh runs with the advice off, of a small one as it is
        mesh = random_disk_mesh(bump(), 300, seed=0)[:2]
        prepare_disk(*mesh, checked=lambda v, f: seen.append(_advised()))
        with pages.small_pages(pages.SMALL_PAGES_MIN - 1):
            assert _advised()
        with pytest.MonkeyPatch.context() as patch:
            patch.setattr(pages, "SMALL_PAGES_MIN", 300)
            prepare_disk(*mesh, checked=lambda v, f: seen.append(_advised()))
        assert seen == [True, False] and _advised()
        switch(False)
        with pages.small_pages():
            pass
        assert not _advised()  # the setting before, not True
        with pages.small_pages():
            disk = prepare_disk(*random_disk_mesh(bump(), 300, seed=0)[:2])
        assert not _advised() and len(disk.faces) > 0
        switch(True)
        blocks = pages._Blocks()  # a child forked while a block ran in another thread: no block, the advice back
        blocks.by_thread[-1] = 1
        blocks.saved = switch(False)
        blocks.forked()
        assert blocks.running == 0 and _advised() and not blocks.lock.locked()
        blocks.enter(switch)  # forked inside the thread's own block: it goes on, and ends, in the child
        blocks.forked()
        assert blocks.running == 1 and not _advised()
        blocks.leave(switch)
        assert blocks.running == 0 and _advised()
    finally:
        switch(before)
