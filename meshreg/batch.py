"""Distance matrices for collections: every unordered pair registered once, locally or on a Dask cluster.

Each surface is prepared once (read, and for meshes cleaned, mapped to the square and resampled); pair
(i, j), i < j, registers surface i (rotated) with surface j (reparametrized): ``distance[i, j] =
distance[j, i] = sqrt(E)`` of that registration (E is not exactly symmetric once discretized; the lower
index is always the first surface, so reruns and clusters give the same numbers).

Every finished pair is appended to a checkpoint file (JSON lines, flushed and fsynced) as it completes;
a rerun with the same inputs and parameters skips the pairs already there, so an interrupted run (Ctrl-C,
SIGTERM, a killed machine) loses at most the pairs in flight. A pair that fails (a bad mesh, a lost worker
process) is recorded with its reason and, by default, tried again by the next run (``retry_failed``); a surface
that cannot be read or prepared is reported and skipped, the rest goes on. The local pool
(:mod:`meshreg.workers`) replaces a lost worker, so that only the pair it held fails. The final ``.npz`` is written
to a temporary file and renamed (atomic); the checkpoint is removed only once every pair has a value.
"""

from __future__ import annotations

import hashlib
import json
import os
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from .checkpoint import CHECKPOINT_SUFFIX, Checkpoint, _digest
from .errors import InputError, RunError
from .files import read_npz, surface_kind, write_atomic
from .grid import GridSurface, read_grid
from .limits import check_jobs
from .options import Options
from .pipeline import register_with
from .result import Registration
from .workers import run_tasks

__all__ = [
    "CHECKPOINT_SUFFIX",
    "DistanceMatrix",
    "Prepared",
    "distance_matrix",
    "pair_grids",
    "prepare_collection",
    "prepare_surface",
    "run_checkpointed",
]


@dataclass
class Prepared:
    """A surface ready to register: its grid, or why it could not be prepared.

    ``kind`` is "grid" (a grid, or a mesh whose corners were not searched), "turned" (a mesh with four clear turns:
    ``grid`` has its corners there) or "round" (a mesh without: ``grid`` is its own corner placement at quarter arc
    lengths, ``placements`` the others tried). A turned mesh in a collection with round ones also has ``arcs``: its
    grids at quarter arc lengths (its own placement first), as a pair of meshes places both meshes when only one has
    four clear turns (:func:`meshreg.mesh.corners.corner_positions`)."""

    name: str
    grid: GridSurface | None
    error: str | None = None
    placements: list = field(default_factory=list)  # a round-boundary mesh: its grids for other corner placements
    kind: str = "grid"
    arcs: list = field(default_factory=list)


def prepare_surface(item, name: str | None = None, options: Options | None = None, *, arcs: bool = False) -> Prepared:
    """Read and prepare one surface: a GridSurface, an (M, N, 3) array, a (vertices, faces) pair, or a path to a
    grid file or a mesh (see :func:`meshreg.mesh.corners.mesh_grids`: a mesh without four clear corners
    keeps its grids for ``options.corner_search`` corner placements; with ``arcs``, a mesh with four clear turns
    keeps its grids at quarter arc lengths too). Errors (unreadable file, not a disk, out of memory, ...) are
    returned in ``error``, not raised: the item is skipped and the rest goes on."""
    if isinstance(item, Prepared):
        return item
    name = name or (str(item) if isinstance(item, (str, Path)) else "surface")
    options = options or Options()
    try:
        if isinstance(item, (str, Path)):
            if surface_kind(item) == "grid":
                item = read_grid(item)
            else:
                from .mesh.topology import load_mesh

                item = load_mesh(item)
        if isinstance(item, tuple):
            from .mesh.corners import mesh_grids

            options.check_grids((options.resolution, options.resolution))
            grids, info = mesh_grids(*item, options, arcs=arcs)
            if info["searched"] == "turned":
                return Prepared(name, grids[0], kind="turned", arcs=grids[1:])
            if info["searched"] == "round":
                return Prepared(name, grids[0], placements=grids[1:], kind="round")
            return Prepared(name, grids[0])
        grid = item if isinstance(item, GridSurface) else GridSurface.from_array(item)
        options.check_grids(grid.shape)
        return Prepared(name, grid)
    except InputError as err:
        text = str(err)
        for prefix in (f"{name}: ", f"{Path(name)}: "):  # the name is said once, by whoever reports the item
            text = text.removeprefix(prefix)
        return Prepared(name, None, text)
    except MemoryError:
        return Prepared(name, None, "out of memory while preparing it")
    except Exception as err:  # noqa: BLE001 - one bad item is reported and skipped, whatever failed
        return Prepared(name, None, f"{type(err).__name__}: {err}")


def register_pair(first: GridSurface, second: GridSurface | list, options: Options) -> dict:
    """One pair's numbers: energy, coordinate residual, number of equally good alternative correspondences,
    rotation (3 x 3 list), seconds (and the chosen corner placement when
    ``second`` is a list of a round-boundary mesh's placements, ranked as in ``meshreg register``). Runs in
    a worker process.

    BLAS is held to one thread: worker processes forked from a parent with a threaded OpenBLAS ran pairs
    5-10x slower on a 2-core machine, and one pair per core is the parallelism that pays.
    """
    result, record = registered_pair(first, second, options)
    return {
        "energy": result.energy,
        "residual": result.residual,
        "alternatives": len(result.alternatives),
        "rotation": result.rotation.tolist(),
        **record,
    }


def registered_pair(first: GridSurface, second: GridSurface | list, options: Options) -> tuple[Registration, dict]:
    """:func:`register_pair`'s registration and its record (``seconds``, and ``placement`` for a list)."""
    from threadpoolctl import threadpool_limits

    tic = time.perf_counter()
    record = {}
    with threadpool_limits(1):
        if isinstance(second, list):
            result, record["placement"] = _placed(first, second, options)
        else:
            result = register_with(first, second, options)
    if not np.isfinite(result.energy):
        raise RunError(f"the registration gave E = {result.energy}")
    record["seconds"] = time.perf_counter() - tic
    return result, record


def _placed(first: GridSurface, placements: list, options: Options) -> tuple[Registration, int]:
    """The registration of ``first`` with the best of the second's corner ``placements`` and the index of the
    placement (:func:`meshreg.mesh.corners.best_placement`, which ranks them as ``meshreg register`` does).

    The pair is registered by E, which cannot tell a match of one shape from one that fits the normals but not the
    points: a saddle over a five-lobed star against a remeshed copy came out half-turned (E 0.0004-0.004, coordinate
    residual 0.25-0.26) from placements whose preferred symmetry at the coarse look was the right one. When the
    answer does not fit the points (residual at least RESIDUAL_FLOOR), the best placement under its preferred
    symmetry, then a placement that fits them better, each only if its match fits them at the coarse look (residual
    below RESIDUAL_FLOOR), are registered with that symmetry pinned, and the first whose answer fits the points
    (residual at most :data:`meshreg.choice.NORMALS_ONLY_RESIDUAL`) replaces it."""
    from .bending import RESIDUAL_FLOOR
    from .choice import NORMALS_ONLY_RESIDUAL
    from .mesh.corners import best_placement

    ranked = best_placement(first, placements, options)
    chosen = ranked[0][0]
    result = register_with(first, placements[chosen], options)
    if result.residual < RESIDUAL_FLOOR:
        return result, chosen
    for k, symmetry, coarse_residual in ranked:
        if coarse_residual < RESIDUAL_FLOOR and (k, symmetry) != (chosen, result.symmetry):
            other = register_with(first, placements[k], options.replace(symmetry=symmetry))
            if other.residual <= NORMALS_ONLY_RESIDUAL:
                return other, k
    return result, chosen


@dataclass
class DistanceMatrix:
    """Pairwise elastic distances of a collection.

    Attributes
    ----------
    names : list of str, length N
    distance : ndarray (N, N)
        sqrt(E), symmetric, zero diagonal, NaN where the pair failed.
    energy : ndarray (N, N)
        E (squared distance), same layout.
    rotations : ndarray (N, N, 3, 3)
        R of pair (i, j), i < j (surface i rotated onto j); ``rotations[j, i]`` is its transpose.
    seconds : ndarray (N, N)
        Registration time of each pair (wall clock in its worker), symmetric.
    failures : dict
        ``(i, j) -> reason`` for pairs without a value (failed, or involving a skipped surface).
    params : dict
        The registration and preparation parameters used.
    skipped : dict
        ``k -> reason`` for surfaces that could not be read or prepared (every pair with them has no value).
    residual : ndarray (N, N)
        The coordinate residual of pair (i, j), i < j (:attr:`meshreg.Registration.residual`), symmetric; NaN
        where the pair has no value (and in matrices saved before it was recorded).
    """

    names: list
    distance: np.ndarray
    energy: np.ndarray
    rotations: np.ndarray
    seconds: np.ndarray
    failures: dict = field(default_factory=dict)
    params: dict = field(default_factory=dict)
    skipped: dict = field(default_factory=dict)
    residual: np.ndarray | None = None

    def save(self, path) -> None:
        """Write ``.npz`` atomically (temporary file in the same directory, then rename; RunError on OSError)."""
        failures = [f"{i} {j} {reason}" for (i, j), reason in sorted(self.failures.items())]
        skipped = [f"{k} {reason}" for k, reason in sorted(self.skipped.items())]
        write_atomic(
            path,
            lambda tmp: np.savez(
                tmp,
                distance=self.distance,
                energy=self.energy,
                files=np.array(self.names),
                rotations=self.rotations,
                seconds=self.seconds,
                failures=np.array(failures, dtype=str),
                skipped=np.array(skipped, dtype=str),
                params=json.dumps(self.params),
                residual=np.full_like(self.distance, np.nan) if self.residual is None else self.residual,
            ),
        )

    @classmethod
    def load(cls, path) -> DistanceMatrix:
        """Read a matrix written by :meth:`save` (InputError when the file is not one)."""
        data = read_npz(path, "distance matrix")
        try:
            failures = {}
            for line in data["failures"].tolist():
                i, j, reason = line.split(" ", 2)
                failures[int(i), int(j)] = reason
            skipped = {}
            for line in data["skipped"].tolist() if "skipped" in data else []:
                k, reason = line.split(" ", 1)
                skipped[int(k)] = reason
            return cls(
                data["files"].tolist(),
                data["distance"],
                data["energy"],
                data["rotations"],
                data["seconds"],
                failures,
                json.loads(str(data["params"])),
                skipped,
                data["residual"] if "residual" in data else np.full(data["distance"].shape, np.nan),
            )
        except (KeyError, ValueError, TypeError, AttributeError) as err:
            raise InputError(f"{path}: not a meshreg distance matrix file ({type(err).__name__}: {err})") from None


def _params_key(params: dict) -> str:
    """The checkpoint key of a run: its parameters (``force`` left out: it changes no result)."""
    kept = {k: v for k, v in params.items() if k != "force"}
    return _digest(json.dumps(kept, sort_keys=True, default=str).encode())


def _surface_key(p: Prepared) -> str | None:
    """A digest of a prepared surface: its grid and partitions, and its other corner placements."""
    if p.grid is None:
        return None
    return _digest(*(a for g in [p.grid, *p.placements, *p.arcs] for a in (g.points, g.r, g.t)))


def _run_key(names, grids, params) -> str:
    """A digest of a run: names, parameters and grids (the atlas ties its stages' checkpoints to it)."""
    digest = hashlib.sha256(json.dumps({"names": names, "params": params}, sort_keys=True, default=str).encode())
    for g in grids:
        digest.update(b"-" if g is None else np.ascontiguousarray(g.points).tobytes())
    return digest.hexdigest()


def distance_matrix(
    surfaces,
    options: Options | None = None,
    *,
    names=None,
    client=None,
    jobs: int | None = None,
    checkpoint=None,
    progress=None,
    retry_failed: bool = True,
    preparing=None,
) -> DistanceMatrix:
    """All pairwise elastic distances of a collection.

    Parameters
    ----------
    surfaces : sequence
        GridSurfaces, (M, N, 3) arrays, (vertices, faces) pairs, or paths of grid files or meshes. An item that
        cannot be read or prepared is skipped (``skipped`` of the result); the rest goes on.
    options : Options, optional
        How meshes become grids (``resolution``, ``weights``, ``cleanup``, ``corner_search``) and how every pair
        is registered (default mode "auto").
    names : list of str, optional
        Labels (default: the paths, else "surface i").
    client : dask.distributed.Client, optional
        Run the pairs on this Dask cluster. Default: a local process pool.
    jobs : int, optional
        Processes of the local pool (default: the machine's cores; 1 runs in this process). A lost process costs
        only the pair it held (that pair fails; a new process takes its place).
    checkpoint : path, optional
        JSON-lines file recording each finished pair (:class:`Checkpoint`); an existing one for the same
        parameters is resumed.
    progress : callable, optional
        ``progress(done, total)`` after every finished pair (and once at the start).
    retry_failed : bool
        When resuming, run again the pairs the checkpoint records as failed (default); False keeps them failed.
    preparing : callable, optional
        ``preparing(done, total)`` after each surface is prepared (read; meshes cleaned, mapped, resampled).

    Returns
    -------
    DistanceMatrix

    Examples
    --------
    >>> from meshreg.samples import sample, sine, helicoid
    >>> grids = [sample(sine(2), 21, 21), sample(sine(2), 21, 21), sample(helicoid(1), 21, 21)]
    >>> d = distance_matrix(grids, jobs=1)
    >>> bool(d.distance[0, 1] < 1e-3 < d.distance[0, 2]), bool((d.distance == d.distance.T).all())
    (True, True)
    """
    items = collection_items(surfaces)
    n = len(items)
    if n < 2:
        raise InputError("a distance matrix needs at least 2 surfaces")
    options = options or Options()
    jobs = check_jobs(jobs, options.force) if client is None else None
    if names is None:
        names = [str(x) if isinstance(x, (str, Path)) else f"surface {k}" for k, x in enumerate(items)]
    if len(names) != n:
        raise InputError(f"{len(names)} names for {n} surfaces")
    prepared = prepare_collection(items, names, options, preparing)
    run_params = options.as_dict()
    pairs = [(i, j) for i in range(n) for j in range(i + 1, n)]
    done = run_checkpointed(
        prepared,
        pairs,
        options,
        key=_params_key(run_params),
        checkpoint=checkpoint,
        client=client,
        jobs=jobs,
        progress=progress,
        retry_failed=retry_failed,
    )
    skipped = {k: p.error for k, p in enumerate(prepared) if p.error}
    return _assemble(names, done, run_params, skipped)


def collection_items(surfaces) -> list:
    """The members of a collection as a list; InputError for one surface given in place of a sequence of them (a
    path, whose characters would be taken for files; one grid array (M, N, 3), whose rows would; one mesh as
    (vertices (n, 3), faces (m, 3)), whose vertices and faces would be two surfaces, each skipped)."""
    if isinstance(surfaces, (str, bytes, os.PathLike)) or (isinstance(surfaces, np.ndarray) and surfaces.ndim == 3):
        raise InputError(f"give a list of surfaces (paths, grids or meshes), not one {type(surfaces).__name__}")
    items = list(surfaces)
    if len(items) == 2 and all(isinstance(x, np.ndarray) and x.ndim == 2 and x.shape[1:] == (3,) for x in items):
        if np.issubdtype(items[1].dtype, np.integer) and not np.issubdtype(items[0].dtype, np.integer):
            raise InputError("give a list of surfaces, not one mesh (vertices, faces): e.g. [(v1, f1), (v2, f2)]")
    return items


def run_checkpointed(
    prepared,
    pairs,
    options: Options,
    *,
    key: str,
    checkpoint=None,
    client=None,
    jobs: int | None = None,
    progress=None,
    task=None,
    retry_failed: bool = True,
) -> dict:
    """Run every pair (i, j) of ``pairs`` once (:func:`run_pairs`) and return ``{(i, j): record}``.

    With ``checkpoint`` (a path), each finished pair is appended to that :class:`~meshreg.checkpoint.Checkpoint`,
    tied to the run by ``key`` and to its two surfaces by their digests; pairs already there are not run again
    (failed ones are, with ``retry_failed``). A pair with a surface that could not be prepared is not run.
    ``progress(done, total)`` is called at the start and after every pair.
    """
    keys = [_surface_key(p) for p in prepared]
    store = Checkpoint(checkpoint, key) if checkpoint else None
    done = {}
    for record in store.records if store else []:
        i, j = record["i"], record["j"]
        if j < len(prepared) and keys[i] is not None and (record["first"], record["second"]) == (keys[i], keys[j]):
            done[i, j] = record  # a later record of a pair (a retry) replaces an earlier one
    if retry_failed:
        done = {pair: record for pair, record in done.items() if "error" not in record}
    notify = progress or (lambda finished, total: None)
    notify(len(done), len(pairs))

    def finish(i, j, record):
        record = {"i": i, "j": j, "first": keys[i], "second": keys[j], **record}
        done[i, j] = record
        if store:
            store.add(record)
        notify(len(done), len(pairs))

    todo = [(i, j) for i, j in pairs if (i, j) not in done and keys[i] is not None and keys[j] is not None]
    try:
        run_pairs(prepared, todo, options, finish, client=client, jobs=jobs, task=task)
    finally:
        if store:
            store.close()
    return done


def _outcome(function, args) -> dict:
    """The pair's record, or its error: one failing pair must not stop the run (KeyboardInterrupt does)."""
    try:
        return function(*args)
    except InputError as err:
        return {"error": str(err)}
    except MemoryError:
        return {"error": "out of memory"}
    except Exception as err:  # noqa: BLE001 - any failure of one pair is reported, with its type
        return {"error": f"{type(err).__name__}: {err}"}


def prepare_collection(items: list, names: list[str], options: Options, preparing=None) -> list[Prepared]:
    """Every item prepared (:func:`prepare_surface`, ``preparing(done, total)`` after each); when the collection
    has meshes with four clear turns and round-boundary meshes, the turned ones are prepared again with their
    grids at quarter arc lengths (``arcs``), which their pairs with round ones use (:func:`pair_grids`); a turned
    mesh whose second preparation fails (a boundary too coarse for every trial placement) keeps its first and its
    corners. ``preparing`` then counts the second preparations on top of the items."""
    prepared = []
    for item, name in zip(items, names, strict=True):
        prepared.append(prepare_surface(item, name, options))
        if preparing is not None:
            preparing(len(prepared), len(items))
    turned = [k for k, p in enumerate(prepared) if p.kind == "turned"]
    if turned and any(p.kind == "round" for p in prepared):
        for done, k in enumerate(turned, 1):
            again = prepare_surface(items[k], names[k], options, arcs=True)
            prepared[k] = prepared[k] if again.error else again
            if preparing is not None:
                preparing(len(items) + done, len(items) + len(turned))
    return prepared


def _roles(first: Prepared, second: Prepared) -> tuple[bool, bool]:
    """Whether the pair takes the first surface at its own quarter-arc placement and the second's quarter-arc
    placements: a mesh with four clear turns against a round-boundary one, placed like it."""
    return bool(first.arcs) and second.kind == "round", first.kind == "round" and bool(second.arcs)  # arcs: turned


def _firsts(p: Prepared, arc: bool) -> GridSurface:
    """What a surface offers as the first of a pair: its grid, or its own quarter-arc placement."""
    return p.arcs[0] if arc else p.grid


def _seconds(p: Prepared, arcs: bool = False):
    """What a surface offers as the second of a pair: its grid, all its corner placements, or its quarter-arc
    placements."""
    if arcs:
        return list(p.arcs)
    return [p.grid, *p.placements] if p.placements else p.grid


def pair_grids(first: Prepared, second: Prepared) -> tuple[GridSurface, GridSurface | list]:
    """The first surface's grid and the second's grid or list of corner placements for the pair (first, second):
    round-boundary meshes offer their placements as the second; a mesh with four clear turns against a round one
    offers its quarter-arc placements instead of its corners (four clear turns on one mesh only are not corners
    of the surface: the dents of a jagged rim)."""
    arc, arcs = _roles(first, second)
    return _firsts(first, arc), _seconds(second, arcs)


def run_pairs(prepared, todo, options: Options, finish, *, client=None, jobs: int | None = None, task=None) -> None:
    """Run ``task(first, second, options)`` for each pair (i, j) of ``todo``, ``first`` and ``second`` being what
    :func:`pair_grids` takes of surfaces i and j (a grid; j's corner placements), on the Dask ``client`` or a local
    pool of ``jobs`` processes (default: the machine's cores; 1 runs in this process; a lost process costs only its
    pair), and call ``finish(i, j, record)`` as each ends (a failed pair's record is ``{"error": reason}``).
    ``task`` defaults to :func:`register_pair`; it must be picklable. Each pair runs in one process
    (``Advanced.processes`` = 1): the pairs already keep the workers busy."""
    task = task or register_pair
    options = options.replace(advanced=replace(options.advanced, processes=1))
    if client is not None:
        _run_dask(client, prepared, todo, options, finish, task)
    else:
        _run_local(prepared, todo, options, finish, jobs or os.cpu_count() or 1, task)


def _run_local(prepared, todo, options: Options, finish, jobs: int, task) -> None:
    tasks = [((i, j), (*pair_grids(prepared[i], prepared[j]), options)) for i, j in todo]
    if jobs <= 1 or len(tasks) <= 1:
        for (i, j), args in tasks:
            finish(i, j, _outcome(task, args))
        return
    run_tasks(task, tasks, jobs, lambda pair, record: finish(*pair, record), _outcome)


def _run_dask(client, prepared, todo, options, finish, task) -> None:
    from distributed import as_completed

    roles = {(i, j): _roles(prepared[i], prepared[j]) for i, j in todo}
    as_first = {(i, arc) for (i, _), (arc, _) in roles.items()}  # each surface scattered once per role it plays
    as_second = {(j, arcs) for (_, j), (_, arcs) in roles.items()}
    firsts = {(i, arc): client.scatter(_firsts(prepared[i], arc)) for i, arc in as_first}
    seconds = {(j, arcs): client.scatter(_seconds(prepared[j], arcs)) for j, arcs in as_second}
    futures = {
        client.submit(task, firsts[i, arc], seconds[j, arcs], options, pure=False): (i, j)
        for (i, j), (arc, arcs) in roles.items()
    }
    try:
        for future in as_completed(futures):
            i, j = futures[future]
            finish(i, j, _outcome(future.result, ()))
    except BaseException:
        client.cancel(list(futures))
        raise


def _assemble(names, done: dict, params: dict, skipped: dict) -> DistanceMatrix:
    n = len(names)
    energy = np.full((n, n), np.nan)
    np.fill_diagonal(energy, 0.0)
    residual = energy.copy()
    rotations = np.tile(np.eye(3), (n, n, 1, 1))
    seconds = np.zeros((n, n))
    failures = {}
    for i in range(n):
        for j in range(i + 1, n):
            record = done.get((i, j))
            bad = [k for k in (i, j) if k in skipped]
            if bad:
                failures[i, j] = "; ".join(f"{names[k]} skipped: {skipped[k]}" for k in bad)
            elif record is None:
                failures[i, j] = "not run"
            elif "error" in record:
                failures[i, j] = record["error"]
            else:
                energy[i, j] = energy[j, i] = record["energy"]
                residual[i, j] = residual[j, i] = record.get("residual", np.nan)
                rotations[i, j] = record["rotation"]
                rotations[j, i] = np.transpose(record["rotation"])
                seconds[i, j] = seconds[j, i] = record["seconds"]
    distance = np.sqrt(np.maximum(energy, 0.0))
    return DistanceMatrix(list(names), distance, energy, rotations, seconds, failures, params, dict(skipped), residual)
