"""Figures drawn beside the computation: on Linux with more than one core, :class:`Painter` forks one worker process
as soon as it is made; the worker imports matplotlib (about 0.4 s) and draws a tiny figure
(:func:`meshreg.viz.warm_up`: fonts, the PNG writer, the mesh renderer's numba kernel; about 0.5 s that the first
real figure would otherwise pay) while the caller registers, then draws the figures it is given while the caller
writes its other files. ``meshreg register`` makes its painter after its own imports (numpy, numba, scipy) and
numba's set-up, which the worker inherits instead of doing them again beside the caller (forked at the start of the
command, the worker made the command 0.4 s slower in 3 of 4 runs on a busy 2-core machine). One worker draws every
figure of a registration: it then spends the CPU time the caller would have spent, on the other core.

The worker is known to :mod:`meshreg.forked` as a helper that pauses for a child (:data:`meshreg.forked.pausable`),
so that the registration may still fork its own child (the maps to the square of two large meshes,
:class:`meshreg.forked.Forked`) while the worker warms up: the child takes the worker's core, and the worker goes on
when the child is done. The caller keeps no thread of its own for the worker (jobs go through a pipe that a
thread of the worker empties), since a fork from a process with other threads is unsafe.

Elsewhere (or with one core, inside a daemonic pool worker, or while other Python threads run, where a fork is
unsafe) the figures are drawn in the calling process by :meth:`Painter.finish`. Either way every figure is written
when :meth:`Painter.finish` returns, and an error drawing one is raised there; a figure the worker could not answer
for (it died) is drawn in the caller. When the block of a painter ends by an exception its worker is stopped at
once (SIGTERM), not left to finish its start-up or a figure.
"""

from __future__ import annotations

import multiprocessing
import queue
import threading

from .forked import leave_signals_to_caller, may_fork, pausable


def _draw(name: str, args: tuple, kwargs: dict):
    from . import viz

    return getattr(viz, name)(*args, **kwargs)


def _receive(conn, jobs: queue.SimpleQueue) -> None:
    """In the worker (a thread): move every job from the pipe to ``jobs`` at once, so that the caller's sends never
    wait for a figure being drawn; None (the pipe closed) ends the worker."""
    while True:
        try:
            jobs.put(conn.recv())
        except (EOFError, OSError):
            jobs.put(None)
            return


def _work(conn) -> None:
    """The worker: leave Ctrl-C and SIGTERM to the caller (it stops the worker), import the figures and draw a tiny
    one (:func:`meshreg.viz.warm_up`), then draw each job and answer None or the error."""
    leave_signals_to_caller()
    jobs = queue.SimpleQueue()
    threading.Thread(target=_receive, args=(conn, jobs), daemon=True).start()
    from . import viz

    viz.warm_up()
    while (job := jobs.get()) is not None:
        try:
            _draw(*job)
            conn.send(None)
        except Exception as err:  # noqa: BLE001 - raised again in the caller by finish()
            try:
                conn.send(err)
            except Exception:  # noqa: BLE001 - an error that cannot be pickled
                conn.send(RuntimeError(f"{job[0]}: {err!r}"))


class Painter:
    """Draws functions of :mod:`meshreg.viz` by name, in a forked worker process when ``fork`` and it is safe (see
    the module), else in the caller at :meth:`finish`.

    Use as a context manager: leaving it stops the worker (a figure still being drawn is abandoned)."""

    def __init__(self, fork: bool = True):
        self._sent: list[tuple] = []
        self._queued: list[tuple] = []
        self._worker = self._conn = None
        if fork and may_fork():
            context = multiprocessing.get_context("fork")
            self._conn, theirs = context.Pipe()
            self._worker = context.Process(target=_work, args=(theirs,), daemon=True)
            self._worker.start()
            theirs.close()
            pausable.add(self._worker)

    @property
    def forked(self) -> bool:
        """Whether the figures are drawn in a worker process."""
        return self._worker is not None

    def draw(self, name: str, *args, **kwargs) -> None:
        """Queue ``meshreg.viz.<name>(*args, **kwargs)`` (for the worker, or for :meth:`finish` without it)."""
        job = (name, args, kwargs)
        if self._worker is not None:
            try:
                self._conn.send(job)
                self._sent.append(job)
                return
            except OSError:  # the worker is gone: the caller draws it
                pass
        self._queued.append(job)

    def finish(self) -> None:
        """Draw (or wait for) every queued figure, raising the first error."""
        sent, queued, self._sent, self._queued = self._sent, self._queued, [], []
        errors = []
        for k in range(len(sent)):
            try:
                answer = self._conn.recv()
            except (EOFError, OSError):  # the worker died: the caller draws what it did not answer for
                queued[:0] = sent[k:]
                break
            if answer is not None:
                errors.append(answer)
        for job in queued:
            _draw(*job)
        if errors:
            raise errors[0]

    def close(self) -> None:
        """Stop the worker (SIGTERM): after :meth:`finish` it has nothing left to do; before, its figures are
        abandoned."""
        if self._worker is None:
            return
        pausable.discard(self._worker)
        self._worker.terminate()
        self._worker.join()
        self._conn.close()
        self._worker = self._conn = None

    def __enter__(self) -> Painter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
