"""The multifrontal LU against scipy's solvers: mesh Laplacians, odd patterns, both thread schedules, pivoting."""

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial import Delaunay

from meshreg.mesh import frontal
from meshreg.mesh.frontal import MultifrontalLU, analyse
from meshreg.mesh.harmonic import Factorization


def _planar_m_matrix(points: int, seed: int) -> sp.csc_matrix:
    """A non-symmetric M-matrix on the Delaunay graph of random points: random positive couplings, each row's
    diagonal their sum plus a little (like a mesh Laplacian's interior block)."""
    rng = np.random.default_rng(seed)
    tri = Delaunay(rng.random((points, 2))).simplices
    i = np.concatenate([tri[:, 0], tri[:, 1], tri[:, 2], tri[:, 1], tri[:, 2], tri[:, 0]])
    j = np.concatenate([tri[:, 1], tri[:, 2], tri[:, 0], tri[:, 0], tri[:, 1], tri[:, 2]])
    w = sp.csr_matrix((rng.uniform(0.01, 1.0, len(i)), (i, j)), shape=(points, points))
    w.sum_duplicates()
    diag = np.asarray(w.sum(axis=1)).ravel() + rng.uniform(1e-3, 1e-2, points)
    return (sp.diags(diag) - w).tocsc()


@pytest.mark.parametrize("seed", [0, 1])
def test_solves_a_planar_m_matrix_like_superlu(seed):
    a = _planar_m_matrix(3000, seed)
    rhs = np.random.default_rng(seed).random((3000, 2))
    x = MultifrontalLU(a).solve(rhs)
    assert np.abs(a @ x - rhs).max() < 1e-10 * np.abs(rhs).max() * spla.norm(a, np.inf)
    assert np.allclose(x, spla.spsolve(a, rhs), rtol=1e-9, atol=1e-12)
    assert np.allclose(MultifrontalLU(a).solve(rhs[:, 1]), x[:, 1], rtol=0, atol=0)


def test_two_threads_give_the_same_bits_as_one(monkeypatch):
    monkeypatch.setattr(frontal, "THREADS_MIN", 0)
    a = _planar_m_matrix(6000, 2)
    rhs = np.random.default_rng(2).random((6000, 2))
    one = MultifrontalLU(a, analyse(a, threads=1))
    two = MultifrontalLU(a, analyse(a, threads=2))
    for part_one, part_two in zip(one.factors, two.factors, strict=True):
        assert np.array_equal(part_one, part_two)
    assert np.array_equal(one.solve(rhs), two.solve(rhs))
    # the threads really split the tree: both got subtrees, and the top is a small part
    bins, top, roots = two.analysis.schedule
    assert all(len(b) > 0 for b in bins) and len(top) < len(two.analysis.first) // 10 and len(roots) >= 2
    assert np.array_equal(np.sort(np.concatenate([*bins, top])), np.arange(len(two.analysis.first) - 1))
    assert np.all(_parents(two.analysis)[roots] >= 0) and np.isin(_parents(two.analysis)[roots], top).all()


@pytest.mark.parametrize("threads", [1, 2])
def test_the_stack_of_update_matrices_is_sized_once_to_its_peak(monkeypatch, threads):
    """Each sequence's stack starts at the most it holds (:func:`frontal._stack_need`): counted here another way,
    after each supernode, as the updates of the supernodes done whose parent is not (those not handed to the top)."""
    monkeypatch.setattr(frontal, "THREADS_MIN", 0)
    an = analyse(_planar_m_matrix(6000, 3), threads=threads)
    bins, top, roots = an.schedule
    nu = np.diff(an.off)
    parent = _parents(an)
    handed = np.zeros(len(nu), bool)
    handed[roots] = True
    ext_off = np.where(handed, 0, -1)
    for seq in [*bins, top]:
        done, peak = np.zeros(len(nu), bool), 1
        for s in seq:
            done[s] = True
            waiting = done & ~handed & (nu > 0) & ~np.isin(parent, seq[done[seq]])
            peak = max(peak, int((nu[waiting] ** 2).sum()))
        assert frontal._stack_need(seq, an.off, an.head, an.following, ext_off) == peak
    assert max(frontal._stack_need(b, an.off, an.head, an.following, ext_off) for b in [*bins, top]) > 1000


def _parents(an) -> np.ndarray:
    """Each supernode's parent supernode (-1 at a root): the owner of its lowest update row."""
    nsup = len(an.first) - 1
    owner = np.repeat(np.arange(nsup), np.diff(an.first))
    rows = [an.flat[an.off[s] : an.off[s + 1]] for s in range(nsup)]
    return np.array([owner[r.min()] if len(r) else -1 for r in rows])


def test_large_fronts_take_the_panel_path():
    """A dense block of 150 unknowns (one front well over BLOCKED_MIN rows, several PANELs) coupled to a chain."""
    rng = np.random.default_rng(5)
    n = 400
    dense = rng.uniform(-1, 0, (150, 150))
    a = sp.lil_matrix((n, n))
    a[250:, 250:] = dense
    for k in range(n - 1):
        a[k, k + 1], a[k + 1, k] = -rng.random(), -rng.random()
    a = a.tocsc()
    a = (a + sp.diags(np.abs(a).sum(axis=1).A1 + 1.0)).tocsc()
    lu = MultifrontalLU(a)
    assert (np.diff(lu.analysis.first) + np.diff(lu.analysis.off)).max() >= frontal.BLOCKED_MIN + frontal.PANEL
    rhs = rng.random(n)
    assert np.allclose(lu.solve(rhs), np.linalg.solve(a.toarray(), rhs), rtol=1e-10, atol=1e-12)


@settings(max_examples=40, deadline=None)
@given(
    n=st.integers(1, 40),
    density=st.floats(0.0, 0.5),
    symmetric=st.booleans(),
    seed=st.integers(0, 2**31 - 1),
)
def test_random_diagonally_dominant_patterns(n, density, symmetric, seed):
    """Any pattern (non-symmetric, empty rows, dense rows) of a diagonally dominant matrix: the dense answer."""
    rng = np.random.default_rng(seed)
    off = sp.random(n, n, density=density, random_state=rng, format="csr")
    off.data -= 0.5
    if symmetric:
        off = off + off.T
    off.setdiag(0)
    a = (off + sp.diags(np.abs(off).sum(axis=1).A1 + rng.uniform(0.5, 2.0, n))).tocsc()
    rhs = rng.standard_normal((n, 3))
    assert np.allclose(MultifrontalLU(a).solve(rhs), np.linalg.solve(a.toarray(), rhs), rtol=1e-9, atol=1e-10)


def test_a_zero_pivot_is_left_to_superlu():
    """A permutation-like block (zero diagonal) cannot be factorized without pivoting: the multifrontal LU says so
    and Factorization solves it by SuperLU's partial pivoting."""
    a = sp.csc_matrix(np.array([[0.0, 2.0, 0.0], [3.0, 0.0, 0.0], [0.0, 0.0, 4.0]]))
    with pytest.raises(ZeroDivisionError):
        MultifrontalLU(a)
    assert np.allclose(Factorization(a).solve(np.array([2.0, 3.0, 8.0])), [1.0, 1.0, 2.0])


def test_an_analysis_of_a_wider_pattern_serves_the_matrix():
    """The harmonic map analyses the pattern of the faces while the weights are computed: any matrix whose
    entries lie within the analysed pattern (here: a few couplings dropped) is factorized with it."""
    a = _planar_m_matrix(2000, 4)
    pattern = a.copy()
    pattern.data[:] = 1.0
    thinned = a.tocoo()
    keep = np.random.default_rng(4).random(thinned.nnz) > 0.1
    keep |= thinned.row == thinned.col
    thinned = sp.csc_matrix((thinned.data[keep], (thinned.row[keep], thinned.col[keep])), shape=a.shape)
    rhs = np.ones(2000)
    x = MultifrontalLU(thinned, analyse(pattern)).solve(rhs)
    assert np.allclose(thinned @ x, rhs, rtol=0, atol=1e-9)
    with pytest.raises(ValueError, match="analysis of 2000 unknowns"):
        MultifrontalLU(a[:100, :100], analyse(pattern))


def test_entries_outside_the_analysed_pattern_are_refused():
    """An analysis serves only matrices within its pattern: an entry outside it has no place in any front."""
    chain = sp.diags([-1.0, 2.5, -1.0], [-1, 0, 1], shape=(200, 200)).tocsc()
    wider = chain.tolil()
    wider[5, 150] = -0.5
    with pytest.raises(ValueError, match="outside the analysed pattern"):
        MultifrontalLU(wider.tocsc(), analyse(chain))


@pytest.mark.parametrize(
    "matrix",
    [
        np.array([[1.0, -1.0, 0.0], [-1.0, 2.0, -1.0], [0.0, -1.0, 1.0]]),  # a path's Laplacian: singular
        np.diag([1.0, 0.0, 2.0]),  # a zero pivot with nothing below it
    ],
)
def test_singular_matrices_raise_instead_of_returning_inf(matrix):
    """The last pivot of a root front divides nothing during the factorization: it is checked after it, and the
    matrix goes to SuperLU, which says it is singular."""
    a = sp.csc_matrix(matrix)
    with pytest.raises(ZeroDivisionError):
        MultifrontalLU(a)
    with pytest.raises(RuntimeError, match="singular"):
        Factorization(a)


def test_an_empty_matrix(monkeypatch):
    monkeypatch.setattr(frontal, "THREADS_MIN", 0)
    lu = MultifrontalLU(sp.csc_matrix((0, 0)))
    assert lu.solve(np.zeros(0)).shape == (0,)
    assert lu.solve(np.zeros((0, 2))).shape == (0, 2)
