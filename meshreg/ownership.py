"""Which files in an output directory meshreg wrote: only those are ever replaced or removed by a later run.

Each directory meshreg writes outputs into holds a record, ``.meshreg-outputs``: one line per file it wrote there,
``name<TAB>size mtime_ns<TAB>blake2b`` (or ``pending`` while the file is being written). A file with an output's name
is meshreg's when its entry is pending (a run stopped while writing it), its size and modification time are those
recorded, or, when they are not (the directory was copied, or the file touched), its content hash is. Anything else
with an output's name is the user's. The record is read and rewritten under an exclusive lock on the directory, so
that two runs writing into one directory keep each other's entries.
"""

from __future__ import annotations

import fcntl
import hashlib
import os
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path

from .errors import InputError

RECORD_FILE = ".meshreg-outputs"
PENDING = "pending"  # the entry of a file being written: meshreg's even if the run stopped before recording it
HASH_BYTES = 16  # blake2b digest size of a recorded file's content
CHUNK = 1 << 20  # bytes read at a time when hashing


def _key(name) -> str:
    return Path(name).as_posix()


def _stamp(path: Path) -> str:
    """A file's size and modification time (ns)."""
    info = path.lstat()
    return f"{info.st_size} {info.st_mtime_ns}"


def _digest(path: Path) -> str:
    """The blake2b hash of a file's content (hex)."""
    hasher = hashlib.blake2b(digest_size=HASH_BYTES)
    with open(path, "rb") as file:
        while chunk := file.read(CHUNK):
            hasher.update(chunk)
    return hasher.hexdigest()


@contextmanager
def _locked(out: Path) -> Iterator[None]:
    """An exclusive lock on the directory ``out`` (flock on its descriptor) for a read-modify-write of the record."""
    fd = os.open(out, os.O_RDONLY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)


def recorded(out: str | Path) -> dict[str, tuple[str, ...]]:
    """The record of the directory ``out``.

    Returns
    -------
    dict
        Relative path (with /) -> ``("pending",)`` or ``(stamp, digest)``; empty without a record.
    """
    try:
        lines = (Path(out) / RECORD_FILE).read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError):
        return {}
    return {parts[0]: tuple(parts[1:]) for parts in (line.split("\t") for line in lines) if len(parts) >= 2}


def _update(out: Path, change) -> None:
    """Rewrite the record of ``out`` (removed when empty) as ``change(entries)`` returns it, under the lock."""
    path = out / RECORD_FILE
    with _locked(out):
        entries = change(recorded(out))
        if not entries:
            path.unlink(missing_ok=True)
            return
        text = "".join("\t".join((name, *entry)) + "\n" for name, entry in sorted(entries.items()))
        tmp = path.with_name(f"{RECORD_FILE}.{os.getpid()}.tmp")
        tmp.write_text(text, encoding="utf-8")
        os.replace(tmp, path)


def claim(out: str | Path, names: Iterable) -> None:
    """Enter the files ``names`` (relative to ``out``) as being written by meshreg, before writing them."""
    _update(Path(out), lambda entries: {**entries, **{_key(name): (PENDING,) for name in names}})


def record(out: str | Path, names: Iterable, written: str | Path | None = None) -> None:
    """Enter the files ``names`` (relative to ``out``) as written by meshreg: their size, modification time and
    content hash, read from ``written`` (a directory holding them under the same names, about to be moved into
    ``out``: a rename keeps all three) or from ``out`` itself."""
    where = Path(out if written is None else written)
    stamps = {_key(name): (_stamp(where / name), _digest(where / name)) for name in names}
    _update(Path(out), lambda entries: {**entries, **stamps})


def forget(out: str | Path, names: Iterable) -> None:
    """Drop the files ``names`` from the record of ``out`` (they were removed)."""
    keys = {_key(name) for name in names}
    if keys & set(recorded(out)):
        _update(Path(out), lambda entries: {k: v for k, v in entries.items() if k not in keys})


def not_ours(out: str | Path, names: Iterable) -> list[str]:
    """The ``names`` (relative to ``out``) that exist there as files meshreg did not write (see the module).

    Returns
    -------
    list of str
        Those names, in the order given.
    """
    entries, foreign = recorded(out), []
    for name in names:
        path = Path(out) / name
        if not (path.is_file() or path.is_symlink()):
            continue
        entry = entries.get(_key(name))
        if entry == (PENDING,):
            continue
        ours = entry is not None and not path.is_symlink() and (entry[0] == _stamp(path) or entry[-1] == _digest(path))
        if not ours:
            foreign.append(str(name))
    return foreign


def refuse_foreign(out: str | Path, names: Iterable, what_to_do: str = "move or delete it, or give another -o") -> None:
    """InputError (:func:`foreign_message`) when one of ``names`` (relative to ``out``) exists there as a file meshreg
    did not write (:func:`not_ours`)."""
    foreign = not_ours(out, names)
    if foreign:
        raise InputError(foreign_message(out, foreign[0], what_to_do))


@contextmanager
def writing(out: str | Path, names: Iterable) -> Iterator[None]:
    """Claim the files ``names`` (relative to ``out``) before the block writes them in place, and record them after:
    a run stopped in between leaves files the next run takes as its own."""
    names = list(names)
    claim(out, names)
    yield
    record(out, names)


def foreign_message(out: str | Path, name: str, what_to_do: str = "move or delete it, or give another -o") -> str:
    """The error for a file with an output's name that meshreg did not write."""
    return (
        f"{Path(out) / name} is not on meshreg's list of its outputs ({Path(out) / RECORD_FILE}): it is your file, or "
        f"an output of a meshreg before 2026-12-01; {what_to_do}"
    )
