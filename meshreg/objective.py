"""The registration energy E(h, R) of two grid surfaces and its derivative along reparametrizations.

How the reparametrized shape function (q2, h) is computed: the second surface is **resampled at h**
(its bicubic interpolant evaluated at h(r_i, t_j)) and q is recomputed from those points with the
cell formula of :mod:`meshreg.srnf`. The factor sqrt(det Jh) is then implicit in the cell areas.
The alternative, interpolating q2 (bicubic, from cell centres) at h and multiplying by
sqrt(det Jh), was measured to be about 1000 times less accurate: with the exact h of the paper's
same-shape pairs (where E = 0 exactly) it leaves E = 3e-6 to 1e-5 on 101 x 101 grids, against
4e-10 to 2e-9 for resampling the points (``python benchmarks/q_recompute.py``). Resampling is also what an
evaluator holding the exact second surface does, so the E reported here is the E that anyone recomputes from R and h.

References
----------
Bernal & Lawrence, Section 4: E(h, R), Theorem 2 (directional derivative of E along a vector field
v on the square, for the composition h o (id + tau v)).
"""

from __future__ import annotations

from functools import cached_property

import numpy as np

from .cell_jacobian import CellJacobian, gram_pattern
from .diffeo import identity, is_valid
from .grid import GridSurface
from .residual import Residual, coordinate_residual, node_weights
from .rotation import kabsch
from .srnf import (
    cell_weights,
    cross_covariance,
    energy,
    energy_gradient_points,
    shape_function,
    shape_function_blocks,
)


class Objective:
    """E(h, R) = sum_cells w |R q1 - q(c2 o h)|^2 for two surfaces, both scaled to area 1.

    Parameters
    ----------
    first : GridSurface
        The surface that is rotated; its grid nodes are where h is sampled.
    second : GridSurface
        The surface that is reparametrized (may have another grid size).
    second_area : float, optional
        Area to scale the second surface by (default: its own). Given when ``second`` is a copy
        under a symmetry of the square, whose two-triangle area differs in the last digits.
    """

    def __init__(self, first: GridSurface, second: GridSurface, second_area: float | None = None):
        self.first = first.scaled()
        area = second.area() if second_area is None else second_area
        self.second = GridSurface(second.points / np.sqrt(area), second.r, second.t)
        self.r, self.t = self.first.r, self.first.t
        self.weights = cell_weights(self.r, self.t)
        self.q1 = shape_function(self.first.points, self.r, self.t)
        self.identity = identity(self.r, self.t)
        self._last: dict = {}  # the last h the second surface was evaluated at, and what was computed there

    def c2(self, h: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The second surface at h and its partial derivatives there: c2(h), dc2/du(h), dc2/dv(h), each (M, N, 3)
        (read-only)."""
        last = self._at(h, derivatives=True)
        return last["points"], last["du"], last["dv"]

    def _at(self, h: np.ndarray, derivatives: bool = False) -> dict:
        """c2(h), with ``derivatives`` also dc2/du and dc2/dv at h, and a slot for (q2, h), all read-only.

        The descent evaluates the second surface at one h several times (the energy of an accepted step, its stretch
        test, the next linearization, the Kabsch step that follows): each is a bicubic evaluation at every node. The
        last h and its values are kept, so that such repeats cost one comparison of h; the numbers are the same.
        """
        last = self._last
        if not (last and np.array_equal(last["h"], h) and (last["du"] is not None or not derivatives)):
            if derivatives:
                points, du, dv = self.second.interpolator(h[..., 0], h[..., 1])
            else:
                points, du, dv = self.second.at(h), None, None
            for array in (points, du, dv):
                if array is not None:
                    array.flags.writeable = False
            self._last = last = {"h": h.copy(), "points": points, "du": du, "dv": dv, "q2": None}
        return last

    def points(self, h: np.ndarray) -> np.ndarray:
        """The second surface at h: c2(h(r_i, t_j)), shape (M, N, 3) (read-only)."""
        return self._at(h)["points"]

    def q2(self, h: np.ndarray) -> np.ndarray:
        """(q2, h), the shape function of c2 o h, shape (M-1, N-1, 3) (read-only)."""
        last = self._at(h)
        if last["q2"] is None:
            last["q2"] = shape_function(last["points"], self.r, self.t)
            last["q2"].flags.writeable = False
        return last["q2"]

    def energy(self, rotation: np.ndarray, h: np.ndarray) -> float:
        """E(h, R)."""
        return energy(self.q1, self.q2(h), self.weights, rotation)

    def carried_area(self, h: np.ndarray) -> float:
        """sum w |(q2, h)|^2: the area of the second surface that (q2, h) carries (1 in the continuum for every h).

        (q2, h) is computed from the chord quadrilaterals c2(h(corners)) of the cells; where h stretches a cell over a
        fold of the second surface, its chord is flatter and smaller than the surface it spans, and the fold's area
        and mismatch drop out of E. A lower carried area is that, not a better match.
        """
        return float(np.sum(self.weights[..., None] * self.q2(h) ** 2))

    @cached_property
    def node_weights(self) -> np.ndarray:
        """Area weights (M, N) of the first surface's nodes, summing to 1 (:func:`meshreg.residual.node_weights`)."""
        return node_weights(self.first.points)

    @cached_property
    def edge_lengths(self) -> tuple[np.ndarray, np.ndarray]:
        """Lengths of the first surface's grid edges along r (M-1, N) and t (M, N-1), at area 1, each at least
        half the median edge (a collapsed side of the first surface must not make every stretch infinite)."""
        along_r = np.linalg.norm(np.diff(self.first.points, axis=0), axis=-1)
        along_t = np.linalg.norm(np.diff(self.first.points, axis=1), axis=-1)
        floor = 0.5 * np.median(np.concatenate([along_r.ravel(), along_t.ravel()]))
        return np.maximum(along_r, floor), np.maximum(along_t, floor)

    def stretch(self, h: np.ndarray) -> float:
        """The largest factor by which h stretches an edge of the first grid both in the square and on the surfaces.

        For each edge: the smaller of |h(x_k+1) - h(x_k)| over |x_k+1 - x_k| (in the parameter square) and the length
        of the edge's image on the second surface (trapezoid rule on |Dc2(h) dh| at its two ends) over its chord on
        the first, both surfaces at area 1. Where h squeezes a long stretch of the second surface into one cell of
        the first, both are large; for two samplings of one shape the exact h may have steep slopes, but the second
        ratio stays near 1.
        """
        return max(float(s.max()) for s in self.edge_stretch(h))

    def edge_stretch(self, h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The factor of :meth:`stretch` for every edge: along r (M-1, N) and along t (M, N-1)."""
        _, dc_du, dc_dv = self.c2(h)
        out = []
        for axis, lengths, in_square in zip((0, 1), self.edge_lengths, self._square_stretch(h), strict=True):
            dh = np.diff(h, axis=axis)
            ends = [np.take(d, np.arange(h.shape[axis] - 1) + k, axis=axis) for d in (dc_du, dc_dv) for k in (0, 1)]
            start = np.linalg.norm(ends[0] * dh[..., :1] + ends[2] * dh[..., 1:], axis=-1)
            end = np.linalg.norm(ends[1] * dh[..., :1] + ends[3] * dh[..., 1:], axis=-1)
            on_surfaces = 0.5 * (start + end) / lengths
            out.append(np.minimum(on_surfaces, in_square))
        return out[0], out[1]

    def _square_stretch(self, h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """|dh| over the edge's length in the square, for every edge: along r (M-1, N) and along t (M, N-1)."""
        spacing_r, spacing_t = np.ix_(np.diff(self.r), np.diff(self.t))
        along_r = np.linalg.norm(np.diff(h, axis=0), axis=-1) / spacing_r
        return along_r, np.linalg.norm(np.diff(h, axis=1), axis=-1) / spacing_t

    def over_stretch(self, h: np.ndarray, max_stretch: float) -> tuple[np.ndarray, np.ndarray]:
        """The edges (along r (M-1, N) and along t (M, N-1), booleans) that h stretches by more than ``max_stretch``
        (:meth:`edge_stretch`). The stretch in the square comes first: when it keeps every edge within the bound, the
        second surface and its derivatives are not evaluated."""
        over = tuple(stretch > max_stretch for stretch in self._square_stretch(h))
        if not (over[0].any() or over[1].any()):
            return over
        along_r, along_t = self.edge_stretch(h)
        return along_r > max_stretch, along_t > max_stretch

    def within_stretch(self, h: np.ndarray, max_stretch: float) -> bool:
        """Whether :meth:`stretch` is at most ``max_stretch`` (True without computing it when that is infinite)."""
        return max_stretch == np.inf or not any(over.any() for over in self.over_stretch(h, max_stretch))

    def admissible(self, h: np.ndarray, max_stretch: float) -> bool:
        """A valid reparametrization (:func:`meshreg.diffeo.is_valid`) within the stretch bound (:meth:`stretch`)."""
        return is_valid(h) and self.within_stretch(h, max_stretch)

    def residual(self, rotation: np.ndarray, h: np.ndarray) -> Residual:
        """The coordinate residual of (R, h): RMS of R c1 - c2 o h and of R c1 + c2 o h (:mod:`meshreg.residual`)."""
        return coordinate_residual(self.first.points @ rotation.T, self.points(h), self.node_weights)

    def evaluate(self, rotation: np.ndarray, h: np.ndarray) -> tuple[float, Residual]:
        """E(h, R) and the coordinate residual, from one evaluation of the second surface at h."""
        e = energy(self.q1, self.q2(h), self.weights, rotation)
        return e, coordinate_residual(self.first.points @ rotation.T, self.points(h), self.node_weights)

    def judge(self, h: np.ndarray) -> tuple[np.ndarray, float, Residual]:
        """For h: the best R (Kabsch), E(h, R) and the residual, from one evaluation of the second surface at h."""
        q2 = self.q2(h)
        rotation = kabsch(cross_covariance(self.q1, q2, self.weights))
        residual = coordinate_residual(self.first.points @ rotation.T, self.points(h), self.node_weights)
        return rotation, energy(self.q1, q2, self.weights, rotation), residual

    def best_rotation_covariance(self, h: np.ndarray) -> np.ndarray:
        """H = sum w q1 (q2, h)^T, whose Kabsch rotation minimizes E(h, .)."""
        return cross_covariance(self.q1, self.q2(h), self.weights)

    def gradient(self, rotation: np.ndarray, h: np.ndarray, dh_dr: np.ndarray, dh_dt: np.ndarray):
        """E(h, R) and its derivative density along vector fields composed on the right of h.

        For a field v on the square, ``d/dtau E(h o (id + tau v), R) = sum_nodes G . v`` at tau = 0
        (Theorem 2 of the paper, for the discretized energy, so that it is exact for the E that
        is minimized).

        Parameters
        ----------
        rotation : ndarray, shape (3, 3)
        h : ndarray, shape (M, N, 2)
        dh_dr, dh_dt : ndarray, shape (M, N, 2)
            Partial derivatives of h at the nodes.

        Returns
        -------
        E : float
        G : ndarray, shape (M, N, 2)
        """
        pts, dc_du, dc_dv = self.c2(h)
        e, g_pts = energy_gradient_points(self.q1 @ rotation.T, pts, self.weights)
        d_dr, d_dt = _composite_derivatives(dc_du, dc_dv, dh_dr, dh_dt)
        grad = np.stack([np.sum(g_pts * d_dr, axis=-1), np.sum(g_pts * d_dt, axis=-1)], axis=-1)
        return e, grad

    def linearize(self, rotation: np.ndarray, h: np.ndarray, dh_dr: np.ndarray, dh_dt: np.ndarray):
        """Residuals of E(h, R) and their derivatives along node displacements composed on h.

        E = |res|^2 with ``res = sqrt(w) (R q1 - (q2, h))`` flattened; for a field v on the square,
        ``res(h o (id + v)) = res + jac @ v.ravel() + O(|v|^2)`` with v given at the nodes (M, N, 2).

        Parameters
        ----------
        rotation : ndarray, shape (3, 3)
        h, dh_dr, dh_dt : ndarray, shape (M, N, 2)
            h and its partial derivatives at the nodes.

        Returns
        -------
        res : ndarray, shape (3 (M-1) (N-1),)
        jac : CellJacobian
            The (3 (M-1) (N-1), 2 M N) Jacobian, kept as per-cell blocks.
        """
        pts, dc_du, dc_dv = self.c2(h)
        d_dr, d_dt = _composite_derivatives(dc_du, dc_dv, dh_dr, dh_dt)
        q, blocks = shape_function_blocks(pts, self.weights, np.stack([d_dr, d_dt], axis=-1))
        sw = np.sqrt(self.weights)[..., None]
        res = sw * (self.q1 @ rotation.T - q)
        blocks *= -sw[..., None]  # (M-1, N-1, 3, 8): columns (corner, component)
        m, n = h.shape[:2]
        return res.ravel(), CellJacobian(blocks.reshape(-1, 3, 8), gram_pattern(m, n))

    def rotation_jacobian(self, rotation: np.ndarray) -> np.ndarray:
        """Derivatives of res = sqrt(w) (R q1 - (q2, h)) along R <- exp([omega]x) R: shape (3 (M-1)(N-1), 3)."""
        p = (self.q1 @ rotation.T) * np.sqrt(self.weights)[..., None]
        cols = [np.cross(axis, p) for axis in np.eye(3)]
        return np.stack([c.ravel() for c in cols], axis=-1)

    def second_on_first_grid(self, h: np.ndarray | None = None) -> np.ndarray:
        """q of the second surface resampled at h (identity by default) on the first's grid."""
        return self.q2(self.identity if h is None else h)


def _composite_derivatives(dc_du, dc_dv, dh_dr, dh_dt):
    """Columns d/dr and d/dt of D(c2 o h) = Dc2(h) Dh, each (M, N, 3)."""
    d_dr = dc_du * dh_dr[..., :1] + dc_dv * dh_dr[..., 1:]
    d_dt = dc_du * dh_dt[..., :1] + dc_dv * dh_dt[..., 1:]
    return d_dr, d_dt
