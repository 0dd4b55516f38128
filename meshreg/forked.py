"""One function computed in a forked child process while the caller goes on with other work.

A fork sees the caller's data as it is (nothing is pickled on the way in); the answer comes back pickled through a
pipe. :class:`Forked` only forks where that is safe and useful (:func:`can_fork`), and falls back to calling the
function in the caller whenever the child gives no answer (it could not fork, the child died or raised, or its
answer could not be pickled): the answer, and any error, are then exactly those of a serial run.
"""

from __future__ import annotations

import atexit
import ctypes
import gc
import multiprocessing
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any


def may_fork() -> bool:
    """Whether forking a worker is safe and useful here: Linux, more than one core, not inside a daemonic process
    (a pool worker may not have children), no other Python thread running (a fork copies locks other threads
    may hold, e.g. in a Dask client or a GUI), and SIGCHLD not ignored (the kernel then reaps children itself, so a
    child's end cannot be waited for: multiprocessing would take it for still running)."""
    return (
        sys.platform.startswith("linux")
        and (os.cpu_count() or 1) > 1
        and not multiprocessing.current_process().daemon
        and threading.active_count() == 1
        and not sigchld_ignored()
    )


def sigchld_ignored(status: str = "/proc/self/status") -> bool:
    """Whether SIGCHLD is ignored in this process: the SigIgn mask of ``status`` (sees an ignore set from C too, by
    an embedding host or an extension), else what Python set."""
    try:
        with open(status) as file:
            for line in file:
                if line.startswith("SigIgn:"):
                    return bool(int(line.split()[1], 16) >> (signal.SIGCHLD - 1) & 1)
    except (OSError, ValueError, IndexError):
        pass
    return signal.getsignal(signal.SIGCHLD) == signal.SIG_IGN


# this process's own helper processes (multiprocessing.Process: the figure worker of :mod:`meshreg.painter`), each
# with a pidfd to signal it by (None where the system has none): they pause (SIGSTOP) while a :class:`Forked` child
# runs and go on (SIGCONT) when it is done, and :func:`idle_core` does not count them as busy, since they give their
# core to the child. A forked child starts with none (os.register_at_fork below).
_pausable: dict = {}
_paused = 0  # Forked children running now: the helpers are paused while there is at least one
_continued_at_exit = False  # whether the exit hook that continues the helpers is registered


def _forget_pausable() -> None:
    """Drop every pausable helper and the count of running children (in a forked child: neither is its own)."""
    global _paused
    for fd in _pausable.values():
        if fd is not None:
            os.close(fd)
    _pausable.clear()
    _paused = 0


def add_pausable(process) -> None:
    """Pause ``process`` (a started child of this process) while a :class:`Forked` child runs; it is continued when
    this process exits, so that no stopped helper is left behind (a stopped process cannot die of SIGTERM)."""
    try:
        fd = os.pidfd_open(process.pid)
    except (AttributeError, OSError):
        fd = None
    global _continued_at_exit
    if not _continued_at_exit:  # registered after multiprocessing's exit hook (a process was started): runs first
        atexit.register(_signal_pausable, signal.SIGCONT)
        _continued_at_exit = True
    _pausable[process] = fd
    if _paused:
        _signal_pausable(signal.SIGSTOP)


def discard_pausable(process) -> None:
    """Stop treating ``process`` as pausable, continuing it first if it is paused."""
    if process not in _pausable:
        return
    fd = _pausable.pop(process)
    _send(process, fd, signal.SIGCONT)
    if fd is not None:
        os.close(fd)


def _send(process, fd, signum: int) -> None:
    """``signum`` to a helper: through its pidfd (exact even after it died), else by pid while it is alive."""
    try:
        if fd is not None:
            signal.pidfd_send_signal(fd, signum)
        elif process.is_alive():
            os.kill(process.pid, signum)
    except (OSError, ValueError, AssertionError):  # gone, closed, or not ours
        pass


def _signal_pausable(signum: int) -> None:
    """Send ``signum`` to every pausable helper."""
    for process, fd in list(_pausable.items()):
        _send(process, fd, signum)


def _pause(step: int) -> None:
    """One more (step 1) or one fewer (-1) Forked child running: pause the helpers at the first, continue them
    after the last."""
    global _paused
    _paused = max(_paused + step, 0)
    if _paused == (1 if step > 0 else 0):
        _signal_pausable(signal.SIGSTOP if step > 0 else signal.SIGCONT)


os.register_at_fork(after_in_child=_forget_pausable)


def _task_stats(pid, proc: str = "/proc") -> Iterator[list[str]]:
    """The fields of ``proc``/<pid>/task/<tid>/stat after the command name, one list per thread of process ``pid``:
    [0] the state (R: runnable), [16] the nice value. OSError when the process is gone."""
    for task in os.listdir(f"{proc}/{pid}/task"):
        with open(f"{proc}/{pid}/task/{task}/stat") as file:
            yield file.read().rsplit(")", 1)[1].split()


def _running_threads(process) -> int:
    """How many threads of a live helper process are runnable now (state R in /proc/<pid>/task/*/stat)."""
    count = 0
    try:
        if not process.is_alive():
            return 0
        for fields in _task_stats(process.pid):
            count += fields[0] == "R"
    except (OSError, IndexError, ValueError, AssertionError):
        pass
    return count


# idle_core reads the runnable tasks this many times, this many seconds apart, and takes the fewest: a task that is
# runnable for an instant (a kernel worker, a thread handing over the GIL) is not a busy core; one read decided
# wrongly in about a third of the commands on an idle 2-core machine
LOAD_READS = 3
LOAD_GAP = 0.002
# runnable tasks this much nicer than this process are background work (CFS weights: nice +10 gets 110 against
# 1024, under a tenth of a core beside us; +19 gets 15)
BACKGROUND_NICE = 10


def _busy_tasks(loadavg: str) -> int:
    """Runnable tasks now (the fourth field of ``loadavg``), less the runnable threads of pausable helpers."""
    with open(loadavg) as file:
        running = int(file.read().split()[3].split("/")[0])
    return running - sum(map(_running_threads, list(_pausable)))


def _background_tasks(proc: str) -> int:
    """Runnable threads (state R in ``proc``/<pid>/task/<tid>/stat) of processes at least :data:`BACKGROUND_NICE`
    nicer than this one: beside this process Linux's scheduler gives each a tenth of a core or less, so they do not
    keep a forked child from a core. 0 where ``proc`` cannot be read."""
    floor = os.getpriority(os.PRIO_PROCESS, 0) + BACKGROUND_NICE
    count = 0
    try:
        pids = [name for name in os.listdir(proc) if name.isdigit()]
    except OSError:
        return 0
    for pid in pids:
        try:
            for fields in _task_stats(pid, proc):
                count += fields[0] == "R" and int(fields[16]) >= floor
        except (OSError, IndexError, ValueError):
            continue  # gone meanwhile, or not readable
    return count


def idle_core(loadavg: str = "/proc/loadavg", proc: str = "/proc") -> bool:
    """Whether a core is idle now: fewer runnable tasks than cores (the fourth field of ``loadavg``, which counts
    this process too; the fewest of LOAD_READS reads; True where it cannot be read), not counting this process's own
    helpers that pause for a child (:func:`add_pausable`) nor, when that count says busy, background work at least
    :data:`BACKGROUND_NICE` nicer than this process (:func:`_background_tasks`). When every core is busy (other jobs
    on a shared machine, a pool of workers) a forked child only takes time from its caller, and its copy-on-write
    page faults cost more CPU than the serial run: on the project's 2-core machine with one other busy process, two
    100k-triangle meshes took 1.76 s with the child against 1.62 s without (medians of 4, alternating)."""
    fewest = None
    cores = os.cpu_count() or 1
    try:
        for read in range(LOAD_READS):
            if read:
                time.sleep(LOAD_GAP)
            busy = _busy_tasks(loadavg)
            fewest = busy if fewest is None else min(fewest, busy)
            if fewest < cores:
                return True
    except (OSError, ValueError, IndexError):
        return True
    return fewest - _background_tasks(proc) < cores


def can_fork() -> bool:
    """Whether :class:`Forked` would fork now (:func:`may_fork` and :func:`idle_core`)."""
    return may_fork() and idle_core()


PR_SET_PDEATHSIG = 1  # prctl option: the signal a process gets when its parent dies (linux/prctl.h)


def leave_signals_to_caller(caller: int) -> None:
    """In a child forked by process ``caller``: ignore Ctrl-C, die on SIGTERM (the caller stops its children) and
    die with the caller (Linux's PR_SET_PDEATHSIG: a helper the caller paused and then lost, killed say, is not left
    stopped)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    try:
        ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL)
    except (OSError, AttributeError):
        return
    if os.getppid() != caller:  # the caller died before the request
        os._exit(1)


def child_started(caller: int) -> None:
    """What every child forked by process ``caller`` does first: leave the signals to the caller
    (:func:`leave_signals_to_caller`) and collect its own garbage, even when the caller runs with the collector off
    (``meshreg register``): the caller's objects are frozen (:func:`frozen_heap`), so a collection visits the child's
    objects only (a figure worker's drawings are full of cycles)."""
    leave_signals_to_caller(caller)
    gc.enable()


def _serve(conn, function: Callable, args: tuple, caller: int) -> None:
    """In the child: leave Ctrl-C to the caller (it stops the child), compute, send the answer; send nothing when
    the function raises or the answer cannot be pickled (the caller then computes it itself)."""
    child_started(caller)
    try:
        conn.send(function(*args))
    except BaseException:  # noqa: BLE001 - the caller recomputes and meets the error itself
        pass
    finally:
        conn.close()


@contextmanager
def frozen_heap() -> Iterator[None]:
    """Around a fork: this process's objects wait in the garbage collector's permanent generation, which the child
    inherits, so that the child's collections never visit what it shares with its parent (a visit writes the
    object's header and copies its page: a child forked after the imports and numba's set-up spent 0.1-0.7 s in
    one full collection); this process's objects are collected as before once the child is started. Left as it is
    when something else froze objects already (the Python documentation's recipe for fork without exec)."""
    if gc.get_freeze_count():
        yield
        return
    gc.freeze()
    try:
        yield
    finally:
        gc.unfreeze()


class Forked:
    """``function(*args)``, computed in a forked child from the moment this is made, else (or when the child gives
    no answer) in the caller by :meth:`result`. ``fork``: None to fork when :func:`can_fork` (safe, and a core is
    idle), True when the caller has found a core idle itself (still only where :func:`may_fork`), False never.

    While the child runs, this process's pausable helpers (:func:`add_pausable`) are paused (they would take the
    child's core); anything that waits on a helper must not run then.
    Use as a context manager: leaving it stops a child whose answer was not asked for (work that turned out not to
    be needed costs the other core only)."""

    def __init__(self, function: Callable, *args, fork: bool | None = None):
        self._function, self._args = function, args
        self._child = self._conn = None
        if can_fork() if fork is None else fork and may_fork():
            context = multiprocessing.get_context("fork")
            ours, theirs = context.Pipe(duplex=False)
            self._child = context.Process(target=_serve, args=(theirs, function, args, os.getpid()), daemon=True)
            with frozen_heap():
                self._child.start()
            theirs.close()
            self._conn = ours
            _pause(1)

    @property
    def forked(self) -> bool:
        """Whether a child was started."""
        return self._child is not None

    def result(self) -> Any:
        """The function's value: the child's answer, or computed here when there is none."""
        if self._conn is not None:
            try:
                return self._conn.recv()
            except (EOFError, OSError):
                pass  # no answer: the function raised in the child, or the child died
            finally:
                self.close()
        return self._function(*self._args)

    def close(self) -> None:
        """Stop the child (if it still runs), release the pipe and let the pausable helpers go on."""
        if self._child is not None:
            _pause(-1)
            if self._child.is_alive():
                self._child.terminate()
            self._child.join()
            self._child.close()
            self._conn.close()
            self._child = self._conn = None

    def __enter__(self) -> Forked:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
