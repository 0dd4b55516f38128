"""Do fine grids pay off? One pair registered on several grids, every answer measured on common finer grids.

    OPENBLAS_NUM_THREADS=1 python benchmarks/bench_fine.py [--pairs "sine2-3 g1" | all] [--grids 101 201 401]
        [--measure 401 801] [--mode auto]

E depends on the grid it is computed on (the node level fits h to the grid's nodes, and q o h is only sampled
there), so the energies two grids report are not comparable. Here each answer (R, and h upsampled bicubically)
is measured on the same grids: the answer that is better on a finer grid is the better answer for the surfaces.
Prints a table (pair, grid, seconds, E on its own grid, the share of the second surface's area that (q2, h)
carries there, E on each measuring grid). (q2, h) is computed from the quadrilaterals c2(h(corners)) of each
cell; where h stretches a cell over a fold of the second surface, that chord quadrilateral is flatter and smaller
than the surface it spans, so the fold's area and its mismatch drop out of E. A share well below 1 says the
answer lives on such chords: its E is not the E of the surfaces, and the E on a finer grid is the one to trust.
"""

import argparse
import time

import numpy as np

import meshreg
from meshreg.diffeo import enforce_boundary
from meshreg.objective import Objective
from meshreg.samples import paper_pairs
from meshreg.search import apply_symmetry, inverse_symmetry, symmetry_map
from meshreg.spline import GridInterpolator


def measured(result, pair) -> tuple[Objective, np.ndarray]:
    """E on ``pair``'s grids and ``result``'s h there (upsampled bicubically when the result was found on another
    grid), both as the registration measured them: on the second surface reparametrized by the result's symmetry
    of the square (an orientation-reversing symmetry flips the sign of q, which the action's sqrt(det Jh) cannot
    see on the original parametrization)."""
    objective = Objective(pair.first, apply_symmetry(pair.second, result.symmetry))
    h = GridInterpolator(result.h, result.r, result.t)(objective.identity[..., 0], objective.identity[..., 1])[0]
    return objective, enforce_boundary(symmetry_map(inverse_symmetry(result.symmetry), h))


def energy_on(result, pair) -> float:
    """E on ``pair``'s grids of ``result`` found on other grids of the same surfaces (:func:`measured`)."""
    objective, h = measured(result, pair)
    return float(objective.energy(result.rotation, h))


def carried_area(result, pair) -> float:
    """sum w |(q2, h)|^2 on ``pair``'s grids: the share of the second surface's area (1) that (q2, h) carries."""
    objective, h = measured(result, pair)
    return objective.carried_area(h)


def paper_pair(name: str, size: int):
    """The paper's pair ``name`` sampled on size x size nodes."""
    return next(p for p in paper_pairs(size, size) if p.name == name)


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--pairs", nargs="+", default=["sine2-3 g1"], help='names of paper pairs, or "all"')
    parser.add_argument("--grids", type=int, nargs="+", default=[101, 201, 401])
    parser.add_argument("--measure", type=int, nargs="+", default=[401, 801])
    parser.add_argument("--mode", default="auto")
    args = parser.parse_args()
    np.seterr(all="ignore")
    names = [p.name for p in paper_pairs(21, 21)] if args.pairs == ["all"] else args.pairs
    warm = paper_pair(names[0], 21)
    meshreg.register(warm.first, warm.second, args.mode)
    print(f"mode {args.mode}")
    measures = " | ".join(f"E on {m}^2" for m in args.measure)
    print(f"| pair | grid | seconds | E on its grid | area carried | {measures} |")
    print("|---|---|---|---|---|" + "---|" * len(args.measure))
    for name in names:
        fine = {m: paper_pair(name, m) for m in args.measure}
        for size in args.grids:
            pair = paper_pair(name, size)
            tic = time.perf_counter()
            result = meshreg.register(pair.first, pair.second, args.mode)
            seconds = time.perf_counter() - tic
            energies = " | ".join(f"{energy_on(result, fine[m]):.3g}" for m in args.measure)
            row = f"| {name} | {size}^2 | {seconds:.2f} | {result.energy:.3g} | {carried_area(result, pair):.3f} |"
            print(f"{row} {energies} |", flush=True)


if __name__ == "__main__":
    main()
