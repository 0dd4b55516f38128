"""The ``meshreg`` command line: it parses arguments, calls the library and prints; nothing else.

meshreg register FIRST SECOND -o OUT [--mode auto|dp|gd|dp+gd] [--window W] [--basis KL] ...
meshreg matrix FILES... -o D.npz [--jobs N] [--scheduler URL] [--plot]
meshreg paper [--grid M] [--modes ...]        rerun the paper's ten pairs beside its numbers
meshreg demo [-o OUT]                          register a sample pair and write result + figures

The registration flags are generated from :data:`meshreg.options.FLAGS`.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from . import __version__
from .errors import InputError


def _progress_callback(bar):
    def callback(stage, iteration, energy):
        bar.set_description(stage)
        bar.set_postfix_str(f"E={energy:.3e}")
        bar.update(1)

    return callback


def _summary(written) -> str:
    import numpy as np

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

    if not quiet and not _kernels_cached():
        print("first run: compiling meshreg's numba kernels (once; about 20-40 s)", file=sys.stderr)
    return tqdm(desc="registering", unit=" steps", disable=quiet, leave=False, delay=1.0)


def _kernels_cached() -> bool:
    """Whether numba has cached the compiled kernels of every module that has them (else the first run compiles)."""
    package = Path(__file__).parent
    modules = ("spline", "dp", "mesh/resample", "mesh/locate")
    return all(any((package / m).parent.glob(f"__pycache__/{Path(m).name}.*.nbi")) for m in modules)


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
            html=args.html,
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

    from .batch import matrix_files
    from .options import options_from_args

    options = options_from_args(args)
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

        result, figure = matrix_files(
            args.files,
            args.output,
            options,
            jobs=args.jobs,
            scheduler=args.scheduler,
            plot=args.plot,
            progress=progress,
        )
    print(f"{n} surfaces, {n * (n - 1) // 2} pairs -> {args.output} (distance = sqrt(E), energy, rotations, seconds)")
    for (i, j), reason in sorted(result.failures.items()):
        print(f"failed pair {Path(args.files[i]).name} / {Path(args.files[j]).name}: {reason}")
    if figure is not None:
        print(f"figure         {figure}")
    return 0


def cmd_view(args) -> int:
    from .outputs import view_outputs

    print(f"written        {view_outputs(args.output)}")
    return 0


def cmd_paper(args) -> int:
    from .paper import format_table, run_paper

    rows = run_paper(args.grid, args.modes, progress=not args.quiet)
    print(format_table(rows, args.modes))
    return 0


def build_parser() -> argparse.ArgumentParser:
    from .options import MODES, add_flags

    parser = argparse.ArgumentParser(prog="meshreg", description="Elastic shape registration of surfaces.")
    parser.add_argument("--version", action="version", version=f"meshreg {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)

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

    view = sub.add_parser("view", help="write OUT/view.html, an interactive page of a mesh registration in OUT")
    view.add_argument("output", metavar="OUT", help="the output directory of a `meshreg register` of two meshes")
    view.set_defaults(func=cmd_view)

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
    add_flags(matrix, groups=("registration", "meshes"))
    matrix.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    matrix.set_defaults(func=cmd_matrix)

    paper = sub.add_parser("paper", help="rerun the paper's ten pairs and print E, R and time beside its numbers")
    paper.add_argument("--grid", type=int, default=101, help="grid size M = N (default 101, as in the paper)")
    paper.add_argument("--modes", nargs="+", choices=MODES, default=["dp", "gd", "dp+gd", "auto"])
    paper.add_argument("-q", "--quiet", action="store_true")
    paper.set_defaults(func=cmd_paper)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except InputError as err:
        print(f"meshreg: error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("meshreg: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # the reader of our output went away (`meshreg ... | head`): nothing left to say
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0


if __name__ == "__main__":
    sys.exit(main())
