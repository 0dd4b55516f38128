"""Shape atlas of a collection: an elastic template, every member in the template's connectivity, and the principal
modes of variation.

The template is the Karcher mean of the members under the registration's energy E, by the usual fixed-point
iteration:

1. Start from the medoid: the member with the least sum of E to the others, from a distance matrix
   (:func:`meshreg.distance_matrix`) on coarse grids (``AtlasSettings.medoid_grid`` nodes per axis, one start,
   no refinement: the medoid only has to be a good start).
2. Register every member to the template T (T rotated, the member reparametrized, as in :func:`meshreg.register`):
   member j resampled at h_j on T's grid and turned back by R_j^T is its *aligned shape*, in T's frame and
   parametrization, at area 1.
3. The new template is the node-by-node mean of the aligned shapes, centred and scaled to area 1. Steps 2-3 repeat
   while the mean energy F = mean_j E(T, member j) (the Karcher objective) falls by more than
   ``AtlasSettings.tolerance`` of itself; the template kept is the iterate with the lowest F, with its registrations.

Why the mean of coordinates: the minimizer of F for fixed alignments is the mean of the aligned shape functions q_j,
but a mean of q's is in general the q of no surface (inverting the square-root normal field has no closed form).
The mean of the aligned coordinates is a surface on the template's grid. What this costs is measured and recorded
(``Atlas.params["karcher_gap"]``): ||q(T) - mean_j q_j||^2 / F, the fraction of F that the q-space mean would remove
with the same alignments.

Why stop on F rather than on the template's nodes: E hardly sees tangential slides of a surface along itself where
it is nearly flat, so h is loose there, and the averaged template keeps sliding a little after F has stopped falling
(12 meshes of a bump sheet, about 2k triangles each, at 41 x 41: from the third iteration on the template's nodes
moved by 6e-3 RMS and its elastic distance to the previous one was 3e-3, 4% of the members' distance to it, at every
iteration, while F varied by +-0.6%). The same looseness puts tangential noise into the aligned coordinates and so
into the modes: on 8 meshes of one shape (1000-1200 vertices, 41 x 41) the aligned vertices spread by 0.36% of the
size about their mean, 0.03% of it along the normals.

Speed: from the second iteration on, each member starts from its last symmetry of the square and rotation (its grid
reparametrized and turned by them beforehand, then registered without the start search); a member that fails is
reported in ``Atlas.failures`` and left out. Every stage runs on the local process pool or a Dask cluster and is
checkpointed (:func:`meshreg.batch.run_checkpointed`), so an interrupted run resumes and gives the same atlas bit
for bit.
"""

from __future__ import annotations

import base64
import hashlib
import json
import os
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from .batch import Prepared, _run_key, distance_matrix, prepare_surface, registered_pair, run_checkpointed
from .errors import InputError
from .grid import GridSurface
from .mesh.export import grid_faces
from .options import Options, _integer, _number
from .search import apply_symmetry, symmetry_map
from .srnf import cell_weights, shape_function

ATLAS_RESOLUTION = 41
ATLAS_OPTIONS = Options(resolution=ATLAS_RESOLUTION, keep_orientation=True)
"""The atlas's registration defaults: :class:`~meshreg.options.Options` but for meshes resampled on 41 x 41 grids (a
2k-triangle mesh has about 32 x 32 vertices; 101 costs 2-3x the time for detail such meshes do not hold) and
``keep_orientation`` (a cohort's meshes are wound alike; mirrored matches of nearly symmetric members come within a
few percent of the right E and would put vertex k at mirrored places on different members)."""


@dataclass(frozen=True)
class AtlasSettings:
    """How the template is iterated and what the atlas keeps; validated when made.

    Attributes
    ----------
    tolerance : float
        Stop when the mean energy F to the template falls by at most this fraction of itself in one iteration (plus
        ``Options.advanced.abs_tol``, the accuracy of E). Default 0.01.
    max_iterations : int
        Most registration rounds (the first registers to the medoid). Default 8.
    modes : int
        Principal modes kept (at most the number of members minus one). Default 10.
    medoid_grid : int
        Nodes per axis of the coarse grids the medoid's distance matrix is computed on. Default 21.
    """

    tolerance: float = 0.01
    max_iterations: int = 8
    modes: int = 10
    medoid_grid: int = 21

    def __post_init__(self):
        _number("tolerance", self.tolerance, 0.0, 1.0)
        _integer("max_iterations", self.max_iterations, 1, 1000)
        _integer("modes", self.modes, 1, 100_000)
        _integer("medoid_grid", self.medoid_grid, 5, 1001)


@dataclass
class Atlas:
    """A collection in one template and one connectivity, with its principal modes.

    Coordinates are in the *template's frame*: the frame of the medoid as given (the iteration runs there), at the
    members' mean size. K members were kept; V = M N grid nodes; F = 2 (M - 1)(N - 1) triangles.

    Attributes
    ----------
    names : list of str, length K
    template : ndarray (V, 3)
        The mean shape, at size ``scale``, centred at ``centre``.
    faces : ndarray (F, 3)
        The template grid's triangles (two per cell, :func:`meshreg.mesh.export.grid_faces`), shared by all.
    grid : (int, int)
        (M, N); vertex i N + j is grid node (r[i], t[j]).
    r, t : ndarray (M,), (N,)
    aligned : ndarray (K, V, 3)
        Each member on the template's grid (vertex k the same point on all), rotated into the template's frame,
        at its own size, centred at ``centre``.
    sizes : ndarray (K,)
        sqrt(area) of each member (as given).
    scale : float
        The template's size: the mean of ``sizes``.
    centre : ndarray (3,)
        The centroid (node mean) of the medoid as given; every shape here is centred there.
    centroids : ndarray (K, 3)
        Node mean of each member resampled on the template's grid, in its own frame: that resampled member is
        ``(aligned[k] - centre) @ rotations[k].T + centroids[k]``.
    rotations : ndarray (K, 3, 3)
        R of each member's registration (the template rotated onto the member).
    energies : ndarray (K,)
        E(template, member), both at area 1.
    h : ndarray (K, M, N, 2)
        Each member's reparametrization: its parameter point at each template grid node (symmetry included).
    symmetries, placements : ndarray (K,) int
        The symmetry of the square in h, and the corner placement (round-boundary meshes; else 0).
    mean, modes, variances, explained, scores
        PCA of the shapes (aligned members scaled to the template's size: shape, not size): mean (V, 3), unit
        modes (k, V, 3), variances (k,) in squared units, explained variance fractions (k,), scores (K, k) with
        shape k ~ mean + sum_m scores[k, m] modes[m].
    objective : ndarray (I,)
        F = mean E to the template at each iteration; the template kept is the iterate with the least F.
    seconds : ndarray (K, I)
        Each member's registration time (wall clock in its worker) at each iteration (NaN: not run).
    failures : dict
        name -> why a member was left out.
    medoid : str
    params : dict
        Options, settings, iterations run and kept, convergence, ``karcher_gap`` (see the module) and ``spread``
        (RMS distance of the shapes' vertices from the mean's, as a fraction of ``scale``).
    timings : dict
        Seconds of each stage (``prepare``, ``medoid``, ``iterations``, ``pca``, ``total``) and ``per_member``
        (total / members given).
    """

    names: list
    template: np.ndarray
    faces: np.ndarray
    grid: tuple
    r: np.ndarray
    t: np.ndarray
    aligned: np.ndarray
    sizes: np.ndarray
    scale: float
    centre: np.ndarray
    centroids: np.ndarray
    rotations: np.ndarray
    energies: np.ndarray
    h: np.ndarray
    symmetries: np.ndarray
    placements: np.ndarray
    mean: np.ndarray
    modes: np.ndarray
    variances: np.ndarray
    explained: np.ndarray
    scores: np.ndarray
    objective: np.ndarray
    seconds: np.ndarray
    failures: dict = field(default_factory=dict)
    medoid: str = ""
    params: dict = field(default_factory=dict)
    timings: dict = field(default_factory=dict)

    def save(self, path) -> None:
        """Write ``.npz`` atomically (the keys are the attribute names; dicts as JSON strings)."""
        path = Path(path)
        tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp.npz")
        arrays = {k: v for k, v in asdict(self).items() if k not in ("names", "failures", "params", "timings")}
        np.savez(
            tmp,
            **arrays,
            names=np.array(self.names, dtype=str),
            failures=json.dumps(self.failures),
            params=json.dumps(self.params),
            timings=json.dumps(self.timings),
        )
        os.replace(tmp, path)

    @classmethod
    def load(cls, path) -> Atlas:
        """Read an atlas written by :meth:`save`."""
        try:
            with np.load(path, allow_pickle=False) as data:
                values = {k: data[k] for k in data.files}
        except (OSError, ValueError) as err:
            raise InputError(f"{path}: not a meshreg atlas file ({err})") from None
        if "modes" not in values or "template" not in values:
            raise InputError(f"{path}: not a meshreg atlas file (no template or modes)")
        values["names"] = values["names"].tolist()
        for key in ("failures", "params", "timings"):
            values[key] = json.loads(str(values[key]))
        values["grid"] = tuple(int(x) for x in values["grid"])
        values["scale"] = float(values["scale"])
        values["medoid"] = str(values["medoid"])
        return cls(**values)

    def shapes(self) -> np.ndarray:
        """The aligned members at the template's size (K, V, 3): what the PCA is of."""
        return (self.aligned - self.centre) * (self.scale / self.sizes)[:, None, None] + self.centre


@dataclass
class _Member:
    """One member's registration to the template (in the member's own terms: h with its symmetry, total R)."""

    rotation: np.ndarray
    h: np.ndarray
    symmetry: int
    placement: int
    energy: float
    seconds: float


def register_member(template: GridSurface, member, options: Options) -> dict:
    """Register a member to the template (worker side): the record of :func:`meshreg.batch.registered_pair` with
    E, R, the symmetry and h (packed for the JSON-lines checkpoint, exactly)."""
    result, record = registered_pair(template, member, options)
    return {
        "energy": result.energy,
        "rotation": result.rotation.tolist(),
        "symmetry": result.symmetry,
        "h": _pack(result.h),
        **record,
    }


def _pack(a: np.ndarray) -> dict:
    """An array as JSON-ready shape and base64 of its float64 bytes (exact round trip)."""
    a = np.ascontiguousarray(a, dtype="<f8")
    return {"shape": list(a.shape), "data": base64.b64encode(a.tobytes()).decode("ascii")}


def _unpack(packed: dict) -> np.ndarray:
    return np.frombuffer(base64.b64decode(packed["data"]), dtype="<f8").reshape(packed["shape"]).copy()


def _grids(p: Prepared) -> list[GridSurface]:
    """A prepared member's grids: its own, then its other corner placements."""
    return [p.grid, *p.placements]


def _turned(p: Prepared, last: _Member) -> Prepared:
    """The member as it starts a warm registration: its placement's grid under its last symmetry, turned by R^T."""
    g = apply_symmetry(_grids(p)[last.placement], last.symmetry)
    return Prepared(p.name, GridSurface(g.points @ last.rotation, g.r, g.t))


def _member(record: dict, last: _Member | None) -> _Member:
    """A worker's record as the member's registration; a warm one composed with the start it was turned by."""
    rotation, h, symmetry = np.array(record["rotation"]), _unpack(record["h"]), int(record["symmetry"])
    placement = int(record.get("placement", 0))
    if last is not None:
        rotation, h, symmetry, placement = (
            last.rotation @ rotation,
            symmetry_map(last.symmetry, h),
            last.symmetry,
            last.placement,
        )
    return _Member(rotation, h, symmetry, placement, float(record["energy"]), float(record["seconds"]))


def aligned_shape(member: GridSurface, reg: _Member) -> np.ndarray:
    """The member on the template's grid in the template's frame: c o h turned by R^T, at area 1, centred (M, N, 3)."""
    points = member.scaled().at(reg.h) @ reg.rotation
    return points - points.reshape(-1, 3).mean(axis=0)


def karcher_update(aligned: np.ndarray, r: np.ndarray, t: np.ndarray) -> GridSurface:
    """The next template: the node-by-node mean of aligned shapes (K, M, N, 3), centred, at area 1."""
    mean = GridSurface(aligned.mean(axis=0), r, t).scaled()
    return GridSurface(mean.points - mean.points.reshape(-1, 3).mean(axis=0), r, t)


def rms_spread(shapes: np.ndarray) -> float:
    """Root mean square distance of the shapes' vertices (K, V, 3) from the mean shape's."""
    return float(np.sqrt(np.mean(np.sum((shapes - shapes.mean(axis=0)) ** 2, axis=-1))))


def karcher_gap(template: GridSurface, aligned: np.ndarray, energies: np.ndarray, floor: float = 0.0) -> float:
    """||q(T) - mean_j q(aligned_j)||^2 / mean_j E_j: the fraction of the Karcher objective that the mean of the aligned
    shape functions (the minimizer for these alignments, not a surface in general) would remove (0 when the mean E
    is at most ``floor``, where it means nothing)."""
    r, t = template.r, template.t
    w = cell_weights(r, t)[..., None]
    q_mean = np.mean([shape_function(a, r, t) for a in aligned], axis=0)
    gap = float(np.sum(w * (shape_function(template.points, r, t) - q_mean) ** 2))
    objective = float(np.mean(energies))
    return gap / objective if objective > floor else 0.0


def principal_modes(shapes: np.ndarray, count: int):
    """PCA of K shapes (K, V, 3) in correspondence.

    Returns mean (V, 3), unit modes (k, V, 3) (each signed so that its largest component is positive), variances
    (k,) (sample variances, K - 1 in the denominator), explained fractions of the total variance (k,; 0 when all
    shapes are equal) and scores (K, k), with k = min(count, K - 1). The total variance is ``variances.sum() /
    explained.sum()`` (when not 0).
    """
    k_shapes = len(shapes)
    x = shapes.reshape(k_shapes, -1)
    mean = x.mean(axis=0)
    u, s, vt = np.linalg.svd(x - mean, full_matrices=False)
    k = min(count, max(k_shapes - 1, 0))
    signs = np.sign(vt[np.arange(k), np.argmax(np.abs(vt[:k]), axis=1)])
    modes, scores = vt[:k] * signs[:, None], u[:, :k] * s[:k] * signs
    denominator = max(k_shapes - 1, 1)
    variances = s[:k] ** 2 / denominator
    total = float(np.sum(s**2)) / denominator
    explained = variances / total if total > 0 else np.zeros(k)
    return mean.reshape(-1, 3), modes.reshape(k, -1, 3), variances, explained, scores


def atlas(
    surfaces,
    options: Options | None = None,
    settings: AtlasSettings | None = None,
    *,
    names=None,
    client=None,
    jobs: int | None = None,
    checkpoint=None,
    progress=None,
) -> Atlas:
    """The elastic atlas of a collection: template, every member in its connectivity, principal modes.

    Parameters
    ----------
    surfaces : sequence
        GridSurfaces, (M, N, 3) arrays, (vertices, faces) pairs, or paths of grid files or meshes (at least 2).
    options : Options, optional
        Mesh preparation and registration (default :data:`ATLAS_OPTIONS`: resolution 41, keep_orientation).
    settings : AtlasSettings, optional
    names : list of str, optional
        Labels (default: the paths, else "surface i").
    client : dask.distributed.Client, optional
        Run the registrations on this Dask cluster. Default: a local process pool.
    jobs : int, optional
        Processes of the local pool (default: the machine's cores; 1 runs in this process).
    checkpoint : path, optional
        Directory of JSON-lines checkpoints (one per stage); an existing one of the same run is resumed.
    progress : callable, optional
        ``progress(stage, done, total)`` with stage "medoid" or "iteration k", at the start of each stage and after
        each registration.

    Returns
    -------
    Atlas

    Raises
    ------
    InputError
        Fewer than 2 surfaces, or fewer than 2 that could be prepared and registered.
    """
    started = tic = time.perf_counter()
    options = options or ATLAS_OPTIONS
    settings = settings or AtlasSettings()
    items = list(surfaces)
    if len(items) < 2:
        raise InputError("an atlas needs at least 2 surfaces")
    if names is None:
        names = [str(x) if isinstance(x, (str, Path)) else f"surface {k}" for k, x in enumerate(items)]
    if len(set(names)) != len(names):
        raise InputError("the surfaces' names must be distinct")
    timings = {}
    prepared = [prepare_surface(x, nm, options) for x, nm in zip(items, names, strict=True)]
    failures = {p.name: p.error for p in prepared if p.error}
    members = [p for p in prepared if not p.error]
    _enough(members, failures)
    timings["prepare"] = time.perf_counter() - tic
    store = Path(checkpoint) if checkpoint else None
    if store:
        store.mkdir(parents=True, exist_ok=True)
    params = {**options.as_dict(), **asdict(settings)}
    key = _run_key([p.name for p in members], [p.grid for p in members], params)
    run = {"client": client, "jobs": jobs}
    notify = progress or (lambda stage, done, total: None)

    tic = time.perf_counter()
    medoid, grid = _medoid(members, options, settings, key, run, store, notify)
    timings["medoid"] = time.perf_counter() - tic
    template = karcher_update(grid.scaled().points[None], grid.r, grid.t)
    active = list(range(len(members)))
    history, last, converged = [], None, False
    for iteration in range(1, settings.max_iterations + 1):
        tic = time.perf_counter()
        stage = f"iteration {iteration}"
        records = _register_all(template, members, active, last, options, key, stage, run, store, notify)
        regs = {}
        for k, record in records.items():
            if "error" in record:
                failures[members[k].name] = record["error"]
            else:
                regs[k] = _member(record, None if last is None else last[k])
        active = [k for k in active if k in regs]
        _enough([members[k] for k in active], failures)
        aligned = np.array([aligned_shape(_grids(members[k])[regs[k].placement], regs[k]) for k in active])
        history.append({"template": template, "regs": regs, "aligned": aligned, "active": list(active)})
        timings[stage] = time.perf_counter() - tic
        objective = [_objective(step, active) for step in history]
        floor = options.advanced.abs_tol  # E is accurate to about this
        converged = objective[-1] <= floor or (
            len(history) > 1 and objective[-2] - objective[-1] <= settings.tolerance * objective[-2] + floor
        )
        if converged:
            break
        template = karcher_update(aligned, template.r, template.t)
        last = regs
    params.update(iterations=len(history), converged=converged)
    frame = (members[medoid].name, grid.points.reshape(-1, 3).mean(axis=0))
    result = _assemble(members, frame, history, active, failures, settings, params, timings)
    timings["total"] = time.perf_counter() - started
    timings["per_member"] = timings["total"] / len(items)
    return result


def _enough(members: list, failures: dict) -> None:
    if len(members) < 2:
        reasons = "; ".join(f"{name}: {why}" for name, why in failures.items())
        raise InputError(f"an atlas needs at least 2 surfaces that can be registered ({reasons})")


def _objective(step: dict, active: list) -> float:
    """F of an iteration over the members still kept."""
    return float(np.mean([step["regs"][k].energy for k in active]))


def rank_placement(first: GridSurface, placements: list, options: Options) -> dict:
    """The corner placement of a round-boundary member that best matches ``first`` (worker side)."""
    from threadpoolctl import threadpool_limits

    from .mesh.corners import best_placement

    with threadpool_limits(1):
        return {"placement": best_placement(first, placements, options.keep_orientation)}


def _medoid(members, options, settings: AtlasSettings, key: str, run: dict, store, notify) -> tuple[int, GridSurface]:
    """The member with the least sum of E to the others (coarse grids, one start, no refinement): its index and
    grid. A member with several corner placements takes the one that matches the first member best (ranked once,
    not per pair)."""
    chosen = [p.grid for p in members]
    several = [k for k, p in enumerate(members) if p.placements]
    if several:
        done = run_checkpointed(
            [Prepared("reference", members[0].grid), *(members[k] for k in several)],
            [(0, j + 1) for j in range(len(several))],
            options,
            key=f"{key}:placements",
            checkpoint=store / "placements.jsonl" if store else None,
            progress=lambda finished, total: notify("corner placements", finished, total),
            task=rank_placement,
            **run,
        )
        for (_, j), record in done.items():
            k = several[j - 1]
            chosen[k] = _grids(members[k])[record.get("placement", 0)]
    n = settings.medoid_grid
    coarse = [Prepared(p.name, g.scaled().resampled(n, n)) for p, g in zip(members, chosen, strict=True)]
    d = distance_matrix(
        coarse,
        options.replace(max_starts=1, refine="none"),
        names=[p.name for p in members],
        checkpoint=store / "medoid.jsonl" if store else None,
        progress=lambda done, total: notify("medoid", done, total),
        **run,
    )
    energy = d.energy
    worst = np.nanmax(energy) if np.isfinite(energy).any() else 1.0
    medoid = int(np.argmin(np.where(np.isfinite(energy), energy, 2 * worst).sum(axis=1)))
    return medoid, chosen[medoid]


def _register_all(template, members, active, last, options, key, stage, run, store, notify) -> dict:
    """Every active member registered to the template: ``{member index: record}``. With ``last`` (the previous
    iteration's registrations) each member starts from its last symmetry and rotation, without the start search."""
    if last is None:
        entries, opts = [members[k] for k in active], options
    else:
        entries, opts = [_turned(members[k], last[k]) for k in active], options.replace(search=False)
    digest = hashlib.sha256(f"{key}:{stage}".encode())
    digest.update(np.ascontiguousarray(template.points).tobytes())
    done = run_checkpointed(
        [Prepared("template", template), *entries],
        [(0, j + 1) for j in range(len(active))],
        opts,
        key=digest.hexdigest(),
        checkpoint=store / f"{stage.replace(' ', '-')}.jsonl" if store else None,
        progress=lambda finished, total: notify(stage, finished, total),
        task=register_member,
        **run,
    )
    return {active[j - 1]: record for (_, j), record in done.items()}


def _assemble(members, frame, history, active, failures, settings, params, timings) -> Atlas:
    """The Atlas of the iterate with the least F (over the members kept), in the template's frame and units; ``frame``
    is the medoid's name and centroid."""
    objective = np.array([_objective(step, active) for step in history])
    best = history[int(np.argmin(objective))]
    template = best["template"]
    regs = [best["regs"][k] for k in active]
    rows = [best["active"].index(k) for k in active]
    aligned1 = best["aligned"][rows]
    m, n = template.shape
    grids = [_grids(members[k])[reg.placement] for k, reg in zip(active, regs, strict=True)]
    sizes = np.array([np.sqrt(g.area()) for g in grids])
    scale = float(sizes.mean())
    medoid, centre = frame
    tic = time.perf_counter()
    shapes = aligned1.reshape(len(active), -1, 3) * scale + centre
    mean, modes, variances, explained, scores = principal_modes(shapes, settings.modes)
    timings["pca"] = time.perf_counter() - tic
    energies = np.array([reg.energy for reg in regs])
    centroids = [g.at(reg.h).reshape(-1, 3).mean(axis=0) for g, reg in zip(grids, regs, strict=True)]
    seconds = np.full((len(active), len(history)), np.nan)
    for i, step in enumerate(history):
        for row, k in enumerate(active):
            if k in step["regs"]:
                seconds[row, i] = step["regs"][k].seconds
    timings["iterations"] = float(sum(v for s, v in timings.items() if s.startswith("iteration ")))
    return Atlas(
        names=[members[k].name for k in active],
        template=template.points.reshape(-1, 3) * scale + centre,
        faces=grid_faces(m, n),
        grid=(m, n),
        r=template.r,
        t=template.t,
        aligned=aligned1.reshape(len(active), -1, 3) * sizes[:, None, None] + centre,
        sizes=sizes,
        scale=scale,
        centre=centre,
        centroids=np.array(centroids),
        rotations=np.array([reg.rotation for reg in regs]),
        energies=energies,
        h=np.array([reg.h for reg in regs]),
        symmetries=np.array([reg.symmetry for reg in regs]),
        placements=np.array([reg.placement for reg in regs]),
        mean=mean,
        modes=modes,
        variances=variances,
        explained=explained,
        scores=scores,
        objective=objective,
        seconds=seconds,
        failures=dict(failures),
        medoid=medoid,
        params={
            **params,
            "kept_iteration": int(np.argmin(objective)) + 1,
            "karcher_gap": karcher_gap(template, aligned1, energies, params["abs_tol"]),
            "spread": rms_spread(shapes) / scale,
        },
        timings=timings,
    )


def canonical_correlations(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Canonical correlations (min(p, q),) of two sets of variables x (K, p) and y (K, q), largest first: how well
    linear combinations of one (e.g. the first modes' scores) follow the other (e.g. known generating parameters)."""
    x = np.asarray(x, dtype=float).reshape(len(x), -1)
    y = np.asarray(y, dtype=float).reshape(len(y), -1)
    qx, _ = np.linalg.qr(x - x.mean(axis=0))
    qy, _ = np.linalg.qr(y - y.mean(axis=0))
    return np.clip(np.linalg.svd(qx.T @ qy, compute_uv=False), 0.0, 1.0)
