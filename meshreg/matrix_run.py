"""``meshreg matrix``: the distance matrix of files, checked before any work, checkpointed beside its output,
resumed after an interruption and written all together or not at all."""

from __future__ import annotations

from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .batch import DistanceMatrix, distance_matrix
from .checkpoint import CHECKPOINT_SUFFIX
from .errors import InputError, RunError
from .files import output_dir, remove_outputs, surface_kind, write_atomic
from .limits import check_jobs
from .options import Options, check_scheduler
from .ownership import refuse_foreign, writing


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
    reused : bool
        True when ``written`` already held this run's finished matrix (same files and parameters, newer than every
        input, every pair with a value): nothing was recomputed.
    """

    result: DistanceMatrix
    written: Path | None
    figure: Path | None
    checkpoint: Path | None
    reused: bool = False

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
    figure = out.with_suffix(".png").name
    output_dir(out.parent, [out.name, out.name + CHECKPOINT_SUFFIX, figure], files, False)
    refuse_foreign(out.parent, [figure])  # the matrix file is named by the user; its figure is not
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
    preparing=None,
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
    finished = None if options.force or checkpoint.exists() else _finished(out, files, options)
    if finished is not None:
        return MatrixRun(finished, out, _figure(finished, figure_path) if plot else None, None, reused=True)
    with scheduler_client(scheduler, f"finished pairs are kept in {checkpoint}") as client:
        result = distance_matrix(
            files,
            options,
            client=client,
            jobs=jobs,
            checkpoint=checkpoint,
            progress=progress,
            retry_failed=retry_failed,
            preparing=preparing,
        )
    if len(result.failures) == len(result.names) * (len(result.names) - 1) // 2:
        remove_outputs(out.parent, [out.name, figure_path.name])
        return MatrixRun(result, None, None, checkpoint)
    try:
        result.save(out)
    except RunError as err:
        raise RunError(f"{err}: the finished pairs are kept in {checkpoint}; rerun the same command") from None
    figure = None
    if plot:
        figure = _figure(result, figure_path)
    else:
        remove_outputs(out.parent, [figure_path.name])
    if result.failures:
        return MatrixRun(result, out, figure, checkpoint)
    checkpoint.unlink(missing_ok=True)
    return MatrixRun(result, out, figure, None)


@contextmanager
def scheduler_client(scheduler: str | None, kept: str):
    """A dask.distributed Client of the scheduler at ``scheduler`` (None without one) for the ``with`` block, closed
    when it ends; a KeyboardInterrupt in it goes on with the note ``kept`` (where the finished work is) and how to
    resume."""
    client = _client(scheduler) if scheduler else None
    try:
        yield client
    except KeyboardInterrupt as err:
        err.add_note(f"{kept}; rerun the same command to resume")
        raise
    finally:
        if client is not None:
            client.close()


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


def _finished(out: Path, files: list[Path], options: Options) -> DistanceMatrix | None:
    """The matrix already at ``out`` when it is this run's, finished: the same files and parameters, every pair with
    a value, and written after the last change of every input (its modification or its status change: a file moved
    or copied into place with an older modification time, by ``mv``, ``cp -p`` or ``rsync -a``, was taken for the
    one the matrix was computed from); else None."""
    import json

    if not out.is_file():
        return None
    written = out.stat().st_mtime
    if any(max(stat.st_mtime, stat.st_ctime) > written for stat in (f.stat() for f in files)):
        return None
    try:
        done = DistanceMatrix.load(out)
    except InputError:
        return None

    def key(params: dict) -> str:  # force changes no result
        return json.dumps({k: v for k, v in params.items() if k != "force"}, sort_keys=True, default=str)

    same_params = key(done.params) == key(options.as_dict())
    return done if done.names == [str(f) for f in files] and same_params and not done.failures else None


def _figure(result: DistanceMatrix, path: Path) -> Path:
    """The heat map, dendrogram and MDS figure of a matrix, written atomically and recorded as meshreg's. A surface
    without any value (unreadable, or every pair failed) is left out of it, and the title says so."""
    from .viz import classical_mds, plot_matrix

    off = np.where(np.eye(len(result.names), dtype=bool), np.nan, result.distance)
    valued = np.isfinite(off).any(axis=1)
    kept = np.flatnonzero(valued)
    left = [Path(str(name)).stem for name, has in zip(result.names, valued, strict=True) if not has]
    distance = result.distance[np.ix_(kept, kept)]
    names = [result.names[k] for k in kept]
    title = f"{len(names)} surfaces, {len(names) * (len(names) - 1) // 2} pairs" + (
        f"; left out, without any value: {', '.join(left)}" if left else ""
    )
    embedding = classical_mds(distance)
    with writing(path.parent, [path.name]):
        write_atomic(path, lambda tmp: plot_matrix(names, distance, embedding, tmp, title=title))
    return path
