"""Figures drawn beside the computation: on Linux with more than one core, :class:`Painter` forks its worker
process(es) as soon as it is made; a worker imports matplotlib (about 0.4 s) and draws a tiny figure
(:func:`meshreg.viz.warm_up`: fonts, the PNG writer, the mesh renderer's numba kernel; about 0.5 s that the first
real figure would otherwise pay) while the caller registers, then draws the figures it is given while the caller
writes its other files. ``meshreg register`` makes its painter after its own imports (numpy, numba, scipy) and
numba's set-up, which the worker inherits instead of doing them again beside the caller (forked at the start of the
command, the worker made the command 0.4 s slower in 3 of 4 runs on a busy 2-core machine). One worker draws every
figure of a registration: it then spends the CPU time the caller would have spent, on the other core (a second
worker would import matplotlib twice and, on a loaded 2-core machine, slow the caller more than it saves). Elsewhere
(or with one core) the figures are drawn in the calling process by :meth:`Painter.finish` (also inside a daemonic
pool worker or while other Python threads run, where a fork is unsafe). Either way every figure is written when
:meth:`Painter.finish` returns, and an error drawing one is raised there; when the block of a painter ends by an
exception its workers are stopped at once (SIGTERM), not left to finish their start-up or a figure.
"""

from __future__ import annotations

import multiprocessing
import os
import signal
import sys
import threading
from concurrent.futures import Future, ProcessPoolExecutor


def _may_fork() -> bool:
    """Whether forking a worker is safe and useful here: Linux, more than one core, not inside a daemonic process
    (a pool worker may not have children) and no other Python thread running (a fork copies locks other threads
    may hold, e.g. in a Dask client or a GUI)."""
    return (
        sys.platform.startswith("linux")
        and (os.cpu_count() or 1) > 1
        and not multiprocessing.current_process().daemon
        and threading.active_count() == 1
    )


def _start_worker() -> None:
    """In a worker: leave Ctrl-C and SIGTERM to the caller (it stops the workers), then import the figures and draw
    a tiny one (:func:`meshreg.viz.warm_up`)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    from . import viz

    viz.warm_up()


def _draw(name: str, args: tuple, kwargs: dict):
    from . import viz

    return getattr(viz, name)(*args, **kwargs)


class Painter:
    """Draws functions of :mod:`meshreg.viz` by name, in up to ``workers`` forked processes (see the module).

    Use as a context manager: leaving it stops the workers (a figure still being drawn is abandoned)."""

    def __init__(self, workers: int):
        self._pool = None
        self._jobs: list[Future] = []
        self._queued: list[tuple] = []
        self._workers: list = []
        if workers > 0 and _may_fork():
            context = multiprocessing.get_context("fork")
            before = set(multiprocessing.active_children())
            self._pool = ProcessPoolExecutor(workers, mp_context=context, initializer=_start_worker)
            self._pool.submit(int)  # the workers start now (forked ones all at once) and import matplotlib
            self._workers = [p for p in multiprocessing.active_children() if p not in before]

    def draw(self, name: str, *args, **kwargs) -> None:
        """Queue ``meshreg.viz.<name>(*args, **kwargs)`` (for a worker, or for :meth:`finish` without them)."""
        if self._pool is None:
            self._queued.append((name, args, kwargs))
        else:
            self._jobs.append(self._pool.submit(_draw, name, args, kwargs))

    def finish(self) -> None:
        """Draw (or wait for) every queued figure, raising the first error."""
        jobs, queued, self._jobs, self._queued = self._jobs, self._queued, [], []
        for job in jobs:
            job.result()
        for name, args, kwargs in queued:
            _draw(name, args, kwargs)

    def __enter__(self) -> Painter:
        return self

    def __exit__(self, *exc) -> None:
        if self._pool is None:
            return
        if exc[0] is not None:  # nothing more will be drawn: stop the workers now, even in their start-up
            for worker in self._workers:
                worker.terminate()
        self._pool.shutdown(wait=exc[0] is None, cancel_futures=True)
