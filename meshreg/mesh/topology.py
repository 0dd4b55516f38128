"""Loading meshes and checking/cleaning them into disks (one component, one boundary loop, manifold)."""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

import numba
import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import breadth_first_order, connected_components

from ..errors import InputError
from ..files import MESH_SUFFIXES, existing_file
from ..grid import check_scale, coordinates
from .boundary import sharp_corners
from .graph import edge_table, face_components, triangle_areas
from .ordering import spatial_order
from .pages import small_pages
from .ply import read_ply

# a mesh whose vertices sit further from the origin than this many times its size has lost the digits of its
# shape if it was stored in float32 (7 digits): its triangles collapse
FAR_FROM_ORIGIN = 1e4
# the cleanup may drop at most this share of a mesh's triangles: beyond it the file is damaged rather than a disk with
# a few defects (a float32 file far from the origin had 737 of its 2001 triangles collapse and kept 44 after the
# cleanup), and what is left would register as another surface. Two pieces of equal size keep the larger, reported
MAX_DROPPED = 0.75
# float32 coordinates are refused when their spacing at the mesh's distance from the origin is above this fraction of
# the median edge length: the triangles' shapes are then quantized beyond repair (a mesh 1e6 from the origin with edges
# of 0.05 has a spacing of 0.0625, 125%; a float32 scan in UTM metres, 5e5 from the origin with edges of 0.5, 6%, kept)
FLOAT32_STEP = 0.25
# meshes of at least this many vertices are cleaned and mapped in space order (:func:`prepare_disk`): at 1M triangles in
# random vertex order, every linear kernel of the front end (the cleanup's edge table and components, the Laplacian's
# pattern and weights, the resampling) ran 18-25 times its time at 100k triangles, its arrays beyond the caches
SPACE_ORDER_MIN = 100_000


def load_mesh(path) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (n, 3) and faces (m, 3) of a mesh file, vertex order kept (trimesh, ``process=False``).

    Binary PLY files of vertices and triangles are read by :func:`meshreg.mesh.ply.read_ply`, other files by
    trimesh. OBJ files are read without splitting vertices at texture or normal seams (a textured scan would
    otherwise fall apart into pieces) and in file order. STL and glTF/GLB files, which repeat vertices
    along seams or per triangle, have coincident vertices welded.
    """
    path = existing_file(path)
    suffix = path.suffix.lower()
    if suffix not in MESH_SUFFIXES:
        raise InputError(
            f"{path}: unknown mesh file type {suffix or '(no suffix)'!r}: meshes are {' '.join(MESH_SUFFIXES)}"
        )
    try:
        read = read_ply(path) if suffix == ".ply" else None
        vertices, faces = read if read is not None else _read_with_trimesh(path, suffix)
    except MemoryError:
        raise InputError(f"{path}: too large to read into memory") from None
    except InputError:
        raise
    except Exception as err:  # trimesh raises many types on bad files
        words = str(err).replace(str(path), "").strip(" :'\"")
        raise InputError(f"{path}: cannot read it as a {suffix} mesh ({type(err).__name__}: {words})") from None
    if len(vertices) == 0 or len(faces) == 0:
        raise InputError(f"{path}: no triangles read (an empty mesh, a point cloud, or a file cut short)")
    return vertices, faces


def _read_with_trimesh(path: Path, suffix: str) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and faces of a mesh file as trimesh reads it (``process=False``; see :func:`load_mesh`)."""
    import trimesh

    options = {"merge_tex": True, "merge_norm": True, "maintain_order": True} if suffix == ".obj" else {}
    _check_text_mesh(path, suffix)
    mesh = trimesh.load(path, process=False, force="mesh", **options)
    if suffix in (".stl", ".glb", ".gltf") and len(getattr(mesh, "faces", [])):
        mesh.merge_vertices()  # these formats repeat vertices along seams or per triangle: weld them
    vertices = np.asarray(getattr(mesh, "vertices", np.empty((0, 3))), dtype=float)
    return vertices, np.asarray(getattr(mesh, "faces", np.empty((0, 3))), dtype=np.int64)


# a face line of an OBJ file with a vertex index 0 (OBJ counts vertices from 1; some exporters write from 0)
_OBJ_ZERO = re.compile(rb"(?m)^[ \t]*f[ \t][^\n#]*?(?<=[ \t])0(?:/[^ \t\r\n#]*)?(?=[ \t\r\n#]|$)")


def _check_text_mesh(path: Path, suffix: str) -> None:
    """InputError for text files that trimesh would read wrong without a word: an OBJ face with vertex index 0
    (indices count from 1: trimesh takes 0 for the last vertex), an OFF file with fewer lines than its header's
    vertex and face counts promise (a file cut short, or counts that would read face lines as vertices)."""
    if suffix not in (".obj", ".off"):
        return
    data = path.read_bytes()
    if suffix == ".obj":
        if _OBJ_ZERO.search(data):
            raise InputError(
                f"{path}: a face refers to vertex 0, but OBJ counts vertices from 1 (an exporter that counts from "
                "0?): add 1 to every face index"
            )
        return
    lines = [t for t in (line.split(b"#")[0].strip() for line in data.splitlines()) if t]
    first = lines[0].split() if lines else [b""]
    if not first[0].endswith(b"OFF"):
        return  # not a header trimesh reads either: its own error says so
    counts = b" ".join(lines[:2]).split()[1:3]  # right after the keyword, on its line or the next
    body = lines[1:] if len(first) > 1 else lines[2:]
    try:
        vertices, faces = int(counts[0]), int(counts[1])
    except (IndexError, ValueError):
        return
    if len(body) < vertices + faces:
        raise InputError(
            f"{path}: its header promises {vertices} vertices and {faces} faces, one per line, but {len(body)} lines "
            "follow (a file cut short, or wrong counts): fix the header or export the mesh again"
        )


@dataclass(frozen=True)
class EarFeet:
    """Vertices that cleanup dropped with the boundary ears they were the apex of, and where each is matched: its foot
    on the ear's base, a boundary edge of the disk (the ear collapses onto it under the map to the square).

    Attributes
    ----------
    ids : ndarray (k,)
        Input ids of the apexes.
    points : ndarray (k, 3)
        Their positions.
    base : ndarray (k, 2)
        The disk vertices at the two ends of each ear's base.
    t : ndarray (k,)
        The foot of each apex on its base: (1 - t) base[:, 0] + t base[:, 1], t in [0, 1].
    """

    ids: np.ndarray
    points: np.ndarray
    base: np.ndarray
    t: np.ndarray


@dataclass
class DiskMesh:
    """A mesh with disk topology and its boundary loop.

    Attributes
    ----------
    vertices : ndarray (n, 3)
    faces : ndarray (m, 3)
    boundary : ndarray (b,)
        Vertex indices of the boundary loop, in the order that makes the faces' orientation positive.
    vertex_map : ndarray (k,), k <= n
        Index in the mesh as given of each of the first k vertices (cleanup may drop vertices); the
        n - k vertices after them were added by hole filling (one at the centre of each filled hole). Increasing,
        except for a mesh cleaned in space order (SPACE_ORDER_MIN vertices or more, see :func:`prepare_disk`).
    report : list of str
        What the cleanup did.
    aliases : ndarray (n_input,) or None
        The representative of each input vertex when cleanup welded coincident vertices.
    ear_feet : EarFeet or None
        The apexes of removed boundary ears that no other triangle held, each with its foot on the ear's base.
    """

    vertices: np.ndarray
    faces: np.ndarray
    boundary: np.ndarray
    vertex_map: np.ndarray
    report: list = field(default_factory=list)
    aliases: np.ndarray | None = None
    ear_feet: EarFeet | None = None

    def to_input(self, values: np.ndarray, n_input: int, fill) -> np.ndarray:
        """Per-vertex values (n, k) of this disk carried back to the ``n_input`` vertices of the mesh as given.

        Vertices that cleanup dropped get ``fill``; welded duplicates get their representative's value;
        vertices added by hole filling have no input vertex and are left out.
        """
        out = np.tile(np.asarray(fill, dtype=float), (n_input, 1))
        out[self.vertex_map] = values[: len(self.vertex_map)]
        return out if self.aliases is None else out[self.aliases]

    def source_of(self, ids) -> np.ndarray:
        """Ids in the mesh as given of this disk's vertices ``ids`` (any shape): -1 for a vertex the input does not
        have (a hole-filling centre, a cut point of a trimmed disk). The inverse of :meth:`input_ids`."""
        ids = np.asarray(ids, dtype=np.int64)
        known = ids < len(self.vertex_map)
        return np.where(known, self.vertex_map[np.minimum(ids, len(self.vertex_map) - 1)], -1)

    def input_ids(self, ids) -> np.ndarray:
        """Indices in this disk of vertices given by their ids in the input mesh (InputError if dropped, or if the ids
        are not integers)."""
        given = np.asarray(ids)
        if given.dtype.kind not in "iu":
            raise InputError(f"vertex ids are integers, got {ids!r}")
        given = ids = given.astype(np.int64)
        if self.aliases is not None:
            inside = (ids >= 0) & (ids < len(self.aliases))
            ids = np.where(inside, self.aliases[np.clip(ids, 0, len(self.aliases) - 1)], -1)
        where = np.full(int(self.vertex_map.max(initial=0)) + 1, -1, dtype=np.int64)
        where[self.vertex_map] = np.arange(len(self.vertex_map))
        at = np.where((ids >= 0) & (ids < len(where)), where[np.clip(ids, 0, len(where) - 1)], -1)
        if np.any(at < 0):
            raise InputError(f"vertex ids {given[at < 0].tolist()} are not in the (cleaned) mesh")
        return at


def loop_segments(vertices: np.ndarray, loop) -> np.ndarray:
    """Length of each edge (b,) of a closed vertex loop, edge k running from loop[k] to loop[k + 1]."""
    loop = np.asarray(loop)
    return np.linalg.norm(vertices[np.roll(loop, -1)] - vertices[loop], axis=1)


def _repeated_corner(faces: np.ndarray) -> np.ndarray:
    """Whether each face (m,) uses one vertex twice."""
    return (faces[:, 0] == faces[:, 1]) | (faces[:, 1] == faces[:, 2]) | (faces[:, 0] == faces[:, 2])


def _edges(faces):
    """Directed edges (3m, 2), the first directed edge of each undirected edge, each directed edge's undirected
    edge id, use counts (:func:`~meshreg.mesh.graph.edge_table`), and the directed edges used once (the rims)."""
    directed, first, inverse, counts = edge_table(faces)
    return directed, first, inverse, counts, np.flatnonzero(counts[inverse] == 1)


def prepare_disk(
    vertices: np.ndarray,
    faces: np.ndarray,
    *,
    cleanup: bool = True,
    fill_holes: bool | None = None,
    checked: Callable[[np.ndarray, np.ndarray], None] | None = None,
) -> DiskMesh:
    """Check (and with ``cleanup``, repair what is safe) that a mesh is a topological disk.

    Cleanup, always reported: drop degenerate (zero-area) triangles, keep the largest connected
    component, fill holes, drop boundary ears (triangles with two sides, hence all three corners, on the
    boundary: they collapse under a convex map) except those at the four clear corners of a boundary that has
    them, drop unreferenced vertices.

    Parameters
    ----------
    vertices : ndarray (n, 3)
    faces : ndarray (m, 3)
    cleanup : bool
        Repair what is safe (default) instead of raising: also removes the triangles around vertices
        where the boundary touches itself (non-manifold vertices, common in range scans).
    fill_holes : bool, optional
        Close every boundary loop but the longest (the outer boundary) with a fan around a new vertex
        at the hole's centroid. Defaults to ``cleanup``.
    checked : callable, optional
        Called with the vertices (n, 3) and faces (m, 3) once they are checked and (SPACE_ORDER_MIN vertices or
        more) renumbered, before the cleanup: work that needs the mesh as the disk will most often have it can begin
        there (:meth:`meshreg.mesh.early.EarlyAnalysis.begin`).

    Raises
    ------
    InputError
        NaN coordinates, non-manifold edges, a closed surface, several boundary loops (without hole filling), a
        cleanup that would drop more than MAX_DROPPED of the triangles, a boundary of fewer than 4 vertices (too
        small to map to a square).

    Examples
    --------
    >>> import trimesh
    >>> ring = trimesh.creation.annulus(r_min=0.3, r_max=1.0, height=0.1, sections=32)
    >>> top = ring.faces[ring.face_normals[:, 2] > 0.9]
    >>> disk = prepare_disk(ring.vertices, top)
    >>> disk.report[0]
    'filled 1 hole (32 boundary vertices)'
    """
    fill_holes = cleanup if fill_holes is None else fill_holes
    v, f = _checked_arrays(vertices, faces)
    with small_pages(len(v)):  # large meshes' arrays: see meshreg.mesh.pages
        return _cleaned(v, f, cleanup, fill_holes, checked)


def _cleaned(v: np.ndarray, f: np.ndarray, cleanup: bool, fill_holes: bool, checked) -> DiskMesh:
    """:func:`prepare_disk` of checked arrays (:func:`_checked_arrays`)."""
    v, f, order = _space_ordered(v, f)
    if checked is not None:
        checked(v, f)
    given, report = f, []
    f = _drop_degenerate(v, f, cleanup, report)
    edges = _edges(f)  # recomputed only when a step changes the faces
    welded, aliases = _welded(v, f, cleanup, report, edges)
    f, edges = _unchanged_or_new(welded, f, edges)
    f, edges = _unchanged_or_new(_consistent_orientation(f, cleanup, report, edges), f, edges)
    f, edges = _unchanged_or_new(_unpinched(f, cleanup, report, edges), f, edges)
    n = len(v)
    f, edges = _unchanged_or_new(_largest_component(f, n, cleanup, report), f, edges)
    loops, rim = _boundary_loops(f, edges), 0
    if len(loops) > 1 and fill_holes:
        v, f, added, rim = _fill_holes(v, f, loops)
        edges = _edges(f)
        report.append(f"filled {added} hole{'s' if added > 1 else ''} ({rim} boundary vertices)")
    ears = np.empty((0, 3), dtype=np.int64)
    if cleanup:
        kept, ears = _without_ears(v, f, report, edges)
        f, edges = _unchanged_or_new(kept, f, edges)
        _kept_enough(v, given, len(f) - rim, report)
    disk = _disk(v, f, edges, n, ears, report, aliases)
    return disk if order is None else _input_numbered(disk, order)


def _space_ordered(v: np.ndarray, f: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """A mesh of SPACE_ORDER_MIN vertices or more renumbered along a Morton curve (:func:`_relabelled`) and the
    order (input id of each new vertex); a smaller one as it is, and None."""
    if len(v) < SPACE_ORDER_MIN:
        return v, f, None
    order = spatial_order(v)
    return v[order], _relabelled(f, order), order


@numba.njit(cache=True, nogil=True)
def _relabelled(faces: np.ndarray, order: np.ndarray) -> np.ndarray:
    """The faces (m, 3) with vertex ``order[k]`` renamed k, corners in their order, the faces sorted by their lowest
    new vertex (a counting sort, stable): neighbouring faces get nearby places too."""
    n, m = len(order), faces.shape[0]
    rank = np.empty(n, np.int64)
    for k in range(n):
        rank[order[k]] = k
    start = np.zeros(n + 1, np.int64)
    for t in range(m):
        start[min(rank[faces[t, 0]], rank[faces[t, 1]], rank[faces[t, 2]]) + 1] += 1
    for k in range(n):
        start[k + 1] += start[k]
    out = np.empty((m, 3), np.int64)
    for t in range(m):
        a, b, c = rank[faces[t, 0]], rank[faces[t, 1]], rank[faces[t, 2]]
        at = start[min(a, b, c)]
        out[at, 0], out[at, 1], out[at, 2] = a, b, c
        start[min(a, b, c)] += 1
    return out


def _input_numbered(disk: DiskMesh, order: np.ndarray) -> DiskMesh:
    """A disk cleaned in space order (vertex ``order[k]`` of the input was numbered k) with its references to the
    input (:attr:`DiskMesh.vertex_map`, the aliases, the ear apexes' ids) in the input's numbering."""
    aliases = None
    if disk.aliases is not None:
        aliases = np.empty_like(disk.aliases)
        aliases[order] = order[disk.aliases]
    feet = None if disk.ear_feet is None else replace(disk.ear_feet, ids=order[disk.ear_feet.ids])
    return replace(disk, vertex_map=order[disk.vertex_map], aliases=aliases, ear_feet=feet)


def _welded(
    v: np.ndarray, f: np.ndarray, cleanup: bool, report: list, edges: tuple
) -> tuple[np.ndarray, np.ndarray | None]:
    """With ``cleanup``, the faces with coincident vertices welded where :func:`_weld_pieces` welds them (a mesh in
    pieces, or a seam cut into one piece; ``edges``: :func:`_edges` of f), and each vertex's representative (None:
    nothing welded, and f itself returned)."""
    aliases, pieces = _weld_pieces(v, f, edges) if cleanup else (None, 0)
    if aliases is None:
        return f, None
    welded = int(np.sum(aliases != np.arange(len(v))))
    how = f"the mesh came in {pieces} pieces" if pieces > 1 else "a seam cut into the surface"
    report.append(f"welded {welded} coincident vertices ({how})")
    f = aliases[f]
    return f[~_repeated_corner(f)], aliases


def _disk(v, f, edges, n: int, ears: np.ndarray, report: list, aliases) -> DiskMesh:
    """The DiskMesh of cleaned faces ``f`` (edge table ``edges``) over ``v`` (the ``n`` input vertices first, then
    hole-filling ones): unreferenced vertices dropped (reported), the rest renumbered in order, the removed ``ears``'
    apexes kept as feet."""
    used = _used_vertices(f, len(v))
    original = used[used < n]
    if len(original) < n:
        report.append(f"dropped {n - len(original)} unreferenced vertices")
    remap = np.full(len(v), -1)
    remap[used] = np.arange(len(used))
    feet = _ear_feet(v, ears, remap)
    v, f = v[used], remap[f]
    edges = (remap[edges[0]], *edges[1:])  # an increasing renumbering keeps the edge table's order
    loop = np.array(_single_loop(v, f, edges))
    if len(loop) < 4:
        after = f" after the cleanup ({'; '.join(report)})" if report else ""
        raise InputError(
            f"the mesh is too small to map to a square: its boundary has {len(loop)} vertices{after}, at least 4 "
            "are needed; give a mesh of more triangles"
        )
    return DiskMesh(v, f, loop, original, report, aliases, feet)


def _ear_feet(v: np.ndarray, ears: np.ndarray, remap: np.ndarray) -> EarFeet | None:
    """The apexes of removed ears (faces (e, 3), ids before ``remap``, the renumbering of the kept vertices, -1 for
    dropped ones) that were dropped, each with its foot on the ear's base (kept vertices, renumbered); None without."""
    dropped = remap[ears] < 0
    ears, dropped = ears[dropped.sum(axis=1) == 1], dropped[dropped.sum(axis=1) == 1]
    if len(ears) == 0:
        return None
    apex = ears[dropped]
    base = ears[~dropped].reshape(-1, 2)
    apex, first = np.unique(apex, return_index=True)  # an apex of two ears: the first
    base = base[first]
    a, b = v[base[:, 0]], v[base[:, 1]]
    t = np.clip(np.sum((v[apex] - a) * (b - a), axis=1) / np.maximum(np.sum((b - a) ** 2, axis=1), 1e-300), 0, 1)
    return EarFeet(apex, v[apex], remap[base], t)


def _used_vertices(faces: np.ndarray, n: int) -> np.ndarray:
    """Ids (increasing) of the vertices, of n, that some face uses."""
    used = np.zeros(n, dtype=bool)
    used[faces.ravel()] = True
    return np.flatnonzero(used)


def _unchanged_or_new(new: np.ndarray, old: np.ndarray, edges: tuple) -> tuple[np.ndarray, tuple]:
    """The faces a cleanup step returned and their :func:`_edges`: those of ``old`` when the step kept them."""
    return new, edges if new is old else _edges(new)


def _checked_arrays(vertices, faces) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (n, 3) float and faces (m, 3) int, refused when misshapen, empty, not finite real numbers, beyond
    the coordinate range of :func:`meshreg.grid.check_scale`, or out of range."""
    v = coordinates(vertices, "mesh vertex coordinates")
    try:
        f = np.asarray(faces)
    except ValueError as err:
        raise InputError(f"mesh faces are not an array of vertex ids ({err})") from None
    if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3:
        raise InputError(f"a mesh needs vertices (n, 3) and triangular faces (m, 3), got {v.shape} and {f.shape}")
    if len(f) == 0 or len(v) == 0:
        raise InputError("the mesh has no triangles (a point cloud?): give a triangle mesh")
    if f.dtype.kind not in "iu" and not (f.dtype.kind == "f" and np.all(np.isfinite(f)) and np.all(f == np.round(f))):
        raise InputError(f"mesh faces must be integer vertex ids, got {f.dtype}")
    f = f.astype(np.int64)
    if f.min() < 0 or f.max() >= len(v):
        raise InputError("faces refer to vertices that do not exist")
    check_scale(v, "mesh vertex coordinates")
    return v, f


def _check_precision(v: np.ndarray, f: np.ndarray) -> None:
    """InputError when the coordinates of a mesh with degenerate triangles are float32 values (a float32 file) whose
    step at their distance from the origin is more than FLOAT32_STEP of the median edge length: the triangles
    collapsed because the shape lost its digits. (Exact double data on a coarse lattice, a DEM on whole metres at
    a northing of 8.5e6, has float32 values too, but no degenerate triangles.)"""
    if not np.array_equal(v, v.astype(np.float32)):
        return
    offset = float(np.abs(v).max())
    step = float(np.spacing(np.float32(offset)))
    edge = float(np.median(np.linalg.norm(v[f[:, 0]] - v[f[:, 1]], axis=1)))
    if step > FLOAT32_STEP * edge:
        share = f"{step / edge:.0%} of the median edge length ({edge:.1e})" if edge > 0 else "and the edges collapsed"
        raise InputError(
            f"the triangles collapsed: the vertex coordinates are float32 values {offset:.1e} from the origin, where "
            f"float32 steps by {step:.1e}, {share}; save the mesh in double precision, or move it to the origin first"
        )


def _drop_degenerate(v: np.ndarray, f: np.ndarray, cleanup: bool, report: list) -> np.ndarray:
    """Faces without the zero-area ones (or an error without ``cleanup``); an error when more than MAX_DROPPED of
    them are, or when they come from a float32 file's collapse (:func:`_check_precision`)."""
    area = triangle_areas(v, f)
    bad = (area <= 1e-14 * max(area.max(), 1e-300)) | _repeated_corner(f)
    if not bad.any():
        return f
    _check_precision(v, f)
    if bad.sum() > MAX_DROPPED * len(f):
        share = "all" if bad.all() else f"{int(bad.sum())} of the"
        raise InputError(f"{share} {len(f)} triangles of the mesh are degenerate (zero area){_collapse_hint(v, f)}")
    if not cleanup:
        raise InputError(
            f"the mesh has {int(bad.sum())} degenerate (zero-area) triangles: remove them or allow cleanup"
        )
    report.append(f"removed {int(bad.sum())} degenerate triangles")
    return f[~bad]


def _collapse_hint(v: np.ndarray, f: np.ndarray) -> str:
    """Why a mesh's triangles may have collapsed: its used vertices all coincide, or sit far from the origin for
    their span (a float32 file); "" otherwise."""
    used = v[np.unique(f)]
    offset, size = float(np.abs(used).max()), float(np.linalg.norm(np.ptp(used, axis=0)))
    hint = "; its vertices all coincide" if size == 0 else ""
    if offset > FAR_FROM_ORIGIN * size:
        hint += (
            f"; they sit {offset:.1e} from the origin and span {size:.1e}: a float32 file keeps 7 digits, so a "
            "small mesh far from the origin collapses (move it to the origin before saving it)"
        )
    return hint


def _kept_enough(v: np.ndarray, given: np.ndarray, kept: int, report: list) -> None:
    """InputError when the cleanup kept fewer than 1 - MAX_DROPPED of the ``given`` faces (``kept`` of them left,
    the hole fillings not counted), naming its first steps."""
    if kept < (1 - MAX_DROPPED) * len(given):
        steps = "; ".join(report[:2]) + ("; ..." if len(report) > 2 else "")
        raise InputError(
            f"the cleanup kept only {kept} of the mesh's {len(given)} triangles ({steps}){_collapse_hint(v, given)}: "
            "it is too damaged to register as one disk; repair it first (cleanup=False names the first defect)"
        )


def _consistent_orientation(f: np.ndarray, cleanup: bool, report: list, edges: tuple) -> np.ndarray:
    """Faces wound like their neighbours (``edges``: :func:`_edges` of f); non-manifold edges are refused."""
    counts = edges[3]
    if np.any(counts > 2):
        raise InputError(
            f"the mesh has {int(np.sum(counts > 2))} non-manifold edges (shared by 3+ triangles): repair it first"
        )
    flipped = _orientation_flips(f, edges)
    if not flipped.any():
        return f
    if not cleanup:
        raise InputError(
            f"{int(flipped.sum())} triangles are oriented against their neighbours: fix the winding or allow cleanup"
        )
    report.append(f"reoriented {int(flipped.sum())} triangles to agree with their neighbours")
    return np.where(flipped[:, None], f[:, ::-1], f)


def _unpinched(f: np.ndarray, cleanup: bool, report: list, edges: tuple) -> np.ndarray:
    """With ``cleanup``, faces without the triangles around vertices where the boundary touches itself
    (``edges``: :func:`_edges` of f)."""
    for _ in range(10):
        starts, uses = np.unique(boundary_edges(f, edges)[:, 0], return_counts=True)
        pinched = starts[uses > 1]  # the boundary passes twice through these vertices
        if not (cleanup and len(pinched)):
            break
        touching = np.isin(f, pinched).any(axis=1)
        f = f[~touching]
        edges = _edges(f)
        report.append(
            f"removed {int(touching.sum())} triangles around {len(pinched)} vertices where the boundary touches itself"
        )
    if len(f) == 0:
        raise InputError("no triangles are left after cleanup: the mesh is not a usable disk")
    return f


def _largest_component(f: np.ndarray, n: int, cleanup: bool, report: list) -> np.ndarray:
    """The faces of the connected component with the most triangles (an error without ``cleanup``)."""
    labels, ncomp = face_components(f, n)
    if ncomp == 1:
        return f
    if not cleanup:
        raise InputError(f"the mesh has {ncomp} connected components: keep one or allow cleanup")
    keep = labels == np.bincount(labels).argmax()
    report.append(f"kept the largest of {ncomp} components ({int(keep.sum())} of {len(f)} triangles)")
    return f[keep]


def _without_ears(v: np.ndarray, f: np.ndarray, report: list, edges: tuple) -> tuple[np.ndarray, np.ndarray]:
    """Faces without boundary ears (two sides on the boundary), in one pass: peeling again would eat thin strips
    triangle by triangle; and the ears removed.

    An ear collapses under a map onto a convex boundary when its three corners land on one side of the square, but
    not when its apex (the vertex between its two boundary sides) is a corner of the square: so when the boundary
    has exactly four clear corners (:func:`~meshreg.mesh.boundary.sharp_corners`, counted with the ears in place),
    the ears at those corners are kept (a square sheet's corner triangles are ears)."""
    none = np.empty((0, 3), dtype=f.dtype)
    if len(f) <= 1:
        return f, none
    _, _, inverse, counts, _ = edges
    on_boundary = (counts[inverse] == 1).reshape(3, -1).T  # (m, 3): side k runs from corner k to corner k + 1
    ears = on_boundary.sum(axis=1) >= 2
    if not ears.any() or ears.all():
        return f, none
    loops = _boundary_loops(f, edges)
    corners = sharp_corners(v, f, loops[0]) if len(loops) == 1 else None
    if corners is not None:
        apex = f[np.arange(len(f)), (np.argmax(on_boundary & np.roll(on_boundary, 1, axis=1), axis=1))]
        ears &= ~np.isin(apex, np.asarray(loops[0])[corners])
        if not ears.any():
            return f, none
    report.append(f"removed {int(ears.sum())} boundary ears (triangles with two sides on the boundary)")
    return f[~ears], f[ears]


def _single_loop(v: np.ndarray, f: np.ndarray, edges: tuple) -> list:
    """The one boundary loop of a disk (``edges``: :func:`_edges` of f); a closed surface, several loops or another
    Euler characteristic is refused."""
    loops = _boundary_loops(f, edges)
    if not loops:
        raise InputError("the surface is closed (no boundary): cut it open first (a disk is needed)")
    if len(loops) > 1:
        sizes = sorted((len(x) for x in loops), reverse=True)
        raise InputError(
            f"the mesh has {len(loops)} boundary loops (sizes {sizes[:5]}): fill its holes so that one loop is left"
        )
    euler = len(v) - len(edges[1]) + len(f)
    if euler != 1:
        raise InputError(f"the mesh is not a disk (Euler characteristic {euler}, a disk has 1)")
    return loops[0]


def _weld_pieces(v, f, edges: tuple) -> tuple[np.ndarray | None, int]:
    """For a mesh in several pieces held together only by coincident vertices (a triangle soup, seams of an
    exporter): each vertex's representative (the first vertex at its position) and the number of pieces. A mesh in
    one piece gets its coincident boundary vertices welded only when that leaves a disk (:func:`_seam_aliases`;
    ``edges``: :func:`_edges` of f). Else (None, pieces)."""
    pieces = face_components(f, len(v))[1]
    if pieces < 2:
        return _seam_aliases(v, f, edges), pieces
    _, first, inverse = np.unique(v, axis=0, return_index=True, return_inverse=True)
    aliases = first[inverse.ravel()]
    if np.all(aliases == np.arange(len(v))) or face_components(aliases[f], len(v))[1] >= pieces:
        return None, pieces
    return aliases, pieces


def _seam_aliases(v, f, edges: tuple) -> np.ndarray | None:
    """Representatives of a one-piece mesh's coincident boundary vertices when welding them closes a slit without
    changing the surface's kind (an exporter's seam cut into the surface from its rim: welded, the loops are as many
    as before or fewer, none added, and the surface has genus 0: Euler characteristic 2 - loops; a hole elsewhere
    stays a hole for the cleanup to fill); None otherwise, so that a deliberate cut is kept (a cylinder cut open would
    become an annulus, a sphere cut open a closed surface). ``edges``: :func:`_edges` of f."""
    if len(f) == 0:
        return None
    rim = np.unique(boundary_edges(f, edges))
    _, first, inverse = np.unique(v[rim], axis=0, return_index=True, return_inverse=True)
    if len(first) == len(rim):
        return None
    aliases = np.arange(len(v))
    aliases[rim] = rim[first[inverse.ravel()]]
    welded = aliases[f]
    welded = welded[~_repeated_corner(welded)]
    welded_edges = _edges(welded)
    counts = welded_edges[3]
    loops = len(boundary_sizes(welded, welded_edges))
    if len(welded) < len(f) or np.any(counts > 2) or not 1 <= loops <= len(boundary_sizes(f, edges)):
        return None
    euler = len(np.unique(welded)) - len(counts) + len(welded)
    return aliases if euler == 2 - loops else None


def _fill_holes(v, f, loops):
    """Close all loops but the longest (in length) by fans around their centroids; returns v, f, the number of
    holes filled and of vertices around them."""
    outer = int(np.argmax([loop_segments(v, x).sum() for x in loops]))
    new_v, new_f = [v], [f]
    n = len(v)
    for k, loop in enumerate(loops):
        if k == outer:
            continue
        loop = np.asarray(loop)
        new_v.append(v[loop].mean(axis=0, keepdims=True))
        # the loop runs with the mesh on its left: the filling faces use its edges backwards
        new_f.append(np.c_[np.roll(loop, -1), loop, np.full(len(loop), n)])
        n += 1
    return np.vstack(new_v), np.vstack(new_f), len(loops) - 1, sum(len(x) for x in loops) - len(loops[outer])


def _orientation_flips(faces, edges) -> np.ndarray:
    """Which triangles (m,) to reverse so that every interior edge is crossed in opposite directions by its
    two triangles (a consistent winding; per component, the orientation of most triangles wins). ``edges``
    is :func:`_edges` of the faces."""
    e, first, inverse, _, _ = edges
    m = len(faces)
    b = np.flatnonzero(first[inverse] != np.arange(len(e)))  # the second directed edge of each interior edge
    a = first[inverse[b]]
    same = e[a, 0] == e[b, 0]  # both triangles run the shared edge the same way: one must flip
    if not same.any():
        return np.zeros(m, dtype=bool)
    fa, fb = a % m, b % m
    graph = sp.csr_matrix((np.ones(len(fa)), (fa, fb)), shape=(m, m))
    parity = np.full(m, -1)
    keys = zip(np.minimum(fa, fb).tolist(), np.maximum(fa, fb).tolist(), strict=True)
    same_lookup = dict(zip(keys, same.tolist(), strict=True))
    for root in range(m):
        if parity[root] >= 0:
            continue
        nodes, parents = breadth_first_order(graph, root, directed=False)
        parity[root] = 0
        for node in nodes[1:]:
            p = parents[node]
            parity[node] = parity[p] ^ same_lookup[min(p, node), max(p, node)]
        component = nodes
        if parity[component].sum() * 2 > len(component):
            parity[component] ^= 1
    flips = parity.astype(bool)
    check = flips[fa] ^ flips[fb]
    if np.any(check != same):
        raise InputError("the mesh is not orientable (a Moebius-like band): it cannot be mapped to a square")
    return flips


def boundary_sizes(faces, edges: tuple | None = None) -> list[int]:
    """Edges of each boundary of a triangle mesh, largest first: its boundary edges (used by one triangle) grouped
    into connected pieces. Works on raw meshes too (a boundary that touches itself counts as one piece). ``edges``:
    :func:`_edges` of the faces, when known."""
    f = np.asarray(faces, dtype=np.int64)
    if len(f) == 0:
        return []
    edges = boundary_edges(f, edges)
    if len(edges) == 0:
        return []
    n = int(f.max()) + 1
    graph = sp.coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n, n))
    labels = connected_components(graph, directed=False)[1][edges[:, 0]]
    return sorted(np.bincount(labels)[np.unique(labels)].tolist(), reverse=True)


def boundary_edges(faces: np.ndarray, edges: tuple | None = None) -> np.ndarray:
    """Directed edges (b, 2) used by one triangle only (the rim and the rims of holes), in the faces' order
    (``edges``: :func:`_edges` of the faces, when known)."""
    e, _, _, _, rim = _edges(faces) if edges is None else edges
    return e[rim]


def unique_edges(faces: np.ndarray) -> np.ndarray:
    """Undirected edges (e, 2) of a triangle mesh, each once as (lower id, higher id), sorted."""
    directed, first, _, _, _ = _edges(faces)
    edges = np.sort(directed[first], axis=1)
    return edges[np.lexsort((edges[:, 1], edges[:, 0]))]


def _boundary_loops(faces, edges: tuple | None = None) -> list[list[int]]:
    """Boundary loops following the faces' directed edges (so the interior lies to their left; ``edges``:
    :func:`_edges` of the faces, when known)."""
    directed = boundary_edges(faces, edges)
    nxt = {}
    for a, b in directed:
        if a in nxt:
            raise InputError("the boundary touches itself at a vertex (non-manifold vertex): repair the mesh first")
        nxt[int(a)] = int(b)
    loops, seen = [], set()
    for start in nxt:
        if start in seen:
            continue
        loop, cur = [], start
        while cur not in seen:
            seen.add(cur)
            loop.append(cur)
            cur = nxt.get(cur)
            if cur is None:
                raise InputError("the boundary is not a closed loop: the faces are not consistently oriented")
        loops.append(loop)
    return loops
