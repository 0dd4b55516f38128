"""Which way of recomputing (q2, h) is more accurate? Measured with the exact h of same-shape pairs.

For the paper's same-shape pairs the true h = gamma^-1 is known and E(h, P) = 0 exactly. Two ways to
compute (q2, h) on the first grid:
  points  resample the second surface at h (bicubic) and recompute q from the points (meshreg's way)
  q       interpolate q2 (bicubic, from cell centres) at h and multiply by sqrt(det Jh)
The table prints E for each: what is left is discretization/interpolation error.

    python benchmarks/q_recompute.py
"""

import numpy as np

from meshreg.diffeo import jacobian_determinant
from meshreg.objective import Objective
from meshreg.samples import paper_pairs
from meshreg.spline import GridInterpolator
from meshreg.srnf import shape_function


def energy_by_q_interpolation(ob: Objective, rotation, h):
    s2 = ob.second
    q2 = shape_function(s2.points, s2.r, s2.t)
    rc, tc = 0.5 * (s2.r[1:] + s2.r[:-1]), 0.5 * (s2.t[1:] + s2.t[:-1])
    hc = 0.25 * (h[1:, 1:] + h[:-1, :-1] + h[1:, :-1] + h[:-1, 1:])
    q_at_h = GridInterpolator(q2, rc, tc)(hc[..., 0], hc[..., 1])[0]
    q_tilde = q_at_h * np.sqrt(np.maximum(jacobian_determinant(h, ob.r, ob.t), 0))[..., None]
    diff = ob.q1 @ rotation.T - q_tilde
    return float(np.sum(ob.weights * np.sum(diff**2, -1)))


def main():
    print("| grid | pair | E, points resampled | E, q interpolated |")
    print("|---|---|---|---|")
    for m in (51, 101):
        for pair in paper_pairs(m, m):
            if not pair.same_shape:
                continue
            ob = Objective(pair.first, pair.second)
            h = pair.h_true(ob.identity[..., 0], ob.identity[..., 1])
            print(
                f"| {m} | {pair.name} | {ob.energy(pair.rotation, h):.2e} "
                f"| {energy_by_q_interpolation(ob, pair.rotation, h):.2e} |"
            )


if __name__ == "__main__":
    main()
