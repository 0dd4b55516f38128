"""Similarity pre-alignment of two meshes that may overlap only partly.

Where the elastic registration maps the whole of one surface onto the whole of the other, two scans of one object
share only part of their area; the overlap is found in space first, which needs the pose of the second mesh in
the first's frame. This module finds it without any start (the meshes may come in any pose and orientation):

1. candidate poses: feature matching (FPFH, Rusu et al. 2009, on a voxel sample of each mesh; RANSAC over triplets
   of matches, scored by the matches they explain), both orientations of the second mesh's normals (its faces
   may be wound the other way), at the scales worth trying (1: two scans in the same units; the ratio of the areas
   (:func:`tiled_area`): the same region at another scale; a hint's); the identity (meshes given in one frame); a
   hint (e.g. the elastic registration's similarity); and, unless one of those already coincides closely after ICP
   (a score of SCORE_ENOUGH at the tightest of SCORE_LEVELS: the same surface), the principal axes of both meshes
   times the 24 rotations of the cube;
2. each refined by a trimmed ICP (point-to-plane, rigid: the candidate's scale is kept; a pair whose areas' ratio is
   within SCALE_TIE of 1, posed at scale 1 only, is also refined with a scale), which drops pairs beyond a robust
   distance, pairs whose closest point is on the other mesh's rim (the part of one scan that the other does not
   cover) and pairs whose normals disagree;
3. ranked by the overlap they give: the sampled area of both meshes within :data:`SCORE_DISTANCE` edge lengths of
   the other with normals agreeing and away from its rim, then by the trimmed RMS. A wrong pose of a nearly flat
   sheet can have a small RMS, but it puts less area within that distance than the right one.

numpy/scipy, the FPFH histograms in numba; deterministic (seeded).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numba
import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from ..rotation import angle_between, kabsch_stack
from ..search import cube_rotations
from .graph import face_normals, neighbourhood_sums
from .surface import NORMAL_AGREEMENT, Surface, cube_labels, transform_normals, transform_points

FEATURE_VOXEL = 0.03  # voxel of the feature sample, in units of sqrt(area) of the smaller mesh (>= 1 edge length)
FPFH_RADIUS = 5.0  # feature radius, in voxels (Open3D's usual choice)
FPFH_NEIGHBOURS = 60  # most neighbours per point in a feature
FPFH_BINS = 11
RANSAC_TRIALS = 20_000  # triplets of feature matches tried
RANSAC_EDGE_RATIO = 0.9  # a triplet's sides must agree within this ratio on both meshes
RANSAC_DISTANCE = 1.5  # a match is explained within this many voxels
RANSAC_KEEP = 4  # best RANSAC poses refined per scale and orientation
RANSAC_SEED = 0
ICP_COARSE = 10  # ICP iterations of every candidate (COARSE_POINTS points, nearest vertices' tangent planes)
ICP_FINE = 20  # ICP iterations of the best candidates (every sample point)
ICP_EXACT = 10  # ICP iterations of the best pose against the triangles (exact closest points)
COARSE_POINTS = 500
ICP_TRIM = 2.5  # pairs farther than this times the median distance are dropped
ICP_TRIM_FLOOR = 1.0  # ... but never those within this many edge lengths
ICP_TOL = 1e-7  # ICP stops when the pose changes by less than this (relative)
SCORE_LEVELS = (0.05, 0.25, 4.0)  # distances (edge lengths) at which poses are scored, tightest first
SCORE_ENOUGH = 0.25  # a level ranks the poses when one of them scores this much at it (see _ranking)
SCORE_REACH = 2.0  # scored points lie within this many times the level (>= 1 edge length) of the other's vertices
FINALISTS = 3  # candidates refined on every sample point
SCALE_TIE = 0.05  # scales within this log ratio of one another are tried once
# ... and a pose at scale 1 of a pair whose areas' ratio is within SCALE_TIE of 1 is also refined with a scale, kept
# when its score at the tightest level exceeds the rigid pose's by this much: a copy scaled by 0.96-0.98 (the rigid
# pose off by the scale), not a crop in the same units of a gentle relief (its scale drifted to 1.001, closest points
# 0.05% of sqrt(area) off where they were exact) nor a noisy 97% crop (taken for the whole)
SCALED_MARGIN = 0.1
POINT_WEIGHT = 0.0  # weight of the point-to-point distances beside the point-to-plane ones in an ICP step
AXES_TURNS = (0.0, 90.0)  # degrees: turns of the principal-axes poses about the third axis (axes_pose)
UNIT_REFINED = 0.5  # axes_pose refines the pose at scale 1 when, coarsely, it scores this fraction of the best's
ICP_VOXEL = 0.03  # voxel of the ICP samples, in units of sqrt(area) of each mesh (>= 1 edge length)


@dataclass(frozen=True)
class Alignment:
    """A pose of the second mesh in the first's frame.

    Attributes
    ----------
    matrix : ndarray, shape (4, 4)
        The similarity x -> s R x + b moving the second mesh's points into the first's frame.
    rms : float
        Root mean square distance of the kept ICP pairs (first's units).
    scores : tuple of float
        :func:`overlap_scores` at each of SCORE_LEVELS.
    source : str
        The candidate it was refined from ("features", "principal axes", "identity", "hint").
    """

    matrix: np.ndarray
    rms: float
    scores: tuple
    source: str

    @property
    def scale(self) -> float:
        """s of the similarity."""
        return float(np.cbrt(np.linalg.det(self.matrix[:3, :3])))


@dataclass
class Cloud:
    """Points (k, 3) with unit normals (k, 3)."""

    points: np.ndarray
    normals: np.ndarray

    def moved(self, matrix: np.ndarray) -> Cloud:
        return Cloud(transform_points(matrix, self.points), transform_normals(matrix, self.normals))


def voxel_sample(surface: Surface, voxel: float) -> Cloud:
    """The mean vertex and mean normal of each occupied voxel of side ``voxel``."""
    label = cube_labels(surface.vertices, voxel)
    count = np.bincount(label)
    points = np.stack([np.bincount(label, surface.vertices[:, k]) for k in range(3)], axis=1) / count[:, None]
    normals = np.stack([np.bincount(label, surface.normals[:, k]) for k in range(3)], axis=1)
    norm = np.linalg.norm(normals, axis=1, keepdims=True)
    ok = norm[:, 0] > 0
    return Cloud(points[ok], normals[ok] / norm[ok])


def fpfh(cloud: Cloud, radius: float) -> np.ndarray:
    """Fast point feature histograms (k, 33) of a cloud with normals (Rusu, Blodow & Beetz 2009; as Open3D
    computes them: 11 bins per angle, at most FPFH_NEIGHBOURS neighbours within ``radius``, weights 1 / squared
    distance)."""
    p, n = cloud.points, cloud.normals
    if len(p) < 2:  # a mesh about one voxel across: no neighbours, empty histograms
        return np.zeros((len(p), 3 * FPFH_BINS))
    k = min(FPFH_NEIGHBOURS + 1, len(p))
    dist, idx = cKDTree(p).query(p, k=k, distance_upper_bound=radius)
    idx = np.where(np.isfinite(dist) & (dist > 0), idx, -1).astype(np.int64)
    return _fpfh(np.ascontiguousarray(p, dtype=float), np.ascontiguousarray(n, dtype=float), idx, FPFH_BINS)


def flipped_fpfh(features: np.ndarray) -> np.ndarray:
    """The FPFH (k, 33) of a cloud with every normal reversed, from its FPFH ``features``: reversing both normals
    of a pair negates its angle features f1 and f3 and keeps f2, so the bins of f1 and of f3 run backwards."""
    bins = np.arange(FPFH_BINS)
    order = np.r_[bins[::-1], FPFH_BINS + bins, 3 * FPFH_BINS - 1 - bins]
    return features[:, order]


@numba.njit(cache=True)
def _pair_features(p, n, i, j):
    """The three angle features (f1, f2, f3) of points i and j, and their distance (0: degenerate pair)."""
    dx, dy, dz = p[j, 0] - p[i, 0], p[j, 1] - p[i, 1], p[j, 2] - p[i, 2]
    d = max(np.sqrt(dx * dx + dy * dy + dz * dz), 1e-300)
    a1 = (n[i, 0] * dx + n[i, 1] * dy + n[i, 2] * dz) / d
    a2 = (n[j, 0] * dx + n[j, 1] * dy + n[j, 2] * dz) / d
    s, t, sign = i, j, 1.0
    if abs(a1) < abs(a2):  # the source is the point whose normal is closer to the line between them
        s, t, sign = j, i, -1.0
    f3 = sign * (a1 if sign > 0 else a2)
    lx, ly, lz = sign * dx / d, sign * dy / d, sign * dz / d
    sx, sy, sz = n[s, 0], n[s, 1], n[s, 2]
    tx, ty, tz = n[t, 0], n[t, 1], n[t, 2]
    vx, vy, vz = ly * sz - lz * sy, lz * sx - lx * sz, lx * sy - ly * sx  # line x source normal
    v_norm = np.sqrt(vx * vx + vy * vy + vz * vz)
    if v_norm <= 1e-12:
        return 0.0, 0.0, 0.0, 0.0
    vx, vy, vz = vx / v_norm, vy / v_norm, vz / v_norm
    wx, wy, wz = sy * vz - sz * vy, sz * vx - sx * vz, sx * vy - sy * vx  # source normal x v
    f1 = np.arctan2(wx * tx + wy * ty + wz * tz, sx * tx + sy * ty + sz * tz)
    return f1, vx * tx + vy * ty + vz * tz, f3, d


@numba.njit(cache=True)
def _fpfh(p, n, idx, bins):
    """FPFH of points p (k, 3) with normals n (k, 3) and neighbour indices idx (k, m) (-1: none): (k, 3 bins)."""
    k, m = idx.shape
    spfh = np.zeros((k, 3 * bins))
    weight = np.zeros((k, m))
    found = np.zeros((m, 3), np.int64)
    for i in range(k):
        count = 0
        for c in range(m):
            j = idx[i, c]
            if j < 0:
                continue
            f1, f2, f3, d = _pair_features(p, n, i, j)
            if d == 0.0:
                continue
            found[count, 0] = min(max(int(np.floor(bins * (f1 + np.pi) / (2 * np.pi))), 0), bins - 1)
            found[count, 1] = min(max(int(np.floor(bins * (f2 + 1) * 0.5)), 0), bins - 1)
            found[count, 2] = min(max(int(np.floor(bins * (f3 + 1) * 0.5)), 0), bins - 1)
            weight[i, c] = 1.0 / max(d * d, 1e-300)
            count += 1
        share = 100.0 / max(count, 1)
        for c in range(count):
            for f in range(3):
                spfh[i, f * bins + found[c, f]] += share
    out = spfh.copy()
    neighbours = np.zeros(3 * bins)
    for i in range(k):
        neighbours[:] = 0.0
        for c in range(m):
            if weight[i, c] > 0.0:
                for b in range(3 * bins):
                    neighbours[b] += weight[i, c] * spfh[idx[i, c], b]
        for f in range(3):
            total = 0.0
            for b in range(f * bins, (f + 1) * bins):
                total += neighbours[b]
            if total > 0.0:
                for b in range(f * bins, (f + 1) * bins):
                    out[i, b] += neighbours[b] * (100.0 / total)
    return out


def _kabsch_batch(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Rigid 4 x 4 matrices (t, 4, 4) taking point triplets p (t, 3, 3) onto q (t, 3, 3) in least squares."""
    pc, qc = p.mean(axis=1, keepdims=True), q.mean(axis=1, keepdims=True)
    rot = kabsch_stack(np.einsum("tki,tkj->tij", p - pc, q - qc))
    out = np.tile(np.eye(4), (len(p), 1, 1))
    out[:, :3, :3] = rot
    out[:, :3, 3] = qc[:, 0] - np.einsum("tij,tj->ti", rot, pc[:, 0])
    return out


def ransac_poses(source: Cloud, target: Cloud, f_source, f_target, voxel: float, rng) -> list[np.ndarray]:
    """Rigid poses (4 x 4) of ``source`` in ``target``'s frame from feature matches: the RANSAC_KEEP distinct
    poses explaining the most matches (mutual nearest features) within RANSAC_DISTANCE voxels."""
    nearest_t = cKDTree(f_target).query(f_source)[1]
    nearest_s = cKDTree(f_source).query(f_target)[1]
    mutual = nearest_s[nearest_t] == np.arange(len(f_source))
    src_idx = np.flatnonzero(mutual) if mutual.sum() >= 10 else np.arange(len(f_source))
    ps, pt = source.points[src_idx], target.points[nearest_t[src_idx]]
    if len(ps) < 3:
        return []
    picks = rng.integers(0, len(ps), size=(RANSAC_TRIALS, 3))
    a, b = ps[picks], pt[picks]
    sides_a = np.linalg.norm(a - np.roll(a, 1, axis=1), axis=-1)
    sides_b = np.linalg.norm(b - np.roll(b, 1, axis=1), axis=-1)
    ratio = np.minimum(sides_a, sides_b) / np.maximum(np.maximum(sides_a, sides_b), 1e-300)
    good = np.all(ratio > RANSAC_EDGE_RATIO, axis=1) & np.all(sides_a > 2 * voxel, axis=1)
    if not good.any():
        return []
    poses = _kabsch_batch(a[good], b[good])
    counts = _explained(poses, ps, pt, (RANSAC_DISTANCE * voxel) ** 2)
    order = np.argsort(-counts, kind="stable")
    ranked, distinct = poses[order], counts[order] >= 3  # distinct: not the same as a pose kept already
    kept = []
    while len(kept) < RANSAC_KEEP and distinct.any():
        kept.append(ranked[np.argmax(distinct)])
        distinct &= ~_same_pose(ranked, kept[-1], voxel)
    return kept


@numba.njit(cache=True)
def _explained(poses, source, target, limit):
    """Per pose (t, 4, 4): how many of the matches source (k, 3) -> target (k, 3) it moves within sqrt(limit)."""
    counts = np.zeros(len(poses), dtype=np.int64)
    for t in range(len(poses)):
        m = poses[t]
        for k in range(len(source)):
            d2 = 0.0
            for a in range(3):
                x = m[a, 0] * source[k, 0] + m[a, 1] * source[k, 1] + m[a, 2] * source[k, 2] + m[a, 3]
                d2 += (x - target[k, a]) ** 2
            if d2 < limit:
                counts[t] += 1
    return counts


def _same_pose(poses: np.ndarray, pose: np.ndarray, voxel: float) -> np.ndarray:
    """Whether each of the poses (t, 4, 4) differs from ``pose`` (4 x 4) by less than 5 degrees and 3 voxels."""
    near = np.linalg.norm(poses[:, :3, 3] - pose[:3, 3], axis=1) < 3 * voxel
    return (angle_between(poses[:, :3, :3], pose[:3, :3]) < 5.0) & near


def rigid_step(x, n, p, scaled: bool = False) -> np.ndarray:
    """The small rigid motion (4 x 4) that best moves points x (k, 3) onto the planes through p (k, 3) with unit
    normals n (k, 3): linearized point-to-plane least squares in (rotation vector, shift) about x's centroid, plus
    POINT_WEIGHT^2 times the point-to-point distances, which fix what the planes leave free. With ``scaled``, a
    similarity: also a scale about the centroid (a column n . (x - c); planes through the centroid leave it free,
    and it then stays), without the point-to-point term."""
    c = x.mean(axis=0)
    xc = x - c
    k = len(x)
    plane = np.hstack([np.cross(xc, n), n])  # n . (x - p) + omega . (xc x n) + n . t
    if scaled:
        plane = np.hstack([plane, np.sum(n * xc, axis=1)[:, None]])  # + sigma n . xc
    a = plane.T @ plane
    b = -plane.T @ np.sum(n * (x - p), axis=1)
    if POINT_WEIGHT and not scaled:  # 0 by default: the (3k, 6) point-to-point system is not built
        skew = np.zeros((k, 3, 3))  # omega x xc = -[xc]_x omega, per axis
        skew[:, 0, 1], skew[:, 0, 2], skew[:, 1, 2] = xc[:, 2], -xc[:, 1], xc[:, 0]
        skew[:, 1, 0], skew[:, 2, 0], skew[:, 2, 1] = -xc[:, 2], xc[:, 1], -xc[:, 0]
        point = np.concatenate([skew, np.broadcast_to(np.eye(3), (k, 3, 3))], axis=2).reshape(-1, 6)
        a += POINT_WEIGHT**2 * point.T @ point
        b += POINT_WEIGHT**2 * point.T @ (-(x - p)).ravel()
    sol = np.linalg.solve(a + 1e-12 * np.trace(a) * np.eye(len(a)), b)
    rot = Rotation.from_rotvec(sol[:3]).as_matrix() * (1.0 + sol[6] if scaled else 1.0)
    out = np.eye(4)
    out[:3, :3] = rot
    out[:3, 3] = c + sol[3:6] - rot @ c
    return out


def icp(
    source: Cloud,
    target: Surface,
    matrix: np.ndarray,
    *,
    iterations: int = ICP_COARSE,
    exact: bool = False,
    scaled: bool = False,
) -> tuple[np.ndarray, float]:
    """Trimmed point-to-plane ICP (rigid: the scale of ``matrix`` is kept; with ``scaled`` a similarity) of
    ``source`` (in its own frame) onto ``target`` from ``matrix``.

    Each iteration pairs every moved point with the target's nearest vertex (its tangent plane) or, with ``exact``,
    its closest point on the triangles; drops pairs farther than ICP_TRIM times the median distance (but keeps those
    within ICP_TRIM_FLOOR edge lengths), pairs on the target's rim and pairs whose normals disagree; and applies the
    rigid motion that best closes the rest. Returns the matrix and the RMS distance of the pairs kept last.
    """
    rms = np.inf
    for _ in range(iterations):
        moved = source.moved(matrix)
        if exact:
            p, dist, n = target.closest(moved.points)
            on_rim = target.rim_distance(p) < 1e-9 * target.edge
        else:
            dist, j = target.tree.query(moved.points)
            p, n, on_rim = target.vertices[j], target.normals[j], target.rim[j]
        limit = max(ICP_TRIM * float(np.median(dist)), ICP_TRIM_FLOOR * target.edge)
        keep = (dist <= limit) & ~on_rim & (np.abs(np.sum(moved.normals * n, axis=1)) >= NORMAL_AGREEMENT)
        if keep.sum() < 6:
            return matrix, np.inf
        rms = float(np.sqrt(np.mean(dist[keep] ** 2)))
        step = rigid_step(moved.points[keep], n[keep], p[keep], scaled)
        matrix = step @ matrix
        change = np.linalg.norm(step - np.eye(4))
        if change < ICP_TOL:
            break
    return matrix, rms


def overlap_scores(first: Cloud, first_surface: Surface, second: Cloud, second_surface: Surface, matrix) -> np.ndarray:
    """How well the second mesh, moved by ``matrix``, and the first overlap, at each distance of SCORE_LEVELS: for
    each mesh, the mean over its sample points of 1 - (d / t)^2 (0 beyond t), d the distance to the other's nearest
    tangent plane and t the level times the other's edge length, counting only points within SCORE_REACH times the
    level of the other's nearest vertex, away from its rim, with normals agreeing; the smaller of the two means.
    Large overlaps that coincide closely score high; a pose that leaves one mesh mostly off the other scores low
    whatever its RMS. Shape (len(SCORE_LEVELS),)."""
    inverse = np.linalg.inv(matrix)
    levels = np.asarray(SCORE_LEVELS)
    scores = []
    for cloud, surface, m in ((second, first_surface, matrix), (first, second_surface, inverse)):
        moved = cloud.moved(m)
        t = levels[:, None] * surface.edge
        reach = SCORE_REACH * np.maximum(t, surface.edge)
        # points beyond the reach do not count: the search stops there (a point far off a sheet visits many cells)
        dist, j = surface.tree.query(moved.points, distance_upper_bound=float(reach.max()) * (1 + 1e-9))
        j = np.minimum(j, len(surface.vertices) - 1)
        normal = surface.normals[j]
        plane = np.abs(np.sum(normal * (moved.points - surface.vertices[j]), axis=1))
        valid = ~surface.rim[j] & (np.abs(np.sum(moved.normals * normal, axis=1)) >= NORMAL_AGREEMENT)
        near = valid & (dist <= reach)
        scores.append(np.mean(np.where(near, np.maximum(0.0, 1.0 - (plane / t) ** 2), 0.0), axis=1))
    return np.minimum(*scores)


def _ranking(scores: np.ndarray) -> np.ndarray:
    """Which level of SCORE_LEVELS ranks a set of candidates (rows of ``scores``): the tightest at which one of
    them scores at least SCORE_ENOUGH (the same surface: the right pose coincides closely), else the loosest (a
    deformed pair: no pose coincides, the right one comes closest over the largest area)."""
    enough = np.flatnonzero(scores.max(axis=0) >= SCORE_ENOUGH)
    return int(enough[0]) if len(enough) else len(SCORE_LEVELS) - 1


def principal_frame(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Centroid (3,) and principal axes (3, 3) (columns, decreasing variance, right-handed) of points."""
    c = points.mean(axis=0)
    _, vecs = np.linalg.eigh((points - c).T @ (points - c))
    axes = vecs[:, ::-1]
    if np.linalg.det(axes) < 0:
        axes[:, 2] *= -1
    return c, axes


def _similarity(rotation: np.ndarray, scale: float, source_point: np.ndarray, target_point: np.ndarray):
    out = np.eye(4)
    out[:3, :3] = scale * rotation
    out[:3, 3] = target_point - scale * rotation @ source_point
    return out


def align(first: Surface, second: Surface, hint: np.ndarray | None = None) -> Alignment:
    """The pose of ``second`` in ``first``'s frame that overlaps them best (see the module docstring).

    Parameters
    ----------
    first, second : Surface
    hint : ndarray (4, 4), optional
        A similarity taking the second mesh into the first's frame (e.g. the inverse of the elastic registration's
        :attr:`~meshreg.result.Registration.transform`): one more candidate, and its scale one more scale.
    """
    rng = np.random.default_rng(RANSAC_SEED)
    scales = [1.0, areas_scale(first, second)]
    near_unit = scales[1] != 1.0 and abs(np.log(scales[1])) <= SCALE_TIE  # posed at 1 only: ICP with a scale too
    if hint is not None:
        scales.append(float(np.cbrt(abs(np.linalg.det(hint[:3, :3])))))
    scales = [s for i, s in enumerate(scales) if all(abs(np.log(s / t)) > SCALE_TIE for t in scales[:i])]
    candidates, axes = [], []  # (matrix, source): feature poses, principal-axes poses
    for s in scales:
        voxel = max(FEATURE_VOXEL * np.sqrt(min(first.area, s * s * second.area)), first.edge, s * second.edge)
        sample1 = voxel_sample(first, voxel)
        sample2 = voxel_sample(second, voxel / s)
        shrink = _similarity(np.eye(3), s, np.zeros(3), np.zeros(3))
        sample2s = sample2.moved(shrink)
        f1 = fpfh(sample1, FPFH_RADIUS * voxel)
        f2 = fpfh(sample2s, FPFH_RADIUS * voxel)
        for flip, features in ((1.0, f2), (-1.0, flipped_fpfh(f2))):
            flipped = Cloud(sample2s.points, flip * sample2s.normals)
            for pose in ransac_poses(flipped, sample1, features, f1, voxel, rng):
                candidates.append((pose @ shrink, "features"))
        c1, axes1 = principal_frame(sample1.points)
        c2, axes2 = principal_frame(sample2.points)
        for rot in cube_rotations():
            axes.append((_similarity(axes1 @ rot @ axes2.T, s, c2, c1), "principal axes"))
    candidates.append((np.eye(4), "identity"))
    if hint is not None:
        candidates.append((np.asarray(hint, dtype=float), "hint"))
    cloud1 = voxel_sample(first, max(ICP_VOXEL * np.sqrt(first.area), first.edge))
    cloud2 = voxel_sample(second, max(ICP_VOXEL * np.sqrt(second.area), second.edge))
    coarse = _subsample(cloud2, COARSE_POINTS, rng)
    poses, scores = _refined(coarse, first, candidates, near_unit, (cloud1, cloud2, second))
    if max(score[0] for score in scores) < SCORE_ENOUGH:  # no feature pose coincides closely: try the axes too
        more, more_scores = _refined(coarse, first, axes, near_unit, (cloud1, cloud2, second), len(candidates))
        candidates, poses, scores = candidates + axes, poses + more, scores + more_scores
    scores = np.array(scores)
    order = np.argsort(-scores[:, _ranking(scores)], kind="stable")[:FINALISTS]
    finals = [_fine(cloud2, first, poses[k]) for k in order]
    scores = np.array([overlap_scores(cloud1, first, cloud2, second, m) for m in finals])
    best = int(np.argmax(scores[:, _ranking(scores)]))
    matrix, rms = icp(cloud2, first, finals[best], iterations=ICP_EXACT, exact=True)
    scores = overlap_scores(cloud1, first, cloud2, second, matrix)
    return Alignment(matrix, rms, tuple(float(x) for x in scores), candidates[poses[order[best]].candidate][1])


class Refined(NamedTuple):
    """A candidate pose after the coarse ICP: its matrix (4, 4), whether its scale was refined too, and the index of
    the candidate it came from."""

    matrix: np.ndarray
    scaled: bool
    candidate: int


def _refined(
    coarse: Cloud, target: Surface, candidates: list, near_unit: bool, scoring: tuple, start: int = 0
) -> tuple[list[Refined], list[np.ndarray]]:
    """Each candidate pose (``(matrix, source)``) refined by the coarse ICP and scored (:func:`overlap_scores` with
    ``scoring`` = (first's cloud, second's cloud, second surface)): the :class:`Refined` poses and their scores. When
    ``near_unit``, each is also refined by the coarse ICP with a scale, and that pose kept when its scale stays within
    SCALE_TIE of 1 and it scores SCALED_MARGIN above the rigid one at the tightest level. A pair whose areas' ratio is
    within SCALE_TIE of 1 is posed at scale 1 only (a crop in the same units must not be blown up to the whole): one
    surface scaled by 0.98 then fitted a half-turned pose over 80% of a sheet symmetric about an axis better than the
    right one over all of it (docs/heldout.md, seventeenth session)."""
    cloud1, cloud2, second = scoring
    poses, scores = [], []
    for k, (matrix, _) in enumerate(candidates, start):
        rigid = icp(coarse, target, matrix)[0]
        poses.append(Refined(rigid, False, k))
        scores.append(overlap_scores(cloud1, target, cloud2, second, rigid))
        if near_unit:
            scaled = icp(coarse, target, matrix, scaled=True)[0]
            if _near_unit(scaled):
                score = overlap_scores(cloud1, target, cloud2, second, scaled)
                if score[0] >= scores[-1][0] + SCALED_MARGIN:
                    poses.append(Refined(scaled, True, k))
                    scores.append(score)
    return poses, scores


def _fine(cloud: Cloud, target: Surface, pose: Refined) -> np.ndarray:
    """A finalist refined by the fine ICP, with a scale if the coarse one had it (rigid again if that leaves SCALE_TIE
    of 1: the drift docs/overlap.md measured on partial sheets)."""
    if pose.scaled:
        matrix = icp(cloud, target, pose.matrix, iterations=ICP_FINE, scaled=True)[0]
        if _near_unit(matrix):
            return matrix
    return icp(cloud, target, pose.matrix, iterations=ICP_FINE)[0]


def _near_unit(matrix: np.ndarray) -> bool:
    """Whether the similarity ``matrix`` (4, 4) scales by a factor within SCALE_TIE of 1 (NaN: no)."""
    return bool(abs(np.log(np.cbrt(abs(np.linalg.det(matrix[:3, :3]))))) <= SCALE_TIE)


def axes_pose(first: Surface, second: Surface) -> Alignment | None:
    """A cheap pose of the second mesh in the first's frame that is right when both cover the same region, or None.

    The principal axes of their ICP samples matched (the 4 proper sign choices of the axes, each also turned by
    AXES_TURNS about the third axis, the normal of a sheet: the first two axes of a round or square patch are
    arbitrary) at the scale of the ratio of their areas (1 when within SCALE_TIE of it, as in :func:`align`), each
    refined by the coarse ICP, the best (by :func:`overlap_scores`) by the fine one. At another scale than 1, the
    same rotation at scale 1 is refined too (by the coarse ICP, and by the fine one unless it then scores below
    UNIT_REFINED times the best coarse pose at the level that ranks the two), and when it overlaps better (a crop
    in the same units, which the ratio of the areas would blow up to the whole) the answer is None. No feature
    search: :func:`align` is the general answer."""
    rng = np.random.default_rng(RANSAC_SEED)
    scale = areas_scale(first, second)
    scale = 1.0 if abs(np.log(scale)) <= SCALE_TIE else scale
    cloud1 = voxel_sample(first, max(ICP_VOXEL * np.sqrt(first.area), first.edge))
    cloud2 = voxel_sample(second, max(ICP_VOXEL * np.sqrt(second.area), second.edge))
    (c1, axes1), (c2, axes2) = principal_frame(cloud1.points), principal_frame(cloud2.points)
    coarse = _subsample(cloud2, COARSE_POINTS, rng)
    flips = [np.diag(d) for d in ((1.0, 1.0, 1.0), (1.0, -1.0, -1.0), (-1.0, 1.0, -1.0), (-1.0, -1.0, 1.0))]
    turns = Rotation.from_rotvec(np.outer(np.radians(AXES_TURNS), [0.0, 0.0, 1.0])).as_matrix()
    poses, scores = [], []
    for turn in turns:  # until a pose coincides closely (SCORE_ENOUGH at the tightest level: the same surface)
        for d in flips:
            poses.append(icp(coarse, first, _similarity(axes1 @ turn @ d @ axes2.T, scale, c2, c1))[0])
            scores.append(overlap_scores(cloud1, first, cloud2, second, poses[-1]))
        if max(score[0] for score in scores) >= SCORE_ENOUGH:
            break
    scores = np.array(scores)
    best = int(np.argmax(scores[:, _ranking(scores)]))
    matrix, rms = icp(cloud2, first, poses[best], iterations=ICP_FINE)
    finals = [(matrix, rms)]
    if scale != 1.0:
        unit = icp(coarse, first, _similarity(poses[best][:3, :3] / scale, 1.0, c2, c1))[0]
        coarsely = np.array([scores[best], overlap_scores(cloud1, first, cloud2, second, unit)])
        level = _ranking(coarsely)
        if coarsely[1, level] >= UNIT_REFINED * coarsely[0, level]:  # else far behind: the fine ICP cannot close it
            finals.append(icp(cloud2, first, unit, iterations=ICP_FINE))
    scores = np.array([overlap_scores(cloud1, first, cloud2, second, m) for m, _ in finals])
    if int(np.argmax(scores[:, _ranking(scores)])) != 0:
        return None
    return Alignment(matrix, rms, tuple(float(x) for x in scores[0]), "principal axes")


def areas_scale(first: Surface, second: Surface) -> float:
    """The scale of one region in two units: the square root of the ratio of the meshes' :func:`tiled_area`, or of
    their plain areas where a tiled area is not positive (a mesh folded flat onto itself: two triangles over one
    square, whose projections cancel)."""
    tiled = tiled_area(first), tiled_area(second)
    if min(tiled) > 0:
        return float(np.sqrt(tiled[0] / tiled[1]))
    return float(np.sqrt(first.area / second.area))


def tiled_area(surface: Surface) -> float:
    """A surface's area, not raised by noise of its vertices: each triangle's area projected onto the mean normal
    of the triangles that share a corner with it (area-weighted). A noisy triangulation of a smooth sheet tiles that
    sheet's projection, while its own area grows with the noise: random relief sheets of 800-3000 vertices with
    Gaussian vertex noise 0.003 (0.14 edge lengths) had the square root of their areas' ratio 6.4% off the scale
    (their poses left 11% of one mesh beyond the other's rim), 0.24% off with this area (0.08% without noise, against
    0.14% with the plain area)."""
    normals = face_normals(surface.vertices, surface.faces)
    mean = neighbourhood_sums(surface.faces, normals, surface.incident)
    length = np.linalg.norm(mean, axis=1)
    ok = length > 0
    return 0.5 * float(np.sum(normals[ok] * mean[ok] / length[ok, None]))


def _subsample(cloud: Cloud, count: int, rng) -> Cloud:
    if len(cloud.points) <= count:
        return cloud
    pick = np.sort(rng.choice(len(cloud.points), count, replace=False))
    return Cloud(cloud.points[pick], cloud.normals[pick])
