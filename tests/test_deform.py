"""The generators of pairs with a known material map (meshreg.mesh.deform) are right: checked against geometry, not
against themselves."""

import numpy as np
import pytest
from scipy.spatial import Delaunay

from meshreg.errors import InputError
from meshreg.mesh import deform, plane
from meshreg.mesh.topology import triangle_areas


def flat(u, v):
    return np.c_[u, v, 0 * u]


def similarity_fit(moving, fixed):
    """Least-squares s, R, b with s R moving + b ~ fixed, and the largest residual."""
    m0, f0 = moving - moving.mean(axis=0), fixed - fixed.mean(axis=0)
    u, sv, vt = np.linalg.svd(m0.T @ f0)
    d = np.diag([1, 1, np.sign(np.linalg.det(u @ vt))])
    rotation = (u @ d @ vt).T
    scale = np.sum(sv * np.diag(d)) / np.sum(m0 * m0)
    residual = np.linalg.norm(scale * m0 @ rotation.T - f0, axis=1)
    return scale, rotation, residual.max()


def test_locate_agrees_with_delaunay_barycentrics():
    rng = np.random.default_rng(0)
    pts = rng.random((300, 2))
    tri = Delaunay(pts)
    q = 0.05 + 0.9 * rng.random((500, 2))
    face, bary, inside = plane.locate(pts, tri.simplices, q)
    hull = tri.find_simplex(q) >= 0
    assert np.all(inside == hull) and 0 < np.sum(~hull) < 10
    assert np.allclose(plane.interpolate(pts, tri.simplices, face, bary)[hull], q[hull])
    assert np.all(face[hull] == tri.find_simplex(q[hull]))
    _, bary, inside = plane.locate(pts, tri.simplices, np.array([[2.0, 2.0]]))
    assert not inside[0] and np.all(bary >= 0) and np.isclose(bary.sum(), 1)


def test_remeshed_truth_is_the_second_moved_back_by_the_known_similarity():
    pair = deform.remeshed_pair(n_first=400, n_second=600)
    assert np.isfinite(pair.truth).all() and pair.covered.all() and pair.overlap > 0.999
    scale, rotation, residual = similarity_fit(pair.second[0], pair.truth)
    assert residual < 1e-9 * pair.unit
    assert np.isclose(scale, 1 / 2.5)
    assert np.allclose(rotation, deform.SECOND_ROTATION.T, atol=1e-9)
    # the truth lies on the first mesh: inside its triangles in material coordinates, on the relief
    assert np.allclose(pair.errors(pair.truth), 0)
    assert np.isclose(pair.unit**2, triangle_areas(*pair.first).sum())


def test_bend_of_a_flat_sheet_keeps_lengths_and_reaches_the_angle():
    pair = deform.bent_pair("bend", 72.0, surface=flat, n_first=300, n_second=1500, scale=1.0, rotation=None)
    assert pair.info["edge_ratio"] < 1.005  # edges (up to 0.2 long on the border) become chords: 1 - L^2 / (24 R^2)
    p = np.array([[0.0, 0.5, 0.0], [1.0, 0.5, 0.0], [0.5, 0.5, 0.0]])
    b = deform.bend(p, np.radians(72.0))
    radius = 1 / np.radians(72.0)
    assert np.isclose(np.linalg.norm(b[1] - b[0]), 2 * radius * np.sin(np.radians(36.0)))  # chord of the arc
    assert np.isclose(np.linalg.norm(b[2] - [0.0, 0.5, radius]), radius)  # on the cylinder
    # a fold: the part beyond the band is moved rigidly
    q = np.array([[0.7, 0.1, 0.02], [0.9, 0.4, -0.03], [0.95, 0.8, 0.0]])
    f = deform.bend(q, np.pi / 2, start=0.45, width=0.1)
    assert np.allclose(np.linalg.norm(f[:, None] - f[None], axis=-1), np.linalg.norm(q[:, None] - q[None], axis=-1))


def test_stretch_is_the_known_non_isometric_map():
    pair = deform.stretched_pair(a=0.5, surface=flat, n_first=200, n_second=800, scale=1.0, rotation=None)
    assert 1.8 < pair.info["edge_ratio"] <= 2.0  # local stretch 1 + 2 a x along x
    x = np.array([[0.0, 0, 0], [0.5, 0, 0], [1.0, 0, 0]])
    assert np.allclose(deform.stretch(x, 0.5)[:, 0], [0.0, 0.625, 1.5])


@pytest.mark.parametrize(
    "region, fraction",
    [
        (deform.centred_region(0.9), 0.9),
        (deform.centred_region(0.81), 0.81),
        ((0, 0.8, 0, 0.8), 0.64),
        ((0, 1, 0.2, 0.8), 0.6),
    ],
)
def test_partial_overlap_covers_what_was_asked(region, fraction):
    pair = deform.partial_pair("p", region, surface=flat, n_first=1500, n_second=600)
    assert abs(pair.overlap - fraction) < 0.03
    assert pair.same_scale and np.isclose(pair.unit**2, fraction, rtol=1e-6)
    u0, u1, v0, v1 = region
    p = pair.first_params
    inside = (p[:, 0] > u0 + 1e-6) & (p[:, 0] < u1 - 1e-6) & (p[:, 1] > v0 + 1e-6) & (p[:, 1] < v1 - 1e-6)
    assert np.all(pair.covered[inside])
    assert not np.any(pair.covered[(p[:, 0] < u0 - 0.05) | (p[:, 0] > u1 + 0.05)])
    scale, _, residual = similarity_fit(pair.second[0], pair.truth)  # same scale, rigid motion
    assert np.isclose(scale, 1.0) and residual < 1e-9


def test_errors_count_missing_predictions_and_check_shapes():
    pair = deform.remeshed_pair(n_first=200, n_second=300)
    predicted = pair.truth.copy()
    predicted[:3] = np.nan
    err = pair.errors(predicted)
    assert np.sum(np.isinf(err)) == 3 and np.all(err[np.isfinite(err)] == 0)
    with pytest.raises(InputError, match="shape"):
        pair.errors(pair.truth[:-1])
    with pytest.raises(InputError, match="region"):
        deform.partial_pair("p", (0.5, 0.2, 0, 1))
    with pytest.raises(InputError, match="angle"):
        deform.bend(np.zeros((1, 3)), 0.0)


@pytest.mark.slow
def test_scan_crops_offset_and_bent():
    pytest.importorskip("pymeshlab")
    pair = deform.scan_pair("crops", radius=30.0, offset=6.0, n_second=1500)
    known = np.isfinite(pair.truth[:, 0])
    assert 0.7 < pair.overlap < 0.9 and 0.7 < known.mean() < 0.95
    scale, _, residual = similarity_fit(pair.second[0][known], pair.truth[known])
    assert np.isclose(scale, 1.0) and residual < 1e-6 * pair.unit  # exactly the scan, moved rigidly
    bent = deform.scan_pair("bent", radius=30.0, bend_angle=72.0, n_second=1500)
    assert 1.05 < bent.info["edge_ratio"] < 2.0  # relief over the cylinder is stretched, as documented
    on = np.isfinite(bent.truth[:, 0])
    assert similarity_fit(bent.second[0][on], bent.truth[on])[2] > 0.05 * bent.unit  # not a rigid motion
