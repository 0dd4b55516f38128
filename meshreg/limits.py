"""What a run may cost, checked before it starts: grid sizes, the DP window, the basis, the corner search and worker
processes against stated limits. Each refusal gives the estimate, the limit and what to change; ``force=True``
(``--force``) lifts these limits knowingly (the hard ranges of :class:`~meshreg.options.Options` stay).

The figures behind the limits were measured on the development machine (2 cores shared with other work, so
within a factor of two; ``/usr/bin/time`` of :func:`meshreg.register` in mode "auto" on the paper's pair 2):

- peak memory 0.46 GB on a 201 x 201 grid, 1.05 GB on 401 x 401, 2.0 GB on 601 x 601 (about 5 KB per node
  above the interpreter's 0.3 GB), CPU time 32 s, 37 s and 53 s; a distance matrix holds one registration per
  worker, so :data:`MAX_NODES` is 401 x 401;
- one DP solve (:func:`meshreg.dp.dp_surface_min`, one round) costs about :data:`DP_SECONDS_PER_PIECE` per edge
  piece it evaluates (:func:`dp_pieces`: the steps of the window times the nodes of its table); a registration
  runs several (up to ``dp_rounds`` per DP pass), so one may take at most :data:`MAX_DP_SECONDS`;
- the basis descent holds its fields and their Jacobian as dense matrices, :func:`basis_bytes`: 1.33 GB peak for
  ``basis`` 20 (1640 fields) on a 101 x 101 grid, 14 s of CPU in mode "dp+gd"; 4.3 GB for ``basis`` 40; so the
  descent may need at most :data:`MAX_BASIS_BYTES`;
- each trial corner placement costs about 0.16 s per pair (a pair of meshes: the square's symmetries ranked by
  E_w, for the trial and its share of the halving steps, measured 0.14 s on the face bent by 72 degrees; the
  distance matrix and the atlas: a coarse DP over the symmetries): :data:`MAX_CORNER_TRIALS` trials, 10 s per
  pair;
- a morph draws and encodes 2 ``frames`` - 2 images (:data:`MORPH_SECONDS_PER_IMAGE` each): at most
  :data:`MAX_MORPH_FRAMES` frames, about a minute.
"""

from __future__ import annotations

import operator
import os
from typing import TYPE_CHECKING

from .errors import InputError

if TYPE_CHECKING:  # numpy is imported where used: Options are checked here, and `meshreg --help` needs no numpy
    import numpy as np

MAX_NODES = 401 * 401  # nodes of a grid registered (memory and time above)
MAX_DP_SECONDS = 5.0  # estimated seconds of one DP solve
DP_SECONDS_PER_PIECE = 2.5e-9  # measured: 2.7 s for window 100 on a 101 x 101 grid (1.1e9 pieces)
MAX_BASIS_BYTES = 2e9  # estimated memory of the basis descent
BASIS_BYTES_PER_ENTRY = 1.6 * 8  # measured: peaks of 1.6 float64 per (field, row of the Jacobian)
MAX_CORNER_TRIALS = 64  # trial corner placements of a round-boundary mesh
MAX_JOBS_PER_CORE = 4  # worker processes per core of this machine
MAX_MORPH_FRAMES = 500  # frames one way of a morph GIF (drawn there and back)
MORPH_SECONDS_PER_IMAGE = 0.055  # measured: `meshreg morph` of two 21 x 21 grids, 200 frames (398 images), 22 s in all

FORCE_HINT = "or pass --force (API: force=True) to run it anyway"


def dp_pieces(nodes: int, window: int) -> np.ndarray:
    """Edge pieces evaluated by one DP solve along an axis of ``nodes`` nodes, for each window 1, 2, ...,
    min(``window``, nodes - 1) (wider windows add no usable step), shape (W,).

    Step (dk, dl) is tried at every table entry (k, l) with k >= dk and l >= dl, and costs dk + dl pieces. Axes of
    more than ``DP_FULL_NODES`` nodes run the coarse-to-fine DP of :func:`meshreg.dp.dp_surface_min`: a full table
    on about ``DP_STRIP_NODES`` nodes, then a strip of 4 c + 2 entries per row (c = nodes // DP_STRIP_NODES).
    """
    import numpy as np

    from .dp import steps
    from .schedule import DP_FULL_NODES, DP_STRIP_NODES

    def table(rows: int, width: int, cap: int) -> np.ndarray:
        s = steps(max(1, min(window, cap - 1))).astype(float)
        dk, dl = s[:, 0], s[:, 1]
        pieces = (dk + dl) * np.clip(rows - dk, 0, None) * np.clip(width - dl, 0, None)
        by_window = np.bincount(np.maximum(dk, dl).astype(int) - 1, weights=pieces, minlength=min(window, nodes - 1))
        return np.cumsum(by_window)[: min(window, nodes - 1)]

    if nodes <= DP_FULL_NODES:
        return table(nodes, nodes, nodes)
    coarsen = nodes // DP_STRIP_NODES
    coarse = -(-nodes // coarsen) + 1
    full = table(coarse, coarse, coarse)
    strip = table(nodes, 4 * coarsen + 2, nodes)
    return strip + np.pad(full, (0, len(strip) - len(full)), mode="edge")


def basis_bytes(shape: tuple[int, int], basis: int) -> float:
    """Estimated bytes of the basis descent in the Riseth basis KL = ``basis`` (2 (KL + 2 KL^2) fields) on a grid
    of ``shape``: its work grid has at most ``COARSE_NODES`` nodes per axis, and the fields (2 per node) and the
    Jacobian (3 per cell) are dense."""
    from .schedule import COARSE_NODES

    m, n = (min(s, COARSE_NODES) for s in shape)
    return BASIS_BYTES_PER_ENTRY * 2 * (basis + 2 * basis**2) * (2 * m * n + 3 * (m - 1) * (n - 1))


def check_grids(options, *shapes: tuple[int, int]) -> None:
    """Refuse (InputError) grids of more than MAX_NODES nodes and a DP window whose one DP solve on the first grid
    would take more than MAX_DP_SECONDS, unless ``options.force``. ``shapes``: (M, N) of the first grid, then the
    others of the run."""
    import numpy as np

    if options.force:
        return
    for m, n in shapes:
        if m * n > MAX_NODES:
            raise InputError(
                f"a {m} x {n} grid has {m * n} nodes, above the limit of {MAX_NODES} (401 x 401, about 1 GB per "
                f"registration; the memory grows with the nodes): resample it or lower --resolution, {FORCE_HINT}"
            )
    if not shapes:
        return
    if options.mode != "dp":
        basis = max(options.basis, options.start_basis if options.mode == "gd" else 1)
        if basis_bytes(shapes[0], basis) > MAX_BASIS_BYTES:
            fits = max((k for k in range(1, basis) if basis_bytes(shapes[0], k) <= MAX_BASIS_BYTES), default=1)
            raise InputError(
                f"basis {basis} on a {shapes[0][0]} x {shapes[0][1]} grid: its {2 * (basis + 2 * basis**2)} fields "
                f"need about {basis_bytes(shapes[0], basis) / 1e9:.1f} GB (limit {MAX_BASIS_BYTES / 1e9:.0f} GB): "
                f"give --basis {fits} or less, {FORCE_HINT}"
            )
    if options.mode == "gd":
        return
    nodes = max(shapes[0])
    seconds = DP_SECONDS_PER_PIECE * dp_pieces(nodes, options.window)
    if seconds[-1] > MAX_DP_SECONDS:
        fits = int(np.sum(seconds <= MAX_DP_SECONDS))
        raise InputError(
            f"window {options.window} on a grid of {nodes} nodes per axis: one DP solve would take about "
            f"{seconds[-1]:.0f} s (limit {MAX_DP_SECONDS:.0f} s; a registration runs several): give --window "
            f"{max(fits, 1)} or less, {FORCE_HINT}"
        )


def check_static(options) -> None:
    """The limits that need no data: the resolution of meshes and the corner search (unless ``options.force``)."""
    if options.force:
        return
    nodes = options.resolution**2
    if nodes > MAX_NODES:
        raise InputError(
            f"resolution {options.resolution} gives {nodes} nodes per grid, above the limit of {MAX_NODES} "
            f"(about 1 GB per registration at 401 x 401): give --resolution 401 or less, {FORCE_HINT}"
        )
    if options.corner_search > MAX_CORNER_TRIALS:
        raise InputError(
            f"corner_search {options.corner_search} costs about {0.16 * options.corner_search:.0f} s per pair "
            f"(0.16 s per trial placement), above the limit of {MAX_CORNER_TRIALS} trials: give "
            f"--corner-search {MAX_CORNER_TRIALS} or less, {FORCE_HINT}"
        )


def check_jobs(jobs: int | None, force: bool = False) -> int:
    """Worker processes of a local pool: ``None`` means one per core; at least 1, at most MAX_JOBS_PER_CORE per
    core unless ``force``."""
    cores = os.cpu_count() or 1
    if jobs is None:
        return cores
    if isinstance(jobs, bool) or not isinstance(jobs, int) or jobs < 1:
        raise InputError(f"jobs must be a whole number of worker processes, 1 or more, got {jobs!r}")
    if jobs > MAX_JOBS_PER_CORE * cores and not force:
        raise InputError(
            f"{jobs} worker processes on {cores} cores: each holds a registration's memory and more than "
            f"{MAX_JOBS_PER_CORE} per core only slow each other down: give --jobs {MAX_JOBS_PER_CORE * cores} or "
            f"less, {FORCE_HINT}"
        )
    return jobs


def check_frames(frames: int, force: bool = False) -> None:
    """A morph of ``frames`` frames one way (2 ``frames`` - 2 images): at least 2, at most :data:`MAX_MORPH_FRAMES`
    unless ``force`` (each image is drawn and encoded: :data:`MORPH_SECONDS_PER_IMAGE`)."""
    try:
        count = operator.index(frames)  # ints and numpy's integers, not 2.5
    except TypeError:
        count = None
    if count is None or isinstance(frames, bool) or count < 2:
        raise InputError(f"frames must be an integer of at least 2, got {frames!r}")
    if count > MAX_MORPH_FRAMES and not force:
        seconds = (2 * count - 2) * MORPH_SECONDS_PER_IMAGE
        raise InputError(
            f"{count} frames would take about {seconds:.0f} s to draw (limit {MAX_MORPH_FRAMES} frames): give "
            "fewer, or in the API options=Options(force=True)"
        )
