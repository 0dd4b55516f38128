"""The peers of benchmarks/bench_peers.py: the tools a user would pick instead of meshreg (Open3D FPFH + RANSAC +
ICP, trimesh ICP, non-rigid ICP (Amberg, Sumner), CPD (pycpd) and BCPD (probreg)), each given both meshes in one
common frame and returning the second's vertices moved into the first's frame. Optional: the ``bench`` extra."""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from meshreg.mesh import deform
from meshreg.mesh.topology import triangle_areas
from meshreg.search import cube_rotations

SEED = 0
ICP_POINTS = 600
CPD_START_POINTS, CPD_RIGID_POINTS = (300, 500), (600, 1000)  # (moving, fixed) for the 24 starts, for the best
CPD_POINTS = 1000
CPD_BETA, CPD_ALPHA = 0.5, 2.0
BCPD_POINTS = 800
BCPD_ITERATIONS, BCPD_LAMBDA = 100, 20.0
CARRY_NEIGHBOURS = 8
VOXEL = 0.03  # Open3D's voxel (unit-area data), at least the meshes' median edge length


# ---- the peers' common frame


@dataclass
class Frames:
    """Both meshes centred and scaled (the first to unit area; the second too, or by the first's factor when the
    pair is at one scale), the first as a trimesh for closest points."""

    a: np.ndarray
    b: np.ndarray
    faces_a: np.ndarray
    faces_b: np.ndarray
    centre: np.ndarray
    factor: float
    mesh_a: object
    poses: dict = field(default_factory=dict)
    borrowed: np.ndarray = field(default_factory=lambda: np.zeros(2))

    def pose(self, key: str, make):
        """A start shared by several peers (made once): its wall and CPU seconds are added to every peer that uses
        it."""
        if key not in self.poses:
            t0, c0 = time.perf_counter(), time.process_time()
            pose = make(self)
            self.poses[key] = (pose, np.array([time.perf_counter() - t0, time.process_time() - c0]))
        else:
            self.borrowed = self.borrowed + self.poses[key][1]
        return self.poses[key][0]

    def to_first(self, moved_b: np.ndarray) -> np.ndarray:
        """Closest points on the first mesh (original frame) to the second's vertices moved into its frame."""
        closest, _, _ = self.mesh_a.nearest.on_surface(moved_b)
        return closest / self.factor + self.centre


def _centroid_area(v, f):
    area = triangle_areas(v, f)
    return area @ v[f].mean(axis=1) / area.sum(), area.sum()


def frames(pair: deform.Pair) -> Frames:
    import trimesh

    (va, fa), (vb, fb) = pair.first, pair.second
    ca, area_a = _centroid_area(va, fa)
    cb, area_b = _centroid_area(vb, fb)
    fac_b = 1 / np.sqrt(area_b)
    fac_a = fac_b if pair.same_scale else 1 / np.sqrt(area_a)
    a, b = (va - ca) * fac_a, (vb - cb) * fac_b
    return Frames(a, b, fa, fb, ca, fac_a, trimesh.Trimesh(a, fa, process=False))


def subsample(n: int, k: int, salt: int = 0) -> np.ndarray:
    return np.sort(np.random.default_rng(SEED + salt).choice(n, min(n, k), replace=False))


def carry(points: np.ndarray, sub: np.ndarray, moved_sub: np.ndarray) -> np.ndarray:
    """Every point moved by the inverse-distance-weighted displacement of its nearest subsample points."""
    k = min(CARRY_NEIGHBOURS, len(sub))
    d, idx = cKDTree(points[sub]).query(points, k=k)
    d, idx = d.reshape(len(points), k), idx.reshape(len(points), k)
    w = 1 / np.maximum(d, 1e-12) ** 2
    w /= w.sum(axis=1, keepdims=True)
    return points + np.einsum("nk,nkd->nd", w, (moved_sub - points[sub])[idx])


def apply(matrix: np.ndarray, points: np.ndarray) -> np.ndarray:
    return points @ matrix[:3, :3].T + matrix[:3, 3]


# ---- the peers (each returns the second's vertices moved into the first's frame)


def peer_open3d(fr: Frames) -> np.ndarray:
    import open3d as o3d

    o3d.utility.random.seed(SEED)
    e = np.concatenate([fr.faces_b[:, [0, 1]], fr.faces_a[:, [0, 1]] + len(fr.b)])
    points = np.vstack([fr.b, fr.a])
    voxel = max(VOXEL, float(np.median(np.linalg.norm(points[e[:, 0]] - points[e[:, 1]], axis=1))))
    reg = o3d.pipelines.registration

    def cloud(points, faces):
        import trimesh

        pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
        normals = np.array(trimesh.Trimesh(points, faces, process=False).vertex_normals)
        pcd.normals = o3d.utility.Vector3dVector(normals)
        down = pcd.voxel_down_sample(voxel)
        down.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2 * voxel, max_nn=30))
        fpfh = reg.compute_fpfh_feature(down, o3d.geometry.KDTreeSearchParamHybrid(radius=5 * voxel, max_nn=100))
        return pcd, down, fpfh

    a, a_down, a_fpfh = cloud(fr.a, fr.faces_a)
    b, b_down, b_fpfh = cloud(fr.b, fr.faces_b)
    ransac = reg.registration_ransac_based_on_feature_matching(
        b_down,
        a_down,
        b_fpfh,
        a_fpfh,
        True,
        1.5 * voxel,
        reg.TransformationEstimationPointToPoint(False),
        3,
        [reg.CorrespondenceCheckerBasedOnEdgeLength(0.9), reg.CorrespondenceCheckerBasedOnDistance(1.5 * voxel)],
        reg.RANSACConvergenceCriteria(100000, 0.999),
    )
    icp = reg.registration_icp(b, a, voxel, ransac.transformation, reg.TransformationEstimationPointToPlane())
    icp = reg.registration_icp(b, a, 0.25 * voxel, icp.transformation, reg.TransformationEstimationPointToPlane())
    return apply(np.asarray(icp.transformation), fr.b)


def _icp_pose(fr: Frames) -> np.ndarray:
    """trimesh ICP from the 24 cube rotations (a subsample of the second onto the first's vertices), the start
    with the lowest own cost refined on every vertex against the first's triangles."""
    import trimesh

    sub = fr.b[subsample(len(fr.b), ICP_POINTS)]
    best = (np.inf, None)
    for rotation in cube_rotations():
        start = np.eye(4)
        start[:3, :3] = rotation
        matrix, _, cost = trimesh.registration.icp(sub, fr.a, initial=start, max_iterations=30, scale=False)
        best = min(best, (cost, matrix), key=lambda x: x[0])
    matrix, _, _ = trimesh.registration.icp(fr.b, fr.mesh_a, initial=best[1], max_iterations=50, scale=False)
    return matrix


def peer_icp(fr: Frames) -> np.ndarray:
    return apply(fr.pose("icp", _icp_pose), fr.b)


def _nricp(fr: Frames, method: str) -> np.ndarray:
    import trimesh

    source = trimesh.Trimesh(apply(fr.pose("icp", _icp_pose), fr.b), fr.faces_b, process=False)
    return np.asarray(getattr(trimesh.registration, method)(source, fr.mesh_a))


def peer_nricp_amberg(fr: Frames) -> np.ndarray:
    return _nricp(fr, "nricp_amberg")


def peer_nricp_sumner(fr: Frames) -> np.ndarray:
    return _nricp(fr, "nricp_sumner")


def _cpd_rigid(fr: Frames) -> tuple[np.ndarray, float]:
    """Rigid CPD (with scale) of the second onto the first from the 24 cube rotations on small subsamples, the
    start with the lowest own objective q refined on larger ones: the second's vertices moved, and CPD's sigma^2."""
    from pycpd import RigidRegistration

    def run(rotation, sizes, iterations):
        moving, fixed = fr.b[subsample(len(fr.b), sizes[0])], fr.a[subsample(len(fr.a), sizes[1], 1)]
        reg = RigidRegistration(X=fixed, Y=moving @ rotation.T, max_iterations=iterations, tolerance=1e-6)
        _, (s, r, t) = reg.register()
        return reg.q, s * r.T @ rotation, t, reg.sigma2  # pycpd moves rows y to s y r + t

    start = min((run(rotation, CPD_START_POINTS, 50) for rotation in cube_rotations()), key=lambda x: x[0])
    _, linear, shift, sigma2 = run(start[1], CPD_RIGID_POINTS, 100)
    return fr.b @ linear.T + shift, sigma2


def peer_cpd(fr: Frames) -> np.ndarray:
    from pycpd import DeformableRegistration

    rigid, sigma2 = fr.pose("cpd-rigid", _cpd_rigid)
    sub = subsample(len(fr.b), CPD_POINTS, 2)
    target = fr.a[subsample(len(fr.a), CPD_POINTS, 3)]
    reg = DeformableRegistration(
        X=target, Y=rigid[sub], alpha=CPD_ALPHA, beta=CPD_BETA, sigma2=sigma2, max_iterations=150, tolerance=1e-5
    )
    moved_sub, _ = reg.register()
    return carry(rigid, sub, moved_sub)


def peer_bcpd(fr: Frames) -> np.ndarray:
    from probreg import bcpd

    rigid, _ = fr.pose("cpd-rigid", _cpd_rigid)
    sub = subsample(len(fr.b), BCPD_POINTS, 4)
    target = fr.a[subsample(len(fr.a), BCPD_POINTS, 5)]
    tf = bcpd.registration_bcpd(rigid[sub], target, maxiter=BCPD_ITERATIONS, lmd=BCPD_LAMBDA)
    return carry(rigid, sub, tf.transform(rigid[sub]))


PEERS = {
    "open3d": (peer_open3d, "open3d"),
    "icp": (peer_icp, "trimesh"),
    "nricp-amberg": (peer_nricp_amberg, "trimesh"),
    "nricp-sumner": (peer_nricp_sumner, "trimesh"),
    "cpd": (peer_cpd, "pycpd"),
    "bcpd": (peer_bcpd, "probreg"),
}


def missing(module: str) -> str | None:
    """Why a peer cannot run (its module, or rtree for trimesh's closest points), or None."""
    needs = [module, "rtree"] if module == "trimesh" else [module]
    for name in needs:
        try:
            __import__(name)
        except ImportError:
            return f"{name} is not installed (pip install 'meshreg[bench]')"
    return None
