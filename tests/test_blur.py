"""Blurring the grids of coarse meshes (Options.mesh_blur, docs/meshes.md "Blurring coarse meshes")."""

import numpy as np

from meshreg import Options
from meshreg.grid import GridSurface
from meshreg.mesh import deform
from meshreg.mesh.correspond import register_meshes
from meshreg.mesh.resample import blur_grid
from meshreg.samples import saddle


def test_blur_keeps_planes_and_smooths_facets():
    r = np.linspace(0, 1, 41)
    u, v = np.meshgrid(r, r, indexing="ij")
    plane = np.stack([u, v, 0.2 * u + 0.5 * v - 0.1], -1)
    assert np.allclose(blur_grid(GridSurface(plane, r, r), 3.0).points, plane, atol=1e-12)
    facets = plane.copy()
    facets[..., 2] += 0.02 * (np.indices((41, 41)).sum(0) % 2)  # a checkerboard below the grid's resolution
    blurred = blur_grid(GridSurface(facets, r, r), 2.0).points
    offset = blurred[..., 2] - plane[..., 2]  # the checkerboard's mean, 0.01, away from the sides (kept there)
    assert np.abs(offset[8:-8, 8:-8] - 0.01).max() < 1e-4
    corners = (0, 0, -1, -1), (0, -1, 0, -1)
    assert np.allclose(blurred[corners], facets[corners])  # odd reflection keeps the corner nodes


def test_coarse_remeshed_pair_is_registered_through_its_surface_not_its_facets():
    """Two random triangulations of a saddle (about 600 triangles each) moved rigidly: without the blur the descent
    matched the facets (median error 0.0090 of sqrt(area), E 0.0019); blurred 0.0010 (E 3.7e-6)."""
    pair = deform.sheet_pair("saddle", saddle(), n_first=300, n_second=300, seed=2)
    mr = register_meshes(pair.first, pair.second, Options(overlap="off"))
    assert mr.result.params["mesh_blur_sigma"] > 0 and mr.result.params["blurred"]
    assert np.median(pair.errors(deform.matched_points(mr, len(pair.second[0])))) < 0.0035


def test_a_bent_pair_is_not_blurred():
    pair = deform.bent_pair("roll", 90.0, n_first=300, n_second=400, seed=0)
    mr = register_meshes(pair.first, pair.second, Options(overlap="off"))
    assert not mr.result.params["blurred"] and mr.result.params["mesh_blur_sigma"] == 0
    assert not mr.result.params["snapped"]


def _cells(nx: int, ny: int) -> tuple[np.ndarray, np.ndarray]:
    """A grid of nx x ny cells over [-1, 1]^2, each split into two triangles: parameters (n, 2) and faces."""
    x, y = np.meshgrid(np.linspace(-1, 1, nx + 1), np.linspace(-1, 1, ny + 1), indexing="ij")
    idx = np.arange(x.size).reshape(nx + 1, ny + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    return np.c_[x.ravel(), y.ravel()], np.r_[np.c_[a, b, c], np.c_[a, c, d]]


def _terrain(p: np.ndarray) -> np.ndarray:
    x, y = p[:, 0], p[:, 1]
    z = 0.25 * np.exp(-((x - 0.3) ** 2 + (y - 0.2) ** 2) / 0.08) - 0.15 * np.exp(
        -((x + 0.4) ** 2 + (y + 0.3) ** 2) / 0.05
    )
    return np.c_[x, y, z + 0.1 * np.sin(2 * x + y)]


def test_anisotropic_triangulations_whose_maps_nearly_agree_are_blurred():
    """150 x 6 against 6 x 150 cells (25:1 triangles) of one terrain: the maps' own correspondence fits the raw points
    within 0.025 (the facets), the blurred ones within 0.0054, so the gate is judged on the blurred grids; blurred,
    the points are 0.7% off instead of 2.3%."""
    from scipy.spatial.transform import Rotation

    (p1, f1), (p2, f2) = _cells(150, 6), _cells(6, 150)
    rotation = Rotation.from_euler("xyz", [35, -50, 120], degrees=True).as_matrix()
    second = 2.5 * _terrain(p2) @ rotation.T + [3.0, -2.0, 7.0]
    mr = register_meshes((_terrain(p1), f1), (second, f2), Options(overlap="off"))
    truth = 2.5 * _terrain(p1) @ rotation.T + [3.0, -2.0, 7.0]
    error = np.linalg.norm(mr.result.correspondence() - truth, axis=1) / np.ptp(second, axis=0).max()
    assert mr.result.params["blurred"] and np.median(error) < 0.012


def test_one_rigid_surface_is_snapped_to_closest_points():
    """Two triangulations of one sheet (the second's vertices on the first mesh), moved rigidly and scaled 2.5: the
    elastic answer is limited by the grids (median errors 0.0006-0.0014 of sqrt(area) on such pairs); snapped to
    closest points at the refined similarity (meshreg.mesh.snap) it is within 1e-4 (5e-5 measured)."""
    for seed in (0, 1):
        pair = deform.sheet_pair("remeshed", n_first=800, n_second=1100, seed=seed)
        mr = register_meshes(pair.first, pair.second, Options())
        assert mr.result.params["snapped"]
        assert np.median(pair.errors(deform.matched_points(mr, len(pair.second[0])))) < 1e-4


def _gaussian_relief(seed: int, peak_to_peak: float):
    """A sheet (u, v) -> (u, v, z) whose z is six random Gaussian bumps, scaled to ``peak_to_peak``."""
    rng = np.random.default_rng(100 + seed)
    centres, widths, heights = rng.uniform(0.1, 0.9, (6, 2)), rng.uniform(0.1, 0.3, 6), rng.uniform(-1, 1, 6)

    def bumps(p):
        return sum(
            a * np.exp(-np.sum((p - c) ** 2, 1) / (2 * w * w)) for a, c, w in zip(heights, centres, widths, strict=True)
        )

    grid = np.stack(np.meshgrid(np.linspace(0, 1, 101), np.linspace(0, 1, 101)), -1).reshape(-1, 2)
    k = peak_to_peak / np.ptp(bumps(grid))
    return lambda u, v: np.c_[u, v, k * bumps(np.c_[u, v])]


def test_a_bent_pair_is_not_snapped_to_a_collapsed_pose():
    """A relief sheet rolled half a turn: point-to-plane ICP with a scale shrank the second towards a point (RMS
    1.7e-8, scale 6.7e6 after inversion) and the snap took it: 0.39 of sqrt(area) off. The snap now keeps the
    registration's scale within SNAP_SCALE, and the bent answer stands (0.013)."""
    roll = deform.sheet_pair(
        "roll", _gaussian_relief(2, 0.18), deform=lambda p: deform.bend(p, np.pi), n_first=1500, n_second=2000, seed=2
    )
    mr = register_meshes(roll.first, roll.second, Options())
    assert not mr.result.params["snapped"]
    assert 1.5 < mr.result.scale < 2.6
    assert np.median(roll.errors(deform.matched_points(mr, len(roll.second[0])))) < 0.03


def test_one_rigid_surface_with_vertex_noise_is_snapped():
    """The same with Gaussian noise of 0.3% of sqrt(area) on the first mesh's vertices: the ICP residual is the noise
    (about 0.1 edge lengths, above SNAP_TIGHT) but incoherent (averaged over neighbours below SNAP_TIGHT), so the
    pair is snapped: 0.0024 of sqrt(area) off (median), where the elastic answer was 0.0073 (not snapped)."""
    pair = deform.sheet_pair("remeshed", n_first=1000, n_second=1300, seed=0)
    vertices, faces = pair.first
    noisy = vertices + 0.003 * pair.unit * np.random.default_rng(5).normal(size=vertices.shape)
    mr = register_meshes((noisy, faces), pair.second, Options())
    assert mr.result.params["snapped"]
    assert np.median(pair.errors(deform.matched_points(mr, len(pair.second[0])))) < 0.0035


def test_a_slightly_rolled_pair_is_not_snapped_as_noise():
    """A sheet rolled by 3 degrees: ICP RMS 0.06 edge lengths (above SNAP_TIGHT), its residual averaged over
    neighbouring samples 0.049 (below SNAP_TIGHT, but 0.83 of the RMS: a bend, not noise). Snapped, it was 0.0021 of
    sqrt(area) off; the elastic answer 0.0009."""
    pair = deform.bent_pair("roll", 3.0, n_first=1500, n_second=2000, seed=1)
    mr = register_meshes(pair.first, pair.second, Options())
    assert not mr.result.params["snapped"]
    assert np.median(pair.errors(deform.matched_points(mr, len(pair.second[0])))) < 0.0015


def test_one_rigid_surface_snaps_without_a_descent_to_the_descents_answer(monkeypatch):
    """An unbent pair whose parametrizations' own correspondence snaps (one rigid surface) is not descended: the
    snap from the descent's answer gave the same closest points (ICP from either pose converges to one pose)."""
    import meshreg.mesh.correspond as correspond

    pair = deform.sheet_pair("remeshed", n_first=800, n_second=1100, seed=1)
    settled = register_meshes(pair.first, pair.second, Options()).result
    assert settled.params["snapped"] and not settled.params["descended"]
    assert settled.energy_stages == ("start",) and len(settled.energy_history) == 1
    monkeypatch.setattr(correspond, "SETTLE_SLACK", 0.0)  # the settle's snap refused: the descent runs, then the snap
    descended = register_meshes(pair.first, pair.second, Options()).result
    assert descended.params["snapped"] and descended.params["descended"]
    assert "gd" in descended.energy_stages
    scale = np.sqrt(descended.second.area())
    assert np.nanmax(np.linalg.norm(settled.correspondence() - descended.correspondence(), axis=1)) < 1e-6 * scale
    assert np.allclose(settled.transform, descended.transform, atol=1e-6)
    assert settled.symmetry == descended.symmetry


def test_a_bent_pair_is_descended():
    pair = deform.bent_pair("roll", 90.0, n_first=300, n_second=400, seed=0)
    result = register_meshes(pair.first, pair.second, Options(overlap="off")).result
    assert result.params["descended"] and not result.params["snapped"]


def _cylinder_with_a_bump(u, v):
    r = 1 + 0.01 * np.exp(-((u - 0.75) ** 2 + (v - 0.2) ** 2) / 0.01)
    return np.stack([r * np.cos(1.2 * u), r * np.sin(1.2 * u), 0.7 * v], -1)


def test_pose_pinning_is_zero_where_icp_can_slide():
    from meshreg.mesh.align import Cloud
    from meshreg.mesh.samples import random_disk_mesh, terrain_function
    from meshreg.mesh.snap import SETTLE_PINNING, pose_pinning
    from meshreg.mesh.surface import Surface

    def pinning(surface):
        mesh = Surface(*random_disk_mesh(surface, 1500, seed=0)[:2])
        return pose_pinning(Cloud(mesh.vertices, mesh.normals))

    assert pinning(lambda u, v: np.stack([u, v, 0 * u], -1)) < 1e-12  # a plane: three free motions
    assert pinning(_cylinder_with_a_bump) < SETTLE_PINNING / 5
    assert pinning(terrain_function()) > SETTLE_PINNING * 5


def test_a_surface_that_icp_slides_along_is_descended_before_its_snap():
    """Review 2026-12-04: a cylinder patch with one bump 1% high, remeshed, turned and scaled: snapped from the
    parametrizations' correspondence (the pose's shift 1.4 times the start's residual, under SETTLE_SLACK) ICP had
    slid along the cylinder and the points were 0.0042 of sqrt(area) off (median); descended first, 0.0015 (not
    snapped). The surface hardly pins the pose (pose_pinning 0.0002), so the early snap is refused."""
    from scipy.interpolate import LinearNDInterpolator
    from scipy.spatial.transform import Rotation

    from meshreg.mesh.samples import random_disk_mesh

    turn = Rotation.random(random_state=100).as_matrix()
    v1, f1, p1 = random_disk_mesh(_cylinder_with_a_bump, 800, seed=0)
    v2, f2, p2 = random_disk_mesh(_cylinder_with_a_bump, 1200, seed=1, rotation=turn, scale=1.7)
    result = register_meshes((v1, f1), (v2, f2)).result
    assert result.params["descended"] and "settle" in result.timings
    truth = LinearNDInterpolator(p2, v2)(p1)
    error = np.linalg.norm(result.correspondence() - truth, axis=1) / np.sqrt(result.second.area())
    assert np.nanmedian(error) < 0.0025
