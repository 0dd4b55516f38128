"""The harmonic map's symbolic analysis begun on a mesh as given, while its cleanup runs.

The LU of a mesh Laplacian's interior block needs an ordering and a symbolic analysis that depend on the faces
alone (:func:`~meshreg.mesh.frontal.analyse`); on a 1M-triangle mesh they take 1.3 s of one core, the longest part
of the front end, and could begin only after the cleanup (0.3 s more) had settled the faces. Most meshes come out of
the cleanup unchanged: :class:`EarlyAnalysis` analyses the mesh as given (after its space-order renumbering) in a
second thread while the cleanup runs, and the map takes that analysis when the cleaned disk has the same faces and
interior vertices, which makes it the very analysis it would have computed. Otherwise the early one is abandoned (the
thread stops at the next pivot of the ordering or the next stage of the analysis) and the map analyses its own disk
as before.
"""

from __future__ import annotations

from concurrent.futures import Future, ThreadPoolExecutor

import numba
import numpy as np

from .frontal import Analysis, analyse, ordered_in_space
from .harmonic import face_pattern, interior_in_space_order
from .pages import small_pages

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


def _interior(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """The interior vertices (ni,) in space order, as :attr:`~meshreg.mesh.harmonic.HarmonicMap.interior` finds them
    for a disk with these vertices and faces (whose boundary is the vertices on edges that one face alone uses)."""
    return interior_in_space_order(vertices, _rim_vertices(faces, len(vertices)))


def _interior_analysis(
    faces: np.ndarray, interior: np.ndarray, points: np.ndarray | None, n: int, stop: np.ndarray
) -> Analysis:
    """The symbolic analysis of the Laplacian's interior block pattern for a disk of ``n`` vertices with these faces
    and ``interior`` vertices (at ``points`` (ni, 3), or None: see :meth:`EarlyAnalysis.claim`), as
    :class:`~meshreg.mesh.harmonic.HarmonicMap` computes it."""
    ni = len(interior)
    place = np.full(n, ni, np.int64)  # every vertex of the boundary after the interior, as in the map
    place[interior] = np.arange(ni)
    with small_pages(n):  # a block of its own: the thread may outlive the cleanup's
        return analyse(face_pattern(faces, place, ni), stop=stop, symmetric=True, points=points)


class EarlyAnalysis:
    """The harmonic map's analysis of a mesh begun before its cleanup.

    Pass :meth:`begin` to :func:`~meshreg.mesh.topology.prepare_disk` (``checked=``), which calls it with the
    checked, renumbered arrays before it cleans them, and the object to
    :class:`~meshreg.mesh.harmonic.HarmonicMap` (``early=``), which :meth:`claim` s the analysis at its first solve
    when its disk's faces and interior vertices are those analysed. Use it as a context manager: leaving it
    abandons what no map took (after an error in the cleanup, say). Meshes of fewer than ``minimum`` vertices
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

    def __init__(self, minimum: int | None = None):
        self.minimum = EARLY_MIN if minimum is None else minimum
        self.used = False  # whether a map kept the early analysis
        self._given: tuple | None = None  # the faces, interior vertices and their places analysed
        self._future: Future | None = None
        self._stop = np.zeros(1, np.bool_)

    def __enter__(self) -> EarlyAnalysis:
        return self

    def __exit__(self, *exc) -> None:
        self.abandon()

    def begin(self, vertices: np.ndarray, faces: np.ndarray) -> None:
        """Start analysing the mesh (vertices (n, 3) float, faces (m, 3) int, as the cleanup receives them) in a
        thread of its own, when it has ``minimum`` vertices or more and nothing was begun yet. Its interior vertices
        are found here (O(n + m), 0.08 s at 1M triangles), so that :meth:`claim` can compare them at once."""
        if len(vertices) < self.minimum or self._future is not None:
            return
        faces = np.ascontiguousarray(faces, dtype=np.int64)
        interior = _interior(vertices, faces)
        self._given = faces, interior, vertices[interior] if ordered_in_space(len(interior)) else None
        pool = ThreadPoolExecutor(1, thread_name_prefix="meshreg-early")
        self._future = pool.submit(_interior_analysis, *self._given, len(vertices), self._stop)
        pool.shutdown(wait=False)

    def claim(self, faces: np.ndarray, interior: np.ndarray, points: np.ndarray | None) -> bool:
        """Whether the analysis under way is for ``faces``, ``interior`` and ``points`` (the cleaned disk's faces,
        the map's interior vertices and, for a mesh large enough to be ordered by them
        (:func:`~meshreg.mesh.frontal.ordered_in_space`), their places (ni, 3), else None): then it is the analysis
        the map would compute, and :meth:`analysis` gives it; else the early work is abandoned (:meth:`abandon`).
        Once only: later claims are False."""
        if self._future is None or self.used:
            return False
        given = self._given
        self.used = all(np.array_equal(x, y) for x, y in zip((faces, interior, points), given, strict=True))
        if not self.used:
            self.abandon()
        return self.used

    def analysis(self) -> Analysis:
        """The claimed analysis (:meth:`claim`), once it is done."""
        future, self._future, self._given = self._future, None, None
        return future.result()

    def abandon(self) -> None:
        """Stop the analysis under way, if any, and wait until its thread's work has ended (so that no numba
        kernel of it is running when the process forks); its outcome, whatever it is, is dropped."""
        future, self._future, self._given = self._future, None, None
        if future is None:
            return
        self._stop[0] = True
        try:
            future.result()
        except Exception:  # Abandoned, or an error of a mesh the cleanup changed: the result is not wanted
            pass
