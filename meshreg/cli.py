"""The ``meshreg`` command line: it parses arguments, calls the library and prints; nothing else.

meshreg register FIRST SECOND -o OUT [--mode auto|dp|gd|dp+gd] [--window W] [--basis KL] ... [--force]
meshreg matrix FILES... -o D.npz [--jobs N] [--scheduler URL] [--plot] [--no-retry-failed] [--force]
meshreg paper [--grid M] [--modes ...]        rerun the paper's ten pairs beside its numbers
meshreg demo [-o OUT]                          register a sample pair and write result + figures

The registration flags are generated from :data:`meshreg.options.FLAGS`. Exit status: 0 done, 1 a run that did
not finish its work, 2 bad input or usage, 130 Ctrl-C, 143 SIGTERM (see :func:`main`).
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
from pathlib import Path

import numpy as np

from .errors import InputError, RunError

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


def _summary(written) -> str:
    result = written.result
    rows = [
        f"energy E       {result.energy:.6g}   (squared elastic distance, both surfaces at area 1)",
        f"distance       {result.distance:.6g}   (sqrt(E))",
    ]
    if np.isfinite(result.energy_dp):
        rows.append(f"E after DP     {result.energy_dp:.6g}")
    rows.append(
        "rotation R     "
        + np.array2string(result.rotation, precision=4, suppress_small=True).replace("\n", "\n               ")
    )
    rows.append("time (s)       " + ", ".join(f"{k} {v:.2f}" for k, v in result.timings.items()))
    if written.reverse is not None:
        reverse = written.reverse
        rows.append(f"reverse E      {reverse.energy:.6g}   (second rotated, first reparametrized)")
        rows.append(f"mean E         {0.5 * (result.energy + reverse.energy):.6g}")
    rows.append("written        " + ", ".join(str(f) for f in written.files))
    return "\n".join(rows)


def _registering(quiet: bool):
    from tqdm import tqdm

    return tqdm(desc="registering", unit=" steps", disable=quiet, leave=False)


def cmd_register(args) -> int:
    from .options import options_from_args
    from .outputs import register_files

    options = options_from_args(args)
    with _registering(args.quiet) as bar:
        written = register_files(
            args.first,
            args.second,
            args.output,
            options,
            grid_shape=args.grid,
            symmetric=args.symmetric,
            callback=_progress_callback(bar),
        )
    for note in written.notes:
        print(note)
    print(_summary(written))
    return 0


def cmd_demo(args) -> int:
    from .outputs import run_demo

    print("demo: a terrain patch (matplotlib's Jacksboro DEM) meshed twice with different random vertices,")
    print("      the second rotated, scaled and shifted; mode auto")
    with _registering(args.quiet) as bar:
        written = run_demo(args.output, callback=_progress_callback(bar))
    for note in written.notes:
        print(note)
    print(_summary(written))
    return 0


def cmd_matrix(args) -> int:
    from tqdm import tqdm

    from .batch import check_matrix, matrix_files
    from .options import options_from_args

    options = options_from_args(args)
    check_matrix(args.files, args.output, options, jobs=args.jobs, scheduler=args.scheduler)
    n = len(args.files)
    if not args.quiet:
        print(
            f"preparing {n} surfaces (read; meshes cleaned, mapped to the square, resampled), then "
            f"{n * (n - 1) // 2} pairs",
            file=sys.stderr,
        )
    with tqdm(desc="pairs", unit=" pair", disable=args.quiet) as bar:

        def progress(done, total):
            bar.total = total
            if bar.n == 0 and done:
                bar.reset(total)  # resuming: count the checkpointed pairs, time only the new ones
                bar.initial = done
            bar.n = done
            bar.refresh()

        run = matrix_files(
            args.files,
            args.output,
            options,
            jobs=args.jobs,
            scheduler=args.scheduler,
            plot=args.plot,
            progress=progress,
            retry_failed=args.retry_failed,
        )
    result = run.result
    for k, reason in sorted(result.skipped.items()):
        print(f"skipped {args.files[k]}: {reason}")
    for (i, j), reason in sorted(result.failures.items()):
        if i not in result.skipped and j not in result.skipped:
            print(f"failed pair {Path(args.files[i]).name} / {Path(args.files[j]).name}: {reason}")
    if run.written is not None:
        print(
            f"{n} surfaces, {n * (n - 1) // 2} pairs -> {run.written} (distance = sqrt(E), energy, rotations, seconds)"
        )
    if run.figure is not None:
        print(f"figure         {run.figure}")
    if run.error:
        print(f"meshreg: error: {run.error}", file=sys.stderr)
        return EXIT_RUN
    return 0


def cmd_paper(args) -> int:
    from .paper import format_table, run_paper

    rows = run_paper(args.grid, args.modes, progress=not args.quiet)
    print(format_table(rows, args.modes))
    return 0


def build_parser() -> argparse.ArgumentParser:
    from .options import MODES, add_flags

    parser = _Parser(prog="meshreg", description="Elastic shape registration of surfaces.")
    sub = parser.add_subparsers(dest="command", required=True)

    reg = sub.add_parser("register", help="register two surfaces (two disk meshes or two grid files)")
    reg.add_argument(
        "first", help="first surface (rotated): a mesh (.ply .obj .stl .off .glb) or a grid (.npy .npz text)"
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
    reg.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    reg.set_defaults(func=cmd_register)

    demo = sub.add_parser(
        "demo", help="register two sample terrain meshes and write coloured meshes, result and figures"
    )
    demo.add_argument("-o", "--output", default="meshreg-demo", help="output directory (default meshreg-demo)")
    demo.add_argument("-q", "--quiet", action="store_true")
    demo.set_defaults(func=cmd_demo)

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

    paper = sub.add_parser("paper", help="rerun the paper's ten pairs and print E, R and time beside its numbers")
    paper.add_argument("--grid", type=int, default=101, help="grid size M = N (default 101, as in the paper)")
    paper.add_argument("--modes", nargs="+", choices=MODES, default=["dp", "gd", "dp+gd", "auto"])
    paper.add_argument("-q", "--quiet", action="store_true")
    paper.set_defaults(func=cmd_paper)
    return parser


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
    finally:
        if threading.current_thread() is threading.main_thread():
            signal.signal(signal.SIGTERM, previous)


if __name__ == "__main__":
    sys.exit(main())
