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
    for name in (RESULT_FILE, REVERSE_FILE, FIGURE_FILE, "first.ply", "second.ply", "registered.ply", "meshes.png"):
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
    if args.smoothing is not None:
        params["smoothing"] = tuple(args.smoothing)
    if args.start_basis is not None:
        params["start_basis"] = args.start_basis
    if args.max_starts is not None:
        params["max_starts"] = args.max_starts
    return params


def _mesh_params(args) -> dict:
    return {"grid": args.resolution, "weights": args.weights, "cleanup": not args.no_cleanup,
            "corners": (args.corners1, args.corners2), "corner_search": args.corner_search}


def _register_meshes_and_write(first, second, out: Path, params: dict, quiet: bool):
    """Mesh pipeline: register (vertices, faces) pairs and write coloured meshes, result and figures."""
    from tqdm import tqdm

    from .mesh.correspond import register_meshes, similarity_transform
    from .mesh.export import colored_outputs, plot_meshes, write_ply
    from .objective import Objective
    from .viz import plot_registration

    with tqdm(desc="registering", unit=" steps", disable=quiet, leave=False) as bar:
        mr = register_meshes(first, second, callback=_progress_callback(bar), **params)
    (v1, f1), (v2, f2) = first, second
    objective = Objective(*mr.grids)
    c1, c2, registered = colored_outputs(mr, len(v1), len(v2), objective)
    write_ply(out / "first.ply", v1, f1, c1)
    write_ply(out / "second.ply", v2, f2, c2)
    write_ply(out / "registered.ply", *registered)
    uv1 = mr.first.to_input(mr.uv1, len(v1), [np.nan, np.nan])
    uv2 = mr.second.to_input(mr.uv2, len(v2), [np.nan, np.nan])
    mr.result.save(out / RESULT_FILE, uv_first=uv1, uv_second=uv2)
    plot_meshes(out / "meshes.png", v1, f1, c1, v2, f2, c2, title=f"E = {mr.result.energy:.3g}: corresponding points share a colour",
                second_to_first=np.linalg.inv(similarity_transform(mr)))
    plot_registration(mr.result.apply(objective.first.points), objective.points(mr.result.h), mr.result.energy_history,
                      out / FIGURE_FILE, title=f"E = {mr.result.energy:.3g}")
    for name, info in mr.info.items():
        for line in info["cleanup"]:
            print(f"{name} mesh cleanup: {line}")
        if info["flipped"]:
            print(f"{name} mesh: {info['flipped']} triangles flipped by the parametrization")
    return mr.result


def cmd_register(args) -> int:
    from .grid import read_grid
    from .mesh.topology import MESH_SUFFIXES, load_mesh

    is_mesh = [Path(p).suffix.lower() in MESH_SUFFIXES for p in (args.first, args.second)]
    if any(is_mesh):
        if not all(is_mesh):
            raise InputError("give two meshes or two grid files, not one of each")
        first, second = load_mesh(args.first), load_mesh(args.second)
        out = _output_dir(args.output, [Path(args.first), Path(args.second)])
        params = {**_register_params(args), **_mesh_params(args)}
        result = _register_meshes_and_write(first, second, out, params, args.quiet)
        print(_summary(result, out))
        print(f"               {out / 'first.ply'}, {out / 'second.ply'}, {out / 'registered.ply'}, {out / 'meshes.png'}")
        return 0
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
    from .mesh.export import write_ply
    from .mesh.samples import demo_pair

    out = _output_dir(args.output, [])
    (v1, f1, _), (v2, f2, _) = demo_pair()
    inputs = out / "inputs"
    inputs.mkdir(exist_ok=True)
    write_ply(inputs / "terrain_a.ply", v1, f1, np.full((len(v1), 3), 0.8))
    write_ply(inputs / "terrain_b.ply", v2, f2, np.full((len(v2), 3), 0.8))
    print("demo: a terrain patch (matplotlib's Jacksboro DEM) meshed twice (2500 and 4000 random vertices),")
    print(f"      the second rotated, scaled and shifted; inputs in {inputs}; mode auto")
    result = _register_meshes_and_write((v1, f1), (v2, f2), out, {}, args.quiet)
    print(_summary(result, out))
    print(f"               {out / 'first.ply'}, {out / 'second.ply'}, {out / 'registered.ply'}, {out / 'meshes.png'}")
    return 0


def cmd_matrix(args) -> int:
    from tqdm import tqdm

    from .batch import CHECKPOINT_SUFFIX, classical_mds, distance_matrix
    from .viz import plot_matrix

    files = [Path(f) for f in args.files]
    out = Path(args.output)
    if out.suffix != ".npz":
        raise InputError(f"{out}: the matrix file must end in .npz")
    if any(out.resolve() == f.resolve() for f in files):
        raise InputError(f"{out} is one of the inputs: choose another output file")
    missing = [str(f) for f in files if not f.is_file()]
    if missing:
        raise InputError(f"no such file: {', '.join(missing)}")
    out.parent.mkdir(parents=True, exist_ok=True)
    client = None
    if args.scheduler:
        try:
            from distributed import Client
        except ImportError:
            raise InputError("--scheduler needs dask.distributed: pip install 'meshreg[dask]'") from None
        try:
            client = Client(args.scheduler, timeout="20s")
        except (OSError, TimeoutError) as err:
            raise InputError(f"cannot reach the Dask scheduler at {args.scheduler}: {err}") from None
    checkpoint = out.with_name(out.name + CHECKPOINT_SUFFIX)
    if not args.quiet:
        print(f"preparing {len(files)} surfaces (read; meshes cleaned, mapped to the square, resampled), then "
              f"{len(files) * (len(files) - 1) // 2} pairs", file=sys.stderr)
    with tqdm(desc="pairs", unit=" pair", disable=args.quiet) as bar:
        def progress(done, total):
            bar.total = total
            if bar.n == 0 and done:
                bar.reset(total)  # resuming: count the checkpointed pairs, time only the new ones
                bar.initial = done
            bar.n = done
            bar.refresh()

        try:
            result = distance_matrix(files, client=client, jobs=args.jobs, checkpoint=checkpoint,
                                     resolution=args.resolution, progress=progress, mode=args.mode,
                                     **_register_params(args))
        except KeyboardInterrupt:
            raise InputError(f"interrupted: finished pairs are kept in {checkpoint}; rerun the same command to resume") from None
        finally:
            if client is not None:
                client.close()
    result.save(out)
    checkpoint.unlink(missing_ok=True)
    n = len(files)
    print(f"{n} surfaces, {n * (n - 1) // 2} pairs -> {out} (distance = sqrt(E), energy, rotations, seconds)")
    for (i, j), reason in sorted(result.failures.items()):
        print(f"failed pair {files[i].name} / {files[j].name}: {reason}")
    if args.plot:
        figure = plot_matrix(result.names, result.distance, classical_mds(result.distance), out.with_suffix(".png"))
        print(f"figure         {figure}")
    return 0


def cmd_paper(args) -> int:
    from .paper import format_table, run_paper

    rows = run_paper(args.grid, args.modes, progress=not args.quiet)
    print(format_table(rows, args.modes))
    return 0


def _registration_options(parser) -> None:
    from .descent import DEFAULT_BASIS
    from .dp import DEFAULT_WINDOW
    from .register import DEFAULT_MODE, MODES, REFINEMENTS, SOLVERS

    parser.add_argument("--mode", choices=MODES, default=DEFAULT_MODE, help=f"default {DEFAULT_MODE}")
    parser.add_argument("--window", type=int, default=DEFAULT_WINDOW, help=f"DP window W (default {DEFAULT_WINDOW})")
    parser.add_argument("--basis", type=int, default=DEFAULT_BASIS, help=f"KL of the Riseth basis (default {DEFAULT_BASIS})")
    parser.add_argument("--solver", choices=SOLVERS, default="gauss-newton", help="descent direction (default gauss-newton)")
    parser.add_argument("--refine", choices=REFINEMENTS, default="nodes", help="node-wise refinement (default nodes)")
    parser.add_argument("--max-rounds", type=int, default=None, help="most descent + Kabsch rounds per stage")
    parser.add_argument("--max-starts", type=int, default=None, metavar="K",
                        help="mode auto: most ranked starts registered in full (default 3; 1 = the best-ranked only)")
    parser.add_argument("--smoothing", type=float, nargs="*", default=None, metavar="SIGMA",
                        help="mode gd: Gaussian scale-space levels of its second path, in side lengths, largest first "
                             "(default 0.1; give none for the plain descent only)")
    parser.add_argument("--start-basis", type=int, default=None, metavar="KL",
                        help="mode gd: KL of the coarse basis the descent from the identity starts in (default 3)")


def build_parser() -> argparse.ArgumentParser:
    from .mesh.correspond import CORNER_SEARCH
    from .mesh.resample import DEFAULT_GRID
    from .register import MODES

    parser = argparse.ArgumentParser(prog="meshreg", description="Elastic shape registration of surfaces.")
    sub = parser.add_subparsers(dest="command", required=True)

    reg = sub.add_parser("register", help="register two grid surfaces")
    reg.add_argument("first", help="first surface (rotated): a mesh (.ply .obj .stl .off .glb) or a grid (.npy .npz text)")
    reg.add_argument("second", help="second surface (reparametrized)")
    reg.add_argument("-o", "--output", required=True, help="output directory (result.npz, registration.png)")
    _registration_options(reg)
    reg.add_argument("--grid", type=int, nargs=2, metavar=("M", "N"), help="grid size of text files without header")
    mesh = reg.add_argument_group("meshes")
    mesh.add_argument("--resolution", type=int, default=DEFAULT_GRID, help=f"meshes are resampled on N x N grids (default {DEFAULT_GRID})")
    mesh.add_argument("--weights", choices=("mean-value", "cotangent"), default="mean-value", help="Laplacian weights of the map to the square")
    mesh.add_argument("--no-cleanup", action="store_true", help="refuse to repair meshes (holes, components, ears, pinched vertices)")
    mesh.add_argument("--corners1", type=int, nargs=4, metavar="ID", help="corner vertex ids of the first mesh's boundary")
    mesh.add_argument("--corners2", type=int, nargs=4, metavar="ID", help="corner vertex ids of the second mesh's boundary")
    mesh.add_argument("--corner-search", type=int, default=CORNER_SEARCH,
                      help=f"trial corner placements on round boundaries, 0 = off (default {CORNER_SEARCH})")
    reg.add_argument("--symmetric", action="store_true", help="also register SECOND onto FIRST and report both energies")
    reg.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    reg.set_defaults(func=cmd_register)

    demo = sub.add_parser("demo", help="register two sample terrain meshes and write coloured meshes, result and figures")
    demo.add_argument("-o", "--output", default="meshreg-demo", help="output directory (default meshreg-demo)")
    demo.add_argument("-q", "--quiet", action="store_true")
    demo.set_defaults(func=cmd_demo)

    matrix = sub.add_parser("matrix", help="pairwise elastic distances of a collection (grids and/or meshes)")
    matrix.add_argument("files", nargs="+", help="grid files and/or meshes")
    matrix.add_argument("-o", "--output", required=True, help="the matrix file (.npz); a checkpoint sits beside it while running")
    matrix.add_argument("--jobs", type=int, default=None, help="local worker processes (default: all cores)")
    matrix.add_argument("--scheduler", help="a dask.distributed scheduler address, e.g. tcp://host:8786")
    matrix.add_argument("--plot", action="store_true", help="also write OUTPUT.png: heat map, dendrogram, MDS")
    _registration_options(matrix)
    matrix.add_argument("--resolution", type=int, default=DEFAULT_GRID, help=f"meshes are resampled on N x N grids (default {DEFAULT_GRID})")
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


if __name__ == "__main__":
    sys.exit(main())
