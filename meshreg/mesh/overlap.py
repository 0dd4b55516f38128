"""Where two meshes overlap, and each trimmed to that common region with boundaries that correspond.

With the second mesh posed in the first's frame (:mod:`meshreg.mesh.align`; bent onto it by
:mod:`meshreg.mesh.warp` when no pose makes them coincide), every vertex of each mesh gets a signed distance to the
other's rim: its closest point on the other mesh is inside (positive: the distance from that point to the other's
rim) or on the rim (negative: the tangential gap to it). The common region of each mesh is where that distance is
not negative; both meshes are cut along its zero line (triangles split, not dropped whole), so that the two trimmed
boundaries are the same curve of the surface: the first's trimmed boundary runs along the second's rim and its own,
and the other way round.

The verdict (:class:`Overlap`.regime):

- ``"full"``: each mesh's part beyond the other's rim is at most FULL_TOLERANCE (of the regime) of its area; the
  meshes cover the same region and are registered whole, as without this module;
- ``"rigid"``: they overlap partly and a rigid pose makes them coincide (the same surface, two scans);
- ``"elastic"``: they overlap partly and only the warp makes them coincide (a bent scan);
- ``"whole"``: the overlap is not trusted, and the meshes are registered whole: neither the pose nor the warp makes
  them coincide over the overlap (different shapes, or a deformation the warp cannot follow); or the relief does
  not pin the pose (a surface of revolution, a ridge, a flat sheet: a rigid motion slides the meshes along each
  other, and only their rims tell where they are); or only the warp does and the pose changes their scale (a
  deformed pair in different units: a stretched or bent copy of the whole cannot be told from a partial one, so the
  meshes' own units are taken as the evidence of a partial overlap); or a partial overlap the warp finds in the
  meshes' own units when their areas differ is not borne out against one surface in two units (the warp at the
  areas' ratio failed, fits about as closely, or coincides over more of both meshes: :func:`_by_units`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np
import scipy.sparse as sp

from ..rotation import kabsch
from .align import Alignment, align, areas_scale, axes_pose
from .graph import face_normals
from .surface import Surface, transform_points
from .topology import DiskMesh, EarFeet, prepare_disk, triangle_areas
from .warp import arap_warp

RIM_EPSILON = 1e-6  # a closest point within this many edge lengths of the rim lies on it
BAND = 3.0  # signed distances are exact within this many edge lengths of the other's rim
STATISTICS_SAMPLE = 3000  # vertices farther inside whose distance to the other mesh is measured (RMS, coincidence)
SNAP = 0.1  # signed distances within this many edge lengths of 0 are set to 0 (no slivers at the cut)
COINCIDE = 1.0  # vertices within this many edge lengths of the other mesh coincide with it
COINCIDE_ENOUGH = 0.9  # the overlap is trusted when this fraction of it coincides (area)
TIGHT = 0.05  # a pose whose RMS over the overlap is below this many edge lengths needs no warp
RIGID_RATIO = 1.5  # the pose is kept (regime "rigid") when its RMS is within this factor of the warp's
# the meshes cover the same region when each has at most this fraction of its area beyond the other's rim, by regime:
# a warp places the rims less precisely than a rigid pose
FULL_TOLERANCE = {"rigid": 0.02, "elastic": 0.05}
# ... or when neither reaches more than this many edge lengths beyond the other's rim, whatever the area there: the
# rims are one curve up to the triangulations (two held-out meshes of 38 and 70 triangles of one square sheet, whose
# rim chords differ by up to 0.32 edges, were judged 91% / 91% overlaps and 8 of 28 vertices trimmed off); each way in
# edges of the mesh whose rim is crossed, plus the pose's shift, seen as the smaller reach (:func:`_same_rim`: that
# pair, posed 0.2 off, reached 0.19 and 0.14 beyond each other's rims, edges 0.5 and 0.36)
RIM_SLACK = 0.5
SAME_SCALE = 0.05  # a pose within this log ratio of scale 1 keeps the meshes' units
# a same-surface pose is trusted when the relief pins it: the rigid motion that raises the RMS distance over the
# overlap by the pose's own RMS (the fit's noise) moves points by at most this many edge lengths (:func:`slide`).
# Measured: 1.6 on two random triangulations of a sheet with a centred round bump (the pose had turned 7 degrees
# about it); 0.9 with a bump on an axis (the pose right within 0.4 degrees); 0.2-0.6 on the benchmark's partial
# terrain sheets and face scan crops (poses exact); 0 on exact copies
PINNED = 1.0
# ... and when moving it rigidly along its weakest motion, until some vertex has moved this many edge lengths, raises
# the RMS above TIGHT edge lengths (:func:`probed_rms`). The linear test sees only the discretization of the normals
# where the relief pins nothing: two remeshings of one spherical cap fit within 3e-4 after a turn of 169 degrees
# about the sphere's centre, with a slide of 0.99 (sqrt(lambda_min) 0.0095, against 0.015 on two halves of a weak
# relief sheet, whose pose is exact, and 0.07-0.2 on the benchmark's terrain sheets)
PROBE = 10.0
PROBE_HALVINGS = 3  # the probe's distance is halved up to this many times while the overlap is too narrow for it
# a pose above TIGHT (vertex noise: the warp fits no closer) is pinned when the probe raises its RMS above this many
# times the pose's own: 3.1-3.5 on centred crops of a relief sheet with vertex noise 0.003 (80-97%), 2.03-2.04 with
# noise 0.006 (80%), 1.24-1.29 on a nearly flat square with one round bump and noise of 0.2% of its diagonal on one
# mesh (turned 2-23 degrees about the bump, 86-95% overlaps: registered whole, as without the noise); between the two
PROBE_RISE = 1.6
UNPINNED = "the relief does not pin the pose: the meshes slide along each other"
# a partial overlap that the warp finds in the meshes' own units (scale 1), when their areas differ, stands only when
# it fits this many times closer (RMS over the overlap in each warp's edge lengths) than the warp at the scale of the
# areas' ratio, one surface in two units (the pose's scale is a guess when no rigid motion makes the meshes coincide).
# Measured, RMS at the areas' ratio over RMS in the meshes' units: whole pairs posed at scale 1, 0.38 (a random relief
# sheet rolled 90 degrees and scaled 2.5, whose first had been laid on 17% of the second), 0.40 (one rolled 99
# degrees, scaled 2.42) and 0.64 (a sheet of relief 0.03 rolled 90 degrees, scaled 2.5); bent crops of low relief
# (peak to peak 0.037 and 0.024) 0.85 and 1.0: registered whole (the first had been judged partial, 0.38 off; the
# second was whole already, 0.38 off)
UNITS_RATIO = 1.5
# a partial overlap found by the warp needs at least one mesh with this fraction of its area in the common region: a
# warp lays a patch of low relief anywhere on the other. Measured on whole random relief sheets bent 75-102 degrees
# (peak to peak 0.026-0.035), "elastic" overlaps of 0.22 / 0.04, 0.08 / 0.02 and 0.00 / 0.00 (trimmed to nothing: an
# error); the benchmark's bent face crops 0.90 / 0.93; bent crops of 86% and 50% of the same sweep warped in their own
# units 0.67 / 0.57 and 0.43 / 0.87
ELASTIC_OVERLAP = 0.3
UNITS = "a deformed pair that fits as closely at the scale of its areas' ratio as in its own units: not judged"
# ... and a partial overlap in the meshes' own units is not judged against a warp at the areas' ratio that failed:
# a random relief sheet (peak to peak 0.1) rolled 90 degrees and scaled 2.5, posed at scale 1, was laid on 9% of the
# second (57% of the first, "elastic"), while the warp at the areas' ratio, started from a whole registration of the
# wrong symmetry, slid off the first in its first rigid step (60 edges) and coincided nowhere (RMS inf)
UNTESTED = "the warp at the scale of the areas' ratio failed: a partial overlap in the meshes' own units is not judged"
# ... and a partial overlap yields to a warp at the areas' ratio that coincides over more of the less-covered mesh:
# the same sheet (peak to peak 0.1, 1500 / 2000 vertices, rolled 90 degrees, scaled 2.5) posed at scale 1 was laid
# 95% on 14% of the second (RMS 0.033 edges) while the warp at the areas' ratio coincided (99.9% within COINCIDE)
# over 73% / 74% (RMS 0.069: UNITS_RATIO had kept the partial overlap; registered whole, 0.012 off). No true partial
# pair of the benchmark or of 40 random crops of relief sheets (50-81%, bent 0-90 degrees) reaches this comparison
COVERS = "the warp at the scale of the areas' ratio makes more of the less-covered mesh coincide than a partial overlap"
QUICK_SAMPLE = 2000  # points per mesh (spread evenly over its area) that judge the overlap in same_region


@dataclass(frozen=True)
class Side:
    """One mesh's view of the overlap.

    Attributes
    ----------
    signed : ndarray, shape (n,)
        Per disk vertex, the signed distance to the other mesh's rim (first's units; positive inside); per sample
        point when :func:`same_region` decided (regime "full").
    distance : ndarray, shape (n,)
        Per disk vertex (or sample point), the distance to the other mesh (first's units); NaN where it was not
        measured (see :func:`signed_rim_distance`).
    fraction : float
        Fraction of the mesh's area where ``signed`` >= 0 (triangles cut along its zero line).
    """

    signed: np.ndarray
    distance: np.ndarray
    fraction: float


@dataclass(frozen=True)
class Overlap:
    """Where two meshes overlap (see the module docstring).

    Attributes
    ----------
    regime : {"full", "rigid", "elastic", "whole", "deformed"}
    first, second : Side
    alignment : Alignment
        The pose of the second mesh in the first's frame.
    positions : ndarray, shape (n2, 3)
        The second disk's vertices in the first's frame: posed, and bent by the warp in the "elastic" regime.
    edges : tuple of float
        Each mesh's median edge (first's units: the second's at the pose's scale); :attr:`edge`, the pair's edge
        length, is the larger.
    rms : dict
        RMS distance over the overlap of the pose ("pose"), of the pose moved along its weakest motion when it was
        judged (:func:`probed_rms`, "probe") and, when it was tried, of the warp ("warp").
    coincide : float
        Fraction of the overlap's vertices within COINCIDE edge lengths of the other mesh.
    slide : float
        :func:`slide` of the pose over the overlap, in edge lengths (NaN for a warp: not judged).
    seconds : float
        Time taken to find it.
    reason : str
        Why the meshes are registered whole although they may not cover the same region (regime "whole").
    target : Surface
        The first disk as a :class:`~meshreg.mesh.surface.Surface` (its queries cached for the next steps).
    source : Surface
        The second disk as a :class:`~meshreg.mesh.surface.Surface`, unposed (likewise).
    """

    regime: str
    first: Side
    second: Side
    alignment: Alignment
    positions: np.ndarray
    edges: tuple
    rms: dict = field(default_factory=dict)
    coincide: float = float("nan")
    slide: float = float("nan")
    seconds: float = 0.0
    reason: str = ""
    target: Surface | None = field(default=None, repr=False, compare=False)
    source: Surface | None = field(default=None, repr=False, compare=False)

    @property
    def edge(self) -> float:
        """The pair's edge length: the coarser mesh's median edge (first's units)."""
        return max(self.edges)

    def posed_source(self) -> Surface:
        """The second mesh (``source``) moved by the alignment's pose into the first's frame."""
        return self.source.moved(self.alignment.matrix)

    def summary(self) -> dict:
        """The overlap as plain values (for ``result.info``)."""
        return {
            "regime": self.regime,
            "reason": self.reason,
            "first_fraction": self.first.fraction,
            "second_fraction": self.second.fraction,
            "coincide": self.coincide,
            "slide": self.slide,
            "rms": dict(self.rms),
            "edge": self.edge,
            "scale": self.alignment.scale,
            "pose_source": self.alignment.source,
            "pose": self.alignment.matrix.tolist(),
            "seconds": self.seconds,
            "parameters": parameters(),
        }


def parameters() -> dict:
    """The numerics of the pose, the overlap and the warp (module constants), as recorded with each result."""
    from . import align, warp

    names = {
        align: ("FEATURE_VOXEL", "RANSAC_TRIALS", "ICP_TRIM", "SCORE_LEVELS", "SCORE_ENOUGH", "AXES_TURNS")
        + ("SCALE_TIE", "SCALED_MARGIN"),
        warp: ("WARP_WEIGHTS", "WARP_ROUNDS", "WARP_TRIM", "WARP_TRIM_FLOOR", "WARP_TURN"),
    }
    out = {name: getattr(module, name) for module, keys in names.items() for name in keys}
    local = ("SNAP", "BAND", "COINCIDE", "COINCIDE_ENOUGH", "TIGHT", "RIGID_RATIO", "FULL_TOLERANCE", "RIM_SLACK")
    local += ("SAME_SCALE",)
    local += ("PINNED", "PROBE", "PROBE_HALVINGS", "PROBE_RISE", "QUICK_SAMPLE", "UNITS_RATIO", "ELASTIC_OVERLAP")
    out.update({name: globals()[name] for name in local})
    return {k: list(v) if isinstance(v, tuple) else v for k, v in out.items()}


def signed_rim_distance(points: np.ndarray, other: Surface) -> tuple[np.ndarray, np.ndarray]:
    """Per point (k, 3): the signed distance to ``other``'s rim (positive: the closest point on ``other`` is
    inside, by its distance to the rim; negative: it is on the rim, by the tangential gap) and the distance to
    ``other``.

    Exact (closest points on the triangles) for points whose nearest vertex of ``other`` lies within BAND edge
    lengths of its rim, and for a sample of STATISTICS_SAMPLE others; the rest, deep inside, take their nearest
    vertex's distance to the rim (only the sign matters there) and a NaN distance."""
    points = np.asarray(points, dtype=float)
    _, nearest = other.tree.query(points)
    vertex_rim = other.vertex_rim_distance[nearest]
    exact = vertex_rim <= BAND * other.edge
    inner = np.flatnonzero(~exact)
    if len(inner) > STATISTICS_SAMPLE:
        inner = np.random.default_rng(0).choice(inner, STATISTICS_SAMPLE, replace=False)
    exact[inner] = True
    signed, distance = vertex_rim.copy(), np.full(len(points), np.nan)
    signed[exact], distance[exact] = exact_rim_distance(points[exact], other)
    return signed, distance


def exact_rim_distance(points: np.ndarray, other: Surface) -> tuple[np.ndarray, np.ndarray]:
    """:func:`signed_rim_distance` of every point (k, 3) from its closest point on the triangles of ``other``."""
    closest, distance, normal = other.closest(points)
    rim = other.rim_distance(closest)
    gap = points - closest
    tangential = np.linalg.norm(gap - np.sum(gap * normal, axis=1, keepdims=True) * normal, axis=1)
    return np.where(rim <= RIM_EPSILON * other.edge, -tangential, rim), distance


@dataclass(frozen=True)
class Clipped:
    """A mesh cut along the zero line of a per-vertex function, keeping where it is >= 0.

    Attributes
    ----------
    vertices : ndarray, shape (k, 3)
    faces : ndarray, shape (f, 3)
    carry : scipy.sparse matrix, shape (k, n)
        Per-vertex values of the mesh as given carried to the clipped vertices (``carry @ values``): kept vertices
        copy theirs, cut points interpolate along their edge.
    parent : ndarray, shape (k,)
        The vertex each clipped vertex is (-1 for a cut point).
    face_parent : ndarray, shape (f,)
        The triangle each clipped triangle comes from.
    """

    vertices: np.ndarray
    faces: np.ndarray
    carry: sp.csr_matrix
    parent: np.ndarray
    face_parent: np.ndarray


def clip(vertices: np.ndarray, faces: np.ndarray, values: np.ndarray) -> Clipped:
    """Cut a triangle mesh along the zero line of ``values`` (n,) (linear in each triangle) and keep the part where
    they are >= 0: triangles wholly there (with at least one corner above 0) kept, those across the line split, the
    rest dropped, also those with every corner at 0 (which :func:`area_fraction` counts as inside)."""
    n = len(vertices)
    pos = values > 0
    neg = values < 0
    keep_whole = ~neg[faces].any(axis=1) & pos[faces].any(axis=1)
    across = neg[faces].any(axis=1) & pos[faces].any(axis=1)
    new_faces, face_parent = [faces[keep_whole]], [np.flatnonzero(keep_whole)]
    cut_index: dict = {}
    cut_rows: list = []

    def cut(a: int, b: int) -> int:
        key = (min(a, b), max(a, b))
        if key not in cut_index:
            t = values[key[0]] / (values[key[0]] - values[key[1]])
            cut_index[key] = n + len(cut_rows)
            cut_rows.append((key[0], key[1], t))
        return cut_index[key]

    for f in np.flatnonzero(across):
        corners = faces[f]
        polygon = []
        for k in range(3):
            a, b = int(corners[k]), int(corners[(k + 1) % 3])
            if values[a] >= 0:
                polygon.append(a)
            if (values[a] > 0 and values[b] < 0) or (values[a] < 0 and values[b] > 0):
                polygon.append(cut(a, b))
        for k in range(1, len(polygon) - 1):
            new_faces.append(np.array([[polygon[0], polygon[k], polygon[k + 1]]]))
            face_parent.append(np.array([f]))
    faces_out = np.vstack(new_faces).astype(np.int64)
    rows = np.array(cut_rows, dtype=float).reshape(-1, 3)
    a, b, t = rows[:, 0].astype(np.int64), rows[:, 1].astype(np.int64), rows[:, 2]
    k = len(rows)
    carry = sp.vstack(
        [
            sp.identity(n, format="csr"),
            sp.csr_matrix((np.r_[1 - t, t], (np.r_[np.arange(k), np.arange(k)], np.r_[a, b])), shape=(k, n)),
        ]
    ).tocsr()
    used = np.unique(faces_out)
    remap = np.full(n + k, -1)
    remap[used] = np.arange(len(used))
    parent = np.r_[np.arange(n), np.full(k, -1)][used]
    all_vertices = carry @ np.asarray(vertices, dtype=float)
    return Clipped(all_vertices[used], remap[faces_out], carry[used], parent, np.concatenate(face_parent))


def area_fraction(disk: DiskMesh, values: np.ndarray) -> float:
    """Fraction of a disk's area (its triangles as given: hole-filling fans left out) where ``values`` >= 0.
    Triangles whose corners are all at 0 (within SNAP edge lengths of the other's rim, :func:`snapped`) count as
    inside: on a mesh whose triangles near the rim are much smaller than its median edge (long thin triangles,
    a fine band along the rim), whole rows of them lie in that band although the meshes cover the same region."""
    original = np.all(disk.faces < len(disk.vertex_map), axis=1)
    areas = triangle_areas(disk.vertices, disk.faces)
    clipped = clip(disk.vertices, disk.faces, values)
    kept = original[clipped.face_parent]
    on_rim = original & np.all(values[disk.faces] == 0, axis=1)
    inside = triangle_areas(clipped.vertices, clipped.faces[kept]).sum() + areas[on_rim].sum()
    return float(inside / areas[original].sum())


def snapped(values: np.ndarray, edge: float) -> np.ndarray:
    """Signed distances with those within SNAP edge lengths of 0 set to 0."""
    return np.where(np.abs(values) < SNAP * edge, 0.0, values)


def _side(points: np.ndarray, disk: DiskMesh, other: Surface, edge: float) -> Side:
    signed, distance = signed_rim_distance(points, other)
    signed = snapped(signed, edge)
    return Side(signed, distance, area_fraction(disk, signed))


def area_sample(surface: Surface, count: int, seed: int) -> np.ndarray:
    """``count`` random points (count, 3) spread evenly over a surface's area (seeded)."""
    rng = np.random.default_rng(seed)
    areas = np.linalg.norm(face_normals(surface.vertices, surface.faces), axis=1)
    triangle = rng.choice(len(areas), count, p=areas / areas.sum())
    u, v = rng.random((2, count))
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    corners = surface.vertices[surface.faces[triangle]]
    return corners[:, 0] + u[:, None] * (corners[:, 1] - corners[:, 0]) + v[:, None] * (corners[:, 2] - corners[:, 0])


def _sampled_side(signed: np.ndarray, distance: np.ndarray) -> Side:
    """A :class:`Side` from points spread evenly over a mesh's area: the fraction is the share of them inside."""
    return Side(signed, distance, float(np.mean(signed >= 0)))


def _coincidence(first: Side, second: Side, edge: float) -> tuple[float, float]:
    """RMS distance to the other mesh over both overlaps' vertices, and the fraction within COINCIDE edges."""
    d = np.r_[first.distance[first.signed >= 0], second.distance[second.signed >= 0]]
    d = d[np.isfinite(d)]
    if len(d) == 0:
        return np.inf, 0.0
    return float(np.sqrt(np.mean(d**2))), float(np.mean(d <= COINCIDE * edge))


def _normal_matrix(surface: Surface, keep: np.ndarray):
    """The point-to-plane normal matrix (6, 6) of a surface's vertices ``keep`` (rows ``[x cross n, n]``, mean over
    the points, x centred and scaled to unit RMS radius) with that centre and radius; None for fewer than 6."""
    points, normals = surface.vertices[keep], surface.normals[keep]
    if len(points) < 6:
        return None
    centre = points.mean(axis=0)
    radius = max(float(np.sqrt(np.mean(np.sum((points - centre) ** 2, axis=1)))), 1e-300)
    rows = np.hstack([np.cross((points - centre) / radius, normals), normals])
    return rows.T @ rows / len(rows), centre, radius


def slide(surface: Surface, keep: np.ndarray, rms: float) -> float:
    """How far a rigid motion can slide a surface's vertices ``keep`` (bool, (n,)) along the surface while raising
    their RMS distance to it by only ``rms`` (first's units): ``rms / sqrt(lambda_min)``, lambda_min the smallest
    eigenvalue of the point-to-plane normal matrix (:func:`_normal_matrix`: a turn is measured by how far it moves
    points at the RMS radius). Large when the relief leaves a motion free (a turn about a surface of revolution, a
    shift along a ridge, any motion in the plane of a flat sheet); 0 for an exact fit."""
    return _slide(_normal_matrix(surface, keep), rms)


def _slide(system, rms: float) -> float:
    """:func:`slide` from the normal matrix of the vertices (:func:`_normal_matrix`; None: infinite)."""
    if system is None:
        return np.inf
    weakest = float(np.linalg.eigvalsh(system[0])[0])
    return float(rms / np.sqrt(weakest)) if weakest > 0 else np.inf


def probed_rms(points: np.ndarray, system, other: Surface, distance: float) -> float:
    """The RMS distance to ``other`` of a surface's vertices moved rigidly along their weakest motion.

    The motion is the screw motion of the eigenvector of :func:`slide`'s smallest eigenvalue, until the farthest
    vertex has moved ``distance`` (halved, up to PROBE_HALVINGS times, while fewer than half the vertices stay inside
    ``other``'s rim: a narrow overlap). Where the relief pins the motion the RMS grows with ``distance``; on a piece
    of a sphere it stays at the fit's noise.

    Parameters
    ----------
    points : ndarray, shape (k, 3)
        The surface's vertices over the overlap.
    system : tuple or None
        Their point-to-plane normal matrix, centre and radius (:func:`_normal_matrix`, as :func:`slide` uses it).
    other : Surface
        The other mesh, posed.
    distance : float
        How far the farthest vertex moves (the surface's units).

    Returns
    -------
    float
        The RMS over the moved vertices inside ``other``'s rim; NaN when the probe cannot tell (fewer than 6
        vertices, no motion, or too few inside at every distance tried).
    """
    if system is None:
        return np.nan
    matrix, centre, radius = system
    turn, shift = np.linalg.eigh(matrix)[1][:, 0].reshape(2, 3)
    offsets = points - centre
    reach = float(np.linalg.norm(np.cross(turn, offsets / radius) + shift, axis=1).max()) * radius
    if reach <= 0:
        return np.nan
    for _ in range(PROBE_HALVINGS + 1):
        amount = distance / reach
        moved = transform_points(_motion(turn * amount, radius * shift * amount), offsets) + centre
        signed, gaps = signed_rim_distance(moved, other)
        if np.sum(signed >= 0) >= len(offsets) / 2:
            gaps = gaps[(signed >= 0) & np.isfinite(gaps)]
            return float(np.sqrt(np.mean(gaps**2))) if len(gaps) else np.nan
        distance /= 2
    return np.nan


def _motion(turn: np.ndarray, shift: np.ndarray) -> np.ndarray:
    """The rigid motion (4, 4) that the constant velocity (``turn``, ``shift``) (angular, linear at the origin) makes
    in unit time: the exponential of the twist, a screw motion (a turn about a sphere's centre stays on the sphere,
    which the turn about the origin followed by ``shift`` would not)."""
    from scipy.spatial.transform import Rotation

    angle = float(np.linalg.norm(turn))
    cross = np.array([[0.0, -turn[2], turn[1]], [turn[2], 0.0, -turn[0]], [-turn[1], turn[0], 0.0]])
    if angle < 1e-3:  # the series: 1 - cos and angle - sin lose their digits
        first, second = 0.5 - angle**2 / 24, 1 / 6 - angle**2 / 120
    else:
        first, second = 2 * np.sin(angle / 2) ** 2 / angle**2, (angle - np.sin(angle)) / angle**3
    carried = np.eye(3) + first * cross + second * cross @ cross
    out = np.eye(4)
    out[:3, :3] = Rotation.from_rotvec(turn).as_matrix()
    out[:3, 3] = carried @ shift
    return out


def _sides(first: DiskMesh, second: DiskMesh, target: Surface, placed: Surface, edge: float):
    """Both sides of the overlap with the second at ``placed`` (its Surface in the first's frame), the RMS distance
    over the overlap and the fraction that coincides."""
    one = _side(first.vertices, first, placed, edge)
    two = _side(placed.vertices, second, target, edge)
    return one, two, *_coincidence(one, two, edge)


def _verdict(regime: str, one: Side, two: Side, coincide: float, scale: float, slid: float, edges: tuple):
    """The regime (and why the meshes are registered whole, if they are) of an overlap found at a pose ("rigid",
    whose :func:`slide` is ``slid`` edge lengths) or with the warp ("elastic"): "full" also when neither mesh reaches
    further beyond the other's rim than :func:`_same_rim` allows (``edges``: the first's, the second's)."""
    tolerance = FULL_TOLERANCE[regime]
    if coincide < COINCIDE_ENOUGH:
        return "whole", "no pose or warp makes the meshes coincide where they overlap"
    if (one.fraction >= 1 - tolerance and two.fraction >= 1 - tolerance) or _same_rim(one, two, edges):
        return "full", ""
    if regime == "rigid" and not slid <= PINNED:
        return "whole", UNPINNED
    if regime == "elastic" and max(one.fraction, two.fraction) < ELASTIC_OVERLAP:
        return "whole", "the warp brings too little of either mesh into a common region"
    if regime == "elastic" and abs(np.log(scale)) > SAME_SCALE:
        return "whole", "a deformed pair at different scales: its overlap is not judged"
    return regime, ""


def _same_rim(one: Side, two: Side, edges: tuple) -> bool:
    """Whether neither mesh reaches further beyond the other's rim than RIM_SLACK edges of the mesh whose rim it
    crosses (the first's vertices against the second's rim chords, and the reverse), plus the pose's shift: a pose
    off by a shift takes each mesh beyond the other's rim on opposite sides, so the smaller of the two reaches (at
    most RIM_SLACK of the coarser edge) is allowed both ways; a crop reaches one way only."""
    reach = (-float(np.min(one.signed, initial=0.0)), -float(np.min(two.signed, initial=0.0)))
    shift = min(*reach, RIM_SLACK * max(edges))
    return reach[0] <= RIM_SLACK * edges[1] + shift and reach[1] <= RIM_SLACK * edges[0] + shift


def rigid_overlap(first: DiskMesh, second: DiskMesh, quick: float = 0.0) -> Overlap:
    """Pose the second mesh in the first's frame (:func:`meshreg.mesh.align.align`) and find where they overlap at
    that pose. Regime "full" or "rigid" when the pose makes them coincide (RMS over the overlap below TIGHT edge
    lengths); "full" also when the pose is looser but already shows each mesh covering the other at the rigid
    tolerance (a noisy or smoothed copy: the warp would only confirm it; the warp's looser tolerance had taken noisy
    crops of 95% and 97% of a sheet for the whole); else "deformed": the warp of
    :func:`warped_overlap` decides. With ``quick`` > 0, :func:`same_region` at that tolerance is tried first (no
    feature search when it finds the meshes covering the same region)."""
    start = time.perf_counter()
    s1, s2 = Surface(first.vertices, first.faces), Surface(second.vertices, second.faces)
    found = same_region(s1, s2, quick, start) if quick > 0 else None
    if found is not None:
        return found
    alignment = align(s1, s2)
    edges = (s1.edge, alignment.scale * s2.edge)
    edge = max(edges)
    posed = s2.moved(alignment.matrix)
    one, two, rms, coincide = _sides(first, second, s1, posed, edge)
    inside = one.signed >= 0
    system = _normal_matrix(s1, inside)  # for the slide and the probe
    slid, spread = _slide(system, rms) / edge, {"pose": rms}
    if rms <= TIGHT * edge:
        regime, reason = _verdict("rigid", one, two, coincide, alignment.scale, slid, edges)
        if regime == "rigid":
            spread["probe"] = _probe(s1, inside, posed, edge, system)
            # unpinned only when the probe shows it: NaN (a narrow overlap) leaves the verdict to the slide
            regime, reason = ("whole", UNPINNED) if spread["probe"] <= TIGHT * edge else ("rigid", "")
    elif _verdict("rigid", one, two, coincide, alignment.scale, slid, edges)[0] == "full":
        regime, reason = "full", ""  # the pose already shows each mesh covering the other: no warp needed
    else:
        regime, reason = "deformed", ""
    seconds = time.perf_counter() - start
    return Overlap(regime, one, two, alignment, posed.vertices, edges, spread, coincide, slid, seconds, reason, s1, s2)


def rigid_match(first: DiskMesh, second: DiskMesh, found: Overlap) -> Overlap | None:
    """``found`` (regime "full") as the rigid overlap at its pose that :func:`meshreg.mesh.partial.register_overlap`
    registers, when the pose pins a rigid match: RMS over the overlap at most TIGHT edge lengths, :func:`slide` at
    most PINNED, and moved PROBE edge lengths along its weakest motion the RMS rises above TIGHT
    (:func:`probed_rms`): one surface, moved rigidly and scaled, whose right correspondence is the pose's closest
    points. Else None: another regime, or a probe that cannot tell (NaN; :func:`rigid_overlap` leaves such a verdict
    to the slide, this check does not trust it), or one that shows a slide (a cone patch over a round rim: slide 0.74
    but the probe 0.011 edge lengths; the pose was 1.3 degrees off about the axis). The RMS judged is the one the
    verdict "full" was made with; both sides, the RMS and the coincidence are then measured again at every vertex
    (the quick check of :func:`same_region` holds samples: a round-rim Enneper patch measured 0.041 edge lengths on
    its samples, 0.055 over its vertices, and its pose was right within 0.06 degrees)."""
    edge = found.edge
    if not (found.regime == "full" and found.rms["pose"] <= TIGHT * edge and found.slide <= PINNED):
        return None
    posed = found.posed_source()
    one, two, rms, coincide = _sides(first, second, found.target, posed, edge)
    probe = _probe(found.target, one.signed >= 0, posed, edge)
    if not probe > TIGHT * edge:
        return None
    rms = {**found.rms, "pose": rms, "probe": probe}
    return replace(found, regime="rigid", first=one, second=two, rms=rms, coincide=coincide)


def _probe(target: Surface, inside: np.ndarray, posed: Surface, edge: float, system=None) -> float:
    """:func:`probed_rms` of a pose: the ``target``'s vertices ``inside`` (bool, (n,)) the overlap moved PROBE
    ``edge`` lengths along their weakest motion (of ``system``, :func:`_normal_matrix`, computed when not given),
    their RMS distance to the ``posed`` other mesh."""
    system = _normal_matrix(target, inside) if system is None else system
    return probed_rms(target.vertices[inside], system, posed, PROBE * edge)


def same_region(first: Surface, second: Surface, tolerance: float, start: float | None = None) -> Overlap | None:
    """Regime "full" from a cheap look, or None when it does not show it (then :func:`rigid_overlap` runs the
    feature search): at the principal-axes pose (:func:`meshreg.mesh.align.axes_pose`), at most ``tolerance`` of
    QUICK_SAMPLE random points spread evenly over each mesh's area lie beyond the other's rim, and COINCIDE_ENOUGH
    of the rest coincide with the other mesh. The sides of the returned overlap hold the samples' signed
    distances, not every vertex's (a "full" overlap trims nothing).

    Parameters
    ----------
    first, second : Surface
        The two disks.
    tolerance : float
        ``Options.advanced.overlap_quick`` (at most FULL_TOLERANCE["rigid"]: the check only confirms "full").
    start : float, optional
        ``time.perf_counter()`` when the overlap search began (for :attr:`Overlap.seconds`).
    """
    start = time.perf_counter() if start is None else start
    if not (first.area > 0 and second.area > 0):
        return None
    alignment = axes_pose(first, second)
    if alignment is None:
        return None
    matrix, scale = alignment.matrix, alignment.scale
    edges = (first.edge, scale * second.edge)
    edge = max(edges)
    points1, points2 = (area_sample(s, QUICK_SAMPLE, seed) for seed, s in enumerate((first, second)))
    points2 = transform_points(matrix, points2)
    signed1, distance1 = (
        scale * d for d in exact_rim_distance(transform_points(np.linalg.inv(matrix), points1), second)
    )
    signed2, distance2 = exact_rim_distance(points2, first)
    one, two = (_sampled_side(snapped(v, edge), d) for v, d in ((signed1, distance1), (signed2, distance2)))
    rms, coincide = _coincidence(one, two, edge)
    if coincide < COINCIDE_ENOUGH or min(one.fraction, two.fraction) < 1 - min(tolerance, FULL_TOLERANCE["rigid"]):
        return None
    posed = transform_points(matrix, second.vertices)
    quick = Alignment(matrix, alignment.rms, alignment.scores, "principal axes (quick check)")
    slid = slide(first, np.ones(len(first.vertices), dtype=bool), rms) / edge  # reported, as by rigid_overlap
    seconds = time.perf_counter() - start
    return Overlap("full", one, two, quick, posed, edges, {"pose": rms}, coincide, slid, seconds, "", first, second)


def warped_overlap(first: DiskMesh, second: DiskMesh, posed: Overlap, matches: np.ndarray) -> Overlap:
    """The overlap of a pair that no pose makes coincide (``posed``, regime "deformed"), from an
    as-rigid-as-possible warp of the second mesh onto the first (:func:`meshreg.mesh.warp.arap_warp`).

    The warp starts from the pose that fits the second (at the scale of ``posed``) onto ``matches``, its vertices'
    matches on the first by the elastic registration of the whole meshes: that pose centres a bent mesh where a
    rigid fit settles on one side. When the warp does not bring the meshes much closer than the pose (RMS within
    RIGID_RATIO), the pose stands (regime "rigid": noise, not deformation) if the relief pins it (the slide, and the
    probe raising the RMS above PROBE_RISE times the pose's own; else "whole"). The scale of a pose that no rigid motion
    makes coincide is a guess, so a partial overlap in the meshes' own units (scale 1) stands only when it fits
    clearly better than the warp at the scale of the meshes' areas' ratio, one surface in two units
    (:func:`_by_units`; a partial verdict needs the meshes' own units, so the reverse is not tried).

    Parameters
    ----------
    first, second : DiskMesh
    posed : Overlap
        :func:`rigid_overlap` of the two.
    matches : ndarray, shape (n2, 3)
        Per vertex of the second disk, its matched point on the first (NaN: none).
    """
    start = time.perf_counter()
    found = _warped(first, second, posed, matches, posed.alignment.scale)
    if posed.rms["pose"] <= RIGID_RATIO * found.rms["warp"]:
        one, two, coincide = posed.first, posed.second, posed.coincide
        regime, reason = _verdict("rigid", one, two, coincide, posed.alignment.scale, posed.slide, posed.edges)
        rms = found.rms
        if regime == "rigid":  # a noisy pose: pinned when moving it raises its RMS well above the noise's
            moved = posed.posed_source()
            rms = {**rms, "probe": _probe(posed.target, posed.first.signed >= 0, moved, posed.edge)}
            regime, reason = ("whole", UNPINNED) if rms["probe"] <= PROBE_RISE * rms["pose"] else (regime, reason)
        found = replace(posed, regime=regime, reason=reason, rms=rms)
    elif found.regime == "elastic" and (areas := _areas_scale(posed)) is not None:
        found = _by_units(found, _warped(first, second, posed, matches, areas))
    return replace(found, seconds=posed.seconds + time.perf_counter() - start)


def _warped(first: DiskMesh, second: DiskMesh, posed: Overlap, matches: np.ndarray, scale: float) -> Overlap:
    """The overlap after the warp of the second disk at ``scale`` (see :func:`warped_overlap`), judged as elastic;
    its alignment is the pose's at that scale (its centroid kept), its RMS ``{"pose", "warp"}``."""
    target = posed.target
    rest = scale * second.vertices
    known = np.all(np.isfinite(matches), axis=1)
    c0, c1 = rest[known].mean(axis=0), matches[known].mean(axis=0)
    rotation = kabsch((rest[known] - c0).T @ (matches[known] - c1))
    warped = arap_warp((rest - c0) @ rotation.T + c1, second.faces, target)
    ratio = scale / posed.alignment.scale
    edges = (posed.edges[0], posed.edges[1] * ratio)
    one, two, rms, coincide = _sides(first, second, target, Surface(warped, second.faces), max(edges))
    regime, reason = _verdict("elastic", one, two, coincide, scale, float("nan"), edges)
    matrix = posed.alignment.matrix.copy()
    centre = second.vertices.mean(axis=0)
    matrix[:3, :3] *= ratio
    matrix[:3, 3] += posed.alignment.matrix[:3, :3] @ centre - matrix[:3, :3] @ centre
    alignment = replace(posed.alignment, matrix=matrix)
    rms_all = {**posed.rms, "warp": rms}
    return Overlap(
        regime, one, two, alignment, warped, edges, rms_all, coincide, float("nan"), 0.0, reason, target, posed.source
    )


def _areas_scale(posed: Overlap) -> float | None:
    """The scale of one surface in two units: the square root of the meshes' areas' ratio (the other scale of
    :func:`meshreg.mesh.align.align`, :func:`meshreg.mesh.align.areas_scale`); None when it is within SAME_SCALE of
    1."""
    areas = areas_scale(posed.target, posed.source)
    return None if abs(np.log(areas)) <= SAME_SCALE else areas


def _by_units(units: Overlap, areas: Overlap) -> Overlap:
    """Of a deformed pair's warps in its own units (``units``, regime "elastic") and at the scale of its areas' ratio
    (``areas``), the partial overlap when its warp fits UNITS_RATIO times closer (RMS in each warp's edge lengths);
    else ``areas`` (regime "whole", or "full" if it shows the meshes covering each other: registered whole).

    A warp at the areas' ratio whose common region does not coincide (less than COINCIDE_ENOUGH of it within
    COINCIDE edges: the warp failed, it did not test the pair as one surface in two units) leaves nothing for the
    partial overlap to beat, and the pose's scale 1 is only a guess: registered whole (reason UNTESTED). One that
    coincides over a larger share of the less-covered mesh than the partial overlap (:func:`_least_covered`)
    explains more of both meshes as one surface: registered whole whatever the RMS (reason COVERS; a patch fits a
    region of a bent copy more closely than the whole does)."""
    if not areas.coincide >= COINCIDE_ENOUGH:
        return replace(areas, regime="whole", reason=UNTESTED)
    if _least_covered(areas) > _least_covered(units):
        return areas if areas.regime == "full" else replace(areas, regime="whole", reason=COVERS)
    if UNITS_RATIO * units.rms["warp"] / units.edge < areas.rms["warp"] / areas.edge:
        return units
    return areas if areas.regime == "full" else replace(areas, regime="whole", reason=UNITS)


def _least_covered(found: Overlap) -> float:
    """The smaller of the two meshes' fractions of area in the common region of an overlap."""
    return min(found.first.fraction, found.second.fraction)


def trim(disk: DiskMesh, signed: np.ndarray) -> tuple[DiskMesh, sp.csr_matrix]:
    """The disk cut to where ``signed`` >= 0, cleaned into a disk (largest piece, holes filled), its vertices that
    come from the disk as given first (in the order of their input ids), then cut points and hole-filling
    vertices.

    Returns the trimmed disk and the matrix (k, n) carrying per-vertex values of ``disk`` to its vertices (a
    hole-filling vertex gets the mean of its ring)."""
    clipped = clip(disk.vertices, disk.faces, signed)
    piece = prepare_disk(clipped.vertices, clipped.faces)
    k = len(piece.vertex_map)
    carry = clipped.carry[piece.vertex_map]
    if len(piece.vertices) > k:  # hole-filling vertices: the mean of their ring
        rows, cols = [], []
        for v in range(k, len(piece.vertices)):
            ring = np.unique(piece.faces[np.any(piece.faces == v, axis=1)])
            ring = ring[ring < k]
            rows += [v - k] * len(ring)
            cols += ring.tolist()
        counts = np.bincount(rows, minlength=len(piece.vertices) - k)
        fill = sp.csr_matrix((1.0 / counts[rows], (rows, cols)), shape=(len(piece.vertices) - k, k)) @ carry
        carry = sp.vstack([carry, fill]).tocsr()
    parent = np.full(len(piece.vertices), -1)
    parent[:k] = clipped.parent[piece.vertex_map]
    known = (parent >= 0) & (parent < len(disk.vertex_map))
    input_id = np.where(known, disk.vertex_map[np.clip(parent, 0, len(disk.vertex_map) - 1)], -1)
    order = np.r_[np.flatnonzero(known)[np.argsort(input_id[known], kind="stable")], np.flatnonzero(~known)]
    inverse = np.argsort(order)
    report = [f"kept the overlap: {len(order)} vertices ({int(known.sum())} of the mesh's)", *piece.report]
    renumbered = np.full(len(disk.vertices), -1)
    renumbered[parent[known]] = inverse[np.flatnonzero(known)]
    trimmed = DiskMesh(
        piece.vertices[order],
        inverse[piece.faces],
        inverse[piece.boundary],
        input_id[order][: int(known.sum())],
        report,
        disk.aliases,
        _kept_feet(disk.ear_feet, renumbered),
    )
    return trimmed, carry[order]


def _kept_feet(feet: EarFeet | None, renumbered: np.ndarray) -> EarFeet | None:
    """The removed ears' apexes (:class:`~meshreg.mesh.topology.EarFeet`) whose base is kept by the trimming, their
    base renumbered (``renumbered``: the disk's vertex ids to the trimmed disk's, -1 where cut away); None if none."""
    if feet is None:
        return None
    base = renumbered[feet.base]
    kept = np.all(base >= 0, axis=1)
    return EarFeet(feet.ids[kept], feet.points[kept], base[kept], feet.t[kept]) if kept.any() else None
