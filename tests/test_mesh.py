import subprocess
import sys

import numpy as np
import pytest
import trimesh
from scipy.interpolate import LinearNDInterpolator
from scipy.spatial import Delaunay
from scipy.spatial.transform import Rotation

import meshreg
from meshreg.errors import InputError
from meshreg.mesh import load_mesh, parametrize, prepare_disk, resample_grid
from meshreg.mesh.correspond import register_meshes
from meshreg.mesh.export import uv_colors
from meshreg.mesh.samples import random_disk_mesh, terrain_function
from meshreg.options import Options
from meshreg.rotation import angle_between
from meshreg.samples import bump, symmetric_sheet


def test_parametrization_is_bijective_and_sides_on_sides():
    v, f, _ = random_disk_mesh(bump(), 800, seed=0)
    disk = prepare_disk(v, f)
    uv, info = parametrize(disk)
    assert info["flipped"] == 0 and info["degenerate"] == 0
    b = uv[disk.boundary]
    on_side = np.isclose(b[:, 0], 0) | np.isclose(b[:, 0], 1) | np.isclose(b[:, 1], 0) | np.isclose(b[:, 1], 1)
    assert on_side.all()
    grid = resample_grid(disk.vertices, disk.faces, uv, 31, 31)
    assert np.all(np.isfinite(grid.points))


@pytest.mark.parametrize("surface", [bump(), terrain_function()])
def test_remeshed_rotated_copy_gives_small_energy_and_matching_colours(surface):
    rot = Rotation.from_euler("zxz", [70, 35, -120], degrees=True).as_matrix()
    v1, f1, p1 = random_disk_mesh(surface, 1500, seed=3)
    v2, f2, p2 = random_disk_mesh(surface, 2500, seed=4, rotation=rot, scale=3.0)
    mr = register_meshes((v1, f1), (v2, f2), Options(resolution=61))
    assert mr.result.energy <= 0.02
    assert angle_between(mr.result.rotation, rot) < 2.0
    assert colour_error(mr, p1, p2) <= 0.1


def colour_error(mr, p1, p2) -> float:
    """Median colour difference at truly corresponding points (equal parameters p: the first mesh's uv
    interpolated at the second's vertices), over the median difference of random pairs."""
    truth_uv = LinearNDInterpolator(p1[mr.first.vertex_map], mr.uv1)(p2[mr.second.vertex_map])
    ok = ~np.isnan(truth_uv[:, 0])
    truth = uv_colors(truth_uv[ok])
    err = np.median(np.linalg.norm(uv_colors(mr.matched_uv2)[ok] - truth, axis=1))
    typical = np.median(np.linalg.norm(truth - truth[np.random.default_rng(0).permutation(len(truth))], axis=1))
    return float(err / typical)


@pytest.mark.parametrize("kind", ["axis", pytest.param("four-fold", marks=pytest.mark.slow)])
def test_symmetric_sheet_meshes_match_truly_corresponding_points(kind):
    """Two random triangulations of a sheet with a mirror symmetry (a bump on an axis) or with a four-fold one too
    (a centred bump): the mirror image matches at the same E, the residual rules it out. The four-fold sheet has
    four right answers: the chosen one and three alternatives, the true one among them; pinning it gives it."""
    rot = Rotation.random(random_state=5).as_matrix()
    v1, f1, p1 = random_disk_mesh(symmetric_sheet(kind), 1500, seed=5)
    v2, f2, p2 = random_disk_mesh(symmetric_sheet(kind), 2500, seed=15, rotation=rot, scale=3.0)
    options = Options(resolution=41)
    mr = register_meshes((v1, f1), (v2, f2), options)
    result = mr.result
    assert result.energy < 2e-3 and result.residual < 0.02 < 0.5 < result.residual_mirrored
    if kind == "axis":
        assert result.alternatives == [] and colour_error(mr, p1, p2) <= 0.1
        return
    assert np.allclose(sorted(a["angle"] for a in result.alternatives), [90, 90, 180], atol=3)
    answers = [(result.symmetry, result.rotation)] + [
        (a["symmetry"], np.array(a["rotation"])) for a in result.alternatives
    ]
    symmetry, rotation = min(answers, key=lambda answer: angle_between(answer[1], rot))
    assert angle_between(rotation, rot) < 2.0
    pinned = register_meshes((v1, f1), (v2, f2), options.replace(symmetry=symmetry))
    assert angle_between(pinned.result.rotation, rot) < 2.0 and colour_error(pinned, p1, p2) <= 0.1


@pytest.mark.slow
def test_face_scan_at_the_default_resolution_converges():
    """The raw face-scan crop against its remeshed, rotated, rescaled copy with every default (101 x 101): one rigid
    surface, so the answer is snapped to closest points (meshreg.mesh.snap): the true rotation within 0.05 degrees
    (0.5 before the snap), corresponding vertices within 0.02% of sqrt(area) of their true partners (median; 0.15%
    before), E at most 0.008 (0.0056: the scan's noise and its filled holes). Before the meshes' own starts
    (meshreg.mesh.corners.own_start) the first mesh's corners collapsed part of it onto a side of the square, and E
    was 0.0216 with the same correspondence. Point-sampled grids stopped at E = 0.026 (Options.antialias)."""
    from meshreg.mesh.samples import face_scan_errors, face_scan_pair

    (v1, f1), (v2, f2, xy), rot = face_scan_pair()
    mr = register_meshes((v1, f1), (v2, f2), Options())
    assert mr.result.params["snapped"] and mr.result.energy <= 0.008
    assert angle_between(mr.result.rotation, rot) < 0.05
    assert np.nanmedian(face_scan_errors(mr.result, (v1, f1), xy)) <= 0.0002
    assert not mr.result.mirrored


def test_a_round_boundary_gets_its_own_start_whatever_the_numbering():
    """Held out 2026-12-02: the face-scan crop's corners went at quarter arc lengths from a start that the numbering
    of its boundary loop picked; from some starts they put both ends of a boundary chord on one side of the square,
    which collapsed the surface beyond it (E 0.0216 against a remeshed copy in the file's order, 0.0060 with its
    faces shuffled). The own start squeezes the map no more than that start (in the file's order less than half as
    much), as little in every face order, and lands on the same boundary points (within 1% of the boundary's length:
    the squeeze is flat near its least)."""
    from meshreg.mesh.corners import own_start, placement_starts
    from meshreg.mesh.harmonic import HarmonicMap, compression, quarter_corners
    from meshreg.mesh.samples import face_scan_pair
    from meshreg.mesh.topology import loop_segments

    (v, f), _, _ = face_scan_pair(n_points=15000)
    placed, squeezed = [], []
    for seed in (None, 0, 1):
        faces = f if seed is None else f[np.random.default_rng(seed).permutation(len(f))]
        disk = prepare_disk(v, faces)
        hmap = HarmonicMap(disk)
        corners = quarter_corners(disk, own_start(hmap))
        given = quarter_corners(disk, placement_starts(disk, 1)[0] % 1.0)
        squeezed.append((compression(disk, hmap(corners)[0]), compression(disk, hmap(given)[0])))
        placed.append(disk.vertices[disk.boundary[corners]])
    assert squeezed[0][0] < 0.5 * squeezed[0][1]
    assert max(own for own, _ in squeezed) <= 1.5 * min(own for own, _ in squeezed)
    length = loop_segments(disk.vertices, disk.boundary).sum()
    for other in placed[1:]:  # the same four points, in some order (a quarter turn of the square)
        gaps = np.linalg.norm(placed[0][:, None] - other[None], axis=2).min(axis=1)
        assert np.all(gaps < 0.01 * length)


def test_four_clear_turns_on_one_mesh_only_are_not_its_corners(bitten_disk):
    """Held out 2026-12-02 (a probe of round and notched rims): where one mesh of a pair had four clear turns (dents
    of a jagged rim, or a bite's corners, bunched in a tenth of the rim) and the other none, the first kept them and
    the second's corners were searched at quarter arc lengths, which cannot match them: 8 of 62 same-surface pairs
    came out 15-172 degrees and 11-65% of sqrt(area) off. Both are now placed at quarter arc lengths."""
    from meshreg.mesh.harmonic import has_sharp_corners

    (v1, f1, _), (v2, f2, _) = bitten_disk(1400, 46), bitten_disk(4600, 53)
    assert has_sharp_corners(prepare_disk(v1, f1)) and not has_sharp_corners(prepare_disk(v2, f2))
    turn = Rotation.random(random_state=46).as_matrix()
    moved = 2.8 * v2 @ turn.T + [0.3, -1.0, 0.5]
    mr = register_meshes((v1, f1), (moved, f2), Options(resolution=61))
    truth = 2.8 * v1 @ turn.T + [0.3, -1.0, 0.5]
    error = np.linalg.norm(mr.result.correspondence() - truth, axis=1) / (2.8 * np.sqrt(np.pi))
    assert angle_between(mr.result.rotation, turn) < 1.0 and np.median(error) < 0.005


@pytest.mark.slow
@pytest.mark.parametrize("seed", [4, 6])
def test_a_nearly_symmetric_round_pair_is_not_matched_half_turned(star_saddle, seed):
    """Held out 2026-12-02: a saddle over a five-lobed star, remeshed (1,500 and 4,000 vertices), turned and scaled
    2x. Half a turn keeps the saddle and puts the star's lobes on its notches; E_w ranked that match first and 7 of
    12 seeds came out 179.7-179.9 degrees off (point-wise residual 0.25). Seed 4: the right placement ranked 1.27
    times the best E_w with residual 0.024 against 0.252 (meshreg.bending.preferred); seed 6: the trial placements
    stepped over the right one's narrow minimum (meshreg.mesh.corners._fitting)."""
    (v1, f1, _), (v2, f2, _) = star_saddle(1500, seed), star_saddle(4000, seed + 100)
    turn = Rotation.random(random_state=seed).as_matrix()
    shift = np.array([0.3, -1.0, 0.5])
    mr = register_meshes((v1, f1), (2.0 * v2 @ turn.T + shift, f2), Options(resolution=61))
    area = 0.5 * np.sum(np.linalg.norm(np.cross(v1[f1[:, 1]] - v1[f1[:, 0]], v1[f1[:, 2]] - v1[f1[:, 0]]), axis=1))
    error = np.linalg.norm(mr.result.correspondence() - (2.0 * v1 @ turn.T + shift), axis=1) / (2.0 * np.sqrt(area))
    assert angle_between(mr.result.rotation, turn) < 1.0 and np.median(error) < 0.005


@pytest.mark.slow
@pytest.mark.parametrize(
    "lobes, depth, phase, relief, seed",
    [(4, 0.15, 0.3, "cubic", 24), (5, 0.25, 0.0, "saddle", 26)],
)
def test_a_round_pair_whose_right_match_is_a_far_second_by_e_w_is_found(lobed, lobes, depth, phase, relief, seed):
    """Held out 2026-12-02: reliefs over lobed rims, remeshed (1,500 and 3,000 vertices), turned and scaled 1.5x.
    The four-lobed rim under the cubic 0.3 (x^3 - 3 x y^2) + 0.1 y: the right placement's coarse E_w was 1.36 times
    the best trial's with residual 0.085 against 0.112 (too small a gain to refine it: corners._fitting), and the
    halving steps around the best went down to E_w 0.0043 with residual 0.13-0.22 (a half-turned match, 179.4
    degrees off). The star under the saddle: the right match's E_w was 2.2 times the half-turned one's, residuals
    0.057 against 0.27 (beyond a tie of 1.5: bending.RESIDUAL_TIE)."""
    heights = {
        "saddle": lambda x, y: 0.4 * (x**2 - y**2),
        "cubic": lambda x, y: 0.3 * (x**3 - 3 * x * y**2) + 0.1 * y,
    }
    shape = {"lobes": lobes, "depth": depth, "phase": phase, "relief": heights[relief], "box": 1.3}
    (v1, f1, _), (v2, f2, _) = lobed(1500, seed, **shape), lobed(3000, seed + 100, **shape)
    turn = Rotation.random(random_state=seed).as_matrix()
    mr = register_meshes((v1, f1), (1.5 * v2 @ turn.T + 0.3, f2), Options(resolution=61))
    assert angle_between(mr.result.rotation, turn) < 1.0 and mr.result.residual < 0.02


def _random_rim_disk(rng, points: int):
    """A triangulated unit disk: ``points`` random points inside and 3.5 sqrt(points) random points on the circle
    (uneven rim spacing, as a crop's rim), Delaunay; faces and (u, v)."""
    r, turn = 0.994 * np.sqrt(rng.uniform(0, 1, points)), rng.uniform(0, 2 * np.pi, points)
    rim = np.sort(rng.uniform(0, 2 * np.pi, int(3.5 * np.sqrt(points))))
    uv = np.vstack([np.c_[r * np.cos(turn), r * np.sin(turn)], np.c_[np.cos(rim), np.sin(rim)]])
    return Delaunay(uv).simplices, uv


def test_snug_moves_a_placement_that_fits_the_points_to_where_they_fit_best():
    """corners._snug: halving steps around the chosen start by the residual of the chosen symmetry, only when the
    chosen match fits the points (residual below SNUG_RESIDUAL)."""
    from meshreg.mesh.corners import SNUG_HALVINGS, SNUG_RESIDUAL, _snug

    asked = []

    def rank(start, symmetries):  # E_w falls away from the residual's minimum: the move must follow the residual
        asked.append(symmetries)
        return (1.0 - start, 0.001 + abs(start - 0.31), symmetries[0])

    start, moves = _snug(rank, (0.3, (0.7, 0.011, 5)), 1 / 32)
    assert abs(start - 0.31) < 1 / 32 / 2**SNUG_HALVINGS and len(moves) == 2 * SNUG_HALVINGS
    assert all(s == [5] for s in asked)
    assert _snug(rank, (0.3, (0.7, SNUG_RESIDUAL, 5)), 1 / 32) == (0.3, [])
    assert _snug(rank, (0.31, (0.69, 0.001, 5)), 1 / 32)[0] == 0.31  # every move fits worse: the start stays


@pytest.mark.slow
@pytest.mark.parametrize("seed", [1, 8])
def test_a_cone_patch_over_a_round_rim_gets_its_corner_placement_from_the_points(seed):
    """Held out 2026-12-03: a cone patch (not developed flat: its rim is a circle of the parameter plane) meshed
    twice with random rims (1,200 and 4,000 points), turned and scaled 1.5x. The lowest coarse E_w was a placement
    of the second's corners off the right one, which no reparametrization keeping the corners undoes: E 0.0037 and
    0.011 (seeds 1, 8). The placement moved to where the points fit (corners._snug) gives E 1.7e-4 and 1.6e-5."""

    def cone(uv):
        u, v = 0.5 + 0.5 * uv[:, 0], 0.5 + 0.5 * uv[:, 1]
        return np.c_[(1 + 0.45 * v) * np.sin(1.6 * u), 1.5 * v, (1 + 0.45 * v) * np.cos(1.6 * u)]

    rng = np.random.default_rng(seed)
    (f1, uv1), (f2, uv2) = _random_rim_disk(rng, 1200), _random_rim_disk(rng, 4000)
    turn = Rotation.random(random_state=seed).as_matrix()
    mr = register_meshes((cone(uv1), f1), (1.5 * cone(uv2) @ turn.T + 0.3, f2), Options(resolution=61))
    assert mr.info["second"]["other_placement"]["kept"]
    assert mr.result.energy < 1e-3 and angle_between(mr.result.rotation, turn) < 0.5


def _hull_pair(surface: str, seed: int):
    """Two meshes of a patch made of random points only (1,500 and 3,000; Delaunay: their rims are convex hulls), the
    second turned, scaled and shifted: (first, second, turn, scale, shift)."""

    def patch(uv):
        x, y = 2 * uv[:, 0] - 1, 1.8 * uv[:, 1] - 0.7
        if surface == "paraboloid":
            return np.c_[x, y, 0.7 * x**2 + 0.2 * y**2 + 0.3 * x * y]
        x, y = 1.6 * uv[:, 0] - 0.8, 1.6 * uv[:, 1] - 0.8
        return np.c_[x, y, 1.2 * np.sqrt(1 - x**2 / 2.56 - y**2 / 1.69)]

    rng = np.random.default_rng(seed)
    uv1, uv2 = rng.uniform(0, 1, (1500, 2)), rng.uniform(0, 1, (3000, 2))
    turn, scale = Rotation.random(random_state=seed + 7).as_matrix(), rng.uniform(0.5, 3.0)
    shift = rng.normal(0, 2, 3)
    first = patch(uv1), Delaunay(uv1).simplices
    return first, (scale * patch(uv2) @ turn.T + shift, Delaunay(uv2).simplices), turn, scale, shift


@pytest.mark.parametrize("surface, seed", [("paraboloid", 2), ("ellipsoid", 1)])
def test_a_pair_of_convex_hull_rims_is_held_to_the_pose_that_fits_its_points(surface, seed):
    """Random points only, Delaunay (the rim is their convex hull: sliver triangles along it, the square's corners
    cut off differently in each mesh): the whole registration's answers were 177 and 89 degrees off (residual 0.05)
    at a lower E than the right match; the overlap check's pose fits the points, and its answer is kept."""
    from meshreg.mesh.correspond import POSE_CHECK
    from meshreg.outputs import _mesh_notes

    first, second, turn, scale, shift = _hull_pair(surface, seed)
    mr = register_meshes(first, second, Options(resolution=61))
    check = mr.info["pose_check"]
    assert check["kept"] == "pose" and check["residual"] > POSE_CHECK  # the whole answer did not fit the points
    assert any("registered at the overlap's pose" in note for note in _mesh_notes(mr.result.info))
    assert angle_between(mr.result.rotation, turn) < 0.5
    matched = mr.result.correspondence()
    off = np.linalg.norm(matched - (scale * first[0] @ turn.T + shift), axis=1) / scale
    assert np.nanmedian(off) < 0.01 and np.mean(np.isnan(off)) < 0.05


def test_the_pose_check_leaves_the_whole_answer_when_the_pose_does_not_fit_better_or_fails(monkeypatch):
    """The branches of correspond._held_to_the_pose that the hull pairs do not take: the answer at the pose kept only
    when its residual is at most RESIDUAL_GAIN times the whole one's, and an error in it leaving the whole answer."""
    import meshreg.mesh.correspond as correspond

    first, second, *_ = _hull_pair("paraboloid", 2)
    monkeypatch.setattr(correspond, "RESIDUAL_GAIN", 0.0)
    mr = register_meshes(first, second, Options(resolution=61))
    check = mr.info["pose_check"]
    assert (
        check["kept"] == "whole" and check["residual"] < mr.result.residual and mr.info["overlap"]["regime"] == "full"
    )
    assert mr.result.timings["total"] >= mr.result.timings["pose_check"] > 0

    def fails(*args, **kwargs):
        raise np.linalg.LinAlgError("Singular matrix")

    monkeypatch.setattr(correspond, "register_overlap", fails)
    mr = register_meshes(first, second, Options(resolution=61))
    assert mr.info["pose_check"] == {"error": "Singular matrix"} and mr.info["overlap"]["regime"] == "full"


def test_face_scan_crop_with_holes_against_remeshed_copy():
    from meshreg.mesh.samples import face_scan_pair

    # raw crop: holes, a pinched boundary vertex, a round boundary; the copy: its own triangles and holes
    (v1, f1), (v2, f2, xy2), rot = face_scan_pair(n_points=15000)
    mr = register_meshes((v1, f1), (v2, f2), Options(resolution=41))
    assert any("filled" in line for line in mr.info["first"]["cleanup"])
    assert mr.result.energy <= 0.02
    assert angle_between(mr.result.rotation, rot) < 2.0
    k1, k2 = len(mr.first.vertex_map), len(mr.second.vertex_map)  # input vertices (hole centres follow)
    truth_uv = LinearNDInterpolator(mr.first.vertices[:k1, :2], mr.uv1[:k1])(xy2[mr.second.vertex_map])
    ok = ~np.isnan(truth_uv[:, 0])
    truth = uv_colors(truth_uv[ok])
    err = np.median(np.linalg.norm(uv_colors(mr.matched_uv2)[:k2][ok] - truth, axis=1))
    typical = np.median(np.linalg.norm(truth - truth[np.random.default_rng(0).permutation(len(truth))], axis=1))
    assert err <= 0.1 * typical


def _annulus():
    a = trimesh.creation.annulus(r_min=0.5, r_max=1.0, height=0.1, sections=24)
    keep = a.face_normals[:, 2] > 0.9  # the top ring only: a disk with a hole
    return a.vertices, a.faces[keep]


@pytest.mark.parametrize(
    "make, message",
    [
        (lambda: (trimesh.creation.icosphere().vertices, trimesh.creation.icosphere().faces), "closed"),
        (
            lambda: (
                np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [0, -1, 0.0], [0.2, 0.2, -1]]),
                np.array([[0, 1, 2], [0, 1, 3], [0, 1, 4], [0, 2, 5]]),
            ),
            "non-manifold",
        ),
        (lambda: (np.array([[0, 0, np.nan], [1, 0, 0], [0, 1, 0.0]]), np.array([[0, 1, 2]])), "NaN"),
        (lambda: (np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0.0]]), np.array([[0, 1, 2]])), "too small.* 3 vertices"),
        (  # a fan of three triangles: its two outer ones are boundary ears, and the cleanup leaves one triangle
            lambda: (
                np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [-1, 1, 0.0]]),
                [[0, 1, 2], [0, 2, 3], [0, 3, 4]],
            ),
            "too small.*after the cleanup",
        ),
    ],
)
def test_bad_meshes(make, message):
    v, f = make()
    with pytest.raises(InputError, match=message):
        disk = prepare_disk(v, f)
        parametrize(disk)


def test_holes_are_filled_or_refused():
    v, f = _annulus()
    with pytest.raises(InputError, match="boundary loops"):
        prepare_disk(v, f, fill_holes=False)
    disk = prepare_disk(v, f)
    assert disk.report[0] == "filled 1 hole (24 boundary vertices)"
    assert len(disk.vertices) == len(np.unique(f)) + 1 and len(disk.vertex_map) == len(np.unique(f))
    uv, info = parametrize(disk)
    assert info["flipped"] == 0


def test_pinched_boundary_vertex_is_repaired():
    # two triangulated squares (3 x 3 and 4 x 4 nodes) sharing only one corner vertex
    def patch(n, origin, sign):
        x, y = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
        pts = np.c_[x.ravel(), y.ravel(), np.zeros(n * n)] * sign + origin
        k = np.arange(n * n).reshape(n, n)
        quads = np.c_[k[:-1, :-1].ravel(), k[1:, :-1].ravel(), k[1:, 1:].ravel(), k[:-1, 1:].ravel()]
        return pts, np.vstack([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])

    v1, f1 = patch(4, np.zeros(3), 1.0)
    v2, f2 = patch(3, np.zeros(3), -1.0)  # its corner (0, 0) is vertex 0 of the first
    f2 = np.where(f2 == 0, -len(v1), f2) + len(v1)
    v, f = np.vstack([v1, v2]), np.vstack([f1, f2])
    with pytest.raises(InputError, match="touches itself"):
        prepare_disk(v, f, cleanup=False)
    disk = prepare_disk(v, f)
    assert any("touches itself" in line for line in disk.report)


def test_cleanup_is_reported():
    v, f, _ = random_disk_mesh(bump(), 300, seed=5)
    far = v + 100.0  # a second component
    v2 = np.vstack([v, far, [[0, 0, 0]]])
    f2 = np.vstack([f, f + len(v), [[0, 0, 1]]])  # plus a degenerate triangle
    disk = prepare_disk(v2, f2)
    assert any("components" in line for line in disk.report)
    assert any("degenerate" in line for line in disk.report)
    with pytest.raises(InputError, match="components|degenerate"):
        prepare_disk(v2, f2, cleanup=False)


def test_unreadable_and_empty_files(tmp_path):
    (tmp_path / "junk.ply").write_bytes(b"ply\nthis is not a mesh\n")
    with pytest.raises(InputError):
        load_mesh(tmp_path / "junk.ply")
    with pytest.raises(InputError, match="no such file"):
        load_mesh(tmp_path / "missing.obj")
    # held out 2026-12-02 (a fuzz): a cut ASCII PLY was called "empty"
    ascii_ply = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
    ascii_ply += "element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n"
    (tmp_path / "cut.ply").write_text(ascii_ply)
    with pytest.raises(InputError, match="no triangles read .* or a file cut short"):
        load_mesh(tmp_path / "cut.ply")


def test_text_meshes_that_trimesh_would_read_wrong_are_refused(tmp_path):
    """Found by a fuzz (2026-12-03): an OBJ file counting vertices from 0 was read garbled (E 1.94 against itself)
    and OFF files whose header counts do not match their lines lost triangles or were read cut short."""
    v, f, _ = random_disk_mesh(bump(), 60, seed=3)
    points = [f"v {x} {y} {z}" for x, y, z in v]
    (tmp_path / "zero.obj").write_text("\n".join(points + [f"f {a} {b} {c}" for a, b, c in f]) + "\n")
    with pytest.raises(InputError, match="OBJ counts vertices from 1"):
        load_mesh(tmp_path / "zero.obj")
    faces = [f"f {a + 1} {b + 1} {c + 10}" for a, b, c in f[:1]] + ["# f 0 1 2 was the old face", "f -1 -2 -3"]
    (tmp_path / "one.obj").write_text("\n".join(points + faces))
    assert len(load_mesh(tmp_path / "one.obj")[1]) == 2  # an index 10, relative indices, a comment: no 0
    body = [f"{x} {y} {z}" for x, y, z in v] + [f"3 {a} {b} {c}" for a, b, c in f]
    for name, counts in (
        ("ok.off", (len(v), len(f))),
        ("more.off", (len(v) + 5, len(f))),
        ("cut.off", (len(v), len(f) + 9)),
    ):
        (tmp_path / name).write_text("\n".join(["OFF", f"{counts[0]} {counts[1]} 0", *body]) + "\n")
    assert np.array_equal(load_mesh(tmp_path / "ok.off")[1], f)
    for name in ("more.off", "cut.off"):
        with pytest.raises(InputError, match="header promises"):
            load_mesh(tmp_path / name)


@pytest.mark.slow
def test_cli_meshes_end_to_end_and_errors(tmp_path):
    v1, f1, _ = random_disk_mesh(bump(), 800, seed=6)
    v2, f2, _ = random_disk_mesh(bump(), 1200, seed=7, rotation=Rotation.random(random_state=1).as_matrix())
    trimesh.Trimesh(v1, f1, process=False).export(tmp_path / "a.ply")
    trimesh.Trimesh(v2, f2, process=False).export(tmp_path / "b.obj")
    before = (tmp_path / "a.ply").read_bytes()
    out = tmp_path / "out"
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "meshreg.cli",
            "register",
            str(tmp_path / "a.ply"),
            str(tmp_path / "b.obj"),
            "-o",
            str(out),
            "-q",
        ],
        capture_output=True,
        text=True,
    )
    assert proc.returncode == 0, proc.stderr
    for name in ("first.ply", "second.ply", "registered.ply", "result.npz", "meshes.png", "registration.png"):
        assert (out / name).stat().st_size > 0
    colored = trimesh.load(out / "second.ply", process=False)
    assert len(colored.vertices) == len(v2) and np.allclose(colored.vertices, v2)
    assert colored.visual.vertex_colors.shape[0] == len(v2)
    with np.load(out / "result.npz") as data:
        assert data["uv_first"].shape == (len(v1), 2) and float(data["energy"]) < 0.02
    assert (tmp_path / "a.ply").read_bytes() == before
    sphere = trimesh.creation.icosphere()
    sphere.export(tmp_path / "sphere.stl")
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "meshreg.cli",
            "register",
            str(tmp_path / "sphere.stl"),
            str(tmp_path / "b.obj"),
            "-o",
            str(tmp_path / "o2"),
            "-q",
        ],
        capture_output=True,
        text=True,
    )
    assert proc.returncode == 2 and "closed" in proc.stderr and "Traceback" not in proc.stderr
    assert not (tmp_path / "o2" / "result.npz").exists()


@pytest.mark.slow
def test_cli_mesh_options(tmp_path):
    v, f = _annulus()
    trimesh.Trimesh(v, f, process=False).export(tmp_path / "ring.ply")
    v2, f2, _ = random_disk_mesh(bump(), 300, seed=8)
    trimesh.Trimesh(v2, f2, process=False).export(tmp_path / "b.ply")
    base = [sys.executable, "-m", "meshreg.cli", "register", str(tmp_path / "ring.ply"), str(tmp_path / "b.ply"), "-q"]
    proc = subprocess.run(base + ["-o", str(tmp_path / "o1"), "--no-cleanup"], capture_output=True, text=True)
    assert proc.returncode == 2 and "boundary loops" in proc.stderr
    proc = subprocess.run(
        base + ["-o", str(tmp_path / "o2"), "--corners1", "0", "1", "2", "99999"], capture_output=True, text=True
    )
    assert proc.returncode == 2 and "not in the (cleaned) mesh" in proc.stderr and "Traceback" not in proc.stderr
    proc = subprocess.run(
        base + ["-o", str(tmp_path / "o3"), "--resolution", "21", "--weights", "cotangent"],
        capture_output=True,
        text=True,
    )
    assert proc.returncode == 0, proc.stderr
    assert "filled 1 hole" in proc.stdout
    with np.load(tmp_path / "o3" / "result.npz") as data:
        assert data["h"].shape == (21, 21, 2)


def test_obj_with_texture_seams_keeps_its_vertices(tmp_path):
    # textured scans are OBJ files whose faces index separate texture coordinates: the mesh must not fall apart
    v, f, _ = random_disk_mesh(bump(), 200, seed=9)
    lines = [f"v {x} {y} {z}" for x, y, z in v] + [
        f"vt {a} {b}" for a, b in np.random.default_rng(0).random((3 * len(f), 2))
    ]
    lines += [f"f {a + 1}/{3 * k + 1} {b + 1}/{3 * k + 2} {c + 1}/{3 * k + 3}" for k, (a, b, c) in enumerate(f)]
    (tmp_path / "scan.obj").write_text("\n".join(lines) + "\n")
    v2, f2 = load_mesh(tmp_path / "scan.obj")
    assert np.allclose(v2, v) and np.array_equal(f2, f)
    prepare_disk(v2, f2, cleanup=False)


def test_inconsistent_winding_is_repaired():
    v, f, _ = random_disk_mesh(bump(), 300, seed=10)
    bad = f.copy()
    bad[::7] = bad[::7, ::-1]
    with pytest.raises(InputError, match="oriented against"):
        prepare_disk(v, bad, cleanup=False)
    disk = prepare_disk(v, bad)
    assert any("reoriented" in line for line in disk.report)
    assert np.array_equal(disk.faces, prepare_disk(v, f).faces)


def test_triangle_soup_is_welded_but_a_cut_is_kept():
    v, f, _ = random_disk_mesh(bump(), 300, seed=12)
    soup_v, soup_f = v[f].reshape(-1, 3), np.arange(3 * len(f)).reshape(-1, 3)  # every triangle on its own
    disk = prepare_disk(soup_v, soup_f)
    assert any("welded" in line for line in disk.report) and len(disk.faces) == len(prepare_disk(v, f).faces)
    colors = disk.to_input(np.ones((len(disk.vertices), 3)), len(soup_v), [0, 0, 0])
    assert np.mean(colors[:, 0] == 1) > 0.98  # welded or not, input vertices get their value (ears aside)
    # a cylinder cut open along a seam: one piece whose seam vertices coincide; welding would close it
    n = 16
    angle = np.linspace(0, 2 * np.pi, n + 1)
    ring = np.c_[np.cos(angle), np.sin(angle)]
    cv = np.vstack([np.c_[ring, np.full(n + 1, z)] for z in (0.0, 0.5, 1.0)])
    k = np.arange(n)
    cf = np.vstack(
        [np.c_[k, k + 1, k + n + 2] + o for o in (0, n + 1)] + [np.c_[k, k + n + 2, k + n + 1] + o for o in (0, n + 1)]
    )
    cut = prepare_disk(cv, cf)
    assert not any("welded" in line for line in cut.report) and len(cut.boundary) >= 2 * n


def _lattice_triangle(n: int):
    """A relief sheet over a triangle (apex angle 53 degrees) as a lattice of n^2 triangles: its three corner
    triangles are boundary ears."""
    i, j = (a.ravel() for a in np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij"))
    i, j = i[i + j <= n], j[i + j <= n]
    v = np.array([-1.0, -1, 0]) + np.outer(i / n, [2.0, 0, 0]) + np.outer(j / n, [1.0, 2, 0])
    v[:, 2] = 0.2 * np.sin(2 * v[:, 0] + v[:, 1])
    index = {(a, b): k for k, (a, b) in enumerate(zip(i.tolist(), j.tolist(), strict=True))}
    up = [(index[a, b], index[a + 1, b], index[a, b + 1]) for a, b in index if a + b < n]
    down = [(index[a + 1, b], index[a + 1, b + 1], index[a, b + 1]) for a, b in index if a + b < n - 1]
    return v, np.array(up + down)


def test_the_apex_of_a_removed_ear_is_matched_at_its_foot():
    # held out 2026-12-01: the vertices cleanup dropped with boundary ears had no match (NaN rows: 5 on an L-shaped
    # saddle, 3 on a triangular sheet), though they lie on the surface
    v, f = _lattice_triangle(10)
    disk = prepare_disk(v, f)
    assert any("3 boundary ears" in line for line in disk.report) and len(disk.ear_feet.ids) == 3
    rotation = Rotation.from_euler("xyz", [35, -50, 120], degrees=True).as_matrix()
    result = meshreg.register((v, f), (2.5 * v @ rotation.T + 1.0, f), resolution=41, overlap="off")
    matches = result.correspondence()
    assert np.all(np.isfinite(matches))
    edge = np.linalg.norm(v[f[0, 1]] - v[f[0, 0]])
    error = np.linalg.norm(matches - (2.5 * v @ rotation.T + 1.0), axis=1) / 2.5
    assert error[disk.ear_feet.ids].max() < 1.2 * edge and np.median(error) < 0.01 * edge  # at its foot: 0.85-0.95 edge


def test_removed_ears_apexes_inside_a_partial_overlap_are_matched():
    # review 2026-12-01: the trimmed disk of a partial overlap dropped the ear feet, so apexes inside the overlap
    # came back NaN
    v, f = _lattice_triangle(24)
    v[:, 2] = 0.25 * np.exp(-((v[:, 0] - 0.2) ** 2 + (v[:, 1] + 0.3) ** 2) / 0.1) + 0.1 * np.sin(2 * v[:, 0] + v[:, 1])
    apexes = prepare_disk(v, f).ear_feet.ids
    below = v[f].max(axis=1)[:, 1] < 0.2  # the second: the sheet below y = 0.2, without the top apex
    rotation = Rotation.from_euler("xyz", [35, -50, 120], degrees=True).as_matrix()
    result = meshreg.register((v, f), (v @ rotation.T + 1.0, f[below]), resolution=41)
    assert result.info["overlap"]["regime"] == "rigid"
    inside = v[apexes, 1] < 0
    assert inside.sum() == 2 and np.all(np.isfinite(result.correspondence()[apexes[inside]]))


def _slit_grid(n: int = 12):
    """A grid sheet (v, f) of n x n cells, the same with a seam cut from its rim to below the centre (vertices
    duplicated along the cut: (vertices, faces)), and a mask of the faces without one cell (a hole)."""
    x, y = np.meshgrid(np.linspace(-1, 1, n + 1), np.linspace(-1, 1, n + 1), indexing="ij")
    v = np.c_[x.ravel(), y.ravel(), 0.3 * np.sin(2 * x.ravel() + y.ravel())]
    ids = np.arange(len(v)).reshape(n + 1, n + 1)
    a, b, c, d = ids[:-1, :-1].ravel(), ids[1:, :-1].ravel(), ids[1:, 1:].ravel(), ids[:-1, 1:].ravel()
    f = np.r_[np.c_[a, b, c], np.c_[a, c, d]]
    on = np.flatnonzero((np.abs(v[:, 0]) < 1e-9) & (v[:, 1] < -1e-9))  # from the rim y = -1 to below the centre
    copy = np.arange(len(v))
    copy[on] = len(v) + np.arange(len(on))
    right = (v[f].mean(axis=1)[:, 0] > 0) & (v[f].mean(axis=1)[:, 1] < 0)
    holed = np.ones(len(f), dtype=bool)
    holed[[8 * n + 8, 8 * n + 8 + n * n]] = False  # the two triangles of one cell
    return (v, f), (np.vstack([v, v[on]]), np.where(right[:, None], copy[f], f)), holed


def test_seam_slit_in_one_piece_is_welded():
    # an exporter's seam cut into a grid sheet from its rim (one piece, duplicated vertices along the cut): held out
    # 2026-12-01, it was registered as a slit disk, 132 degrees off with points 37% of the size wrong
    (v, f), (seamed, slit), holed = _slit_grid()
    disk = prepare_disk(seamed, slit)
    assert any("welded 6 coincident vertices (a seam" in line for line in disk.report)
    assert len(disk.boundary) == len(prepare_disk(v, f).boundary) == 4 * 12
    disk = prepare_disk(seamed, slit[holed])  # and a hole elsewhere
    assert any("welded 6 coincident vertices (a seam" in line for line in disk.report)
    assert any("filled 1 hole" in line for line in disk.report) and len(disk.boundary) == 4 * 12


def _slit_sheet():
    """The slit grid sheet of :func:`_slit_grid` with its hole: a seam to weld and a hole to fill."""
    _, (seamed, slit), holed = _slit_grid()
    return seamed, slit[holed]


@pytest.mark.parametrize("make", [_slit_sheet, lambda: _lattice_triangle(10), lambda: random_disk_mesh(bump(), 400, 5)])
def test_large_meshes_cleaned_in_space_order_give_the_same_disk(make, monkeypatch):
    """Meshes of SPACE_ORDER_MIN vertices or more are renumbered along a Morton curve before the cleanup (for the
    caches): the disk, its map to the square and its references to the input are the same in the input's ids."""
    from meshreg.mesh import topology

    v, f = make()[:2]
    plain = prepare_disk(v, f)
    monkeypatch.setattr(topology, "SPACE_ORDER_MIN", 10)
    ordered = prepare_disk(v, f)
    assert not np.array_equal(ordered.vertex_map, plain.vertex_map) and ordered.report == plain.report

    def in_input_ids(disk):
        ids = np.r_[disk.vertex_map, -1 - np.arange(len(disk.vertices) - len(disk.vertex_map))]  # hole centres < 0
        loop = ids[disk.boundary]
        start = int(np.argmin(loop))
        return {tuple(np.roll(t, -int(np.argmin(t)))) for t in ids[disk.faces]}, np.roll(loop, -start), ids

    faces, loop, ids = in_input_ids(ordered)
    expected_faces, expected_loop, expected_ids = in_input_ids(plain)
    assert faces == expected_faces and np.array_equal(loop, expected_loop)  # the same triangles, wound alike
    assert np.array_equal(ordered.input_ids(ids[ids >= 0]), np.flatnonzero(ids >= 0))
    back = [d.to_input(d.vertices, len(v), [np.nan] * 3) for d in (ordered, plain)]
    assert np.array_equal(back[0], back[1], equal_nan=True)
    feet = [() if d.ear_feet is None else tuple(np.sort(d.ear_feet.ids)) for d in (ordered, plain)]
    assert feet[0] == feet[1]
    corners = plain.vertex_map[plain.boundary[[0, 3, 6, 9]]]
    uv = [parametrize(d, corners=d.input_ids(corners))[0] for d in (ordered, plain)]
    position = {i: k for k, i in enumerate(expected_ids)}
    assert np.allclose(uv[0], uv[1][[position[i] for i in ids]], atol=1e-12)


def _ellipse_sheet(n_points, seed, rotation=None, scale=1.0):
    """A bent sheet (x, 0.6 sin 2x + 0.1 y^2, y) over a 1.5 x 0.7 ellipse: a random Delaunay mesh with a round
    boundary, nearly symmetric under a half turn (exactly so without the y^2 term)."""
    rng = np.random.default_rng(seed)
    a = np.sort(rng.random(60)) * 2 * np.pi
    r, th = np.sqrt(rng.random(n_points)) * 0.97, rng.random(n_points) * 2 * np.pi
    xy = np.vstack([np.c_[np.cos(a), np.sin(a)], np.c_[r * np.cos(th), r * np.sin(th)]]) * [1.5, 0.7]
    v = np.c_[xy[:, 0], 0.6 * np.sin(2 * xy[:, 0]) + 0.1 * xy[:, 1] ** 2, xy[:, 1]]
    if rotation is not None:
        v = v @ rotation.T
    return scale * v + rng.normal(size=3), Delaunay(xy).simplices


@pytest.mark.slow
def test_nearly_symmetric_sheet_is_not_matched_with_its_mirror_image():
    """The sheet is nearly point-symmetric. Minimizing E (bend_window=0): its best coarse start matches the mirror
    image of the copy (registered, it gave E = 0.014 at a half turn from the true rotation, before starts were
    judged by their residual). Now that start is dropped and the best-ranked one is right: the true rotation at a
    third of that E, with one start registered as with three. The default path ranks the symmetries by E_w, which
    puts the right one first: true rotation within 0.5 degrees (one rigid surface: snapped to closest points, E at
    the snapped answer 0.0165, the descent's own minimum 0.0084)."""
    rot = Rotation.random(random_state=7).as_matrix()
    first, second = _ellipse_sheet(3000, 17), _ellipse_sheet(5000, 27, rotation=rot, scale=1.7)
    default = register_meshes(first, second, Options(resolution=61))
    assert default.result.energy < 0.02 and angle_between(default.result.rotation, rot) < 0.5
    mr = register_meshes(first, second, Options(resolution=61, bend_window=0.0))
    assert mr.result.energy < 0.006
    assert angle_between(mr.result.rotation, rot) < 2.0 and not mr.result.mirrored
    chosen = next(s for s in mr.result.params["starts"] if s["chosen"])
    assert mr.result.params["mirror"]["coarse_energy"] < chosen["coarse_energy"]
    only_best = register_meshes(first, second, Options(resolution=61, max_starts=1, bend_window=0.0))
    assert only_best.result.energy == pytest.approx(mr.result.energy, rel=1e-6)


def test_rendered_mesh_shows_the_nearest_triangle_where_it_covers_the_image():
    """Two squares seen from above (z towards the viewer), the red one nearer and covering the left half of the
    blue one: the image is red where it is, blue on the rest of the blue square, white around; the blue square
    alone, same picture size, fills the image but the margin."""
    from meshreg.viz import RENDER_MARGIN, render_mesh

    square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    half = np.array([[0.0, 0.0], [0.5, 0.0], [0.5, 1.0], [0.0, 1.0]])
    points = np.r_[np.c_[square, np.zeros(4)], np.c_[half, np.ones(4)]]
    faces = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]])
    colors = np.array([[0.0, 0.0, 1.0]] * 2 + [[1.0, 0.0, 0.0]] * 2)
    image = render_mesh(points, faces, colors, 100, 100)
    blue, red, white = (np.all(image == c, axis=2) for c in ([0, 0, 1], [1, 0, 0], [1, 1, 1]))
    assert np.all(blue | red | white)
    inner = slice(5, 95)
    assert red[inner, 5:49].all() and blue[inner, 51:95].all() and not red[:, 51:].any()
    assert white[:2].all() and white[:, :2].all() and white[-2:].all() and white[:, -2:].all()
    alone = render_mesh(points[:4], faces[:2], colors[:2], 100, 100)
    assert np.all(alone[inner, inner] == [0, 0, 1])
    covered = np.all(alone == [0, 0, 1], axis=2).mean()
    assert covered == pytest.approx((1 - 2 * RENDER_MARGIN) ** 2, abs=0.03)
    assert np.all(render_mesh(points, np.zeros((0, 3), int), np.zeros((0, 3)), 10, 10) == 1.0)  # nothing: white


def test_mesh_figure_puts_each_panel_in_its_place(tmp_path):
    """meshes.png of a red first and a blue second square, distances 0: the first third of the picture holds red
    pixels and no blue, the second blue and no red, the third viridis's darkest colour (distance 0)."""
    from PIL import Image

    from meshreg.viz import MESH_DPI, plot_meshes

    points = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]])
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    red, blue = np.tile([1.0, 0.0, 0.0], (4, 1)), np.tile([0.0, 0.0, 1.0], (4, 1))
    plot_meshes(tmp_path / "m.png", points, faces, red, points, faces, blue, distance=np.zeros(4))
    image = np.asarray(Image.open(tmp_path / "m.png").convert("RGB")).astype(int)
    assert image.shape == (round(5.2 * MESH_DPI), round(3 * 5.5 * MESH_DPI), 3)
    r, g, b = image[..., 0], image[..., 1], image[..., 2]
    reddish, bluish = (r > g + 60) & (r > b + 60), (b > g + 60) & (b > r + 60)
    one, two = (round(x * image.shape[1]) for x in (0.315, 0.625))  # between the panels (0.31-0.32, 0.62-0.63)
    assert reddish[:, :one].sum() > 10000 and not bluish[:, :one].any()
    assert bluish[:, one:two].sum() > 10000 and not reddish[:, one:two].any()
    dark_purple = (b > r) & (r > g + 30) & (b < 100)  # viridis(0) = (68, 1, 84), lit by 0.45-1
    assert dark_purple[:, two:].sum() > 10000


def test_colour_bar_labels_keep_ticks_apart_and_small_ones_get_a_power_of_ten():
    from meshreg.viz import _tick_labels

    assert _tick_labels(np.array([0.0, 0.002, 0.004])) == (["0.000", "0.002", "0.004"], "")
    assert _tick_labels(np.array([0.0, 0.5, 1.0])) == (["0.0", "0.5", "1.0"], "")
    assert _tick_labels(np.array([0.0, 2.5e-5, 5e-5, 1.25e-4])) == (["0.00", "0.25", "0.50", "1.25"], " (x 1e-04)")
    assert _tick_labels(np.array([0.0])) == (["0"], "")


def test_inverse_of_a_warp_of_the_square_carries_its_images_back():
    from meshreg.correspondence import h_at, inverse_uv

    r, t = np.linspace(0, 1, 41), np.linspace(0, 1, 31)
    u, v = np.meshgrid(r, t, indexing="ij")
    h = np.stack([u + 0.08 * np.sin(np.pi * u) * np.sin(2 * np.pi * v), v + 0.05 * np.sin(np.pi * v) * u], -1)
    places = np.random.default_rng(1).random((2000, 2))
    images = h_at(h, r, t, places)
    back = inverse_uv(h, r, t, np.vstack([images, [[np.nan, np.nan]], [[0.0, 1.0]]]))
    assert np.abs(back[:-2] - places).max() < 2e-3  # linear between nodes 1/40 apart: second order in the spacing
    assert np.isnan(back[-2]).all()
    assert np.allclose(back[-1], [0.0, 1.0])
    shrunk = 0.1 + 0.8 * np.stack([u, v], -1)  # h's images cover [0.1, 0.9]^2 only: the rest goes to the nearest node
    outside = inverse_uv(shrunk, r, t, np.array([[0.02, 0.5], [0.95, 0.97]]))
    assert np.allclose(outside, [[0.0, 0.5], [1.0, 1.0]])
