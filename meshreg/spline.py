"""Bicubic interpolation of gridded data on the unit square (values and first derivatives).

The interpolant is the tensor-product B-spline that scipy's ``RectBivariateSpline`` fits through
the data (``s=0``, cubic where the grid has at least 4 nodes along an axis). Evaluation of all
channels with their first derivatives is done in one numba pass, about 20x faster than calling
``RectBivariateSpline.ev`` once per channel and derivative. The B-splines of each knot span are kept as
polynomials (made once per interpolant), so that evaluating them is Horner's rule, without the divisions of
the de Boor-Cox recursion: 1.4-1.9x faster, the same values to 2e-15 relative.
"""

from __future__ import annotations

from functools import lru_cache
from math import factorial

import numba
import numpy as np
from scipy.interpolate import BSpline, RectBivariateSpline

SPAN_CACHE = 16  # knot vectors whose span polynomials are kept (per grid axis: the surfaces', h's, the coarse grids')


@lru_cache(maxsize=SPAN_CACHE)
def _span_polynomials(knot_bytes: bytes, k: int) -> np.ndarray:
    """The k + 1 B-splines of degree k that are not zero on each knot span, as polynomials in (x - left end).

    Returns (ncoef - k, k + 1, k + 1) for the knots (given as the bytes of a float64 array, so that the result is
    kept per knot vector: every interpolant on one grid has the same knots): entry [span - k, d, a] is the
    coefficient of (x - knots[span])^d of the B-spline span - k + a, from its derivatives at the span's left end
    (scipy's ``BSpline``, right limits). Read-only.
    """
    knots = np.frombuffer(knot_bytes)
    ncoef = len(knots) - k - 1
    ends = knots[k:ncoef]
    splines = BSpline(knots, np.eye(ncoef), k)
    out = np.empty((ncoef - k, k + 1, k + 1))
    columns = np.arange(ncoef - k)[:, None] + np.arange(k + 1)
    for d in range(k + 1):
        values = (splines.derivative(d) if d else splines)(ends) / factorial(d)
        out[:, d, :] = np.take_along_axis(values, columns, axis=1)
    out.flags.writeable = False
    return out


@numba.njit(cache=True)
def _basis(knots, k, ncoef, polys, x, values, derivs):
    """The non-zero B-splines of degree k at x and their first derivatives, into ``values[:k+1]`` and
    ``derivs[:k+1]`` (Horner on the span's polynomials, :func:`_span_polynomials`); returns the index of the first."""
    x = min(max(x, knots[k]), knots[ncoef])
    span = np.searchsorted(knots, x, side="right") - 1
    span = min(max(span, k), ncoef - 1)
    dx = x - knots[span]
    for a in range(k + 1):
        value = polys[span - k, k, a]
        slope = k * polys[span - k, k, a]
        for d in range(k - 1, -1, -1):
            value = value * dx + polys[span - k, d, a]
        for d in range(k - 1, 0, -1):
            slope = slope * dx + d * polys[span - k, d, a]
        values[a] = value
        derivs[a] = slope
    return span - k


@numba.njit(cache=True)
def _evaluate(tx, ty, kx, ky, px, py, coef, u, v, out, out_u, out_v, derivatives):
    """Values (and, with ``derivatives``, d/du and d/dv) of the spline at the points (u, v)."""
    nx, ny, nc = coef.shape
    bu = np.empty(kx + 1)
    dbu = np.empty(kx + 1)
    bv = np.empty(ky + 1)
    dbv = np.empty(ky + 1)
    for p in range(u.shape[0]):
        i0 = _basis(tx, kx, nx, px, u[p], bu, dbu)
        j0 = _basis(ty, ky, ny, py, v[p], bv, dbv)
        for c in range(nc):
            s = 0.0
            su = 0.0
            sv = 0.0
            for a in range(kx + 1):
                row = 0.0
                row_v = 0.0
                for b in range(ky + 1):
                    cf = coef[i0 + a, j0 + b, c]
                    row += cf * bv[b]
                    if derivatives:
                        row_v += cf * dbv[b]
                s += bu[a] * row
                if derivatives:
                    su += dbu[a] * row
                    sv += bu[a] * row_v
            out[p, c] = s
            if derivatives:
                out_u[p, c] = su
                out_v[p, c] = sv


class GridInterpolator:
    """Interpolant of values (M, N, C) given at the nodes of partitions r (M,), t (N,).

    Examples
    --------
    >>> import numpy as np
    >>> r = np.linspace(0, 1, 7); t = np.linspace(0, 1, 5)
    >>> R, T = np.meshgrid(r, t, indexing="ij")
    >>> f = GridInterpolator(np.stack([R**2 * T, T], axis=-1), r, t)
    >>> val, du, dv = f(np.array([0.5]), np.array([0.5]))
    >>> np.round(val, 6).tolist(), np.round(du, 6).tolist()
    ([[0.125, 0.5]], [[0.5, 0.0]])
    """

    def __init__(self, values: np.ndarray, r: np.ndarray, t: np.ndarray):
        values = np.asarray(values, dtype=float)
        m, n, nc = values.shape
        self.kx = min(3, m - 1)
        self.ky = min(3, n - 1)
        coefs = []
        for c in range(nc):
            spline = RectBivariateSpline(r, t, values[..., c], kx=self.kx, ky=self.ky, s=0)
            tx, ty = spline.get_knots()
            coefs.append(spline.get_coeffs().reshape(len(tx) - self.kx - 1, len(ty) - self.ky - 1))
        self.tx = np.ascontiguousarray(tx)
        self.ty = np.ascontiguousarray(ty)
        self.coef = np.ascontiguousarray(np.stack(coefs, axis=-1))
        self.px = _span_polynomials(self.tx.tobytes(), self.kx)
        self.py = _span_polynomials(self.ty.tobytes(), self.ky)

    def __call__(self, u: np.ndarray, v: np.ndarray):
        """Values and partial derivatives at points (u, v) (clamped to the square).

        Parameters
        ----------
        u, v : ndarray, same shape S
            Coordinates in [0, 1].

        Returns
        -------
        value, d_du, d_dv : ndarray, shape S + (C,)
        """
        return self._run(u, v, derivatives=True)

    def values(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """The values alone at points (u, v), shape S + (C,) (no derivatives computed: about half the time)."""
        return self._run(u, v, derivatives=False)[0]

    def _run(self, u, v, derivatives: bool):
        """(value, d_du, d_dv), or (value,) without ``derivatives``."""
        shape = np.shape(u)
        uu = np.ascontiguousarray(np.ravel(u), dtype=float)
        vv = np.ascontiguousarray(np.ravel(v), dtype=float)
        nc = self.coef.shape[2]
        out = np.empty((uu.size, nc))
        out_u = np.empty((uu.size, nc) if derivatives else (0, nc))
        out_v = np.empty((uu.size, nc) if derivatives else (0, nc))
        _evaluate(
            self.tx, self.ty, self.kx, self.ky, self.px, self.py, self.coef, uu, vv, out, out_u, out_v, derivatives
        )
        return (
            tuple(x.reshape(shape + (nc,)) for x in (out, out_u, out_v))
            if derivatives
            else (out.reshape(shape + (nc,)),)
        )
