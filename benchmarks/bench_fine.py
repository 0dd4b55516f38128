"""Do fine grids pay off? One pair registered on several grids, every answer measured on common finer grids.

    OPENBLAS_NUM_THREADS=1 python benchmarks/bench_fine.py [--pair "sine2-3 g1"] [--grids 101 201 401]
        [--measure 401 801]

E depends on the grid it is computed on (the node level fits h to the grid's nodes, and q o h is only sampled
there), so the energies two grids report are not comparable. Here each answer (R, and h upsampled bicubically)
is measured on the same grids: the answer that is better on a finer grid is the better answer for the surfaces.
Prints a table (grid, seconds, E on its own grid, E on each measuring grid).
"""

import argparse
import time

import numpy as np

import meshreg
from meshreg.diffeo import enforce_boundary
from meshreg.objective import Objective
from meshreg.samples import paper_pairs
from meshreg.spline import GridInterpolator


def energy_on(result, pair) -> float:
    """E on ``pair``'s grids of ``result`` found on other grids of the same surfaces (R, and h upsampled
    bicubically)."""
    objective = Objective(pair.first, pair.second)
    h = GridInterpolator(result.h, result.r, result.t)(objective.identity[..., 0], objective.identity[..., 1])[0]
    return float(objective.energy(result.rotation, enforce_boundary(h)))


def paper_pair(name: str, size: int):
    """The paper's pair ``name`` sampled on size x size nodes."""
    return next(p for p in paper_pairs(size, size) if p.name == name)


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--pair", default="sine2-3 g1")
    parser.add_argument("--grids", type=int, nargs="+", default=[101, 201, 401])
    parser.add_argument("--measure", type=int, nargs="+", default=[401, 801])
    args = parser.parse_args()
    np.seterr(all="ignore")
    warm = paper_pair(args.pair, 21)
    meshreg.register(warm.first, warm.second)
    rows = []
    for size in args.grids:
        pair = paper_pair(args.pair, size)
        tic = time.perf_counter()
        result = meshreg.register(pair.first, pair.second)
        rows.append((size, time.perf_counter() - tic, result))
    measured = {m: paper_pair(args.pair, m) for m in args.measure}
    print(f"pair {args.pair}, mode auto")
    print("| grid | seconds | E on its grid | " + " | ".join(f"E on {m}^2" for m in args.measure) + " |")
    print("|---|---|---|" + "---|" * len(args.measure))
    for size, seconds, result in rows:
        energies = " | ".join(f"{energy_on(result, measured[m]):.3g}" for m in args.measure)
        print(f"| {size}^2 | {seconds:.2f} | {result.energy:.3g} | {energies} |", flush=True)


if __name__ == "__main__":
    main()
