"""A pool of worker processes in which a lost worker costs only the task it held.

Each worker runs one task at a time, sent over its own pipe. When a worker dies (the out-of-memory killer, a
crash in native code), the task it held is reported failed with the cause and a new worker takes its place; the
other workers go on. (``concurrent.futures.ProcessPoolExecutor`` fails every pending task with
``BrokenProcessPool`` when one worker dies, and cannot say which task it held.) When the parent is interrupted
(Ctrl-C, or SIGTERM turned into KeyboardInterrupt by the command line), every worker is terminated before the
interruption goes on: no process of the run is left behind.
"""

from __future__ import annotations

import multiprocessing
import signal
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from multiprocessing.connection import Connection, wait

STOP_SECONDS = 5.0  # how long a terminated worker may take to exit before it is killed


def _serve(conn: Connection, function: Callable, outcome: Callable) -> None:
    """A worker's loop: receive (key, args), send back (key, outcome(function, args)), until None or EOF."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C reaches the parent, which terminates the workers
    signal.signal(signal.SIGTERM, signal.SIG_DFL)  # the parent's handler (KeyboardInterrupt) is not for workers
    _die_with_parent()
    while True:
        try:
            task = conn.recv()
        except (EOFError, OSError):  # the parent is gone
            return
        if task is None:
            return
        key, args = task
        record = outcome(function, args)
        try:
            conn.send((key, record))
        except OSError:  # the parent is gone
            return


def _die_with_parent() -> None:
    """On Linux, have the kernel send SIGTERM to this worker when its parent dies, even by SIGKILL."""
    try:
        import ctypes

        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


@dataclass
class _Worker:
    process: multiprocessing.process.BaseProcess
    conn: Connection
    key: object = None  # the task it holds


def _death(process) -> str:
    code = process.exitcode
    if code is None or code >= 0:
        return f"worker process lost: it exited with status {code}"
    try:
        name = signal.Signals(-code).name
    except ValueError:
        name = f"signal {-code}"
    cause = " (as the out-of-memory killer does)" if -code == signal.SIGKILL else ""
    return f"worker process lost: killed by {name}{cause}"


def run_tasks(
    function: Callable,
    tasks: Iterable[tuple[object, tuple]],
    jobs: int,
    finish: Callable[[object, dict], None],
    outcome: Callable[[Callable, tuple], dict],
) -> None:
    """Run ``outcome(function, args)`` for every ``(key, args)`` of ``tasks`` in ``jobs`` worker processes, calling
    ``finish(key, record)`` in this process as each one ends (in the order they end).

    ``outcome`` turns the function's errors into a record (it must not raise); a worker that dies holding a task
    gives ``finish(key, {"error": "worker process lost: ..."})`` and is replaced. ``function`` and ``outcome`` must
    be module-level functions (they are pickled when processes are spawned rather than forked).
    """
    pending = deque(tasks)
    context = multiprocessing.get_context()
    workers: list[_Worker] = []

    def start() -> _Worker:
        ours, theirs = context.Pipe()
        process = context.Process(target=_serve, args=(theirs, function, outcome), daemon=True)
        process.start()
        theirs.close()
        return _Worker(process, ours)

    try:
        while pending or any(w.key is not None for w in workers):
            for worker in workers:
                if worker.key is None and pending:
                    worker.key, args = pending.popleft()
                    worker.conn.send((worker.key, args))
            while pending and len(workers) < jobs:
                workers.append(start())
                workers[-1].key, args = pending.popleft()
                workers[-1].conn.send((workers[-1].key, args))
            busy = [w for w in workers if w.key is not None]
            ready = set(wait([w.conn for w in busy] + [w.process.sentinel for w in busy]))
            for worker in busy:
                if worker.conn not in ready and worker.process.sentinel not in ready:
                    continue
                try:
                    key, record = worker.conn.recv()
                except (EOFError, OSError):  # the worker died holding its task
                    worker.process.join()
                    finish(worker.key, {"error": _death(worker.process)})
                    worker.conn.close()
                    workers.remove(worker)
                    continue
                worker.key = None
                finish(key, record)
    finally:
        _stop(workers)


def _stop(workers: list[_Worker]) -> None:
    """Stop every worker: idle ones are asked to exit, busy ones (an interruption) terminated; all are joined."""
    for worker in workers:
        if worker.key is None:
            try:
                worker.conn.send(None)
            except OSError:
                pass
        else:
            worker.process.terminate()
    for worker in workers:
        worker.process.join(STOP_SECONDS)
        if worker.process.is_alive():
            worker.process.kill()
            worker.process.join()
        worker.conn.close()
