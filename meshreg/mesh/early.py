"""The harmonic map's symbolic analysis begun on a mesh as given, while its cleanup runs.

The LU of a mesh Laplacian's interior block needs an ordering and a symbolic analysis that depend on the faces
alone (:func:`~meshreg.mesh.frontal.analyse`); on a 1M-triangle mesh they take 1.3 s of one core, the longest part
of the front end, and could begin only after the cleanup (0.3 s more) had settled the faces. Most meshes come out of
the cleanup unchanged: :class:`EarlyAnalysis` analyses the mesh as given (after its space-order renumbering) in a
second thread while the cleanup runs, and the map takes that analysis when the cleaned disk has the same vertices,
faces and boundary, which makes it the very analysis it would have computed. Otherwise the early one is abandoned
(the thread stops within one pivot of the ordering) and the map analyses its own disk as before.
"""

from __future__ import annotations

from concurrent.futures import Future, ThreadPoolExecutor

import numba
import numpy as np

from .frontal import Analysis, analyse
from .harmonic import face_pattern
from .ordering import Abandoned, spatial_order

# vertices from which the analysis begins before the cleanup: on the 100k-triangle benchmark mesh (50k vertices)
# the front end took the same time either way; at 500k vertices (1M triangles) it saved 0.3-0.5 s of 3
EARLY_MIN = 100_000


@numba.njit(cache=True, nogil=True)
def _rim_vertices(faces: np.ndarray, n: int) -> np.ndarray:
    """Whether each of the ``n`` vertices (n,) lies on an edge that one face alone uses: the edges bucketed by
    their lower vertex, each bucket's upper vertices counted (O(n + m))."""
    m = faces.shape[0]
    start = np.zeros(n + 1, np.int64)
    for t in range(m):
        for k in range(3):
            start[min(faces[t, k], faces[t, (k + 1) % 3]) + 1] += 1
    for a in range(n):
        start[a + 1] += start[a]
    upper, fill = np.empty(3 * m, np.int64), start[:-1].copy()
    for t in range(m):
        for k in range(3):
            a, b = faces[t, k], faces[t, (k + 1) % 3]
            low = min(a, b)
            upper[fill[low]] = max(a, b)
            fill[low] += 1
    count, rim = np.zeros(n, np.int64), np.zeros(n, np.bool_)
    for a in range(n):
        for p in range(start[a], start[a + 1]):
            count[upper[p]] += 1
        for p in range(start[a], start[a + 1]):
            if count[upper[p]] == 1:
                rim[a] = rim[upper[p]] = True
        for p in range(start[a], start[a + 1]):
            count[upper[p]] = 0
    return rim


def _interior_analysis(vertices: np.ndarray, faces: np.ndarray, stop: np.ndarray) -> tuple[np.ndarray, Analysis]:
    """The interior vertices in space order and the symbolic analysis of the interior block's pattern, as
    :class:`~meshreg.mesh.harmonic.HarmonicMap` computes them for a disk with these vertices and faces."""
    inside = ~_rim_vertices(faces, len(vertices))
    order = spatial_order(vertices)
    interior = order[inside[order]]
    ni = len(interior)
    place = np.full(len(vertices), ni, np.int64)  # every vertex of the boundary after the interior, as in the map
    place[interior] = np.arange(ni)
    return interior, analyse(face_pattern(faces, place, ni), stop=stop)


class EarlyAnalysis:
    """The harmonic map's analysis of a mesh begun before its cleanup.

    Pass :meth:`begin` to :func:`~meshreg.mesh.topology.prepare_disk` (``checked=``), which calls it with the
    checked, renumbered arrays before it cleans them, and the object to
    :class:`~meshreg.mesh.harmonic.HarmonicMap` (``early=``), which :meth:`claim` s the analysis at its first solve
    and keeps it when its own interior vertices are those analysed. Meshes of fewer than ``minimum`` vertices
    (EARLY_MIN) are not analysed early.

    Examples
    --------
    >>> from meshreg.mesh.samples import random_disk_mesh, terrain_function
    >>> from meshreg.mesh.topology import prepare_disk
    >>> from meshreg.mesh.harmonic import HarmonicMap, choose_corners
    >>> v, f, _ = random_disk_mesh(terrain_function(), 300, seed=0)
    >>> early = EarlyAnalysis(minimum=0)
    >>> disk = prepare_disk(v, f, checked=early.begin)
    >>> uv, info = HarmonicMap(disk, early=early)(choose_corners(disk))
    >>> early.used
    True
    """

    def __init__(self, minimum: int = EARLY_MIN):
        self.minimum = minimum
        self.used = False  # whether a map kept the early analysis
        self._faces: np.ndarray | None = None
        self._future: Future | None = None
        self._stop = np.zeros(1, np.bool_)

    def begin(self, vertices: np.ndarray, faces: np.ndarray) -> None:
        """Start analysing the mesh (vertices (n, 3) float, faces (m, 3) int, as the cleanup receives them) in a
        thread of its own, when it has ``minimum`` vertices or more and nothing was begun yet."""
        if len(vertices) < self.minimum or self._future is not None:
            return
        self._faces = np.ascontiguousarray(faces, dtype=np.int64)
        pool = ThreadPoolExecutor(1, thread_name_prefix="meshreg-early")
        self._future = pool.submit(_interior_analysis, vertices, self._faces, self._stop)
        pool.shutdown(wait=False)

    def claim(self, faces: np.ndarray) -> Future | None:
        """The analysis under way, a future of (interior vertices (ni,), Analysis), when ``faces`` (the cleaned
        disk's) are the faces analysed; else None, the early work abandoned and waited for (no thread is left
        running, e.g. across a fork). Once only: later claims get None."""
        future, given = self._future, self._faces
        self._future = self._faces = None
        if future is None:
            return None
        if np.array_equal(faces, given):
            return future
        self._stop[0] = True
        try:
            future.result()
        except Abandoned:
            pass
        return None

    def kept(self, claimed: Future, interior: np.ndarray) -> Analysis | None:
        """The claimed analysis when its interior vertices are ``interior`` (the map's own: then the analysis is
        the one the map would compute), else None."""
        found, analysis = claimed.result()
        self.used = np.array_equal(found, interior)
        return analysis if self.used else None
