"""Figures drawn beside the computation: on Linux with more than one core, :class:`Painter` forks a worker process as
soon as it is made; the worker imports matplotlib (about 0.4 s) and draws a tiny figure (:func:`meshreg.viz.warm_up`:
fonts, the PNG writer, the mesh renderer's numba kernel; about 0.5 s that the first real figure would otherwise pay)
while the caller registers, then draws the figures it is given while the caller writes its other files.
``meshreg register`` makes its painter after its own imports (numpy, numba, scipy) and numba's set-up, which the
worker inherits instead of doing them again beside the caller (forked at the start of the command, the worker made
the command 0.4 s slower in 3 of 4 runs on a busy 2-core machine).

With ``workers=2`` (the mesh command's two figures) the warmed worker forks a second one, which inherits matplotlib
as it is and costs no second import; each figure goes to the worker with fewer figures waiting, so that
``meshes.png`` need not wait for ``registration.png`` (the second worker is used once it has said it is ready).

The first worker is known to :mod:`meshreg.forked` as a helper that pauses for a child
(:func:`meshreg.forked.add_pausable`), so that the registration may still fork its own child (the maps to the square of
two large meshes, :class:`meshreg.forked.Forked`) while the worker warms up: the child takes the worker's core, and
the worker goes on when the child is done. The caller keeps no thread of its own for the workers (jobs go through
pipes that a thread of each worker empties), since a fork from a process with other threads is unsafe.

Elsewhere (or with one core, inside a daemonic pool worker, or while other Python threads run, where a fork is
unsafe) the figures are drawn in the calling process by :meth:`Painter.finish`. Either way every figure is written
when :meth:`Painter.finish` returns, and an error drawing one is raised there; a figure a worker could not answer
for (it died) is drawn in the caller. When the block of a painter ends by an exception the first worker is stopped
at once (SIGTERM), not left to finish its start-up or a figure, and the second (its child) dies with it. Workers die
with the process that forked them (PR_SET_PDEATHSIG), so none is left behind, running or paused.
"""

from __future__ import annotations

import gc
import multiprocessing
import os
import queue
import threading

from .forked import add_pausable, child_started, discard_pausable, frozen_heap, may_fork


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


def _serve(conn, jobs: queue.SimpleQueue) -> None:
    """Draw each job of ``jobs`` until None and answer None or the error on ``conn``."""
    while (job := jobs.get()) is not None:
        try:
            _draw(*job)
            conn.send(None)
        except Exception as err:  # noqa: BLE001 - raised again in the caller by finish()
            try:
                conn.send(err)
            except Exception:  # noqa: BLE001 - an error that cannot be pickled
                conn.send(RuntimeError(f"{job[0]}: {err!r}"))


def _listen(conn) -> queue.SimpleQueue:
    """The jobs arriving on ``conn``, moved to a queue by a thread of this process (:func:`_receive`)."""
    jobs = queue.SimpleQueue()
    threading.Thread(target=_receive, args=(conn, jobs), daemon=True).start()
    return jobs


def _fork_second(first, second) -> None:
    """In the warmed first worker: fork the second worker, which dies with the first, says it is ready and serves
    ``second`` (and never holds the first's pipe, so that the caller still sees the first die)."""
    me = os.getpid()
    gc.freeze()  # matplotlib's objects too (the first worker's own: see meshreg.forked.frozen_heap)
    if os.fork() == 0:
        try:
            child_started(me)
            first.close()
            second.send("ready")
            _serve(second, _listen(second))
        finally:
            os._exit(0)
    second.close()


def _work(conn, second, callers: list, caller: int) -> None:
    """The first worker: close the caller's ends of the pipes (``callers``: a worker holding one would never see
    the caller close it), leave Ctrl-C and SIGTERM to the caller (it stops the worker), import the figures and draw
    a tiny one (:func:`meshreg.viz.warm_up`), fork the second worker when there is to be one, then draw each job
    and answer None or the error."""
    for end in callers:
        end.close()
    child_started(caller)
    jobs = _listen(conn)
    from . import viz

    viz.warm_up()
    if second is not None:
        _fork_second(conn, second)
    _serve(conn, jobs)


class Painter:
    """Draws functions of :mod:`meshreg.viz` by name, in forked worker processes (``workers``, 1 or 2) when it is
    safe (see the module), else (``workers`` 0) in the caller at :meth:`finish`.

    Use as a context manager: leaving it stops the workers (a figure still being drawn is abandoned)."""

    def __init__(self, workers: int = 1):
        self._queued: list[tuple] = []
        self._worker = None
        self._conns, self._sent, self._ready = [], [], [True, False]
        if workers > 0 and may_fork():
            context = multiprocessing.get_context("fork")
            pipes = [context.Pipe() for _ in range(min(workers, 2))]
            ends = ([theirs for _, theirs in pipes] + [None])[:2]
            self._worker = context.Process(
                target=_work, args=(*ends, [ours for ours, _ in pipes], os.getpid()), daemon=True
            )
            with frozen_heap():
                self._worker.start()
            for ours, theirs in pipes:
                theirs.close()
                self._conns.append(ours)
                self._sent.append([])
            add_pausable(self._worker)

    @property
    def forked(self) -> bool:
        """Whether the figures are drawn in worker processes."""
        return self._worker is not None

    def _free_worker(self) -> int:
        """The ready worker with the fewest figures waiting (the first on a tie)."""
        if not self._ready[1] and len(self._conns) > 1:
            try:
                self._ready[1] = self._conns[1].poll(0) and self._conns[1].recv() == "ready"
            except (EOFError, OSError):  # the first worker died before it forked the second
                self._ready[1] = False
        ready = [k for k in range(len(self._conns)) if self._ready[k]]
        return min(ready, key=lambda k: len(self._sent[k]))

    def draw(self, name: str, *args, **kwargs) -> None:
        """Queue ``meshreg.viz.<name>(*args, **kwargs)`` (for a worker, or for :meth:`finish` without one)."""
        job = (name, args, kwargs)
        if self._worker is not None:
            k = self._free_worker()
            try:
                self._conns[k].send(job)
                self._sent[k].append(job)
                return
            except OSError:  # the worker is gone: the caller draws it
                pass
        self._queued.append(job)

    def finish(self) -> None:
        """Draw (or wait for) every queued figure, raising the first error."""
        queued, errors = self._queued, []
        self._queued = []
        for conn, sent in zip(self._conns, self._sent, strict=True):
            for k in range(len(sent)):
                try:
                    answer = conn.recv()
                except (EOFError, OSError):  # the worker died: the caller draws what it did not answer for
                    queued += sent[k:]
                    break
                if answer is not None:
                    errors.append(answer)
            sent.clear()
        for job in queued:
            _draw(*job)
        if errors:
            raise errors[0]

    def close(self) -> None:
        """Stop the first worker (SIGTERM) and close the pipes (the second worker then ends): after :meth:`finish`
        they have nothing left to do; before, their figures are abandoned."""
        if self._worker is None:
            return
        discard_pausable(self._worker)  # continued first: a stopped process does not die of SIGTERM
        self._worker.terminate()
        self._worker.join()
        for conn in self._conns:
            conn.close()
        self._worker, self._conns = None, []

    def __enter__(self) -> Painter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
