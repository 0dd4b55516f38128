"""Gaussian scale space of grid surfaces (meshreg.scale) and its use by mode "gd"."""

import numpy as np
import pytest

import meshreg
from meshreg.errors import InputError
from meshreg.grid import GridSurface
from meshreg.samples import paper_pairs, sine
from meshreg.scale import level_nodes, smoothed


def _grid(c, m=41, n=31):
    r, t = np.linspace(0, 1, m), np.linspace(0, 1, n) ** 1.3
    return GridSurface(c(*np.meshgrid(r, t, indexing="ij")), r, t)


def test_a_plane_stays_the_same_plane_with_its_sides_in_place():
    plane = _grid(lambda r, t: np.stack([2 * r + 0.5 * t, t, 0.3 * r - t], axis=-1))
    out = smoothed(plane, 0.15, 21)
    u, v = np.meshgrid(out.r, out.t, indexing="ij")
    assert np.allclose(out.points, np.stack([2 * u + 0.5 * v, v, 0.3 * u - v], axis=-1), atol=1e-9)


def test_smoothing_damps_folds_by_the_gaussians_factor():
    wave = _grid(sine(2), 201, 11)  # (sin 2 pi r, r, t): odd at both ends, so the continuation is exact
    out = smoothed(wave, 0.05, 101)
    expected = np.exp(-0.5 * (2 * np.pi * 0.05) ** 2)  # the Gaussian's transfer at frequency 1
    assert np.ptp(out.points[..., 0]) / np.ptp(wave.points[..., 0]) == pytest.approx(expected, rel=0.02)
    assert out.shape == (101, 101)


def test_level_nodes_sample_the_gaussian_and_respect_the_limit():
    assert level_nodes(0.1, 101) == 51
    assert level_nodes(0.01, 101) == 101
    assert level_nodes(1.0, 101) == 11


@pytest.mark.slow
def test_gd_keeps_the_lowest_path_and_records_it():
    pair = next(p for p in paper_pairs(31, 31) if p.name == "sine2-3 g2")
    plain = meshreg.register(pair.first, pair.second, mode="gd", smoothing=(), start_basis=5)
    coarse = meshreg.register(pair.first, pair.second, mode="gd", smoothing=())
    every = meshreg.register(pair.first, pair.second, mode="gd")
    assert plain.params["gd_path"] == {"smoothing": [], "bases": [5]}
    # the path kept is the one with the lowest E (the first of equals): plain < coarse basis first < scale space
    assert coarse.params["gd_path"]["bases"] == ([3, 5] if coarse.energy < plain.energy else [5])
    assert every.params["gd_path"] == (
        {"smoothing": [0.1], "bases": [3, 5]} if every.energy < coarse.energy else coarse.params["gd_path"]
    )
    assert every.energy <= coarse.energy + 1e-12 <= plain.energy + 2e-12
    assert "smoothing" in every.timings and "smoothing" not in coarse.timings
    assert np.all(np.diff(every.energy_history) <= 1e-12)


@pytest.mark.parametrize("bad", [(0.0,), (-0.1,), (float("nan"),)])
def test_bad_smoothing_is_a_clear_error(bad):
    pair = paper_pairs(11, 11)[0]
    with pytest.raises(InputError, match="smoothing"):
        meshreg.register(pair.first, pair.second, mode="gd", smoothing=bad)
