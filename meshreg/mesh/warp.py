"""As-rigid-as-possible warp of one mesh onto another that it overlaps (a non-rigid ICP).

A bent scan cannot be brought onto the other by any similarity: only a strip of it coincides, and where the two
overlap is then unclear. This module bends the second mesh onto the first while keeping its triangles' shapes
(ARAP: Sorkine & Alexa 2007; the data term pulls each vertex towards the first mesh's tangent plane at its nearest
vertex, as in non-rigid ICP), so that the part of it that the first does not cover keeps its size and shape beyond
the first's rim. The warp is used to find the overlap, not as the correspondence.

Pure numpy/scipy (sparse Cholesky-free solve: one sparse LU per iteration of an n x n system, the three coordinates
sharing it).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.spatial.transform import Rotation

from ..rotation import kabsch_stack
from .align import rigid_step
from .frontal import analyse
from .harmonic import factorize
from .surface import NORMAL_AGREEMENT, Surface, transform_points, vertex_normals
from .topology import unique_edges

WARP_WEIGHTS = (0.01, 0.03, 0.1, 0.3, 1.0)  # data weight per vertex against the ARAP energy, annealed
WARP_ROUNDS = 10  # iterations (closest points, rigid step, rotations, solve) at each weight
WARP_TRIM = 3.0  # pairs farther than this times the median distance are left out of the data term ...
WARP_TRIM_FLOOR = 2.0  # ... but never those within this many edge lengths of the first mesh
# the rigid step of a warp iteration turns the mesh by at most this many degrees (the step is cut back along its own
# twist). The linearized point-to-plane step is only valid for small turns, and it leaves the motions that a nearly
# flat target does not pin almost free: on a random relief sheet (peak to peak 0.18) against its copy rolled 90
# degrees and scaled 2.5, the first step turned the mesh by 107 degrees and the warp ended 44 edge lengths off the
# sheet (2.4 before the warp, 0.8 with the turns cut back); the largest turn of a step on the benchmark's bent face
# crops is 13.6 degrees (unchanged)
WARP_TURN = 20.0


def _rotations(rest_edges: np.ndarray, current: np.ndarray, ends: sp.csr_matrix, i, j) -> np.ndarray:
    """Per vertex, the rotation (n, 3, 3) that best turns its rest edges (e, 3) into its current ones (Kabsch);
    ``ends`` (n, e) is 1 where a vertex is an end of an edge."""
    outer = np.einsum("ea,eb->eab", rest_edges, current[i] - current[j])
    return kabsch_stack((ends @ outer.reshape(len(outer), 9)).reshape(-1, 3, 3))


def arap_warp(rest: np.ndarray, faces: np.ndarray, target: Surface) -> np.ndarray:
    """Bend a mesh onto ``target`` as rigidly as possible.

    Parameters
    ----------
    rest : ndarray, shape (n, 3)
        The mesh's vertices, already in the target's frame (posed and scaled by a similarity).
    faces : ndarray, shape (m, 3)
    target : Surface

    Returns
    -------
    ndarray, shape (n, 3)
        The vertices after the warp.
    """
    n = len(rest)
    edges = unique_edges(faces)
    i, j = edges[:, 0], edges[:, 1]
    k = np.arange(len(edges))
    incidence = sp.csr_matrix((np.r_[np.ones(len(k)), -np.ones(len(k))], (np.r_[i, j], np.r_[k, k])), (n, len(k)))
    ends = abs(incidence)
    laplacian = incidence @ incidence.T  # the graph Laplacian
    rest_edges = rest[i] - rest[j]
    current = rest.copy()
    analysis = analyse(laplacian + sp.identity(n))  # every system below has this pattern
    for weight in WARP_WEIGHTS:
        for _ in range(WARP_ROUNDS):
            # a rigid point-to-plane step first: the whole mesh slides along the target, which the per-vertex goals
            # below (points of the target's tangent planes) would hold back
            held, tn, foot = _pairs(current, faces, target)
            if held.sum() >= 6:
                step = rigid_step(current[held], tn[held], foot[held])
                current = transform_points(capped(step, current[held], np.radians(WARP_TURN)), current)
            plane = np.sum(tn * (current - foot), axis=1)
            goal = current - plane[:, None] * tn
            rot = _rotations(rest_edges, current, ends, i, j)
            # ARAP right-hand side: sum over neighbours of (R_i + R_j) / 2 (rest_i - rest_j)
            rhs = incidence @ (0.5 * np.einsum("eab,eb->ea", rot[i] + rot[j], rest_edges))
            data = weight * held + 1e-9
            rhs += data[:, None] * np.where(held[:, None], goal, current)
            current = factorize((laplacian + sp.diags(data)).tocsc(), analysis).solve(rhs)
    return current


def capped(step: np.ndarray, points: np.ndarray, limit: float) -> np.ndarray:
    """The rigid motion ``step`` (4, 4) cut back along its twist (the rotation vector and the shift of the points'
    (k, 3) centroid, scaled alike) so that it turns by at most ``limit`` radians."""
    turn = Rotation.from_matrix(step[:3, :3]).as_rotvec()
    angle = float(np.linalg.norm(turn))
    if angle <= limit:
        return step
    fraction = limit / angle
    centre = points.mean(axis=0)
    rotation = Rotation.from_rotvec(turn * fraction).as_matrix()
    shift = (step[:3, :3] @ centre + step[:3, 3] - centre) * fraction
    out = np.eye(4)
    out[:3, :3] = rotation
    out[:3, 3] = centre + shift - rotation @ centre
    return out


def _pairs(current: np.ndarray, faces: np.ndarray, target: Surface):
    """Which vertices the data term holds (near the target, away from its rim, normals agreeing; beyond WARP_TRIM
    times the median distance left out), the target's normals at their nearest vertices, and those vertices."""
    normals = vertex_normals(current, faces)
    dist, nearest = target.tree.query(current)
    tn = target.normals[nearest]
    limit = max(WARP_TRIM * float(np.median(dist)), WARP_TRIM_FLOOR * target.edge)
    held = (dist <= limit) & ~target.rim[nearest] & (np.abs(np.sum(normals * tn, axis=1)) >= NORMAL_AGREEMENT)
    return held, tn, target.vertices[nearest]
