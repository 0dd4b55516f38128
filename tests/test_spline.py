"""The interpolating spline, the B-spline tables and the Gaussian smoothing that stand in for scipy.interpolate and
scipy.ndimage (which the registration no longer imports: 0.25 s at every start) agree with scipy's."""

import os
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import given, seed, settings
from hypothesis import strategies as st
from scipy.interpolate import BSpline, RectBivariateSpline
from scipy.ndimage import gaussian_filter1d as scipy_gaussian

from meshreg.gaussian import gaussian_filter1d
from meshreg.spline import GridInterpolator, bspline_table, interpolation_knots

SETTINGS = settings(
    max_examples=int(os.environ.get("MESHREG_HYPOTHESIS_EXAMPLES", "0")) or 60, deadline=None, database=None
)


def _nodes(rng, m):
    return np.sort(np.r_[0.0, rng.uniform(0.0, 1.0, m - 2), 1.0]) if m > 2 else np.array([0.0, 1.0])


@pytest.mark.parametrize("m, n", [(2, 3), (3, 5), (4, 4), (5, 9), (8, 6), (61, 101)])
def test_grid_interpolator_matches_fitpack_interpolating_spline(m, n):
    rng = np.random.default_rng(m * 100 + n)
    r, t = _nodes(rng, m), np.linspace(0.0, 1.0, n)
    values = rng.standard_normal((m, n, 3))
    ours = GridInterpolator(values, r, t)
    u, v = rng.uniform(0.0, 1.0, 200), rng.uniform(0.0, 1.0, 200)
    value, du, dv = ours(u, v)
    for c in range(3):
        theirs = RectBivariateSpline(r, t, values[..., c], kx=ours.kx, ky=ours.ky, s=0)
        assert np.array_equal(ours.tx, theirs.get_knots()[0]) and np.array_equal(ours.ty, theirs.get_knots()[1])
        scale = np.abs(theirs.get_coeffs()).max()
        assert np.allclose(ours.coef[..., c].ravel(), theirs.get_coeffs(), rtol=0, atol=1e-13 * scale)
        assert np.allclose(value[:, c], theirs.ev(u, v), rtol=0, atol=1e-13 * scale)
        if ours.kx == 1:  # FITPACK's derivative routine refuses linear pieces: scipy's BSpline along that axis
            along = BSpline(ours.tx, ours.coef[..., c], 1).derivative()(u)  # (points, n): then the spline along t
            slopes = [BSpline(ours.ty, along[p], ours.ky)(v[p]) for p in range(len(u))]
            assert np.allclose(du[:, c], slopes, rtol=0, atol=1e-12 * scale)
        if ours.kx > 1 and ours.ky > 1:
            assert np.allclose(du[:, c], theirs.ev(u, v, dx=1), rtol=0, atol=1e-12 * scale)
            assert np.allclose(dv[:, c], theirs.ev(u, v, dy=1), rtol=0, atol=1e-12 * scale)


def test_the_interpolant_goes_through_the_data_and_keeps_cubics():
    r, t = np.linspace(0.0, 1.0, 9), np.r_[0.0, 0.1, 0.35, 0.4, 0.8, 1.0]
    rr, tt = np.meshgrid(r, t, indexing="ij")
    cubic = np.stack([rr**3 - 2 * rr * tt**2, tt**3 + rr], axis=-1)
    f = GridInterpolator(cubic, r, t)
    assert np.allclose(f.values(rr, tt), cubic, atol=1e-13)
    u, v = np.array([0.33, 0.71]), np.array([0.05, 0.9])
    value, du, dv = f(u, v)
    assert np.allclose(value[:, 0], u**3 - 2 * u * v**2, atol=1e-12)
    assert np.allclose(du[:, 0], 3 * u**2 - 2 * v**2, atol=1e-11)
    assert np.allclose(dv[:, 1], 3 * v**2, atol=1e-11)


@pytest.mark.parametrize("k, m", [(1, 2), (2, 3), (3, 4), (3, 7)])
def test_interpolation_knots_are_fitpacks(k, m):
    x = _nodes(np.random.default_rng(m), m)
    y = np.random.default_rng(k).standard_normal((m, 4))
    fitpack = RectBivariateSpline(x, np.linspace(0, 1, 4), y, kx=k, ky=3, s=0).get_knots()[0]
    assert np.array_equal(interpolation_knots(x, k), fitpack)


@pytest.mark.parametrize("n", [4, 5, 9])
def test_bspline_table_matches_scipys_bsplines(n):
    x = np.r_[-0.1, np.linspace(0.0, 1.0, 41), 1.05]  # outside [0, 1]: 0, as scipy's NaN made 0
    knots = np.concatenate([[0.0] * 3, np.linspace(0.0, 1.0, n - 2), [1.0] * 3])
    spline = BSpline(knots, np.eye(n), 3, extrapolate=False)
    values, slopes = bspline_table(knots, 3, x)
    assert np.allclose(values, np.nan_to_num(spline(x)), rtol=0, atol=1e-15)
    assert np.allclose(slopes, np.nan_to_num(spline.derivative()(x)), rtol=0, atol=1e-12)


@seed(20261202)
@SETTINGS
@given(
    n=st.integers(1, 40),
    width=st.integers(0, 3),
    sigma=st.floats(0.05, 12.0),
    truncate=st.sampled_from([1.0, 2.5, 3.0, 4.0]),
    mode=st.sampled_from(["nearest", "constant"]),
    magnitude=st.floats(-3, 3),
    draw=st.integers(0, 2**31),
)
def test_gaussian_filter_is_scipys_to_the_bit(n, width, sigma, truncate, mode, magnitude, draw):
    values = np.random.default_rng(draw).standard_normal((n,) + (width,) * min(width, 2)) * 10.0**magnitude
    assert np.array_equal(
        gaussian_filter1d(values, sigma, mode, truncate), scipy_gaussian(values, sigma, 0, mode=mode, truncate=truncate)
    )


def test_registering_imports_neither_scipy_interpolate_nor_ndimage():
    code = (
        "import sys, meshreg\n"
        "from meshreg.samples import paper_pairs\n"
        "import meshreg.mesh.correspond, meshreg.outputs, meshreg.bending\n"
        "p = paper_pairs(21, 21)[0]\n"
        "meshreg.register(p.first, p.second)\n"
        "print(sorted(m for m in ('scipy.interpolate', 'scipy.ndimage') if m in sys.modules))\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert done.stdout.strip().splitlines()[-1] == "[]"
