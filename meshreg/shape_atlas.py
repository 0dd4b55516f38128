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
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from .atlas_result import Atlas
from .atlas_settings import ATLAS_OPTIONS, AtlasSettings
from .batch import (
    Prepared,
    _run_key,
    collection_items,
    distance_matrix,
    prepare_collection,
    registered_pair,
    run_checkpointed,
)
from .errors import InputError
from .grid import GridSurface
from .mesh.export import grid_faces
from .options import Options
from .search import apply_symmetry, symmetry_map
from .shape_stats import karcher_gap, karcher_update, principal_modes, rms_spread


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


def _placed_round(p: Prepared) -> Prepared:
    """A member with four clear turns in a collection with round-boundary members (its ``arcs``) as a round one:
    its placements at quarter arc lengths, like theirs (:func:`meshreg.batch.prepare_collection`)."""
    if not p.arcs:
        return p
    return Prepared(p.name, p.arcs[0], placements=p.arcs[1:], kind="round")


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
    items = collection_items(surfaces)
    members, failures = _prepared_members(items, names, options)
    timings = {"prepare": time.perf_counter() - tic}
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
    context = {"key": key, "run": run, "store": store, "notify": notify}
    history, active, converged = _iterate(members, grid, options, settings, context, failures, timings)
    params.update(iterations=len(history), converged=converged)
    frame = (members[medoid].name, grid.points.reshape(-1, 3).mean(axis=0))
    result = _assemble(members, frame, history, active, failures, settings, params, timings)
    timings["total"] = time.perf_counter() - started
    timings["per_member"] = timings["total"] / len(items)
    return result


def _prepared_members(items: list, names, options: Options) -> tuple[list[Prepared], dict]:
    """Every surface prepared (read; meshes cleaned, mapped, resampled): those that could be, and name -> reason of
    those that could not (at least 2 must be left)."""
    if len(items) < 2:
        raise InputError("an atlas needs at least 2 surfaces")
    if names is None:
        names = [str(x) if isinstance(x, (str, Path)) else f"surface {k}" for k, x in enumerate(items)]
    if len(set(names)) != len(names):
        raise InputError("the surfaces' names must be distinct")
    prepared = prepare_collection(items, names, options)
    failures = {p.name: p.error for p in prepared if p.error}
    members = [_placed_round(p) for p in prepared if not p.error]
    _enough(members, failures)
    return members, failures


def _iterate(
    members, grid: GridSurface, options: Options, settings: AtlasSettings, context: dict, failures: dict, timings: dict
):
    """The Karcher iteration from the medoid's grid: register all, average, until F stops falling by
    ``settings.tolerance``. ``context`` holds the checkpoint key, the executor (``run``), the checkpoint directory
    and the progress callback. Returns the history of iterations, the members kept and whether it converged."""
    template = karcher_update(grid.scaled().points[None], grid.r, grid.t)
    active = list(range(len(members)))
    history, last, converged = [], None, False
    for iteration in range(1, settings.max_iterations + 1):
        tic = time.perf_counter()
        stage = f"iteration {iteration}"
        records = _register_all(
            template,
            members,
            active,
            last,
            options,
            context["key"],
            stage,
            context["run"],
            context["store"],
            context["notify"],
        )
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
    return history, active, converged


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
        return {"placement": best_placement(first, placements, options)[0][0]}


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
