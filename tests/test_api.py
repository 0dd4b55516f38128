"""One register for every surface, and a result a user can use: correspondence, vertex pairs, transform, errors."""

import numpy as np
import pytest
import trimesh
from scipy.interpolate import LinearNDInterpolator
from scipy.spatial.transform import Rotation

import meshreg
from meshreg.errors import InputError
from meshreg.mesh.samples import random_disk_mesh
from meshreg.rotation import angle_between
from meshreg.samples import bump, paper_pairs

ROT = Rotation.from_euler("xyz", [20, -35, 60], degrees=True).as_matrix()
SCALE = 1.7


@pytest.fixture(scope="module")
def pair():
    """One bump sheet meshed twice (1500 and 2500 random points), the second rotated, scaled and shifted; each
    vertex's parameter on the sheet says which points correspond."""
    return random_disk_mesh(bump(), 1500, seed=11), random_disk_mesh(bump(), 2500, seed=12, rotation=ROT, scale=SCALE)


@pytest.fixture(scope="module")
def result(pair):
    (v1, f1, _), (v2, f2, _) = pair
    return meshreg.register((v1, f1), (v2, f2), resolution=41)


def _truth(pair, ids=None):
    """The true partner on the second mesh of first-mesh vertices: the second at the same sheet parameter."""
    (_, _, p1), (v2, _, p2) = pair
    return LinearNDInterpolator(p2, v2)(p1 if ids is None else p1[ids])


def test_every_form_of_a_mesh_gives_the_same_registration(pair, result, tmp_path):
    (v1, f1, _), (v2, f2, _) = pair
    trimesh.Trimesh(v1, f1, process=False).export(tmp_path / "a.ply")
    trimesh.Trimesh(v2, f2, process=False).export(tmp_path / "b.obj")
    from_files = meshreg.register(str(tmp_path / "a.ply"), tmp_path / "b.obj", resolution=41)
    from_trimesh = meshreg.register(
        trimesh.Trimesh(v1, f1, process=False), trimesh.Trimesh(v2, f2, process=False), resolution=41
    )
    # files round the coordinates: a PLY from trimesh holds float32 (1.2e-7 here), which moved E by 1.7e-4 (2026-12-02)
    assert from_files.energy == pytest.approx(result.energy, rel=1e-3)
    assert from_trimesh.energy == result.energy and np.array_equal(from_trimesh.h, result.h)


def test_open3d_meshes_are_taken_too(pair, result):
    o3d = pytest.importorskip("open3d")
    (v1, f1, _), (v2, f2, _) = pair
    meshes = [
        o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(v), o3d.utility.Vector3iVector(f.astype(np.int32)))
        for v, f in ((v1, f1), (v2, f2))
    ]
    assert meshreg.register(*meshes, resolution=41).energy == result.energy


def test_the_transform_and_the_correspondence_are_the_true_ones(pair, result):
    (v1, _, _), _ = pair
    assert result.energy < 0.002
    assert angle_between(result.rotation, ROT) < 1.5 and result.scale == pytest.approx(SCALE, rel=0.005)
    size = np.sqrt(result.second.area())
    error = np.linalg.norm(result.correspondence() - _truth(pair), axis=1) / size
    assert np.nanmedian(error) < 0.006  # matched points lie on the true partners, to 0.6% of the sheet's size
    assert result.correspondence().shape == (len(v1), 3)
    moved = result.aligned(v1)
    assert np.nanmedian(np.linalg.norm(moved - _truth(pair), axis=1)) / size < 0.01  # transform: first -> second


def test_correspondence_by_ids_by_points_and_barycentric(pair, result):
    (v1, _, _), (v2, f2, _) = pair
    ids = np.array([3, 50, 400])
    by_ids = result.correspondence(ids)
    assert np.allclose(by_ids, result.correspondence()[ids], equal_nan=True)
    by_points = result.correspondence(v1[ids] + 0.0)  # points on the first surface give the same matches
    assert np.allclose(by_points, by_ids, atol=1e-6 * np.ptp(v2))
    points, corner_ids, weights = result.correspondence(ids, barycentric=True)
    ok = np.all(corner_ids >= 0, axis=1)
    assert ok.any() and np.allclose(weights.sum(axis=1), 1.0) and np.all(weights > -1e-6)
    assert np.allclose(
        np.einsum("kc,kcx->kx", weights[ok], v2[corner_ids[ok]]), points[ok]
    )  # on the second's triangles
    with pytest.raises(InputError, match="vertex ids"):
        result.correspondence([len(v1)])
    # integer coordinates are points too (held out 2026-12-01: refused as "vertex ids (k,) or points (k, 3)")
    corner = np.round(v1[ids[:1]]).astype(np.int64)
    assert np.allclose(result.correspondence(corner), result.correspondence(corner.astype(float)))
    with pytest.raises(InputError, match="finite points"):  # held out 2026-12-02: scipy's KD-tree error before
        result.correspondence(np.array([[np.nan, 0.0, 0.0]]))


def test_vertex_pairs_distances_fitness_and_inlier_rmse(pair, result):
    (v1, _, p1), (v2, _, p2) = pair
    pairs = result.vertex_pairs()
    assert pairs.shape[1] == 2 and len(pairs) >= 0.98 * len(v1)
    spacing = np.sqrt(result.second.area() / len(v2))
    truth = _truth(pair, pairs[:, 0])
    assert np.nanmedian(np.linalg.norm(v2[pairs[:, 1]] - truth, axis=1)) < 2 * spacing  # the nearest vertex
    d = result.distances()
    assert d.shape == (len(v1),) and np.nanmedian(d) / np.sqrt(result.second.area()) < 0.006
    assert 0.85 < result.fitness() <= 1.0 and result.inlier_rmse() <= result.inlier_threshold()
    assert result.fitness(threshold=0.0) < 0.05 and np.isnan(result.inlier_rmse(threshold=-1.0))


def test_save_and_load_keep_the_correspondence(result, tmp_path):
    result.save(tmp_path / "r.npz")
    back = meshreg.Registration.load(tmp_path / "r.npz")
    assert np.array_equal(back.transform, result.transform)
    assert np.allclose(back.correspondence(), result.correspondence(), equal_nan=True)
    assert back.info == result.info and back.info["first"]["cleanup"] == result.info["first"]["cleanup"]


def test_a_result_without_surfaces_says_so_from_every_correspondence_method(result):
    from dataclasses import replace

    bare = replace(result, first=None, second=None)
    calls = [
        bare.correspondence,
        lambda: bare.correspondence([0]),
        bare.correspondence_on_first,
        bare.vertex_pairs,
        bare.distances,
        bare.fitness,
        bare.inlier_rmse,
    ]
    for call in calls:
        with pytest.raises(InputError, match="no surfaces attached"):
            call()


def test_grids_have_the_same_api():
    pair = paper_pairs(21, 21)[6]  # helicoid against P times itself, reparametrized
    result = meshreg.register(pair.first, pair.second, mode="dp+gd")
    truth = pair.second.scaled().points  # not used for values: shapes only
    assert result.correspondence().shape == (21 * 21, 3) == truth.reshape(-1, 3).shape
    assert result.fitness() > 0.99 and result.scale == pytest.approx(1.0, rel=1e-3)
    assert np.nanmax(result.distances()) < 0.01 * np.sqrt(result.second.area())


def test_bad_surfaces_are_refused_with_what_is_accepted(pair):
    (v1, f1, _), _ = pair
    grid = paper_pairs(11, 11)[0].first
    with pytest.raises(InputError, match="two meshes or two grids"):
        meshreg.register((v1, f1), grid)
    with pytest.raises(InputError, match="cannot register a dict"):
        meshreg.register({}, grid)
    with pytest.raises(InputError, match="integer"):
        meshreg.register((v1, f1.astype(float)), (v1, f1))
    ragged = [list(v1[0]), list(v1[1]), list(v1[2, :2])]  # a row of 2 numbers: numpy refuses the nested list
    with pytest.raises(InputError, match=r"first: the vertices are not an \(n, 3\) table"):
        meshreg.register((ragged, [[0, 1, 2]]), (v1, f1))
    with pytest.raises(InputError, match=r"the faces are not an \(n, 3\) table"):
        meshreg.register((v1, [[0, 1, 2], [0, 1]]), (v1, f1))
