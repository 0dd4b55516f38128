"""Figures drawn beside the computation: on Linux with more than one core, :class:`Painter` forks its worker
process(es) as soon as it is made; a worker imports matplotlib (about 0.4 s) while the caller registers, then draws
the figures it is given while the caller writes its other files. One worker draws every figure of a registration:
it then spends the CPU time the caller would have spent, on the other core (a second worker would import matplotlib
twice and, on a loaded 2-core machine, slow the caller more than it saves). Elsewhere (or with one core) the
figures are drawn in the calling process by :meth:`Painter.finish` (also inside a daemonic pool worker or while other
Python threads run, where a fork is unsafe). Either way every figure is written when
:meth:`Painter.finish` returns, and an error drawing one is raised there.
"""

from __future__ import annotations

import multiprocessing
from concurrent.futures import Future, ProcessPoolExecutor

from .forked import leave_signals_to_caller, may_fork


def _start_worker() -> None:
    """In a worker: leave Ctrl-C and SIGTERM to the caller (it stops the workers), then import the figures."""
    leave_signals_to_caller()
    from . import viz  # noqa: F401


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
        if workers > 0 and may_fork():
            context = multiprocessing.get_context("fork")
            self._pool = ProcessPoolExecutor(workers, mp_context=context, initializer=_start_worker)
            self._pool.submit(int)  # the workers start now (forked ones all at once) and import matplotlib

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
        if self._pool is not None:
            self._pool.shutdown(wait=exc[0] is None, cancel_futures=True)
