"""Memory pages of the mesh front end's large arrays: small (4 kB) ones, not NumPy's transparent huge pages.

NumPy advises Linux to back every array of 4 MB or more with transparent huge pages (2 MB, ``madvise``), which saves
page faults and TLB misses where huge pages come cheap. On the 2-core virtual machine where the benchmarks run (AMD
EPYC, Linux 6.18, transparent huge pages on ``madvise``), a fresh process's first writes to huge pages cost about
3 ms per MB: 300 MB took 0.52-0.93 s, against 0.15-0.18 s with NumPy's advice off (``NUMPY_MADVISE_HUGEPAGE=0``),
each a fresh process started 3 s after the last. The front end of a 1M-triangle mesh writes about 570 MB of new
arrays (half of them the LU's factors): in fresh processes alternating with the code before, 2.35-3.39 s (median
2.56) with these blocks against 2.74-3.19 s (median 3.08); the 100k-triangle front end and the two-mesh command were
the same either way (docs/benchmarks.md, nineteenth session).

:func:`small_pages` turns NumPy's advice off (for meshes of SMALL_PAGES_MIN vertices or more) while a block runs
(the whole process's new arrays, any thread) and back to what it was when the last block of any thread ends. With
NumPy builds that lack the switch, it does nothing. A child forked while blocks run keeps those of the thread that
forked it (the only thread it has), and without any has NumPy's setting as it was before the blocks.
"""

from __future__ import annotations

import importlib
import os
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager

HUGE_PAGES = False  # True: leave NumPy's huge-page advice as it is in the front end (to measure the difference)
# vertices of a mesh from which its front end and registration run in small pages: the 1M-triangle benchmark mesh
# (500k vertices) gained 0.5 s in a fresh process, the 100k one (50k vertices) nothing, and a 100k pair in a warm
# process lost 0.05 s of 1.5 (mean of 16 runs each way)
SMALL_PAGES_MIN = 100_000


def _switch() -> Callable[[bool], bool] | None:
    """NumPy's switch of its huge-page advice (returns the previous setting), or None."""
    for name in ("numpy._core.multiarray", "numpy.core.multiarray"):
        try:
            return getattr(importlib.import_module(name), "_set_madvise_hugepage", None)
        except ImportError:
            continue
    return None


class _Blocks:
    """The :func:`small_pages` blocks running in each thread, and NumPy's setting before the first."""

    def __init__(self):
        self.lock = threading.Lock()
        self.by_thread: dict[int, int] = {}
        self.saved = True

    @property
    def running(self) -> int:
        return sum(self.by_thread.values())

    def enter(self, switch: Callable[[bool], bool]) -> None:
        me = threading.get_ident()
        with self.lock:
            if not self.by_thread:
                self.saved = switch(False)
            self.by_thread[me] = self.by_thread.get(me, 0) + 1

    def leave(self, switch: Callable[[bool], bool]) -> None:
        me = threading.get_ident()
        with self.lock:
            self.by_thread[me] -= 1
            if not self.by_thread[me]:
                del self.by_thread[me]
            if not self.by_thread:
                switch(self.saved)

    def forked(self) -> None:
        """In a forked child, which has only the thread that forked: the other threads' blocks are gone, and
        without blocks of its own NumPy's setting is the one from before the blocks."""
        self.lock = threading.Lock()
        me = threading.get_ident()
        self.by_thread = {me: self.by_thread[me]} if me in self.by_thread else {}
        switch = _switch()
        if not self.by_thread and switch is not None:
            switch(self.saved)


_BLOCKS = _Blocks()
if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_BLOCKS.forked)


@contextmanager
def small_pages(vertices: int | None = None) -> Iterator[None]:
    """Within the block, NumPy does not advise huge pages for new arrays (see the module's notes); blocks may nest
    and run in several threads at once.

    Parameters
    ----------
    vertices : int, optional
        Of the mesh the block works on: below SMALL_PAGES_MIN the block changes nothing. None: always.

    Examples
    --------
    >>> import numpy as np
    >>> with small_pages():
    ...     factors = np.empty(10**6)
    """
    small = vertices is None or vertices >= SMALL_PAGES_MIN
    switch = None if HUGE_PAGES or not small else _switch()
    if switch is None:
        yield
        return
    entered = False
    try:
        _BLOCKS.enter(switch)
        entered = True
        yield
    finally:
        if entered:
            _BLOCKS.leave(switch)
