"""Speed and accuracy of grid registration: per pair, grid size and mode, the seconds of each stage and E.

    python benchmarks/bench_grid.py [--grids 101 201] [--modes dp dp+gd auto] [--pairs all]

Runs warm (numba kernels compiled by a first small registration). Set OPENBLAS_NUM_THREADS=1 to
match CI.
"""

import argparse
import platform
import time

import numpy as np

import meshreg
from meshreg.samples import paper_pairs

DEFAULT_PAIRS = ["sine2-2 g2", "sine2-3 g1", "helicoid4 g2", "cossin g2"]


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--grids", type=int, nargs="+", default=[101])
    parser.add_argument("--modes", nargs="+", default=["dp", "dp+gd", "auto"])
    parser.add_argument("--pairs", nargs="+", default=DEFAULT_PAIRS, help="pair names, or 'all'")
    args = parser.parse_args()
    warm = paper_pairs(21, 21)[0]
    for mode in args.modes:
        meshreg.register(warm.first, warm.second, mode=mode)
    print(
        f"machine: {platform.processor() or platform.machine()}, "
        f"{platform.python_implementation()} {platform.python_version()}"
    )
    print("| grid | pair | mode | dp s | gd s | refine s | total s | E |")
    print("|---|---|---|---|---|---|---|---|")
    for m in args.grids:
        pairs = paper_pairs(m, m)
        if args.pairs != ["all"]:
            pairs = [p for p in pairs if p.name in args.pairs]
        for pair in pairs:
            for mode in args.modes:
                tic = time.perf_counter()
                result = meshreg.register(pair.first, pair.second, mode=mode)
                wall = time.perf_counter() - tic
                t = result.timings
                cells = [f"{t[k]:.2f}" if k in t else "-" for k in ("dp", "gd", "refine")]
                print(
                    f"| {m}x{m} | {pair.name} | {mode} | {' | '.join(cells)} | {wall:.2f} | {result.energy:.3g} |",
                    flush=True,
                )


if __name__ == "__main__":
    np.seterr(all="ignore")
    main()
