"""The second refinement pass of a stalled answer (:mod:`meshreg.stalled`): E at the level of one shape while the
points are still a few percent apart, as on a nearly flat sheet, where sliding h changes E only by the relief
squared."""

import numpy as np
from scipy.spatial.transform import Rotation

import meshreg
from meshreg.grid import GridSurface
from meshreg.objective import Objective
from meshreg.options import Options
from meshreg.residual import Residual
from meshreg.samples import paper_pairs
from meshreg.schedule import Candidate, Log
from meshreg.stalled import POLISH_KEEP_RESIDUAL, STALLED_RESIDUAL, is_stalled, polish_stalled


def _sheet(r, t):
    """Relief 1% of its size (the held-out "nearly-flat" surface of benchmarks/bench_heldout.py)."""
    return np.stack([r, t, 0.01 * (np.sin(5 * r + 1) * np.cos(3 * t) + r * t**2)], -1)


def _swirl_swapped(r, t):
    """A smooth warp of the square composed with the swap (r, t) -> (t, r)."""
    r, t = t, r
    return r + 0.12 * np.sin(np.pi * r) * np.cos(np.pi * t), t + 0.10 * np.sin(np.pi * t) * np.sin(2 * np.pi * r)


def test_a_stalled_nearly_flat_sheet_is_polished_to_its_points():
    """Without the polish: E 1.7e-5 (the exact answer ~1e-12), residual 0.070, points 4.6% off on average."""
    n = 41
    r, t = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n), indexing="ij")
    rotation, shift = Rotation.random(random_state=500).as_matrix(), np.array([0.7, -1.1, 3.0])

    def second(r, t):
        return 2.3 * _sheet(*_swirl_swapped(r, t)) @ rotation.T + shift

    result = meshreg.register(_sheet(r, t), second(r, t))
    record = result.params["stalled_polish"]
    assert record["kept"] and record["residual_before"] > STALLED_RESIDUAL and record["energy_before"] > 1e-6
    assert record["keep_residual"] == POLISH_KEEP_RESIDUAL
    assert result.energy == record["energy_after"] < 1e-7 and result.residual == record["residual_after"] < 0.01
    assert result.timings["stalled_polish"] == record["seconds"] > 0
    assert "polish" in result.energy_stages and result.energy_history[-1] == result.energy
    moved = _sheet(r, t) @ result.transform[:3, :3].T + result.transform[:3, 3]
    exact = second(result.h[..., 0], result.h[..., 1])  # the second surface, exactly, at the points h matches
    size = np.ptp(exact.reshape(-1, 3), axis=0).max()
    assert np.linalg.norm(moved - exact, axis=-1).mean() < 0.005 * size


def _ridge(r, t):
    """Two flat sides meeting at a rounded crease along r = 0.4 + 0.15 t^2 (a held-out surface of a helper's probe)."""
    return np.stack([r, t, 0.25 * np.sqrt((r - 0.4 - 0.15 * t**2) ** 2 + 0.03**2) + 0.05 * t], -1)


def test_a_polish_that_brings_the_points_closer_is_kept_without_halving_the_residual():
    """The polish took the residual to 0.61 of itself (kept since POLISH_KEEP_RESIDUAL is 0.75, not 0.5): the
    points' mean error 0.0243 -> 0.0139 and their largest 0.142 -> 0.121 (in the second surface's units)."""
    rotation = Rotation.random(random_state=6).as_matrix()

    def second(r, t):
        r, t = r + 0.088 * np.sin(np.pi * r) * np.cos(np.pi * t), t + 0.07 * np.sin(np.pi * t) * np.sin(2 * np.pi * r)
        return 1.4 * _ridge(r, t) @ rotation.T + np.array([0.3, -0.2, 1.0])

    r1, r2, t2 = np.linspace(0, 1, 61), np.linspace(0, 1, 65), np.linspace(0, 1, 57)
    first = _ridge(*np.meshgrid(r1, r1, indexing="ij"))
    result = meshreg.register(
        GridSurface.from_array(first, r1, r1),
        GridSurface.from_array(second(*np.meshgrid(r2, t2, indexing="ij")), r2, t2),
    )
    record = result.params["stalled_polish"]
    assert record["kept"] and 0.5 < record["residual_after"] / record["residual_before"] < record["keep_residual"]
    moved = first @ result.transform[:3, :3].T + result.transform[:3, 3]
    error = np.linalg.norm(moved - second(result.h[..., 0], result.h[..., 1]), axis=-1)
    assert error.mean() < 0.018 and error.max() < 0.13


def test_right_answers_and_other_shapes_are_not_polished():
    pairs = paper_pairs(21, 21)
    for pair in (pairs[0], pairs[1]):  # sine2-2 against itself (E ~ 1e-9), sine2-3 against sine2-2 (E ~ 0.3)
        result = meshreg.register(pair.first, pair.second)
        assert result.params["stalled_polish"] is None and "stalled_polish" not in result.timings


def test_is_stalled_needs_the_energy_of_one_shape_and_points_apart():
    assert is_stalled(1e-5, Residual(0.07, 1.0))
    assert not is_stalled(1e-5, Residual(0.009, 1.0))  # right: points fit
    assert not is_stalled(0.3, Residual(0.2, 0.3))  # different shapes


def test_a_polish_that_does_not_help_is_not_kept():
    """An answer already at E ~ 0 but reported with a large residual: the polish cannot lower E, so R and h stay."""
    r = np.linspace(0, 1, 15)
    surface = GridSurface.from_array(_sheet(*np.meshgrid(r, r, indexing="ij")))
    objective = Objective(surface, surface)
    rotation, h = np.eye(3), objective.identity.copy()
    candidate = Candidate(objective, rotation, h, objective.energy(rotation, h), Log())
    timings = {}
    residual, record = polish_stalled(candidate, Residual(0.5, 1.0), Options(), timings)
    assert not record["kept"] and residual == Residual(0.5, 1.0)
    assert candidate.h is h and candidate.rotation is rotation and "stalled_polish" in timings
