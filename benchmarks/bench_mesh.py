"""Speed of the mesh front end: parametrize (mean-value Laplacian) and resample on 101 x 101, per mesh size,
and the whole registration of two meshes of about the same size.

    python benchmarks/bench_mesh.py [--faces 10000 100000 1000000] [--register 100000]
"""

import argparse
import time

import numpy as np
from scipy.spatial.transform import Rotation

from meshreg.mesh import parametrize, prepare_disk, resample_grid
from meshreg.mesh.correspond import register_meshes
from meshreg.mesh.samples import random_disk_mesh, terrain_function


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--faces", type=int, nargs="+", default=[10_000, 100_000, 1_000_000])
    parser.add_argument("--register", type=int, nargs="*", default=[100_000])
    args = parser.parse_args()
    surface = terrain_function()
    v, f, _ = random_disk_mesh(surface, 500, seed=0)
    disk = prepare_disk(v, f)
    resample_grid(disk.vertices, disk.faces, parametrize(disk)[0])  # compile the numba kernel
    print("| faces | check s | parametrize s | resample 101x101 s | total s |")
    print("|---|---|---|---|---|")
    for nf in args.faces:
        v, f, _ = random_disk_mesh(surface, nf // 2, seed=1)
        t0 = time.perf_counter()
        disk = prepare_disk(v, f)
        t1 = time.perf_counter()
        uv, _ = parametrize(disk)
        t2 = time.perf_counter()
        resample_grid(disk.vertices, disk.faces, uv)
        t3 = time.perf_counter()
        print(f"| {len(f)} | {t1 - t0:.2f} | {t2 - t1:.2f} | {t3 - t2:.2f} | {t3 - t0:.2f} |", flush=True)
    for nf in args.register:
        a = random_disk_mesh(surface, nf // 2, seed=2)
        b = random_disk_mesh(surface, nf // 2, seed=3, rotation=Rotation.random(random_state=4).as_matrix(), scale=2.0)
        t0 = time.perf_counter()
        mr = register_meshes(a[:2], b[:2])
        print(
            f"register two meshes of {len(a[1])} and {len(b[1])} faces: {time.perf_counter() - t0:.2f} s, "
            f"E = {mr.result.energy:.3g}"
        )


if __name__ == "__main__":
    np.seterr(all="ignore")
    main()
