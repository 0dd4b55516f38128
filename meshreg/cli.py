"""The ``meshreg`` command line.

meshreg register FIRST SECOND -o OUT [--mode auto|dp|gd|dp+gd] [--window W] [--basis KL] ...
meshreg paper [--grid M] [--modes ...]        rerun the paper's ten pairs beside its numbers
meshreg demo [-o OUT]                          register a sample pair and write result + figure
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from .errors import InputError

RESULT_FILE = "result.npz"
REVERSE_FILE = "result_reverse.npz"
FIGURE_FILE = "registration.png"


def _progress_callback(bar):
    def callback(stage, iteration, energy):
        bar.set_description(stage)
        bar.set_postfix_str(f"E={energy:.3e}")
        bar.update(1)

    return callback


def _output_dir(path: str, inputs: list[Path]) -> Path:
    out = Path(path)
    if out.exists() and not out.is_dir():
        raise InputError(f"{out} exists and is not a directory: give another -o")
    resolved = {p.resolve() for p in inputs}
    for name in (RESULT_FILE, REVERSE_FILE, FIGURE_FILE):
        if (out / name).resolve() in resolved:
            raise InputError(f"{out / name} is an input file: choose another output directory")
    out.mkdir(parents=True, exist_ok=True)
    return out


def _run_and_write(first, second, out: Path, mode: str, params: dict, quiet: bool):
    from tqdm import tqdm

    from .objective import Objective
    from .register import register
    from .viz import plot_registration

    with tqdm(desc="registering", unit=" steps", disable=quiet, leave=False) as bar:
        result = register(first, second, mode=mode, callback=_progress_callback(bar), **params)
    result.save(out / RESULT_FILE)
    objective = Objective(first, second)
    plot_registration(
        result.apply(objective.first.points),
        objective.points(result.h),
        result.energy_history,
        out / FIGURE_FILE,
        title=f"{mode}: E = {result.energy:.3g}",
    )
    return result


def _summary(result, out: Path) -> str:
    rows = [
        f"energy E       {result.energy:.6g}   (squared elastic distance, both surfaces at area 1)",
        f"distance       {result.distance:.6g}   (sqrt(E))",
    ]
    if np.isfinite(result.energy_dp):
        rows.append(f"E after DP     {result.energy_dp:.6g}")
    rows.append("rotation R     " + np.array2string(result.rotation, precision=4, suppress_small=True).replace("\n", "\n               "))
    rows.append("time (s)       " + ", ".join(f"{k} {v:.2f}" for k, v in result.timings.items()))
    rows.append(f"written        {out / RESULT_FILE}, {out / FIGURE_FILE}")
    return "\n".join(rows)


def _register_params(args) -> dict:
    params = {"window": args.window, "basis": args.basis, "solver": args.solver, "refine": args.refine}
    if args.max_rounds is not None:
        params["max_rounds"] = args.max_rounds
    return params


def cmd_register(args) -> int:
    from .grid import read_grid

    shape = tuple(args.grid) if args.grid else None
    first = read_grid(args.first, shape)
    second = read_grid(args.second, shape)
    out = _output_dir(args.output, [Path(args.first), Path(args.second)])
    result = _run_and_write(first, second, out, args.mode, _register_params(args), args.quiet)
    print(_summary(result, out))
    if args.symmetric:
        from .register import register

        reverse = register(second, first, mode=args.mode, **_register_params(args))
        reverse.save(out / REVERSE_FILE)
        print(f"reverse E      {reverse.energy:.6g}   (second rotated, first reparametrized; {out / REVERSE_FILE})")
        print(f"mean E         {0.5 * (result.energy + reverse.energy):.6g}")
    return 0


def cmd_demo(args) -> int:
    from .samples import paper_pairs

    pair = {p.name: p for p in paper_pairs()}["helicoid4 g2"]
    out = _output_dir(args.output, [])
    print(f"demo: {pair.name} (helicoid k=4 against a rotated copy sampled at (r^5/4, t^5/4)), mode auto")
    result = _run_and_write(pair.first, pair.second, out, "auto", {}, args.quiet)
    print(_summary(result, out))
    return 0


def cmd_paper(args) -> int:
    from .paper import format_table, run_paper

    rows = run_paper(args.grid, args.modes, progress=not args.quiet)
    print(format_table(rows, args.modes))
    return 0


def build_parser() -> argparse.ArgumentParser:
    from .descent import DEFAULT_BASIS
    from .dp import DEFAULT_WINDOW
    from .register import DEFAULT_MODE, MODES, REFINEMENTS, SOLVERS

    parser = argparse.ArgumentParser(prog="meshreg", description="Elastic shape registration of surfaces.")
    sub = parser.add_subparsers(dest="command", required=True)

    reg = sub.add_parser("register", help="register two grid surfaces")
    reg.add_argument("first", help="first surface (rotated): .npy, .npz or text grid")
    reg.add_argument("second", help="second surface (reparametrized)")
    reg.add_argument("-o", "--output", required=True, help="output directory (result.npz, registration.png)")
    reg.add_argument("--mode", choices=MODES, default=DEFAULT_MODE, help=f"default {DEFAULT_MODE}")
    reg.add_argument("--window", type=int, default=DEFAULT_WINDOW, help=f"DP window W (default {DEFAULT_WINDOW})")
    reg.add_argument("--basis", type=int, default=DEFAULT_BASIS, help=f"KL of the Riseth basis (default {DEFAULT_BASIS})")
    reg.add_argument("--solver", choices=SOLVERS, default="gauss-newton", help="descent direction (default gauss-newton)")
    reg.add_argument("--refine", choices=REFINEMENTS, default="nodes", help="node-wise refinement (default nodes)")
    reg.add_argument("--max-rounds", type=int, default=None, help="most descent + Kabsch rounds per stage")
    reg.add_argument("--grid", type=int, nargs=2, metavar=("M", "N"), help="grid size of text files without header")
    reg.add_argument("--symmetric", action="store_true", help="also register SECOND onto FIRST and report both energies")
    reg.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    reg.set_defaults(func=cmd_register)

    demo = sub.add_parser("demo", help="register a sample pair and write the result and a figure")
    demo.add_argument("-o", "--output", default="meshreg-demo", help="output directory (default meshreg-demo)")
    demo.add_argument("-q", "--quiet", action="store_true")
    demo.set_defaults(func=cmd_demo)

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


if __name__ == "__main__":
    sys.exit(main())
