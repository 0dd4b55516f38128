"""Time of a shape atlas of 12 meshes of about 2k triangles: the demo's terrain family and the tests' bump sheets.

    OPENBLAS_NUM_THREADS=1 python benchmarks/bench_atlas.py [--jobs 1 2] [--members 12]

Prints a table (family, jobs, members, iterations, wall seconds of each stage and in all, per member, CPU seconds of
this process and its workers, the canonical correlations of the first two modes' scores with the known parameters).
"""

import argparse
import os
import platform
import resource
import time

import numpy as np
from scipy.spatial.transform import Rotation

import meshreg
from meshreg.mesh.samples import random_disk_mesh, terrain_family
from meshreg.shape_stats import canonical_correlations


def bump_sheets(count: int, seed: int = 1):
    """The tests' family: a skewed dome with a bump of height a at (b, 0.3), random triangulations and poses."""
    rng = np.random.default_rng(seed)
    params = np.c_[rng.uniform(0.1, 0.3, count), rng.uniform(0.35, 0.65, count)]
    meshes = []
    for k, (a, b) in enumerate(params):

        def sheet(u, v, a=a, b=b):
            dome = 0.4 * np.sin(np.pi * u) * np.sin(np.pi * v) * (0.6 + 0.8 * u)
            return np.stack([u, v, dome + a * np.exp(-((u - b) ** 2 + (v - 0.3) ** 2) / 0.03)], axis=-1)

        rotation = Rotation.random(random_state=100 + k).as_matrix()
        v, f, _ = random_disk_mesh(sheet, 900 + int(rng.integers(225)), 10 + k, rotation=rotation, scale=1.0)
        meshes.append((v, f))
    return meshes, params


def cpu_seconds() -> float:
    own, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--jobs", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--members", type=int, default=12)
    args = parser.parse_args()
    families = {"terrain (demo)": terrain_family(args.members), "bump sheets (tests)": bump_sheets(args.members)}
    meshreg.atlas(families["terrain (demo)"][0][:2], jobs=1)  # compile / load the numba kernels
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, load {os.getloadavg()}")
    print(
        "| family | jobs | members | triangles | iterations | medoid s | iterations s | total s | per member s "
        "| CPU s | CC |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for name, (meshes, params) in families.items():
        triangles = f"{min(len(f) for _, f in meshes)}-{max(len(f) for _, f in meshes)}"
        for jobs in args.jobs:
            cpu = cpu_seconds()
            tic = time.perf_counter()
            result = meshreg.atlas(meshes, jobs=jobs)
            wall = time.perf_counter() - tic
            t = result.timings
            print(
                f"| {name} | {jobs} | {len(result.names)} | {triangles} | {result.params['iterations']} | "
                f"{t['medoid']:.1f} | {t['iterations']:.1f} | {wall:.1f} | {t['per_member']:.2f} | "
                f"{cpu_seconds() - cpu:.1f} | {np.round(canonical_correlations(result.scores[:, :2], params), 3)} |"
            )


if __name__ == "__main__":
    main()
