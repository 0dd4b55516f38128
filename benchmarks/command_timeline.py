"""Wall-clock timeline of one ``meshreg register FIRST SECOND -o OUT`` command, from process start to exit: when the
main process and the figure worker start and end each phase (imports of the modules that do the work, reading,
registration, coloured outputs, each file written, each figure drawn, exit).

    OPENBLAS_NUM_THREADS=1 python benchmarks/command_timeline.py a.ply b.ply [-- more register flags]

The command runs in a fresh interpreter (``sys.executable``) whose functions are wrapped as their modules are
imported (nothing is imported earlier than in a plain run); times are seconds since just before the process was
started. Whatever is first on ``PYTHONPATH`` is measured (run it from outside a source tree).
"""

import importlib.abc
import importlib.machinery
import os
import subprocess
import sys
import tempfile
import time

# module -> (function, show its first argument) wrapped to print when it begins and ends
WRAPPED = {
    "meshreg.mesh.topology": [("load_mesh", True)],
    "meshreg.mesh.correspond": [("register_meshes", False)],
    "meshreg.mesh.export": [("write_ply", True), ("colored_outputs", False)],
    "meshreg.result": [("Registration.save", False)],
    "meshreg.painter": [
        ("Painter.__init__", False),
        ("Painter.draw", False),
        ("Painter.finish", False),
        ("_draw", True),
    ],
    "meshreg.viz": [("warm_up", False)],
    "meshreg.forked": [("Forked.__init__", False), ("Forked.result", False)],
    "meshreg.outputs": [("write_mesh_registration", False), ("write_grid_registration", False)],
}


def _mark(what: str) -> None:
    start = float(os.environ["TIMELINE_T0"])
    print(f"{time.time() - start:7.3f} s  [{os.getpid()}] {what}", file=sys.stderr, flush=True)


def _wrap(module, dotted: str, show: bool) -> None:
    owner = module
    *parents, name = dotted.split(".")
    for parent in parents:
        owner = getattr(owner, parent)
    function = getattr(owner, name, None)
    if function is None:
        return
    short = module.__name__.split(".")[-1]

    def wrapper(*args, **kwargs):
        _mark(f"{short}.{name} begins {os.path.basename(str(args[0])) if show and args else ''}")
        try:
            return function(*args, **kwargs)
        finally:
            _mark(f"{short}.{name} ends")

    # the same name, so that the figure worker's pickled calls still find it
    wrapper.__module__, wrapper.__qualname__, wrapper.__name__ = function.__module__, function.__qualname__, name
    setattr(owner, name, wrapper)


class _Hook(importlib.abc.MetaPathFinder):
    """Wraps the functions of :data:`WRAPPED` when their module is imported, and marks the import."""

    def find_spec(self, name, path, target=None):
        if name not in WRAPPED:
            return None
        spec = importlib.machinery.PathFinder.find_spec(name, path)
        if spec is None:
            return None
        execute = spec.loader.exec_module

        def exec_module(module):
            _mark(f"import {name} begins")
            execute(module)
            for dotted, show in WRAPPED[name]:
                _wrap(module, dotted, show)
            _mark(f"import {name} ends")

        spec.loader.exec_module = exec_module
        return spec


def _child(argv: list[str]) -> None:
    """In the measured process: install the hook, run the command line, mark the exit."""
    _mark("python code starts")
    sys.meta_path.insert(0, _Hook())
    import meshreg.cli

    _mark("meshreg.cli imported")
    exit_now = os._exit

    def marked_exit(code):
        _mark("exit")
        exit_now(code)

    os._exit = marked_exit
    sys.argv = ["meshreg", *argv]
    meshreg.cli.run()


def main() -> None:
    if sys.argv[1:2] == ["--child"]:
        _child(sys.argv[2:])
        return
    first, second, *more = [a for a in sys.argv[1:] if a != "--"]
    with tempfile.TemporaryDirectory() as folder:
        command = [sys.executable, __file__, "--child", "register", first, second, "-o", folder, "-q", *more]
        environment = dict(os.environ, TIMELINE_T0=repr(time.time()))
        done = subprocess.run(command, env=environment, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        end = time.time() - float(environment["TIMELINE_T0"])
    print(done.stderr, end="")
    print(f"{end:7.3f} s  process ended (status {done.returncode})")


if __name__ == "__main__":
    main()
