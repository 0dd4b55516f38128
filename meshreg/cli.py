"""The ``meshreg`` command line: it parses arguments, calls the library and prints; nothing else.

meshreg register FIRST SECOND -o OUT [--mode auto|dp|gd|dp+gd] [--window W] [--basis KL] ... [--force]
meshreg matrix FILES... -o D.npz [--jobs N] [--scheduler URL] [--plot] [--no-retry-failed] [--force]
meshreg atlas FILES... -o OUT [--jobs N] [--scheduler URL] [--modes K] ...   template, one connectivity, modes
meshreg atlas --demo -o OUT                    the atlas of a family of deformed terrain patches
meshreg morph A B -o morph.gif | meshreg morph OUT/atlas.npz --mode 1 -o mode1.gif
meshreg paper [--grid M] [--modes ...]        rerun the paper's ten pairs beside its numbers
meshreg demo [-o OUT]                          register a sample pair and write result + figures

The registration flags are generated from :data:`meshreg.flags.FLAGS`. Exit status: 0 done, 1 a run that did
not finish its work, 2 bad input or usage, 130 Ctrl-C, 143 SIGTERM (see :func:`main`).
"""

from __future__ import annotations

import argparse
import gc
import os
import signal
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from . import __version__
from .errors import InputError, RunError
from .report import atlas_summary, count, summary

EXIT_RUN, EXIT_INPUT, EXIT_INTERRUPTED, EXIT_TERMINATED = 1, 2, 130, 143


class Terminated(KeyboardInterrupt):
    """SIGTERM, handled like Ctrl-C: the run stops its workers and says where its finished work is."""


def _terminate(signum, frame):
    raise Terminated()


class _Parser(argparse.ArgumentParser):
    """Usage errors in one line (with where to find the usage), exit status 2."""

    def error(self, message):
        self.exit(EXIT_INPUT, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def _progress_callback(bar):
    def callback(stage, iteration, energy):
        bar.set_description(stage)
        bar.set_postfix_str(f"E={energy:.3e}")
        bar.update(1)

    return callback


def _bar_class():
    """tqdm without its monitor thread: that thread (started by the first bar, even a disabled one, and never
    stopped) would keep :class:`~meshreg.painter.Painter` from forking, and the figures would be drawn serially."""
    from tqdm import tqdm

    class Bar(tqdm):
        monitor_interval = 0

    return Bar


def _registering(quiet: bool):
    tqdm = _bar_class()

    if not quiet and not _kernels_cached():
        print("first run: compiling meshreg's numba kernels (once; about 20-40 s)", file=sys.stderr)
    return tqdm(desc="registering", unit=" steps", disable=quiet, leave=False, delay=1.0)


# modules whose numba kernels every registration runs (grids and meshes): when their caches are missing, the run
# compiles; kernels of other modules (the mesh front end, the node system of large grids) are compiled by the runs
# that need them, so a missing cache there says nothing about this run
CORE_KERNELS = ("spline", "srnf", "cell_jacobian")


def _kernels_cached() -> bool:
    """Whether numba has cached the kernels every registration runs (:data:`CORE_KERNELS`; else this run compiles)."""
    package = Path(__file__).parent
    return all(any(package.glob(f"__pycache__/{name}.*.nbi")) for name in CORE_KERNELS)


@contextmanager
def _collector_off() -> Iterator[None]:
    """One registration: Python's cyclic garbage collector off meanwhile. Its passes visit every object of numpy,
    scipy and numba (about 10^5 after the imports): 0.13-0.15 s of a 100k-triangle pair's command, while the whole
    registration leaves about 2,000 objects in cycles (gc.get_stats after ``meshreg register``)."""
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if enabled:
            gc.enable()


def cmd_register(args) -> int:
    from .flags import options_from_args
    from .outputs import register_files

    options = options_from_args(args)
    with _collector_off(), _registering(args.quiet) as bar:
        written = register_files(
            args.first,
            args.second,
            args.output,
            options,
            grid_shape=args.grid,
            symmetric=args.symmetric,
            html=args.html,
            callback=_progress_callback(bar),
        )
    for note in written.notes:
        print(note)
    print(summary(written))
    return 0


def cmd_demo(args) -> int:
    from .outputs import run_demo

    print("demo: a terrain patch (matplotlib's Jacksboro DEM) meshed twice with different random vertices,")
    print("      the second rotated, scaled and shifted; mode auto")
    with _collector_off(), _registering(args.quiet) as bar:
        written = run_demo(args.output, callback=_progress_callback(bar))
    for note in written.notes:
        print(note)
    print(summary(written))
    return 0


def cmd_matrix(args) -> int:
    from .flags import options_from_args
    from .matrix_run import check_matrix, matrix_files

    tqdm = _bar_class()
    options = options_from_args(args)
    check_matrix(args.files, args.output, options, jobs=args.jobs, scheduler=args.scheduler)
    n = len(args.files)
    pairs = count(n * (n - 1) // 2, "pair")
    bars = {}

    def preparing(done, total):
        bar = bars.get("prepare")
        if bar is None or bar.total != total:  # a second pass (turned meshes among round ones) raises the total
            bars["prepare"] = bar = tqdm(
                desc="preparing surfaces", total=total, initial=bar.n if bar else 0, unit=" surface", disable=args.quiet
            )
        bar.update(done - bar.n)
        if done == total:
            bar.close()

    def progress(done, total):
        if "pairs" not in bars:  # resuming: the checkpointed pairs are counted, only the new ones timed
            bars["pairs"] = tqdm(desc="pairs", total=total, initial=done, unit=" pair", disable=args.quiet)
        bars["pairs"].update(done - bars["pairs"].n)

    try:
        run = matrix_files(
            args.files,
            args.output,
            options,
            jobs=args.jobs,
            scheduler=args.scheduler,
            plot=args.plot,
            progress=progress,
            retry_failed=args.retry_failed,
            preparing=preparing,
        )
    finally:
        for bar in bars.values():
            bar.close()
    result = run.result
    for k, reason in sorted(result.skipped.items()):
        print(f"skipped {args.files[k]}: {reason}")
    for (i, j), reason in sorted(result.failures.items()):
        if i not in result.skipped and j not in result.skipped:
            print(f"failed pair {Path(args.files[i]).name} / {Path(args.files[j]).name}: {reason}")
    if run.reused:
        print(
            f"{run.written} already holds the finished matrix of these {count(n, 'surface')} and parameters "
            "(newer than every input): nothing recomputed (--force recomputes)"
        )
    elif run.written is not None:
        print(f"{count(n, 'surface')}, {pairs} -> {run.written} (distance = sqrt(E), energy, rotations, seconds)")
    if run.figure is not None:
        print(f"figure         {run.figure}")
    if run.error:
        print(f"meshreg: error: {run.error}", file=sys.stderr)
        return EXIT_RUN
    return 0


def cmd_view(args) -> int:
    from .outputs import view_outputs

    print(f"written        {view_outputs(args.output)}")
    return 0


def _stage_bars(quiet: bool):
    """A progress callback ``(stage, done, total)`` showing one tqdm bar per stage, and a function closing the last."""
    tqdm = _bar_class()

    bars = {}

    def progress(stage, done, total):
        if stage not in bars:
            for bar in bars.values():
                bar.close()
            bars[stage] = tqdm(desc=stage, total=total, initial=done, unit=" reg", disable=quiet, leave=False)
        bars[stage].n = done
        bars[stage].refresh()

    def close():
        for bar in bars.values():
            bar.close()

    return progress, close


def cmd_atlas(args) -> int:
    from .atlas_outputs import atlas_demo, atlas_files
    from .atlas_settings import ATLAS_RESOLUTION, AtlasSettings
    from .flags import options_from_args

    progress, close = _stage_bars(args.quiet)
    try:
        if args.demo:
            if args.files:
                raise InputError("--demo builds its own family: give no FILES")
            print("demo: 12 deformed terrain patches (relief and uplift known), random triangulations of ~2k")
            print("      triangles, random poses and scales; their atlas")
            written = atlas_demo(args.output, jobs=args.jobs, progress=progress)
        else:
            if len(args.files) < 2:
                raise InputError("an atlas needs at least 2 FILES (or --demo)")
            options = options_from_args(args, resolution=ATLAS_RESOLUTION, keep_orientation=not args.any_orientation)
            given = {k: getattr(args, k) for k in ("tolerance", "max_iterations", "modes", "medoid_grid")}
            settings = AtlasSettings(**{k: v for k, v in given.items() if v is not None})
            written = atlas_files(
                args.files,
                args.output,
                options,
                settings,
                jobs=args.jobs,
                scheduler=args.scheduler,
                progress=progress,
            )
    finally:
        close()
    print(atlas_summary(written))
    return 0


def cmd_morph(args) -> int:
    from .atlas_outputs import morph_files

    path = morph_files(args.first, args.second, args.output, mode=args.mode, frames=args.frames)
    print(f"written        {path} ({2 * args.frames - 2} frames, there and back)")
    return 0


def cmd_paper(args) -> int:
    from .paper import format_table, run_paper

    rows = run_paper(args.grid, args.modes, progress=not args.quiet)
    print(format_table(rows, args.modes))
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="meshreg", description="Elastic shape registration of surfaces.")
    parser.add_argument("--version", action="version", version=f"meshreg {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    for add in (_add_register, _add_view, _add_demo, _add_matrix, _add_atlas, _add_morph, _add_paper):
        add(sub)
    return parser


def _add_register(sub) -> None:
    from .flags import add_flags

    reg = sub.add_parser("register", help="register two surfaces (two disk meshes or two grid files)")
    reg.add_argument(
        "first", help="first surface (rotated): a mesh (.ply .obj .stl .off .glb .gltf) or a grid (.npy .npz text)"
    )
    reg.add_argument("second", help="second surface (reparametrized)")
    reg.add_argument(
        "-o",
        "--output",
        required=True,
        help="output directory (result.npz, registration.png; for meshes also first.ply, second.ply, "
        "registered.ply, meshes.png)",
    )
    add_flags(reg)
    reg.add_argument("--grid", type=int, nargs=2, metavar=("M", "N"), help="grid size of text files without header")
    reg.add_argument(
        "--symmetric", action="store_true", help="also register SECOND onto FIRST and report both energies"
    )
    reg.add_argument("--html", action="store_true", help="meshes: also write view.html, an interactive page")
    reg.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    reg.set_defaults(func=cmd_register)


def _add_view(sub) -> None:
    view = sub.add_parser("view", help="write OUT/view.html, an interactive page of a mesh registration in OUT")
    view.add_argument("output", metavar="OUT", help="the output directory of a `meshreg register` of two meshes")
    view.set_defaults(func=cmd_view)


def _add_demo(sub) -> None:
    demo = sub.add_parser(
        "demo", help="register two sample terrain meshes and write coloured meshes, result and figures"
    )
    demo.add_argument("-o", "--output", default="meshreg-demo", help="output directory (default meshreg-demo)")
    demo.add_argument("-q", "--quiet", action="store_true")
    demo.set_defaults(func=cmd_demo)


def _add_matrix(sub) -> None:
    from .flags import add_flags

    matrix = sub.add_parser("matrix", help="pairwise elastic distances of a collection (grids and/or meshes)")
    matrix.add_argument("files", nargs="+", help="grid files and/or meshes")
    matrix.add_argument(
        "-o", "--output", required=True, help="the matrix file (.npz); a checkpoint sits beside it while running"
    )
    matrix.add_argument("--jobs", type=int, default=None, help="local worker processes (default: all cores)")
    matrix.add_argument("--scheduler", help="a dask.distributed scheduler address, e.g. tcp://host:8786")
    matrix.add_argument("--plot", action="store_true", help="also write OUTPUT.png: heat map, dendrogram, MDS")
    matrix.add_argument(
        "--retry-failed",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="when resuming, run again the pairs that failed before (default; --no-retry-failed keeps them failed)",
    )
    add_flags(matrix, groups=("registration", "meshes"))
    matrix.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    matrix.set_defaults(func=cmd_matrix)


def _add_atlas(sub) -> None:
    from .atlas_settings import ATLAS_RESOLUTION, AtlasSettings
    from .flags import add_flags

    defaults = AtlasSettings()
    atlas = sub.add_parser(
        "atlas",
        help="elastic template of a collection, every member in its connectivity, and the modes of variation",
        epilog=f"In an atlas, --resolution defaults to {ATLAS_RESOLUTION} (not 101) and each mesh keeps its front "
        "side (--keep-orientation is on; --any-orientation turns it off).",
    )
    atlas.add_argument("files", nargs="*", help="grid files and/or disk meshes (at least 2)")
    atlas.add_argument(
        "-o",
        "--output",
        required=True,
        help="output directory: template.ply, aligned/NAME.ply, atlas.npz, modes.png, scores.png",
    )
    atlas.add_argument(
        "--demo", action="store_true", help="build a family of 12 deformed terrain patches and its atlas"
    )
    atlas.add_argument("--jobs", type=int, default=None, help="local worker processes (default: all cores)")
    atlas.add_argument("--scheduler", help="a dask.distributed scheduler address, e.g. tcp://host:8786")
    atlas.add_argument(
        "--tolerance",
        type=float,
        help=f"stop when the mean E to the template falls by at most this fraction (default {defaults.tolerance})",
    )
    atlas.add_argument(
        "--max-iterations", type=int, help=f"most registration rounds (default {defaults.max_iterations})"
    )
    atlas.add_argument("--modes", type=int, help=f"principal modes kept (default {defaults.modes})")
    atlas.add_argument(
        "--medoid-grid", type=int, help=f"grid of the medoid's coarse distance matrix (default {defaults.medoid_grid})"
    )
    atlas.add_argument(
        "--any-orientation",
        action="store_true",
        help="also match members mirrored or wound the other way (default: keep each mesh's front side)",
    )
    add_flags(atlas, groups=("registration", "meshes"))
    atlas.set_defaults(func=cmd_atlas)
    atlas.add_argument("-q", "--quiet", action="store_true", help="no progress bars")


def _add_morph(sub) -> None:
    morph = sub.add_parser("morph", help="GIF of the straight path between two shapes, or along a mode of an atlas")
    morph.add_argument("first", help="a surface (mesh or grid file), or an atlas.npz with --mode")
    morph.add_argument("second", nargs="?", help="the surface to morph into (registered to the first)")
    morph.add_argument("-o", "--output", required=True, help="the GIF file")
    morph.add_argument("--mode", type=int, help="animate this mode (from 1) of the atlas, from -2 to +2 sd")
    morph.add_argument("--frames", type=int, default=24, help="frames one way (default 24; the GIF goes and returns)")
    morph.set_defaults(func=cmd_morph)


def _add_paper(sub) -> None:
    from .options import MODES

    paper = sub.add_parser("paper", help="rerun the paper's ten pairs and print E, R and time beside its numbers")
    paper.add_argument("--grid", type=int, default=101, help="grid size M = N (default 101, as in the paper)")
    paper.add_argument("--modes", nargs="+", choices=MODES, default=["dp", "gd", "dp+gd", "auto"])
    paper.add_argument("-q", "--quiet", action="store_true")
    paper.set_defaults(func=cmd_paper)


def _line(text: str) -> str:
    return " ".join(str(text).split())


def main(argv: list[str] | None = None) -> int:
    """Run a command; returns the exit status: 0 done, 1 a run that did not finish its work (RunError, pairs
    without a value, out of memory), 2 bad input (InputError, usage), 130 Ctrl-C, 143 SIGTERM. Each error is one
    line on stderr; only an unexpected exception (a bug) shows a traceback."""
    args = build_parser().parse_args(argv)
    previous = signal.getsignal(signal.SIGTERM)
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, _terminate)
    try:
        return args.func(args)
    except InputError as err:
        print(f"meshreg: error: {_line(err)}", file=sys.stderr)
        return EXIT_INPUT
    except RunError as err:
        print(f"meshreg: error: {_line(err)}", file=sys.stderr)
        return EXIT_RUN
    except MemoryError:
        print(
            "meshreg: error: out of memory: lower --resolution, the grid size or --jobs, or free memory "
            "(no output written)",
            file=sys.stderr,
        )
        return EXIT_RUN
    except KeyboardInterrupt as err:
        notes = "; ".join(getattr(err, "__notes__", []))
        print(f"meshreg: interrupted{': ' + notes if notes else ''}", file=sys.stderr)
        return EXIT_TERMINATED if isinstance(err, Terminated) else EXIT_INTERRUPTED
    except BrokenPipeError:  # the reader of our output went away (`meshreg ... | head`): nothing left to say
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    finally:
        if threading.current_thread() is threading.main_thread():
            signal.signal(signal.SIGTERM, previous)


def run() -> None:
    """The console command: :func:`main`, then a quick exit. Once nothing else runs (no other thread, no child
    process), the exit handlers run and the process ends without the interpreter's teardown, which only frees what
    the system reclaims anyway (modules, numba's compiled code: 0.1-0.3 s after a registration). NumPy's tool
    submodules that SciPy's import touches load only if used (:func:`meshreg.startup.defer_numpy_tools`)."""
    import atexit
    import multiprocessing

    from .startup import defer_numpy_tools

    defer_numpy_tools()
    code = main()
    try:
        sys.stdout.flush()
        sys.stderr.flush()
    except OSError:  # a closed pipe: nothing left to say
        pass
    if threading.active_count() == 1 and not multiprocessing.active_children():
        atexit._run_exitfuncs()
        os._exit(code)
    sys.exit(code)


if __name__ == "__main__":
    run()
