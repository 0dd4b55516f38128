"""Speed of the mesh front end per mesh size: check and clean (prepare_disk), parametrize (mean-value Laplacian),
resample on 101 x 101, each size in a fresh process with its peak memory; and the whole registration of two meshes
of about the same size.

    python benchmarks/bench_mesh.py [--faces 10000 100000 1000000] [--register 100000]

Peak memory is how far the process's resident set rose above its size before the front end (the mesh itself is made
first): the peak is reset just before (Linux ``/proc/self/clear_refs``), so an earlier, higher peak (imports, making
the mesh) cannot hide it.
Times on a shared machine vary by +-30 %.
"""

import argparse
import multiprocessing
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from meshreg.mesh import parametrize, prepare_disk, resample_grid
from meshreg.mesh.correspond import register_meshes
from meshreg.mesh.samples import random_disk_mesh, terrain_function


def _status_mb(field: str) -> float:
    """A ``kB`` field of /proc/self/status (``VmRSS``, ``VmHWM``) in MB."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1]) / 1024
    raise RuntimeError(f"/proc/self/status has no {field} (peak memory is measured on Linux only)")


def reset_peak() -> float:
    """Reset the process's peak resident set to its current size (Linux) and return that size in MB."""
    Path("/proc/self/clear_refs").write_text("5")
    return _status_mb("VmRSS")


def peak_since(start: float) -> float:
    """MB the peak resident set rose above ``start`` (from :func:`reset_peak`)."""
    return _status_mb("VmHWM") - start


def front_end(faces: int) -> tuple[int, float, float, float, float]:
    """Triangles, seconds to check, parametrize and resample one terrain mesh of about ``faces`` triangles, and the
    peak memory (MB) they added; run in a fresh process after a small warm-up (numba kernels)."""
    np.seterr(all="ignore")
    surface = terrain_function()
    v, f, _ = random_disk_mesh(surface, 500, seed=0)
    disk = prepare_disk(v, f)
    resample_grid(disk.vertices, disk.faces, parametrize(disk)[0])
    v, f, _ = random_disk_mesh(surface, faces // 2, seed=1)
    before = reset_peak()
    t0 = time.perf_counter()
    disk = prepare_disk(v, f)
    t1 = time.perf_counter()
    uv, _ = parametrize(disk)
    t2 = time.perf_counter()
    resample_grid(disk.vertices, disk.faces, uv)
    t3 = time.perf_counter()
    return len(f), t1 - t0, t2 - t1, t3 - t2, peak_since(before)


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--faces", type=int, nargs="+", default=[10_000, 100_000, 1_000_000])
    parser.add_argument("--register", type=int, nargs="*", default=[100_000])
    args = parser.parse_args()
    print("| faces | check s | parametrize s | resample 101x101 s | total s | peak MB |")
    print("|---|---|---|---|---|---|")
    context = multiprocessing.get_context("spawn")
    for nf in args.faces:
        with ProcessPoolExecutor(1, mp_context=context) as pool:
            count, check, param, resample, memory = pool.submit(front_end, nf).result()
        total = check + param + resample
        print(f"| {count} | {check:.2f} | {param:.2f} | {resample:.2f} | {total:.2f} | +{memory:.0f} |", flush=True)
    surface = terrain_function()
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
