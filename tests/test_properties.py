"""Property-based: whatever small grids, meshes and parameter values are thrown at the registration, each call
either returns a finite result or raises meshreg's own InputError (never a traceback from deep inside numpy).

The examples come from a fixed seed (the same ones on every run, so that CI is stable); set
MESHREG_HYPOTHESIS_EXAMPLES to run that many random ones instead.
"""

import os

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from hypothesis import HealthCheck, event, given, seed, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

import meshreg
from meshreg.errors import InputError
from meshreg.mesh.correspond import register_meshes
from meshreg.mesh.harmonic import factorize
from meshreg.mesh.ordering import minimum_degree
from meshreg.mesh.samples import random_disk_mesh
from meshreg.options import MODES, Advanced, Options
from meshreg.samples import bump, sample, sine

EXAMPLES = int(os.environ.get("MESHREG_HYPOTHESIS_EXAMPLES", "0"))
SETTINGS = settings(
    max_examples=EXAMPLES or 40,
    deadline=None,
    database=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)
SEED = None if EXAMPLES else 5  # a fixed seed unless more examples are asked for
# few, short iterations: the property is about what comes out, not how good it is
FAST = {"max_iterations": 5, "dp_rounds": 2, "max_rounds": 2, "refine_iterations": 2, "fine_iterations": 1}


def often(valid, invalid):
    """A strategy drawing from ``valid`` 7 times in 8, else from ``invalid``."""
    return st.sampled_from([True] * 7 + [False]).flatmap(lambda ok: valid if ok else invalid)


coordinate = often(
    st.floats(-10, 10, allow_nan=False), st.sampled_from([0.0, 1.0, -1.0, 1e-30, 1e30, 1e60, 1e-60, np.nan, np.inf])
)


def grid(draw, max_nodes: int = 7) -> np.ndarray:
    """A random (M, N, 3) array: noise, a smooth surface, a smooth surface with noise, or a degenerate one."""
    m, n = (draw(often(st.integers(3, max_nodes), st.integers(1, 2))) for _ in range(2))
    kind = draw(st.sampled_from(["noise", "smooth", "noisy", "flat", "scaled"]))
    if kind == "noise":
        return draw(arrays(np.float64, (m, n, 3), elements=coordinate))
    smooth = sample(sine(draw(st.integers(1, 3))), max(m, 3), max(n, 3)).points
    if kind == "noisy":
        return smooth + draw(arrays(np.float64, smooth.shape, elements=st.floats(-0.5, 0.5)))
    if kind == "flat":
        return smooth * np.array(draw(st.sampled_from([[1, 1, 0], [1, 0, 0], [0, 0, 0], [1, 1e-13, 0]])))
    if kind == "scaled":
        return smooth * draw(st.sampled_from([1e-45, 1e-20, 1e20, 1e45]))
    return smooth


def parameters(draw) -> dict:
    """Registration parameters, each valid most of the time."""
    return {
        "mode": draw(often(st.sampled_from(MODES), st.just("fast"))),
        "window": draw(often(st.integers(1, 40), st.integers(-1, 0))),
        "basis": draw(often(st.integers(1, 4), st.just(0))),
        "max_starts": draw(often(st.integers(1, 2), st.just(0))),
        "start_basis": draw(often(st.integers(1, 4), st.just(0))),
        "smoothing": tuple(
            draw(st.lists(often(st.floats(0.05, 1.0), st.sampled_from([-0.1, 1.5, np.nan])), max_size=2))
        ),
        "solver": draw(st.sampled_from(["gauss-newton", "gradient"])),
        "refine": draw(st.sampled_from(["nodes", "none"])),
    }


def _finite(result) -> bool:
    return bool(
        np.isfinite(result.energy)
        and result.energy >= 0
        and np.isfinite(result.rotation).all()
        and np.allclose(result.rotation @ result.rotation.T, np.eye(3), atol=1e-6)
        and np.isfinite(result.h).all()
        and result.h.min() >= -1e-9
        and result.h.max() <= 1 + 1e-9
    )


@pytest.mark.slow
@SETTINGS
@seed(SEED)
@given(st.data())
def test_register_returns_a_finite_result_or_an_input_error(data):
    first, second = grid(data.draw), grid(data.draw)
    params = parameters(data.draw)
    numerics = {**FAST, "step_fraction": data.draw(often(st.sampled_from([0.5, 1.0]), st.sampled_from([0.0, 2.0])))}
    try:
        result = meshreg.register(first, second, advanced=Advanced(**numerics), **params)
    except InputError as err:
        event(f"InputError: {str(err)[:40]}")
        return
    event("registered")
    assert _finite(result)


@pytest.mark.slow
@SETTINGS
@seed(SEED)
@given(st.data())
def test_register_meshes_returns_a_finite_result_or_an_input_error(data):
    meshes = []
    for k in (1, 2):
        kind = data.draw(st.sampled_from(["disk"] * 4 + ["soup", "few"]))
        if kind == "disk":
            v, f, _ = random_disk_mesh(bump(), data.draw(st.integers(30, 120)), seed=k)
            v = v * data.draw(often(st.sampled_from([1.0, 1e-3, 1e6]), st.just(0.0)))
        else:
            count = data.draw(st.integers(0, 40 if kind == "soup" else 4))
            v = data.draw(arrays(np.float64, (count, 3), elements=coordinate))
            f = data.draw(arrays(np.int64, (data.draw(st.integers(0, 30)), 3), elements=st.integers(-1, max(count, 1))))
        meshes.append((v, f))
    options = {
        "resolution": data.draw(often(st.integers(5, 13), st.just(2))),
        "corner_search": data.draw(often(st.integers(0, 3), st.just(-1))),
        "cleanup": data.draw(st.booleans()),
        "weights": data.draw(st.sampled_from(["mean-value", "cotangent"])),
    }
    try:
        mr = register_meshes(*meshes, Options(mode="auto", max_starts=1, advanced=Advanced(**FAST), **options))
    except InputError as err:
        event(f"InputError: {str(err)[:40]}")
        return
    event("registered")
    assert _finite(mr.result) and np.isfinite(mr.uv1).all() and np.isfinite(mr.uv2).all()


@seed(SEED)
@SETTINGS
@given(
    size=st.integers(1, 150),
    density=st.floats(0.0, 0.5),
    symmetric=st.booleans(),
    hub=st.booleans(),
    draw=st.integers(0, 2**32 - 1),
)
def test_minimum_degree_factorization_solves_any_pattern(size, density, symmetric, hub, draw):
    """Any pattern (empty, dense, one-sided, with hubs) gets a permutation, and the LU in its order solves the
    system: the order changes the work, never the answer."""
    rng = np.random.default_rng(draw)
    off = sp.random(size, size, density=density, random_state=rng, format="csc")
    off = -(off + off.T) if symmetric else -off
    if hub:  # unknown 0 coupled to all others: past the dense rule's max(16, 10 sqrt(n)) once n > 101
        off = off.tolil()
        off[0, 1:] = -1.0
        off = off.tocsc()
    matrix = (off + sp.diags(1.0 + abs(off).sum(axis=0).A1 + abs(off).sum(axis=1).A1)).tocsc()
    order = minimum_degree(matrix)
    assert np.array_equal(np.sort(order), np.arange(size))
    rhs = rng.standard_normal((size, 2))
    assert np.allclose(factorize(matrix).solve(rhs), spla.spsolve(matrix, rhs), rtol=1e-9, atol=1e-12)


CUT_HEADERS = st.builds(
    lambda key, cut: (b'{"key": "' + key.encode() + b'"}')[:cut],
    st.text("0123456789abcdef", max_size=64),
    st.integers(0, 80),
)


@seed(SEED)
@SETTINGS
@given(content=st.one_of(st.binary(max_size=80), st.text(max_size=80).map(str.encode), CUT_HEADERS))
def test_a_file_given_as_checkpoint_is_begun_afresh_only_when_meshreg_wrote_it(content, tmp_path_factory):
    """Whatever a file without a line ending holds, it is either begun afresh, when it is empty or the start of a
    checkpoint's header that a kill cut short, or refused with an InputError and left as it was (a fuzz found a
    user's one-line file truncated and overwritten)."""
    from meshreg.checkpoint import Checkpoint

    content = content.replace(b"\n", b" ")
    path = tmp_path_factory.mktemp("checkpoint") / "given.txt"
    path.write_bytes(content)
    opening = b'{"key": "'
    try:
        Checkpoint(path, key="0123abcd").close()
    except InputError:
        assert path.read_bytes() == content
    else:
        assert content[: len(opening)] == opening[: len(content)] and set(content[len(opening) :]) <= set(
            b'0123456789abcdef"}'
        )
        assert path.read_bytes() == b'{"key": "0123abcd"}\n'
