import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import meshreg
from meshreg.objective import Objective
from meshreg.rotation import angle_between
from meshreg.samples import bump, saddle, sample, terrain, warp, wave
from meshreg.search import SQUARE_SYMMETRIES, apply_symmetry, cube_rotations, principal_rotations, symmetry_map
from meshreg.spline import GridInterpolator


def test_cube_group():
    rots = cube_rotations()
    assert len(rots) == 24 and len({r.tobytes() for r in rots}) == 24
    assert np.allclose(np.linalg.det(rots), 1.0)


def test_symmetry_copy_matches_the_map():
    s = sample(bump(), 21, 17, warp(0.05))
    uv = np.random.default_rng(0).random((30, 2))
    original = GridInterpolator(s.points, s.r, s.t)
    for k in range(len(SQUARE_SYMMETRIES)):
        copy = apply_symmetry(s, k)
        mapped = symmetry_map(k, uv)
        assert np.allclose(
            GridInterpolator(copy.points, copy.r, copy.t)(uv[:, 0], uv[:, 1])[0],
            original(mapped[:, 0], mapped[:, 1])[0],
            atol=1e-12,
        )


def test_principal_rotations_are_proper_and_align_axes():
    c = bump()
    rot = Rotation.from_euler("zyx", [40, 10, -70], degrees=True).as_matrix()
    a, b = sample(c, 21, 21), sample(lambda r, t: c(r, t) @ rot.T, 21, 21)
    cands = principal_rotations(a, b)
    assert np.allclose(np.linalg.det(cands), 1.0)
    assert min(angle_between(r, rot) for r in cands) < 1.0


@pytest.mark.parametrize("seed, k", [(11, 0), (12, 3), (13, 6), (14, 1)])
def test_any_rotation_and_corner_choice_is_recovered(seed, k):
    """Random rotations and any of the 8 symmetries of the square, with a non-separable warp."""
    c = bump()
    rot = Rotation.random(random_state=seed).as_matrix()
    first = sample(c, 41, 41)
    second = apply_symmetry(sample(lambda r, t: c(r, t) @ rot.T, 43, 39, warp(0.1)), k)
    result = meshreg.register(first, second)
    assert result.energy < 1e-4
    assert angle_between(result.rotation, rot) < 1.0
    assert Objective(first, second).energy(result.rotation, result.h) == pytest.approx(result.energy, rel=1e-9)
    # h' = sigma^-1 o h is an orientation-preserving reparametrization of the square
    assert np.all(result.h >= 0) and np.all(result.h <= 1)


@pytest.mark.parametrize("make, seed", [(saddle, 21), (wave, 22), (lambda: terrain(3), 23)])
def test_other_surfaces_with_general_rotations(make, seed):
    c = make()
    rot = Rotation.random(random_state=seed).as_matrix()
    first = sample(c, 41, 41)
    second = sample(lambda r, t: 0.7 * c(r, t) @ rot.T - 4.0, 41, 41, warp(-0.07))
    result = meshreg.register(first, second)
    assert result.energy < 1e-3
    assert angle_between(result.rotation, rot) < 1.0


def test_later_dp_passes_in_a_band_find_the_whole_table_paths():
    """Mode auto's DP passes after the first one each way search within Advanced.dp_radius nodes of the identity
    path: on a pair of different shapes (several passes) the answer is the one of the whole table (dp_radius=0)."""
    from meshreg.options import Advanced

    pair = next(p for p in meshreg.samples.paper_pairs(41, 41) if p.name == "sine2-3 g2")
    banded = meshreg.register(pair.first, pair.second)
    whole = meshreg.register(pair.first, pair.second, advanced=Advanced(dp_radius=0))
    assert banded.params["dp_radius"] == 20 and whole.params["dp_radius"] == 0
    assert banded.energy_dp == pytest.approx(whole.energy_dp, rel=1e-9)
    assert banded.energy == pytest.approx(whole.energy, rel=1e-9)


def test_of_twin_starts_the_one_with_the_clearly_lower_coarse_residual_is_registered():
    from meshreg.choice import close_starts
    from meshreg.search import Start

    best, twin_right, twin_worse, far = (
        Start(3, None, 0.50, residual=0.40),
        Start(5, None, 0.87 * (1 + 1e-15), residual=0.34),
        Start(4, None, 0.87, residual=1.06),
        Start(1, None, 5.0, residual=0.1),
    )
    for order in ([best, twin_worse, twin_right, far], [best, twin_right, twin_worse, far]):
        chosen = close_starts(order, max_starts=3, margin=1.0)
        assert [s.symmetry for s in chosen] == [3, 5]  # whichever twin rounding put first; the far start left out
    even = [best, Start(4, None, 0.87, residual=0.34), Start(5, None, 0.87, residual=0.33)]
    assert [s.symmetry for s in close_starts(even, 3, 1.0)] == [3, 4]  # equally good twins: the first
    identity_twin = [Start(2, None, 1.0, residual=0.3), Start(0, None, 1.0 + 1e-12, residual=1.0)]
    assert [s.symmetry for s in close_starts(identity_twin, 3, 0.1)] == [2]  # put first, still replaced
