"""Accuracy and speed on a real scan: pymeshlab's face000 crop against a remeshed, rotated, rescaled copy
(``meshreg.mesh.samples.face_scan_pair``), registered with the default options (101 x 101), whose true answer is
known: E, the angle from the true rotation, the distance of corresponding vertices from their true partners
(median and 90th percentile, % of sqrt(area)) and the seconds of ``register_meshes``.

    python benchmarks/bench_face.py [--resolution 101] [--antialias 3] [--seeds 1]

Set OPENBLAS_NUM_THREADS=1 to match CI. Needs pymeshlab (the scan ships in its wheel).
"""

import argparse
import time

import numpy as np

from meshreg.mesh.correspond import register_meshes
from meshreg.mesh.samples import face_scan_errors, face_scan_pair
from meshreg.options import Options
from meshreg.rotation import angle_between


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--resolution", type=int, default=Options().resolution)
    parser.add_argument("--antialias", type=int, default=Options().antialias)
    parser.add_argument("--seeds", type=int, nargs="+", default=[1], help="seeds of the copy's random vertices")
    args = parser.parse_args()
    options = Options(resolution=args.resolution, antialias=args.antialias)
    print(f"resolution {args.resolution}, antialias {args.antialias}")
    print("| seed | E | residual | angle deg | median % | p90 % | seconds |")
    print("|---|---|---|---|---|---|---|")
    for seed in args.seeds:
        (v1, f1), (v2, f2, xy), rotation = face_scan_pair(seed=seed)
        tic = time.perf_counter()
        mr = register_meshes((v1, f1), (v2, f2), options)
        seconds = time.perf_counter() - tic
        errors = face_scan_errors(mr.result, (v1, f1), xy)
        median, p90 = np.nanmedian(errors), np.nanpercentile(errors, 90)
        angle = angle_between(mr.result.rotation, rotation)
        print(
            f"| {seed} | {mr.result.energy:.4f} | {mr.result.residual:.4f} | {angle:.2f} | {100 * median:.3f} "
            f"| {100 * p90:.3f} | {seconds:.1f} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
