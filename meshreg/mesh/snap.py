"""Snap the answer for one rigid surface to closest points: when two meshes are one surface moved rigidly (and scaled),
the registration's similarity is refined by point-to-plane ICP on the triangles, and each node of the first grid is
matched with its closest point on the second mesh in that pose.

The elastic answer h of such a pair is limited by what the grids resolve (the benchmark's remeshed sheet: 0.0014 of
sqrt(area) off, against 0.0001 for Open3D's nearest points; pymeshlab's face scan against a remeshed copy: 0.15%);
the rigid overlap path (:mod:`meshreg.mesh.partial`) already matches crops this way to below 5e-5. Here the same is
done for a pair registered whole in mode "auto" when the ICP pose (a similarity: point-to-plane with a scale, from
``result.transform``) makes the meshes coincide, RMS at most SNAP_TIGHT edge lengths or, for noisy meshes, a residual
that averages out over neighbourhoods (a bent pair does not: it is left as registered); the snapped h is kept only
if its coordinate residual is lower and the refined pose moved the points by no more than the answer's residual (ICP
slides along what pins a surface weakly).
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np
from scipy.spatial import cKDTree

from ..objective import Objective
from ..result import with_stage
from .align import Cloud, icp
from .surface import Surface, transform_points

SNAP_TIGHT = 0.05  # the refined pose must bring the meshes within this RMS (edge lengths): the same surface
SNAP_ITERATIONS = 30  # ICP iterations on the triangles (exact closest points), as the rigid overlap path
# ICP runs on at most this many of the second's vertices (seeded): on two 100k-triangle meshes all 50,000 took 5.6 s,
# 4000 0.25 s and 2000 0.17 s for the whole snap
SNAP_POINTS = 2000
# the refined pose's scale must stay within this fraction of the registration's (one rigid surface: the registration's
# scale is right within 0.2% on the benchmark pairs, but 2-5% off with vertex noise of 0.5% of the size on one mesh,
# whose roughness adds area: two of 12 such sheets were refused at 2%, 0.016-0.017 off, snapped 0.004; a collapsing
# ICP moves the scale by orders of magnitude)
SNAP_SCALE = 0.05
# a pair above SNAP_TIGHT is still one surface when its residual is incoherent noise: ICP RMS at most SNAP_NOISY edge
# lengths and the signed residual averaged over each sample's SNAP_NEIGHBOURS nearest samples at most SNAP_TIGHT and
# at most SNAP_INCOHERENT of the RMS. Measured on 12 remeshed relief sheets (/tmp/co/msweep_noise.py) with vertex noise
# 0.003 / 0.005 on the first (or 0.003 on both): RMS 0.065-0.1 / 0.065-0.13 (0.07-0.18) edge lengths, averaged 0.14-0.27
# of it; rolled (3-30 degrees) and folded sheets: averaged 0.83-1.0 of their RMS (0.06-1.2), with noise 0.003 0.55-1.0
# (a bend's residual does not average out); a noisy sheet registered at the wrong symmetry: 0.77 of 0.21
SNAP_NOISY = 0.3
SNAP_NEIGHBOURS = 64
SNAP_INCOHERENT = 0.4
# the snap of the parametrizations' own correspondence (an unbent pair before any descent: meshreg.bending's settle) may
# move the points by this many times its residual: on seven rigid pairs (remeshed terrains of 2k-100k vertices,
# asymmetric bumps, a four-fold relief with one small feature) the refined pose moved them by 0.61-1.16 times it, and
# snapped to the same answer as from the descent's; a nearly flat sheet, along which ICP slides, by 39 times
SETTLE_SLACK = 2.0
# ... and only when the surface pins the pose (:func:`pose_pinning` at least this): a review found cylinder patches
# and sphere caps with one bump 1% high, along which ICP slides, moved by 1.4-1.7 times the start's residual and
# snapped there 2.8-4.4 times further from the truth than the descent's answer. Measured pinning: remeshed terrains
# 0.028-0.029, asymmetric bumps 0.010-0.012, a four-fold relief 0.077; a saddle of relief 0.125 0.0002-0.0003,
# those cylinders 0.0002, spheres 0.0001, plain cylinder and sphere patches 0.00003-0.00016, a flat sheet 0
SETTLE_PINNING = 0.003


def snap_rigid(
    mr, registered: tuple, tried: bool = True, surfaces: tuple | None = None, slack: float = 1.0, pinning: float = 0.0
):
    """``mr`` (a :class:`~meshreg.mesh.correspond.MeshRegistration` of two meshes registered whole; ``mr.grids``
    the grids as resampled) with h, R, E, the residual and the transform from closest points at the ICP-refined
    pose, when ``tried`` (mode "auto") and the pair is one rigid surface (see the module); else ``mr`` itself.
    E and the residual are measured on ``registered`` (the grids the registration used, blurred or not) at the
    snapped h and the pose's rotation. ``result.params["snapped"]`` says which; ``timings["snap"]`` (in ``total``)
    is the time spent trying. ``surfaces``: the two disks' :class:`~meshreg.mesh.surface.Surface` objects, unposed, when
    already built (by the overlap check: their KD-trees are kept); else built here. ``slack``: how many times the
    answer's residual the refined pose may move the points (1 for a registration's answer; SETTLE_SLACK for the
    parametrizations' own correspondence, which no descent has fitted); ``pinning``: the least :func:`pose_pinning`
    of the refined pose's sample (0: not checked; SETTLE_PINNING for that correspondence)."""
    result, start_time = mr.result, time.perf_counter()
    if not (tried and np.isfinite(result.residual)):
        return _marked(mr, False)
    if surfaces is None or None in surfaces:
        surfaces = [Surface(d.vertices, d.faces) for d in (mr.first, mr.second)]
    first, second = surfaces
    start = np.linalg.inv(result.transform)  # the second into the first's frame
    sample = _vertex_sample(second)
    pose, rms = icp(sample, first, start, iterations=SNAP_ITERATIONS, exact=True, scaled=True)
    scale = float(np.cbrt(np.linalg.det(pose[:3, :3])))
    edge = max(first.edge, scale * second.edge)
    moved = sample.moved(pose)
    pinned = not pinning or pose_pinning(moved) >= pinning
    if not (_kept_scale(scale, start) and _coincide(moved, first, rms, edge) and pinned):
        return _marked(mr, False, time.perf_counter() - start_time)
    nodes, placed = mr.grids[0].points, second.moved(pose)
    _, _, triangle, weights = placed.project(nodes.reshape(-1, 3))
    h = second.at(mr.uv2, triangle, weights).reshape(*nodes.shape[:2], 2)
    transform = np.linalg.inv(pose)
    rotation = transform[:3, :3] * scale  # pose = scale R: its inverse is R^T / scale
    energy, residual = Objective(*registered).evaluate(rotation, h)
    shift = _rms_distance(transform_points(start, second.vertices), placed.vertices)
    if not (residual.plus < result.residual and shift <= slack * result.residual * np.sqrt(first.area)):
        return _marked(mr, False, time.perf_counter() - start_time)
    seconds = time.perf_counter() - start_time
    snapped = replace(
        result,
        h=h,
        rotation=rotation,
        energy=float(energy),
        residual=residual.plus,
        residual_mirrored=residual.minus,
        transform=transform,
        params={**result.params, "snapped": True, "snap_rms": rms, "energy_before_snap": result.energy},
        timings=with_stage(result.timings, "snap", seconds),
    )
    return replace(mr, result=snapped)


def _kept_scale(scale: float, start: np.ndarray) -> bool:
    """Whether the ICP pose's ``scale`` (signed: negative for a reflection) is within SNAP_SCALE of the start
    pose's (4, 4). Point-to-plane ICP with a scale can shrink a surface that does not fit towards a point, which
    lies on any plane: a sheet rolled half a turn was snapped with RMS 1.7e-8 at a scale of -1.2e-7 (its points
    0.42 of the size off)."""
    before = float(np.cbrt(np.linalg.det(start[:3, :3])))
    return before > 0 and scale > 0 and abs(scale / before - 1.0) <= SNAP_SCALE


def _coincide(points: Cloud, first: Surface, rms: float, edge: float) -> bool:
    """Whether the second's sample ``points`` (moved onto the first by the ICP pose, whose RMS is ``rms``) and the
    ``first`` surface coincide: RMS at most SNAP_TIGHT ``edge`` lengths, or at most SNAP_NOISY with the residual's
    coherent part (:func:`_coherent_rms`) at most SNAP_TIGHT edge lengths and SNAP_INCOHERENT of the RMS. Vertex
    noise leaves an RMS about its own size (0.1 edge lengths for noise of 0.3% of the size) that mostly averages out
    over a neighbourhood; a bend leaves a residual that does not (a sheet rolled by 3 degrees: RMS 0.06 edge
    lengths, averaged 0.05)."""
    if rms <= SNAP_TIGHT * edge:
        return True
    if rms > SNAP_NOISY * edge:
        return False
    return bool(_coherent_rms(points, first) <= min(SNAP_TIGHT * edge, SNAP_INCOHERENT * rms))


def _coherent_rms(points: Cloud, first: Surface) -> float:
    """RMS over the ``points`` of their signed distance to the ``first`` surface averaged over each one's
    SNAP_NEIGHBOURS nearest points (those whose closest point is on the first's rim left out): the residual's
    large-scale part, which noise of the vertices does not leave."""
    closest, _, normal = first.closest(points.points)
    inside = first.rim_distance(closest) >= 1e-9 * first.edge
    if inside.sum() <= SNAP_NEIGHBOURS:
        return np.inf
    signed = np.sum((points.points - closest) * normal, axis=1)[inside]
    _, near = cKDTree(points.points[inside]).query(points.points[inside], k=SNAP_NEIGHBOURS)
    return float(np.sqrt(np.mean(np.mean(signed[near], axis=1) ** 2)))


def pose_pinning(points: Cloud) -> float:
    """How firmly points on a surface (with their normals) pin a rigid motion against point-to-plane ICP: the
    smallest eigenvalue of the mean of r r^T over the points, r = ((x - c) x n / rho, n), the point-to-plane rows of a
    rotation (scaled by the points' RMS radius rho about their centroid c) and a shift. Between 0 (a plane, a cylinder
    or a sphere: some motion keeps every point on the surface) and 0.5; the least-pinned motion moves the points by
    about the distance error it causes divided by its square root."""
    centred = points.points - points.points.mean(axis=0)
    radius = max(float(np.sqrt(np.mean(np.sum(centred**2, axis=1)))), 1e-300)
    rows = np.hstack([np.cross(centred, points.normals) / radius, points.normals])
    return float(np.linalg.eigvalsh(rows.T @ rows / len(rows))[0])


def _vertex_sample(surface: Surface) -> Cloud:
    """At most SNAP_POINTS of the surface's vertices (a seeded random choice) with their normals: points on the
    surface itself (voxel centroids of a curved mesh lie off it by more than the snap's tolerance)."""
    count = len(surface.vertices)
    chosen = np.random.default_rng(0).choice(count, SNAP_POINTS, replace=False) if count > SNAP_POINTS else slice(None)
    return Cloud(surface.vertices[chosen], surface.normals[chosen])


def _rms_distance(before: np.ndarray, after: np.ndarray) -> float:
    """RMS distance between two placements (k, 3) of the same points: how far the refined pose moved the second's
    vertices from where the registration put them. ICP may slide a surface that pins it weakly (a curled low-relief
    sheet: 0.0052 of sqrt(area), errors 6 times higher); a snap moving the points by more than the answer's own
    residual is not trusted."""
    return float(np.sqrt(np.mean(np.sum((before - after) ** 2, axis=1))))


def _marked(mr, snapped: bool, seconds: float | None = None):
    """``mr`` with ``params["snapped"]`` set (and the ``seconds`` spent trying, when the ICP ran)."""
    timings = mr.result.timings if seconds is None else with_stage(mr.result.timings, "snap", seconds)
    return replace(mr, result=replace(mr.result, params={**mr.result.params, "snapped": snapped}, timings=timings))
