"""Throughput of distance matrices: pairs per second for a collection of 20 surfaces, locally with 1 and 2
processes and on a Dask cluster of 2 worker processes started on loopback.

    python benchmarks/bench_matrix.py [--grids 61 101] [--surfaces 20] [--backends 1 2 dask]

Prints a table (grid, backend, pairs, seconds, pairs/s, pairs/s per worker, mean seconds of a pair in its worker,
median E). Every run computes all N(N-1)/2 pairs. Pairs/s per worker near 1 / (mean seconds of a pair) says the
workers were kept busy (no time lost to start-up, pickling or waiting).
"""

import argparse
import os
import platform
import time

import numpy as np

import meshreg
from meshreg.samples import bump, cos_sin, helicoid, saddle, sample, sine, terrain, warp, wave


def collection(n: int, size: int):
    """n different surfaces: the paper's families, smooth bumps and waves, random terrains, and warped copies."""
    shapes = [sine(2), sine(3), sine(4), helicoid(1), helicoid(2), helicoid(4), cos_sin(), bump(), saddle(), wave()]
    shapes += [terrain(seed) for seed in range(max(0, n - len(shapes)))]
    return [sample(c, size, size, gamma=warp(0.05) if k % 2 else None) for k, c in enumerate(shapes[:n])]


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--grids", type=int, nargs="+", default=[61, 101])
    parser.add_argument("--surfaces", type=int, default=20)
    parser.add_argument("--backends", nargs="+", default=["1", "2", "dask"], help="local process counts and/or dask")
    args = parser.parse_args()
    from distributed import Client, LocalCluster

    meshreg.distance_matrix(collection(2, 21), jobs=1)  # compile / load the numba kernels
    print(
        f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
        f"Python {platform.python_version()}"
    )
    print("| grid | backend | pairs | seconds | pairs/s | pairs/s per worker | s per pair in its worker | median E |")
    print("|---|---|---|---|---|---|---|---|")
    runs = [
        (f"local, {b} process{'es' if int(b) > 1 else ''}", int(b), dict(jobs=int(b)))
        if b != "dask"
        else ("Dask, 2 workers", 2, None)
        for b in args.backends
    ]
    for size in args.grids:
        grids = collection(args.surfaces, size)
        for label, workers, kwargs in runs:
            tic = time.perf_counter()
            if kwargs is None:
                with (
                    LocalCluster(
                        n_workers=2, threads_per_worker=1, host="127.0.0.1", dashboard_address=None
                    ) as cluster,
                    Client(cluster) as client,
                ):
                    tic = time.perf_counter()  # cluster start-up not counted
                    result = meshreg.distance_matrix(grids, client=client)
            else:
                result = meshreg.distance_matrix(grids, **kwargs)
            seconds = time.perf_counter() - tic
            pairs = len(grids) * (len(grids) - 1) // 2
            upper = np.triu_indices(len(grids), 1)
            energy, each = np.median(result.energy[upper]), np.mean(result.seconds[upper])
            print(
                f"| {size}x{size} | {label} | {pairs} | {seconds:.1f} | {pairs / seconds:.2f} | "
                f"{pairs / seconds / workers:.2f} | {each:.2f} | {energy:.3g} |",
                flush=True,
            )


if __name__ == "__main__":
    main()
