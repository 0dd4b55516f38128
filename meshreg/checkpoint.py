"""The checkpoint of a collection run: an append-only JSON-lines file of finished pairs, validated when read.

Used by distance matrices (:mod:`meshreg.batch`) and atlases (:mod:`meshreg.shape_atlas`): every finished pair is
appended (flushed and fsynced) as it completes, so an interrupted run loses at most the pairs in flight.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
from pathlib import Path

import numpy as np

from .errors import InputError, RunError
from .files import reason

CHECKPOINT_SUFFIX = ".checkpoint.jsonl"


class Checkpoint:
    """Append-only JSON-lines record of finished pairs.

    Line 1 is the header ``{"key": ...}``, a digest of the run's parameters; every other line records one pair:
    ``{"i", "j", "first", "second", "seconds", ...}`` with the task's numbers (a distance matrix's: ``"energy"``,
    ``"rotation"`` and for a round-boundary second surface ``"placement"``), or ``{"i", "j", "first", "second",
    "error"}``. ``first`` and ``second`` are digests of the two surfaces: a record is reused only for the same two
    surfaces, so that replacing one file of a collection redoes only its pairs.

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

        def foreign(why: str) -> InputError:  # no checkpoint at all: maybe the user's file (an input given as output)
            return InputError(
                f"{self.path} is not a meshreg checkpoint ({why}): write the output elsewhere (only if it is a damaged "
                f"checkpoint of yours, {start_over})"
            )

        try:
            data = self.path.read_bytes()
        except OSError as err:
            raise InputError(f"cannot read the checkpoint {self.path} ({reason(err)}): {start_over}") from None
        if b"\n" not in data:
            if _cut_header(data):
                return 0  # empty, or killed while writing its header
            raise foreign("it holds no header")
        keep = data.rindex(b"\n") + 1
        try:
            lines = data[:keep].decode("utf-8").split("\n")[:-1]
        except UnicodeDecodeError as err:
            line = data[: err.start].count(b"\n") + 1
            if line == 1:
                raise foreign("line 1 is not UTF-8 text") from None
            raise InputError(
                f"{self.path} line {line} is not UTF-8 text (a damaged checkpoint): delete that line to keep the other "
                f"finished pairs, or {start_over}"
            ) from None
        header = _json_or_none(lines[0])
        if not isinstance(header, dict) or set(header) != {"key"}:
            raise foreign("line 1 is not its header")
        if header["key"] != self.key:
            raise InputError(
                f"{self.path} is a checkpoint of a run with other inputs or parameters: rerun with those, "
                f"{start_over}, or write the output elsewhere"
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


def _cut_header(data: bytes) -> bool:
    """Whether ``data`` (a file without a newline) is empty or the start of a checkpoint's header line
    ``{"key": "<hex digest>"}``: what a run killed before its header was written leaves. Anything else is someone's
    file, not to be truncated. (The keys of meshreg's runs are sha256 hex digests; a key of other characters would
    have its cut header refused, not lost.)"""
    opening = b'{"key": "'
    return (
        opening.startswith(data[: len(opening)])
        and re.fullmatch(rb'[0-9a-f]*("\}?)?', data[len(opening) :]) is not None
    )


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
    if not _number(record.get("seconds")):
        return "holds no time in seconds"
    if "energy" not in record:
        return None  # a task's own record (corner-placement rankings carry only their choice)
    rotation = np.asarray(record.get("rotation"), dtype=object)
    if not _number(record.get("energy")) or record["energy"] < 0:
        return f"holds no energy E >= 0 (got {record.get('energy')!r})"
    if rotation.shape != (3, 3) or not all(_number(v) for v in rotation.ravel()):
        return "holds no 3 x 3 rotation"
    return None


def _digest(*parts) -> str:
    digest = hashlib.sha256()
    for part in parts:
        digest.update(part if isinstance(part, bytes) else np.ascontiguousarray(part).tobytes())
        digest.update(b"|")
    return digest.hexdigest()
