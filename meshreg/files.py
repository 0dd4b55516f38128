"""Files at the edge: which kind of surface a path holds, and writing outputs so that a failed or interrupted run
never leaves a partial file or a mix of old and new ones.

- :func:`surface_kind` tells a grid file from a mesh by its suffix, and refuses a missing path, a directory or an
  unknown suffix (listing the known ones) before anything is read.
- :func:`output_dir` checks, before any computation, that a directory can take a run's outputs (made if missing;
  not a file, not under a file, writable, no directory in the way of an output, no output on an input, and no file
  with an output's name that meshreg did not write there: :func:`meshreg.ownership.not_ours`).
- only files meshreg wrote (:mod:`meshreg.ownership`) are ever replaced or removed by a later run.
- :func:`write_atomic` writes one file under a temporary name in its directory, then renames it into place.
- :func:`staged` writes a set of files into a temporary directory inside the output directory and moves them
  into place only when every one was written (the first file named last, so its presence means the set is
  complete); on an error nothing moves.
"""

from __future__ import annotations

import os
import shutil
import tempfile
import zipfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from .errors import InputError, RunError
from .ownership import RECORD_FILE, forget, record, refuse_foreign

GRID_SUFFIXES = (".npy", ".npz", ".txt", ".dat")  # .txt and .dat: the paper's text format
MESH_SUFFIXES = (".ply", ".obj", ".stl", ".off", ".glb", ".gltf")


def reason(err: OSError) -> str:
    """The words of an OSError without its repeated path ("Permission denied", "No space left on device")."""
    return err.strerror or str(err) or type(err).__name__


def existing_file(path) -> Path:
    """``path`` as a Path, refused with one line when it is missing or not a regular file."""
    path = Path(path)
    if path.is_dir():
        raise InputError(f"{path} is a directory: give a file")
    if not path.is_file():
        raise InputError(f"{path}: no such file")
    return path


def surface_kind(path) -> str:
    """``"mesh"`` or ``"grid"`` by the suffix of an existing file; InputError for anything else."""
    path = existing_file(path)
    suffix = path.suffix.lower()
    if suffix in MESH_SUFFIXES:
        return "mesh"
    if suffix in GRID_SUFFIXES:
        return "grid"
    raise InputError(
        f"{path}: unknown file type {suffix or '(no suffix)'!r}: grids are {' '.join(GRID_SUFFIXES)} "
        f"(.txt/.dat: the text format 'x y z' per line), meshes {' '.join(MESH_SUFFIXES)}"
    )


def output_dir(path, names, inputs=(), own_only: bool = True) -> Path:
    """The directory ``path`` made ready for the outputs ``names`` (paths relative to it), or InputError.

    Checked before any computation: ``path`` is not a file nor under one, can be made and written in, holds no
    directory where an output goes, no output would overwrite one of ``inputs`` and, with ``own_only``, no file has
    an output's name without meshreg having written it there (:func:`meshreg.ownership.not_ours`; the files named
    by the user, such as the matrix's ``D.npz``, are checked with ``own_only`` False).
    """
    if isinstance(path, str) and not path.strip():  # an unset shell variable, say: not the current directory
        raise InputError("the output directory is an empty name: give one with -o")
    out = Path(path)
    if out.exists() and not out.is_dir():
        raise InputError(f"{out} exists and is not a directory: give another -o")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise InputError(f"cannot make the output directory {out} ({reason(err)}): give another -o") from None
    given = {Path(p).resolve() for p in inputs}
    for name in names:
        target = out / name
        if target.resolve() in given:
            raise InputError(f"{target} is an input file: choose another output directory")
        if target.is_dir():
            raise InputError(f"{target} is a directory where an output file goes: move it or give another -o")
        for parent in target.relative_to(out).parents:
            if (out / parent).exists() and not (out / parent).is_dir():
                raise InputError(f"{out / parent} is a file where an output directory goes: move it or give another -o")
    listed = out / RECORD_FILE
    if listed.exists() and not listed.is_file():
        raise InputError(f"{listed} (where meshreg lists its outputs) is not a file: move it or give another -o")
    if own_only:
        refuse_foreign(out, names)
    try:
        probe = tempfile.NamedTemporaryFile(dir=out, prefix=".meshreg-probe-")
    except OSError as err:
        raise InputError(f"cannot write in {out} ({reason(err)}): give another -o") from None
    probe.close()
    return out


def remove_outputs(out: Path, names) -> None:
    """Remove the files ``names`` in ``out`` left by an earlier run, so that none of them can pass for this run's
    (and drop them from the record of meshreg's outputs)."""
    for name in names:
        target = Path(out) / name
        if target.is_file() or target.is_symlink():
            target.unlink()
    forget(out, names)


def write_atomic(path, write: Callable[[Path], object]) -> Path:
    """Write ``path`` by ``write(temporary)`` on a temporary name in the same directory, then rename it into place:
    ``path`` is either its old content or the whole new one, never a part. OSError becomes a RunError."""
    path = Path(path)
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.tmp{path.suffix}")  # the suffix tells savez/savefig the type
    try:
        write(tmp)
        os.replace(tmp, path)
    except OSError as err:
        raise RunError(f"cannot write {path} ({reason(err)})") from err
    finally:
        try:
            tmp.unlink(missing_ok=True)
        except OSError:  # a read-only file system, where the temporary could not be made either
            pass
    return path


def read_npz(path, what: str) -> dict:
    """Every array of the NumPy archive ``path`` (read whole, no pickles), or one InputError that names the file
    as not a meshreg ``what`` file: unreadable, cut, damaged, a single array (.npy) or not NumPy's at all."""
    try:
        data = np.load(path, allow_pickle=False)
    except OSError as err:
        raise InputError(f"{path}: cannot read it as a meshreg {what} file ({reason(err)})") from None
    except (ValueError, EOFError, zipfile.BadZipFile):
        raise InputError(f"{path}: not a meshreg {what} file (not a NumPy .npz archive, or a cut one)") from None
    if not isinstance(data, np.lib.npyio.NpzFile):
        raise InputError(f"{path}: not a meshreg {what} file (a single array, not an .npz archive)")
    try:
        with data:
            return {k: data[k] for k in data.files}
    except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile) as err:
        raise InputError(f"{path}: not a meshreg {what} file (a damaged archive: {type(err).__name__})") from None


@contextmanager
def staged(out: Path, names: list[str]) -> Iterator[Path]:
    """Yield a temporary directory inside ``out`` to write the files ``names`` into; when the block ends normally
    they move into ``out`` (``names[0]``, the result, last), else nothing moves. The temporary directory is removed
    either way. OSError (a full disk) becomes a RunError."""
    try:
        stage = Path(tempfile.mkdtemp(dir=out, prefix=".meshreg-"))
    except OSError as err:
        raise RunError(f"cannot write in {out} ({reason(err)})") from None
    moved = []
    try:
        yield stage
        record(out, names, written=stage)  # before the moves: a run stopped between two leaves only its own files
        for name in [*names[1:], names[0]]:
            (Path(out) / name).parent.mkdir(parents=True, exist_ok=True)
            os.replace(stage / name, Path(out) / name)
            moved.append(Path(out) / name)
    except BaseException as err:
        for path in moved:
            path.unlink(missing_ok=True)
        cause = err.__cause__ if isinstance(err, RunError) else err  # write_atomic's RunError names the stage
        if isinstance(cause, OSError):
            raise RunError(f"cannot write the outputs in {out} ({reason(cause)}): no output was written") from None
        raise
    finally:
        shutil.rmtree(stage, ignore_errors=True)
