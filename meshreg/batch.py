"""Distance matrices for collections: every unordered pair registered once, locally or on a Dask cluster.

Each surface is prepared once (read, and for meshes cleaned, mapped to the square and resampled); pair
(i, j), i < j, registers surface i (rotated) with surface j (reparametrized): ``distance[i, j] =
distance[j, i] = sqrt(E)`` of that registration (E is not exactly symmetric once discretized; the lower
index is always the first surface, so reruns and clusters give the same numbers).

Every finished pair is appended to a checkpoint file (JSON lines, flushed and fsynced) as it completes;
a rerun with the same inputs and parameters skips the pairs already there, so an interrupted run (Ctrl-C,
a lost worker, a killed machine) loses at most the pairs in flight. The final ``.npz`` is written to a
temporary file and renamed (atomic). A pair that fails (a bad mesh) is recorded with its reason.
"""

from __future__ import annotations

import hashlib
import json
import os
import time
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path

import numpy as np

from .errors import InputError
from .grid import GridSurface, read_grid
from .options import Options
from .pipeline import register_with
from .result import Registration

CHECKPOINT_SUFFIX = ".checkpoint.jsonl"


@dataclass
class Prepared:
    """A surface ready to register: its grid, or why it could not be prepared."""

    name: str
    grid: GridSurface | None
    error: str | None = None
    placements: list = field(default_factory=list)  # a round-boundary mesh: its grids for other corner placements


def prepare_surface(item, name: str | None = None, options: Options | None = None) -> Prepared:
    """Read and prepare one surface: a GridSurface, an (M, N, 3) array, a (vertices, faces) pair, or a path to a
    grid file or a mesh (see :func:`meshreg.mesh.corners.mesh_grids`: a mesh without four clear corners
    keeps its grids for ``options.corner_search`` corner placements); a Prepared is returned as it is. Errors
    (unreadable file, not a disk, ...) are returned in ``error``, not raised."""
    from .mesh.topology import MESH_SUFFIXES

    if isinstance(item, Prepared):
        return item
    name = name or (str(item) if isinstance(item, (str, Path)) else "surface")
    try:
        if isinstance(item, GridSurface):
            return Prepared(name, item)
        if isinstance(item, (str, Path)):
            if Path(item).suffix.lower() not in MESH_SUFFIXES:
                return Prepared(name, read_grid(item))
            from .mesh.topology import load_mesh

            item = load_mesh(item)
        if isinstance(item, tuple):
            from .mesh.corners import mesh_grids

            grids, _ = mesh_grids(*item, options or Options())
            return Prepared(name, grids[0], placements=grids[1:])
        return Prepared(name, GridSurface.from_array(item))
    except InputError as err:
        return Prepared(name, None, str(err))


def register_pair(first: GridSurface, second: GridSurface | list, options: Options) -> dict:
    """One pair's numbers: energy, rotation (3 x 3 list), seconds (and the chosen corner placement when
    ``second`` is a list of a round-boundary mesh's placements, ranked as in ``meshreg register``). Runs in
    a worker process.

    BLAS is held to one thread: worker processes forked from a parent with a threaded OpenBLAS ran pairs
    5-10x slower on a 2-core machine, and one pair per core is the parallelism that pays.
    """
    result, record = registered_pair(first, second, options)
    return {"energy": result.energy, "rotation": result.rotation.tolist(), **record}


def registered_pair(first: GridSurface, second: GridSurface | list, options: Options) -> tuple[Registration, dict]:
    """:func:`register_pair`'s registration and its record (``seconds``, and ``placement`` for a list)."""
    from threadpoolctl import threadpool_limits

    tic = time.perf_counter()
    record = {}
    with threadpool_limits(1):
        if isinstance(second, list):
            from .mesh.corners import best_placement

            record["placement"] = best_placement(first, second, options.keep_orientation)
            second = second[record["placement"]]
        result = register_with(first, second, options)
    record["seconds"] = time.perf_counter() - tic
    return result, record


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
        ``(i, j) -> reason`` for pairs that failed.
    params : dict
        The registration and preparation parameters used.
    """

    names: list
    distance: np.ndarray
    energy: np.ndarray
    rotations: np.ndarray
    seconds: np.ndarray
    failures: dict = field(default_factory=dict)
    params: dict = field(default_factory=dict)

    def save(self, path) -> None:
        """Write ``.npz`` atomically (temporary file in the same directory, then rename)."""
        path = Path(path)
        tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp.npz")
        failures = [f"{i} {j} {reason}" for (i, j), reason in sorted(self.failures.items())]
        np.savez(
            tmp,
            distance=self.distance,
            energy=self.energy,
            files=np.array(self.names),
            rotations=self.rotations,
            seconds=self.seconds,
            failures=np.array(failures, dtype=str),
            params=json.dumps(self.params),
        )
        os.replace(tmp, path)

    @classmethod
    def load(cls, path) -> DistanceMatrix:
        with np.load(path) as data:
            failures = {}
            for line in data["failures"].tolist():
                i, j, reason = line.split(" ", 2)
                failures[int(i), int(j)] = reason
            return cls(
                data["files"].tolist(),
                data["distance"],
                data["energy"],
                data["rotations"],
                data["seconds"],
                failures,
                json.loads(str(data["params"])),
            )


class Checkpoint:
    """Append-only JSON-lines record of finished pairs, tied to the inputs and parameters by a key."""

    def __init__(self, path, key: str):
        self.path = Path(path)
        self.key = key
        self.done: dict = {}
        if self.path.exists():
            lines = self.path.read_text().splitlines()
            header = _json_or_none(lines[0]) if lines else None
            if header is None or header.get("key") != key:
                raise InputError(
                    f"{self.path} is a checkpoint of another run (other inputs or parameters): "
                    "delete it or write the matrix elsewhere"
                )
            for line in lines[1:]:
                record = _json_or_none(line)  # a line cut by a kill is skipped: that pair is redone
                if record is not None:
                    self.done[record["i"], record["j"]] = record
        self._file = open(self.path, "a")
        if not self.path.stat().st_size:
            self._write({"key": key})

    def add(self, record: dict) -> None:
        self.done[record["i"], record["j"]] = record
        self._write(record)

    def _write(self, record: dict) -> None:
        self._file.write(json.dumps(record) + "\n")
        self._file.flush()
        os.fsync(self._file.fileno())

    def close(self) -> None:
        self._file.close()


def _json_or_none(line: str):
    try:
        return json.loads(line)
    except json.JSONDecodeError:
        return None


def _run_key(names, grids, params) -> str:
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
) -> DistanceMatrix:
    """All pairwise elastic distances of a collection.

    Parameters
    ----------
    surfaces : sequence
        GridSurfaces, (M, N, 3) arrays, (vertices, faces) pairs, or paths of grid files or meshes.
    options : Options, optional
        How meshes become grids (``resolution``, ``weights``, ``cleanup``, ``corner_search``) and how every pair
        is registered (default mode "auto").
    names : list of str, optional
        Labels (default: the paths, else "surface i").
    client : dask.distributed.Client, optional
        Run the pairs on this Dask cluster. Default: a local process pool.
    jobs : int, optional
        Processes of the local pool (default: the machine's cores; 1 runs in this process).
    checkpoint : path, optional
        JSON-lines file recording each finished pair; an existing one for the same run is resumed.
    progress : callable, optional
        ``progress(done, total)`` after every finished pair (and once at the start).

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
    items = list(surfaces)
    n = len(items)
    if n < 2:
        raise InputError("a distance matrix needs at least 2 surfaces")
    if names is None:
        names = [str(x) if isinstance(x, (str, Path)) else f"surface {k}" for k, x in enumerate(items)]
    options = options or Options()
    prepared = [prepare_surface(x, nm, options) for x, nm in zip(items, names, strict=True)]
    run_params = options.as_dict()
    pairs = [(i, j) for i in range(n) for j in range(i + 1, n)]
    key = _run_key(names, [p.grid for p in prepared], run_params)
    done = run_checkpointed(
        prepared, pairs, options, key=key, checkpoint=checkpoint, client=client, jobs=jobs, progress=progress
    )
    return _assemble(names, done, run_params)


def run_checkpointed(
    prepared, pairs, options: Options, *, key: str, checkpoint=None, client=None, jobs=None, progress=None, task=None
) -> dict:
    """Run every pair (i, j) of ``pairs`` once (see :func:`run_pairs`) and return ``{(i, j): record}``.

    With ``checkpoint`` (a path), each finished pair is appended to that JSON-lines file, tied to the run by
    ``key``; pairs already there are not run again. A pair with a surface that could not be prepared gets an
    error record. ``progress(done, total)`` is called at the start and after every pair.
    """
    store = Checkpoint(checkpoint, key) if checkpoint else None
    done = dict(store.done) if store else {}
    notify = progress or (lambda finished, total: None)
    notify(len(done), len(pairs))

    def finish(i, j, record):
        record = {"i": i, "j": j, **record}
        done[i, j] = record
        if store:
            store.add(record)
        notify(len(done), len(pairs))

    todo = []
    for i, j in pairs:
        if (i, j) in done:
            continue
        bad = [p for p in (prepared[i], prepared[j]) if p.error]
        if bad:
            finish(i, j, {"error": "; ".join(f"{p.name}: {p.error}" for p in bad)})
        else:
            todo.append((i, j))
    try:
        run_pairs(prepared, todo, options, finish, client=client, jobs=jobs, task=task)
    finally:
        if store:
            store.close()
    return done


def _outcome(call) -> dict:
    """The pair's record, or its error: one failing pair must not stop the run (KeyboardInterrupt does)."""
    try:
        return call()
    except InputError as err:
        return {"error": str(err)}
    except Exception as err:  # noqa: BLE001 - any failure of one pair is reported, with its type
        return {"error": f"{type(err).__name__}: {err}"}


def _seconds(p: Prepared):
    """What a surface offers as the second of a pair: its grid, or all its corner placements."""
    return [p.grid, *p.placements] if p.placements else p.grid


def run_pairs(prepared, todo, options: Options, finish, *, client=None, jobs: int | None = None, task=None) -> None:
    """Run ``task(prepared[i].grid, second, options)`` for each pair (i, j) of ``todo``, ``second`` being surface
    j's grid or its corner placements, on the Dask ``client`` or a local pool of ``jobs`` processes (default: the
    machine's cores; 1 runs in this process), and call ``finish(i, j, record)`` as each ends (a failed pair's
    record is ``{"error": reason}``). ``task`` defaults to :func:`register_pair`; it must be picklable."""
    task = task or register_pair
    if client is not None:
        _run_dask(client, prepared, todo, options, finish, task)
    else:
        _run_local(prepared, todo, options, finish, jobs or os.cpu_count() or 1, task)


def _run_local(prepared, todo, options: Options, finish, jobs: int, task=register_pair) -> None:
    if jobs <= 1:
        for i, j in todo:
            finish(i, j, _outcome(partial(task, prepared[i].grid, _seconds(prepared[j]), options)))
        return
    with ProcessPoolExecutor(max_workers=jobs) as pool:
        running = {pool.submit(task, prepared[i].grid, _seconds(prepared[j]), options): (i, j) for i, j in todo}
        try:
            while running:
                finished, _ = wait(running, return_when=FIRST_COMPLETED)
                for future in finished:
                    i, j = running.pop(future)
                    finish(i, j, _outcome(future.result))
        except BaseException:
            pool.shutdown(wait=False, cancel_futures=True)
            raise


def _run_dask(client, prepared, todo, options, finish, task=register_pair) -> None:
    from distributed import as_completed

    used = {k for pair in todo for k in pair}
    firsts = {k: client.scatter(prepared[k].grid) for k in used}
    seconds = {k: client.scatter(_seconds(prepared[k])) for k in used}
    futures = {client.submit(task, firsts[i], seconds[j], options, pure=False): (i, j) for i, j in todo}
    try:
        for future in as_completed(futures):
            i, j = futures[future]
            finish(i, j, _outcome(future.result))
    except BaseException:
        client.cancel(list(futures))
        raise


def _assemble(names, done: dict, params: dict) -> DistanceMatrix:
    n = len(names)
    energy = np.full((n, n), np.nan)
    np.fill_diagonal(energy, 0.0)
    rotations = np.tile(np.eye(3), (n, n, 1, 1))
    seconds = np.zeros((n, n))
    failures = {}
    for (i, j), record in done.items():
        if "error" in record:
            failures[i, j] = record["error"]
            continue
        energy[i, j] = energy[j, i] = record["energy"]
        rotations[i, j] = record["rotation"]
        rotations[j, i] = np.transpose(record["rotation"])
        seconds[i, j] = seconds[j, i] = record["seconds"]
    missing = [(i, j) for i in range(n) for j in range(i + 1, n) if (i, j) not in done]
    for pair in missing:
        failures[pair] = "not run"
    return DistanceMatrix(list(names), np.sqrt(np.maximum(energy, 0.0)), energy, rotations, seconds, failures, params)


def matrix_files(
    files,
    out,
    options: Options | None = None,
    *,
    jobs: int | None = None,
    scheduler: str | None = None,
    plot: bool = False,
    progress=None,
):
    """``meshreg matrix``: the distance matrix of files, checkpointed beside ``out`` (``.npz``) and resumed from
    there, written atomically; with ``plot`` also ``out`` with suffix ``.png``. ``scheduler`` is the address of
    a dask.distributed scheduler (default: the local process pool of ``jobs`` processes).

    Returns the DistanceMatrix and the figure's path (None without ``plot``).
    """
    files, out = [Path(f) for f in files], Path(out)
    if out.suffix != ".npz":
        raise InputError(f"{out}: the matrix file must end in .npz")
    if any(out.resolve() == f.resolve() for f in files):
        raise InputError(f"{out} is one of the inputs: choose another output file")
    missing = [str(f) for f in files if not f.is_file()]
    if missing:
        raise InputError(f"no such file: {', '.join(missing)}")
    out.parent.mkdir(parents=True, exist_ok=True)
    client = _client(scheduler) if scheduler else None
    checkpoint = out.with_name(out.name + CHECKPOINT_SUFFIX)
    try:
        result = distance_matrix(files, options, client=client, jobs=jobs, checkpoint=checkpoint, progress=progress)
    except KeyboardInterrupt:
        raise InputError(
            f"interrupted: finished pairs are kept in {checkpoint}; rerun the same command to resume"
        ) from None
    finally:
        if client is not None:
            client.close()
    result.save(out)
    checkpoint.unlink(missing_ok=True)
    figure = None
    if plot:
        from .viz import classical_mds, plot_matrix

        figure = plot_matrix(result.names, result.distance, classical_mds(result.distance), out.with_suffix(".png"))
    return result, figure


def _client(scheduler: str):
    """A dask.distributed Client of the scheduler at ``scheduler``."""
    try:
        from distributed import Client
    except ImportError:
        raise InputError("--scheduler needs dask.distributed: pip install 'meshreg[dask]'") from None
    try:
        return Client(scheduler, timeout="20s")
    except (OSError, TimeoutError) as err:
        raise InputError(f"cannot reach the Dask scheduler at {scheduler}: {err}") from None
