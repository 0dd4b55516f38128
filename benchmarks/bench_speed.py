"""The figures of issue 17 in one table: grid registration in mode "auto" at 101 x 101 and 401 x 401, the mesh
front end, two meshes through the API and the whole ``meshreg register`` command on two PLY files.

    OPENBLAS_NUM_THREADS=1 python benchmarks/bench_speed.py [--quick | --meshes] [--faces N] [--repeats R]
                                                            [--large 100000 1000000]

Warm runs: the numba kernels are compiled (or loaded from their cache) by small registrations first, and meshreg's
bytecode is written (:func:`warm_up`). Every timed figure but the distance matrix is the median of ``--repeats``
runs (default 3, 1 with ``--quick``), their range beside it: times on this shared machine drift by +-30 % within
minutes. ``--quick`` runs a subset in under a minute (three of the paper's pairs at 101 x 101, sine 2-3 at
201 x 201, the mesh front end, two meshes through the API); the full run adds every paper pair, 401 x 401, the
command line and the distance matrix of ``benchmarks/bench_matrix.py``'s 20 surfaces at 101 x 101 on 2 local
processes (``--jobs``); ``--meshes`` runs only the mesh rows (front end, API, whole command). ``--large`` adds the
front end of one mesh per size, each run in a fresh process (the sizes in turn), with its peak memory (a
1M-triangle mesh takes about 4 s and 0.6 GB), as generated (vertices in random order) and renumbered in space order.
"""

import argparse
import compileall
import datetime
import multiprocessing
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import trimesh
from bench_fine import energy_on
from bench_matrix import collection
from bench_mesh import peak_since, reset_peak
from scipy.spatial.transform import Rotation

import meshreg
from meshreg.mesh.corners import mesh_grids
from meshreg.mesh.ordering import spatial_order
from meshreg.mesh.samples import random_disk_mesh, terrain_function
from meshreg.options import Options
from meshreg.samples import paper_pairs

QUICK_PAIRS = ["sine2-3 g1", "helicoid4 g2", "cossin g2"]
FINE_PAIRS = ["helicoid4 g2", "sine2-3 g1"]


REPEATS = 3  # runs of every timed figure but the distance matrix; the table gives their median


def timed(fn, *args, **kwargs):
    """(seconds, value) of one call."""
    tic = time.perf_counter()
    value = fn(*args, **kwargs)
    return time.perf_counter() - tic, value


def repeated(repeats: int, fn, *args, **kwargs):
    """(median seconds, the runs' range as text, the last value) of ``repeats`` calls: this shared host's speed
    drifts by 30% within minutes, and one run of a figure near its target says little."""
    runs = [timed(fn, *args, **kwargs) for _ in range(repeats)]
    seconds = sorted(r[0] for r in runs)
    spread = f"runs {seconds[0]:.2f}-{seconds[-1]:.2f} s" if repeats > 1 else ""
    return float(np.median(seconds)), spread, runs[-1][1]


def _with_spread(note: str, spread: str) -> str:
    """A row's note with the runs' range after it (when there were several)."""
    return f"{note} ({spread})" if spread else note


def _command(command: list[str]) -> subprocess.CompletedProcess:
    """One run of a command line; a failed run stops the benchmark (its time would count in the median)."""
    done = subprocess.run(command, capture_output=True, text=True)
    if done.returncode:
        raise SystemExit(done.stderr)
    return done


def grid_rows(quick: bool, repeats: int) -> list[tuple[str, float, str]]:
    """Mode auto on the paper's pairs at 101 x 101 (median and slowest) and on two pairs at a finer grid, with
    the ratio of E there to the E of the 101 x 101 answer measured on that finer grid (E on a grid is only comparable
    with E on another grid when both answers are measured on one grid: ``bench_fine.py``)."""
    rows, coarse = [], {}
    pairs = [p for p in paper_pairs(101, 101) if not quick or p.name in QUICK_PAIRS]
    runs = []
    for pair in pairs:
        seconds, spread, result = repeated(repeats, meshreg.register, pair.first, pair.second)
        coarse[pair.name] = result
        runs.append((seconds, pair.name, result.energy))
        rows.append((f"auto 101^2 {pair.name}", seconds, _with_spread(f"{result.energy:.3g}", spread)))
    times = sorted(r[0] for r in runs)
    slowest = max(runs)
    rows.append((f"auto 101^2 median over {len(runs)} pairs", float(np.median(times)), ""))
    rows.append((f"auto 101^2 slowest ({slowest[1]})", slowest[0], f"{slowest[2]:.3g}"))
    size = 201 if quick else 401
    fine = [p for p in paper_pairs(size, size) if p.name in (FINE_PAIRS[1:] if quick else FINE_PAIRS)]
    for pair in fine:
        seconds, spread, result = repeated(repeats, meshreg.register, pair.first, pair.second)
        rows.append((f"auto {size}^2 {pair.name}", seconds, _with_spread(f"{result.energy:.3g}", spread)))
        if pair.name in coarse:
            measured = energy_on(coarse[pair.name], pair)
            rows.append(
                (
                    f"  the 101^2 answer measured on the {size}^2 grid",
                    float("nan"),
                    f"{measured:.3g} (E at {size}^2 / this: {result.energy / measured:.2g})",
                )
            )
    return rows


def mesh_pair(faces: int):
    """Two terrain meshes of about ``faces`` triangles each, the second rotated and scaled."""
    surface = terrain_function()
    a = random_disk_mesh(surface, faces // 2, seed=2)[:2]
    turn = Rotation.random(random_state=4).as_matrix()
    b = random_disk_mesh(surface, faces // 2, seed=3, rotation=turn, scale=2.0)[:2]
    return a, b


def mesh_rows(faces: int, quick: bool, repeats: int) -> list[tuple[str, float, str]]:
    """The front end of one mesh, two meshes through the API and (full run) the command line on two PLY files."""
    a, b = mesh_pair(faces)
    seconds, spread, _ = repeated(repeats, mesh_grids, *a, Options())
    rows = [(f"mesh front end, {len(a[1])} triangles", seconds, spread)]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    seconds, spread, result = repeated(repeats, meshreg.register, a, b)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    child = (after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime) / repeats
    note = f"{result.energy:.3g}" + (f" (forked child: {child:.2f} s CPU)" if child > 0.01 else " (no child: serial)")
    rows.append((f"two meshes of {len(a[1])}/{len(b[1])} triangles, API", seconds, _with_spread(note, spread)))
    if quick:
        return rows
    with tempfile.TemporaryDirectory() as folder:
        paths = [Path(folder) / "a.ply", Path(folder) / "b.ply"]
        for path, (v, f) in zip(paths, (a, b), strict=True):
            trimesh.Trimesh(v, f, process=False).export(path)
        command = [sys.executable, "-m", "meshreg.cli", "register", *map(str, paths), "-o", str(Path(folder) / "o")]
        seconds, spread, _ = repeated(repeats, _command, command)
        rows.append(("meshreg register a.ply b.ply, whole command", seconds, spread))
    return rows


def matrix_rows(jobs: int) -> list[tuple[str, float, str]]:
    """All 190 pairs of bench_matrix.py's 20 different surfaces at 101 x 101 on ``jobs`` local processes: pairs
    per second in all and per worker."""
    grids = collection(20, 101)
    seconds, result = timed(meshreg.distance_matrix, grids, jobs=jobs)
    pairs = len(grids) * (len(grids) - 1) // 2
    energy = np.median(result.energy[np.triu_indices(len(grids), 1)])
    return [
        (
            f"distance matrix, 20 grids 101^2, {pairs} pairs, --jobs {jobs}",
            seconds,
            f"{pairs / seconds:.2f} pairs/s ({pairs / seconds / jobs:.2f} per worker), median E {energy:.3g}",
        )
    ]


def _saved_mesh(faces: int, path: str) -> None:
    """Write the first mesh of :func:`mesh_pair` (``faces`` triangles) to an npz file (in a process of its own)."""
    vertices, triangles = mesh_pair(faces)[0]
    np.savez(path, vertices=vertices, faces=triangles)


def _in_space_order(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The same mesh with its vertices renumbered along a Morton curve and its faces sorted by their first vertex:
    the order of a scanner's or a mesher's output, where neighbours have nearby numbers."""
    order = spatial_order(vertices)
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    faces = rank[faces]
    return vertices[order], faces[np.argsort(faces.min(axis=1), kind="stable")]


def _front_end_cost(path: str, space_order: bool) -> tuple[int, float, float]:
    """Triangles, seconds and peak memory (MB above the process's size before it, the peak reset there) of the front
    end of the mesh in ``path`` (with ``space_order``, renumbered by :func:`_in_space_order` first, untimed), run in a
    fresh process after a small warm-up."""
    small = random_disk_mesh(terrain_function(), 500, seed=0)
    mesh_grids(*small[:2], Options())
    data = np.load(path)
    vertices, faces = data["vertices"], data["faces"]
    if space_order:
        vertices, faces = _in_space_order(vertices, faces)
    before = reset_peak()
    seconds, _ = timed(mesh_grids, vertices, faces, Options())
    return len(faces), seconds, peak_since(before)


def large_rows(sizes: list[int], repeats: int) -> list[tuple[str, float, str]]:
    """The front end of one mesh per size (triangles), ``repeats`` times each in a fresh process (the sizes taken in
    turn): the median seconds and peak memory, and both against the first size's (issue 17 asks for linear growth:
    at most 12x from 100k to 1M triangles). The benchmark's vertices come in random order (random points,
    triangulated), the worst case for memory locality; the same meshes renumbered in space order
    (:func:`_in_space_order`) follow, each against its own first size."""
    rows = []
    context = multiprocessing.get_context("spawn")
    with tempfile.TemporaryDirectory() as folder:
        paths = [str(Path(folder) / f"mesh{faces}.npz") for faces in sizes]
        for faces, path in zip(sizes, paths, strict=True):
            with ProcessPoolExecutor(1, mp_context=context) as pool:
                pool.submit(_saved_mesh, faces, path).result()
        for space_order, label in ((False, "fresh process"), (True, "vertices in space order, fresh process")):
            runs = {path: [] for path in paths}
            for _ in range(repeats):
                for path in paths:
                    with ProcessPoolExecutor(1, mp_context=context) as pool:
                        runs[path].append(pool.submit(_front_end_cost, path, space_order).result())
            first = None
            for path in paths:
                count = runs[path][0][0]
                seconds, memory = (float(np.median([r[k] for r in runs[path]])) for k in (1, 2))
                first = first or (count, seconds, memory)
                note = f"peak memory +{memory:.0f} MB"
                if count != first[0]:
                    times, memories = seconds / first[1], memory / max(first[2], 1e-9)
                    note += f" (x{times:.1f} the time, x{memories:.1f} the memory at {first[0]})"
                if repeats > 1:
                    note += ", runs " + " / ".join(f"{r[1]:.2f}" for r in runs[path]) + " s"
                rows.append((f"mesh front end, {count} triangles, {label}", seconds, note))
    return rows


def _positive(text: str) -> int:
    """A count of at least 1 (argparse type)."""
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"at least 1, not {value}")
    return value


def warm_up():
    """Compile (or load) the numba kernels of grids and meshes, and write meshreg's bytecode: Python's own cache,
    which an environment with PYTHONDONTWRITEBYTECODE=1 (this machine's) never writes for an editable install, so
    that every command would compile the package's sources again (about 0.1 s of the whole command's start)."""
    compileall.compile_dir(Path(meshreg.__file__).parent, quiet=1)
    pair = paper_pairs(21, 21)[0]
    meshreg.register(pair.first, pair.second)
    a, b = mesh_pair(2000)
    meshreg.register(a, b)


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--quick", action="store_true", help="a subset, in under a minute")
    parser.add_argument("--faces", type=int, default=100_000, help="triangles per mesh")
    parser.add_argument("--jobs", type=int, default=2, help="local processes of the distance matrix")
    parser.add_argument(
        "--repeats",
        type=_positive,
        help=f"runs of each timed figure, the median shown (default {REPEATS}, --quick 1)",
    )
    parser.add_argument(
        "--meshes", action="store_true", help="only the mesh rows: front end, API and the whole command"
    )
    parser.add_argument(
        "--large", type=int, nargs="+", metavar="FACES", help="also the front end at these sizes (e.g. 100000 1000000)"
    )
    args = parser.parse_args()
    args.repeats = args.repeats or (1 if args.quick else REPEATS)
    np.seterr(all="ignore")
    warm_up()
    if args.meshes:
        rows = mesh_rows(args.faces, False, args.repeats)
    else:
        rows = grid_rows(args.quick, args.repeats) + mesh_rows(args.faces, args.quick, args.repeats)
    if not (args.quick or args.meshes):
        rows += matrix_rows(args.jobs)
    if args.large:
        rows += large_rows(args.large, args.repeats)
    print(
        f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
        f"{platform.python_implementation()} {platform.python_version()}, "
        f"OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', 'unset')}, "
        f"{datetime.datetime.now(datetime.UTC):%Y-%m-%d %H:%M} UTC, median of {args.repeats} runs per figure"
    )
    print("| figure | seconds | E |")
    print("|---|---|---|")
    for name, seconds, energy in rows:
        print(f"| {name} | {'' if np.isnan(seconds) else f'{seconds:.2f}'} | {energy} |")


if __name__ == "__main__":
    main()
