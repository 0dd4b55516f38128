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
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import InputError, RunError
from .files import output_dir, reason, remove_outputs, surface_kind, write_atomic
from .grid import GridSurface, read_grid
from .limits import check_jobs
from .options import Options, check_scheduler
from .register import register_with
from .workers import run_tasks

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
    keeps its grids for ``options.corner_search`` corner placements). Errors (unreadable file, not a disk, out of
    memory, ...) are returned in ``error``, not raised: the item is skipped and the rest goes on."""
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
            grids, _ = mesh_grids(*item, options)
            return Prepared(name, grids[0], placements=grids[1:])
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
    """One pair's numbers: energy, rotation (3 x 3 list), seconds (and the chosen corner placement when
    ``second`` is a list of a round-boundary mesh's placements, ranked as in ``meshreg register``). Runs in
    a worker process.

    BLAS is held to one thread: worker processes forked from a parent with a threaded OpenBLAS ran pairs
    5-10x slower on a 2-core machine, and one pair per core is the parallelism that pays.
    """
    from threadpoolctl import threadpool_limits

    tic = time.perf_counter()
    record = {}
    with threadpool_limits(1):
        if isinstance(second, list):
            from .mesh.corners import best_placement

            record["placement"] = best_placement(first, second)
            second = second[record["placement"]]
        result = register_with(first, second, options)
    if not np.isfinite(result.energy):
        raise RunError(f"the registration gave E = {result.energy}")
    return {
        "energy": result.energy,
        "rotation": result.rotation.tolist(),
        "seconds": time.perf_counter() - tic,
        **record,
    }


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
    """

    names: list
    distance: np.ndarray
    energy: np.ndarray
    rotations: np.ndarray
    seconds: np.ndarray
    failures: dict = field(default_factory=dict)
    params: dict = field(default_factory=dict)
    skipped: dict = field(default_factory=dict)

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
            ),
        )

    @classmethod
    def load(cls, path) -> DistanceMatrix:
        """Read a matrix written by :meth:`save` (InputError when the file is not one)."""
        try:
            with np.load(path, allow_pickle=False) as data:
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
                )
        except (OSError, KeyError, ValueError, EOFError, zipfile.BadZipFile) as err:
            raise InputError(f"{path}: not a meshreg distance matrix file ({type(err).__name__}: {err})") from None


class Checkpoint:
    """Append-only JSON-lines record of finished pairs.

    Line 1 is the header ``{"key": ...}``, a digest of the registration parameters; every other line records one
    pair: ``{"i", "j", "first", "second", "energy", "rotation", "seconds"[, "placement"]}`` or ``{"i", "j", "first",
    "second", "error"}``, ``first`` and ``second`` being digests of the two surfaces (a record is reused only for
    the same two surfaces, so that replacing one file of a collection redoes only its pairs).

    A last line cut by a kill is dropped (that pair is redone) and an empty file, or one cut inside its header (a
    run killed at its start), starts afresh. A header of other parameters, or a line that is not a pair record,
    is refused with one line that says which and how to start over or salvage the rest.

    Parameters
    ----------
    path : path
    key : str
        The digest of this run's parameters.
    """

    def __init__(self, path, key: str):
        self.path = Path(path)
        self.key = key
        self.records: list[dict] = []
        keep = self._read() if self.path.exists() else 0
        try:
            self._file = open(self.path, "a+b")
            self._file.truncate(keep)  # drop a line cut by a kill, or a cut header
        except OSError as err:
            raise InputError(f"cannot write the checkpoint {self.path} ({reason(err)}): give another -o") from None
        if keep == 0:
            self._write({"key": key})

    def _read(self) -> int:
        """Read the records; returns the bytes to keep (0: start afresh)."""
        start_over = f"delete {self.path} to start over"
        try:
            data = self.path.read_bytes()
        except OSError as err:
            raise InputError(f"cannot read the checkpoint {self.path} ({reason(err)}): {start_over}") from None
        if b"\n" not in data:
            return 0  # empty, or killed while writing its header
        keep = data.rindex(b"\n") + 1
        try:
            lines = data[:keep].decode("utf-8").split("\n")[:-1]
        except UnicodeDecodeError as err:
            line = data[: err.start].count(b"\n") + 1
            salvage = "delete that line to keep the other finished pairs, or " if line > 1 else ""
            raise InputError(
                f"{self.path} line {line} is not UTF-8 text (a damaged checkpoint): {salvage}{start_over}"
            ) from None
        header = _json_or_none(lines[0])
        if not isinstance(header, dict) or set(header) != {"key"}:
            raise InputError(
                f"{self.path} is not a meshreg checkpoint (line 1 is not its header): {start_over}, "
                "or write the matrix elsewhere"
            )
        if header["key"] != self.key:
            raise InputError(
                f"{self.path} is a checkpoint of a run with other parameters: rerun with those, {start_over}, "
                "or write the matrix elsewhere"
            )
        for number, line in enumerate(lines[1:], start=2):
            record = _json_or_none(line)
            problem = _record_problem(record)
            if problem:
                raise InputError(
                    f"{self.path} line {number} {problem}: delete that line to keep the other finished pairs, "
                    f"or {start_over}"
                )
            self.records.append(record)
        return keep

    def add(self, record: dict) -> None:
        self.records.append(record)
        self._write(record)

    def _write(self, record: dict) -> None:
        try:
            self._file.write((json.dumps(record) + "\n").encode("utf-8"))
            self._file.flush()
            os.fsync(self._file.fileno())
        except OSError as err:
            raise RunError(
                f"cannot write the checkpoint {self.path} ({reason(err)}): the pairs recorded before are kept; "
                "free the space and rerun the same command to resume"
            ) from None

    def close(self) -> None:
        self._file.close()


def _json_or_none(line: str):
    try:
        return json.loads(line)
    except json.JSONDecodeError:
        return None


def _number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and bool(np.isfinite(value))


def _record_problem(record) -> str | None:
    """What makes ``record`` not a pair record of :class:`Checkpoint`, or None."""
    if not isinstance(record, dict):
        return "is not a pair record (not a JSON object)"
    i, j = record.get("i"), record.get("j")
    if not all(isinstance(k, int) and not isinstance(k, bool) for k in (i, j)) or not 0 <= i < j:
        return f"names no pair of surfaces (i = {i!r}, j = {j!r}; a pair needs 0 <= i < j)"
    if not all(isinstance(record.get(k), str) for k in ("first", "second")):
        return "lacks the digests of its two surfaces"
    if "error" in record:
        return None if isinstance(record["error"], str) else "holds an error that is not text"
    rotation = np.asarray(record.get("rotation"), dtype=object)
    if not _number(record.get("energy")) or record["energy"] < 0:
        return f"holds no energy E >= 0 (got {record.get('energy')!r})"
    if rotation.shape != (3, 3) or not all(_number(v) for v in rotation.ravel()):
        return "holds no 3 x 3 rotation"
    if not _number(record.get("seconds")):
        return "holds no time in seconds"
    return None


def _digest(*parts) -> str:
    digest = hashlib.sha256()
    for part in parts:
        digest.update(part if isinstance(part, bytes) else np.ascontiguousarray(part).tobytes())
        digest.update(b"|")
    return digest.hexdigest()


def _params_key(params: dict) -> str:
    """The checkpoint key of a run: its parameters (``force`` left out: it changes no result)."""
    kept = {k: v for k, v in params.items() if k != "force"}
    return _digest(json.dumps(kept, sort_keys=True, default=str).encode())


def _surface_key(p: Prepared) -> str | None:
    """A digest of a prepared surface: its grid and partitions, and its other corner placements."""
    if p.grid is None:
        return None
    return _digest(*(a for g in [p.grid, *p.placements] for a in (g.points, g.r, g.t)))


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
    options = options or Options()
    jobs = check_jobs(jobs, options.force) if client is None else None
    if names is None:
        names = [str(x) if isinstance(x, (str, Path)) else f"surface {k}" for k, x in enumerate(items)]
    if len(names) != n:
        raise InputError(f"{len(names)} names for {n} surfaces")
    prepared = [prepare_surface(x, nm, options) for x, nm in zip(items, names, strict=True)]
    run_params = options.as_dict()
    keys = [_surface_key(p) for p in prepared]
    pairs = [(i, j) for i in range(n) for j in range(i + 1, n)]
    store = Checkpoint(checkpoint, _params_key(run_params)) if checkpoint else None
    done = {}
    for record in store.records if store else []:
        i, j = record["i"], record["j"]
        if j < n and keys[i] is not None and (record["first"], record["second"]) == (keys[i], keys[j]):
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
        if client is not None:
            _run_dask(client, prepared, todo, options, finish)
        else:
            _run_local(prepared, todo, options, finish, jobs)
    finally:
        if store:
            store.close()
    skipped = {k: p.error for k, p in enumerate(prepared) if p.error}
    return _assemble(names, done, run_params, skipped)


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


def _seconds(p: Prepared):
    """What a surface offers as the second of a pair: its grid, or all its corner placements."""
    return [p.grid, *p.placements] if p.placements else p.grid


def _run_local(prepared, todo, options: Options, finish, jobs: int) -> None:
    tasks = [((i, j), (prepared[i].grid, _seconds(prepared[j]), options)) for i, j in todo]
    if jobs <= 1 or len(tasks) <= 1:
        for (i, j), args in tasks:
            finish(i, j, _outcome(register_pair, args))
        return
    run_tasks(register_pair, tasks, jobs, lambda pair, record: finish(*pair, record), _outcome)


def _run_dask(client, prepared, todo, options, finish) -> None:
    from distributed import as_completed

    used = {k for pair in todo for k in pair}
    firsts = {k: client.scatter(prepared[k].grid) for k in used}
    seconds = {k: client.scatter(_seconds(prepared[k])) for k in used}
    futures = {client.submit(register_pair, firsts[i], seconds[j], options, pure=False): (i, j) for i, j in todo}
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
                rotations[i, j] = record["rotation"]
                rotations[j, i] = np.transpose(record["rotation"])
                seconds[i, j] = seconds[j, i] = record["seconds"]
    distance = np.sqrt(np.maximum(energy, 0.0))
    return DistanceMatrix(list(names), distance, energy, rotations, seconds, failures, params, dict(skipped))


@dataclass
class MatrixRun:
    """What :func:`matrix_files` did.

    Attributes
    ----------
    result : DistanceMatrix
    written : Path or None
        The matrix file, None when no pair has a value (then nothing is written and an older file of that name
        is removed).
    figure : Path or None
        The figure (``plot``), None without it or without any value.
    checkpoint : Path or None
        The checkpoint, kept while some pair has no value (rerun the same command to retry those); None once
        every pair has one (it is then removed).
    """

    result: DistanceMatrix
    written: Path | None
    figure: Path | None
    checkpoint: Path | None

    @property
    def error(self) -> str | None:
        """One line saying how many pairs have no value and where the reasons are, or None when all have one."""
        missing, total = len(self.result.failures), len(self.result.names) * (len(self.result.names) - 1) // 2
        if not missing:
            return None
        where = f"listed above and in {self.written} ('failures')" if self.written else "listed above"
        return (
            f"{missing} of {total} pairs have no value (reasons {where}); the finished pairs are kept in "
            f"{self.checkpoint}: fix or remove the failing surfaces and rerun the same command to retry them"
        )


def check_matrix(files, out, options: Options, *, jobs: int | None = None, scheduler: str | None = None) -> int | None:
    """What :func:`matrix_files` checks before any work, in milliseconds (InputError): the inputs exist, are files
    of a known type and are at least 2; ``out`` ends in ``.npz`` and its directory can take it, its checkpoint and
    its figure; ``jobs`` and ``scheduler`` are valid. Returns the number of local processes (None with a
    scheduler)."""
    files, out = [Path(f) for f in files], Path(out)
    if len(files) < 2:
        raise InputError("a distance matrix needs at least 2 surfaces")
    for f in files:
        surface_kind(f)
    if out.suffix != ".npz":
        raise InputError(f"{out}: the matrix file must end in .npz")
    output_dir(out.parent, [out.name, out.name + CHECKPOINT_SUFFIX, out.with_suffix(".png").name], files)
    if scheduler is not None:
        check_scheduler(scheduler)
        return None
    return check_jobs(jobs, options.force)


def matrix_files(
    files,
    out,
    options: Options | None = None,
    *,
    jobs: int | None = None,
    scheduler: str | None = None,
    plot: bool = False,
    progress=None,
    retry_failed: bool = True,
) -> MatrixRun:
    """``meshreg matrix``: the distance matrix of files, checkpointed beside ``out`` (``.npz``) and resumed from
    there, written atomically; with ``plot`` also ``out`` with suffix ``.png``. ``scheduler`` is the address of
    a dask.distributed scheduler (default: the local process pool of ``jobs`` processes).

    Everything that can be checked before the first pair is (InputError): the parameters, the inputs (missing
    files, directories, unknown suffixes) and the output place. Unreadable surfaces are skipped. Outputs of an
    earlier run at ``out`` are replaced, or removed when no pair has a value, never left beside this run's. On
    KeyboardInterrupt (Ctrl-C, SIGTERM from the command line) the workers are stopped and the interruption goes
    on with a note saying where the finished pairs are.
    """
    options = options or Options()
    files, out = [Path(f) for f in files], Path(out)
    jobs = check_matrix(files, out, options, jobs=jobs, scheduler=scheduler)
    checkpoint = out.with_name(out.name + CHECKPOINT_SUFFIX)
    figure_path = out.with_suffix(".png")
    client = _client(scheduler) if scheduler else None
    try:
        result = distance_matrix(
            files,
            options,
            client=client,
            jobs=jobs,
            checkpoint=checkpoint,
            progress=progress,
            retry_failed=retry_failed,
        )
    except KeyboardInterrupt as err:
        err.add_note(f"finished pairs are kept in {checkpoint}; rerun the same command to resume")
        raise
    finally:
        if client is not None:
            client.close()
    if len(result.failures) == len(result.names) * (len(result.names) - 1) // 2:
        remove_outputs(out.parent, [out.name, figure_path.name])
        return MatrixRun(result, None, None, checkpoint)
    try:
        result.save(out)
    except RunError as err:
        raise RunError(f"{err}: the finished pairs are kept in {checkpoint}; rerun the same command") from None
    figure = None
    if plot:
        from .viz import classical_mds, plot_matrix

        embedding = classical_mds(result.distance)
        figure = write_atomic(figure_path, lambda tmp: plot_matrix(result.names, result.distance, embedding, tmp))
    else:
        remove_outputs(out.parent, [figure_path.name])
    if result.failures:
        return MatrixRun(result, out, figure, checkpoint)
    checkpoint.unlink(missing_ok=True)
    return MatrixRun(result, out, figure, None)


def _client(scheduler: str):
    """A dask.distributed Client of the scheduler at ``scheduler``."""
    try:
        from distributed import Client
    except ImportError:
        raise InputError("--scheduler needs dask.distributed: pip install 'meshreg[dask]'") from None
    try:
        return Client(scheduler, timeout="20s")
    except (OSError, TimeoutError, ValueError) as err:
        raise InputError(f"cannot reach the Dask scheduler at {scheduler}: {err}") from None
