"""E with rotations that vary over the square: the comparison of normals that bending does not change.

E compares the shape functions of two surfaces after one rotation of the whole first surface. Bending a surface
turns its normals by an amount that varies from place to place, so the true correspondence of a bent copy pays for
the bending, and minimizing E slides the correspondence until normals that point the same way meet. Here each point
x of the square gets its own rotation R(x), fitted to the normals within a Gaussian window of width ``window``
around it (in side lengths of the square):

    E_w(h, R) = sum_x w_x sum_y w_y K(x, y) |R(x) q1(y) - (q2, h)(y)|^2,
    K(x, y) = g(x - y) / kappa(y),  g a Gaussian of standard deviation ``window``,  kappa(y) = sum_x w_x g(x - y),

with w the cell weights dr dt (so that sum_x w_x K(x, y) = 1: every cell counts once, also near the sides). Bending
that turns the normals smoothly over lengths above ``window`` costs (almost) nothing; the relief within a window,
the distribution of area and the relief's shape still decide where each point goes. As ``window`` grows, E_w tends
to E.

For a given h, the best R(x) is the rotation of the polar decomposition of the windowed cross-covariance
C(x) = sum_y K(x, y) w_y (q2, h)(y) q1(y)^T (Kabsch at every x), so E_w(h) = min_R E_w(h, R) is

    E_w(h) = sum_y w_y (|q1(y)|^2 + |(q2, h)(y)|^2) - 2 sum_x w_x nu(C(x)),

nu(C) = trace(R^T C) at the best rotation R (the singular values' sum, the last one signed). Its derivative in h
(the best R does not move to first order) is that of ``sum_y w_y |M(y) q1(y) - (q2, h)(y)|^2`` with the averaged
rotations M(y) = sum_x w_x K(x, y) R(x) held fixed, whose value differs from E_w(h) by a constant: so a step that
lowers this fixed-target energy lowers E_w(h) too, and the Gauss-Newton solver runs on :class:`LocalObjective`
unchanged (:meth:`LocalObjective.linearize` refreshes the target at every iteration).

numpy, the polar factors in numba: the Gaussian is applied as two dense matrices over the cell centres (exact on
non-uniform grids).
"""

from __future__ import annotations

import numba
import numpy as np

from .objective import Objective
from .srnf import cell_weights, shape_function

TRUNCATE = 3.0  # the window's Gaussian is cut at this many standard deviations
POLAR_DET = 1e-12  # polar factors by Newton's iteration where det C > this times |C|^3 (Frobenius), else by SVD
POLAR_STEP = 1e-15  # the iteration stops when a step moves X (|X| = sqrt(3) at the end) by less than this
POLAR_ITERATIONS = 60  # ... or gives up after this many steps (the SVD takes over)


def gaussian_rows(centres: np.ndarray, window: float) -> np.ndarray:
    """The Gaussian g of standard deviation ``window`` between cell centres (k,) of one axis: (k, k), cut at
    TRUNCATE standard deviations."""
    d = (centres[:, None] - centres[None, :]) / window
    return np.where(np.abs(d) <= TRUNCATE, np.exp(-0.5 * d * d), 0.0)


class Window:
    """The windows of one grid: x -> sum_y g(x - y) a(y) over the cells, and kappa.

    Parameters
    ----------
    r, t : ndarray (M,), (N,)
        The grid's partitions.
    window : float
        Standard deviation of the Gaussian, in side lengths of the square (> 0).
    """

    def __init__(self, r: np.ndarray, t: np.ndarray, window: float):
        self.weights = cell_weights(r, t)
        self.gr = gaussian_rows(0.5 * (r[1:] + r[:-1]), window)
        self.gt = gaussian_rows(0.5 * (t[1:] + t[:-1]), window)
        self.kappa = self.apply(self.weights)

    def apply(self, field: np.ndarray) -> np.ndarray:
        """sum_y g(x - y) field(y) for a field (M-1, N-1, ...) over the cells."""
        m, n = field.shape[:2]
        flat = (self.gr @ field.reshape(m, -1)).reshape(m, n, -1)  # along r, then along t
        return np.swapaxes(np.swapaxes(flat, 1, 2) @ self.gt.T, 1, 2).reshape(field.shape)


def polar_rotations(c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotations R (..., 3, 3) maximizing trace(R^T C) for matrices C (..., 3, 3), and the maxima nu (...,).

    Where det C > POLAR_DET |C|^3 (|C| the Frobenius norm), R is the orthogonal polar factor of C, found by
    :func:`_newton_polar` (3-5x faster than a batched SVD); elsewhere (C near singular or turned by a reflection)
    by the SVD: R = U diag(1, 1, d) V^T, d = det(U V^T)."""
    shape = c.shape[:-2]
    flat = np.ascontiguousarray(c.reshape(-1, 3, 3), dtype=float)
    rotations, nu = np.empty_like(flat), np.empty(len(flat))
    done = np.zeros(len(flat), dtype=bool)
    _newton_polar(flat, rotations, nu, done)
    rest = ~done
    if rest.any():
        u, s, vt = np.linalg.svd(flat[rest])
        d = np.sign(np.linalg.det(u @ vt))  # +-1: u and vt are orthogonal
        u[..., :, -1] *= d[..., None]
        s[..., -1] *= d
        rotations[rest], nu[rest] = u @ vt, s.sum(axis=-1)
    return rotations.reshape(*shape, 3, 3), nu.reshape(shape)


@numba.njit(cache=True)
def _det3(x) -> float:
    return (
        x[0, 0] * (x[1, 1] * x[2, 2] - x[1, 2] * x[2, 1])
        - x[0, 1] * (x[1, 0] * x[2, 2] - x[1, 2] * x[2, 0])
        + x[0, 2] * (x[1, 0] * x[2, 1] - x[1, 1] * x[2, 0])
    )


@numba.njit(cache=True)
def _newton_polar(c, rotations, nu, done):
    """For each C of c (k, 3, 3) with det C > POLAR_DET |C|^3: its orthogonal polar factor R (a rotation) into
    ``rotations``, trace(R^T C) into ``nu`` and True into ``done``, by Higham's scaled Newton iteration
    X <- (g X + X^-T / g) / 2, g = (|X^-1| / |X|)^(1/2), until a step changes X by less than POLAR_STEP; the
    others (and any that does not settle within POLAR_ITERATIONS) are left to the SVD."""
    x, y = np.empty((3, 3)), np.empty((3, 3))
    for k in range(c.shape[0]):
        size = np.sqrt(np.sum(c[k] * c[k]))
        if size == 0.0:
            continue
        x[:] = c[k] / size
        if _det3(x) <= POLAR_DET:
            continue
        for _ in range(POLAR_ITERATIONS):
            det = _det3(x)
            xx, yy = 0.0, 0.0
            for i in range(3):  # y = X^-T: the cofactors over the determinant
                for j in range(3):
                    i1, i2, j1, j2 = (i + 1) % 3, (i + 2) % 3, (j + 1) % 3, (j + 2) % 3
                    y[i, j] = (x[i1, j1] * x[i2, j2] - x[i1, j2] * x[i2, j1]) / det
                    xx += x[i, j] ** 2
                    yy += y[i, j] ** 2
            g = np.sqrt(np.sqrt(yy / xx))
            step = 0.0
            for i in range(3):
                for j in range(3):
                    new = 0.5 * (g * x[i, j] + y[i, j] / g)
                    step += (new - x[i, j]) ** 2
                    x[i, j] = new
            if step < POLAR_STEP**2:
                rotations[k] = x
                nu[k] = np.sum(x * c[k])
                done[k] = True
                break


def local_rotations(q1: np.ndarray, q2: np.ndarray, win: Window) -> tuple[float, np.ndarray]:
    """E_w(h) for shape functions q1 and (q2, h) (M-1, N-1, 3), and the best rotation field R (M-1, N-1, 3, 3)."""
    w = win.weights
    a = np.einsum("ija,ijb->ijab", q2, q1) * (w / win.kappa)[..., None, None]
    rotations, nu = polar_rotations(win.apply(a))
    energy = float(np.sum(w * (np.sum(q1 * q1, axis=-1) + np.sum(q2 * q2, axis=-1))) - 2.0 * np.sum(w * nu))
    return max(energy, 0.0), rotations


def fixed_target(q1: np.ndarray, rotations: np.ndarray, win: Window) -> np.ndarray:
    """The target M q1 (M-1, N-1, 3) of the fixed-target form of E_w (see the module's docstring), for the best
    rotation field R (M-1, N-1, 3, 3) of :func:`local_rotations`."""
    averaged = win.apply(rotations * win.weights[..., None, None]) / win.kappa[..., None, None]
    return np.einsum("ijab,ijb->ija", averaged, q1)


def local_energy(first_points: np.ndarray, second_points: np.ndarray, r, t, window: float) -> float:
    """E_w at h = identity of two surfaces sampled on one grid (points (M, N, 3), both at area 1)."""
    win = Window(r, t, window)
    return local_rotations(shape_function(first_points, r, t), shape_function(second_points, r, t), win)[0]


class LocalObjective(Objective):
    """E_w(h) = min over rotation fields R of E_w(h, R) (see the module's docstring), in the interface of
    :class:`~meshreg.objective.Objective`, so that the descent and refinement levels run on it unchanged.

    The global rotation the solvers move is redundant here (the rotation field absorbs it): :meth:`energy`
    ignores it and :meth:`rotation_jacobian` is zero.

    Parameters
    ----------
    first, second, second_area
        As for :class:`~meshreg.objective.Objective`.
    window : float
        Width of the windows, in side lengths of the square.
    """

    def __init__(self, first, second, second_area: float | None = None, *, window: float):
        super().__init__(first, second, second_area)
        self.shape_q1 = self.q1
        self._win = Window(self.r, self.t, window)

    def _fitted(self, h: np.ndarray) -> dict:
        """E_w(h) and the best rotation field at h, kept with the second surface's values at h (the descent asks
        for the energy of an accepted step and then linearizes at the same h: one fit serves both)."""
        last = self._at(h)
        if "rotations" not in last:
            last["energy"], last["rotations"] = local_rotations(self.shape_q1, self.q2(h), self._win)
        return last

    def energy(self, rotation: np.ndarray, h: np.ndarray) -> float:
        """E_w(h) (the rotation is absorbed by the rotation field)."""
        return self._fitted(h)["energy"]

    def _targeted(self, h: np.ndarray) -> float:
        """Refresh the target M q1 from h (the fixed-target energy's q1); returns E_w(h)."""
        last = self._fitted(h)
        self.q1 = fixed_target(self.shape_q1, last["rotations"], self._win)
        return last["energy"]

    def best_rotation_covariance(self, h: np.ndarray) -> np.ndarray:
        """A covariance whose Kabsch rotation is the identity (the rotation field needs no global rotation)."""
        return np.eye(3)

    def gradient(self, rotation: np.ndarray, h: np.ndarray, dh_dr: np.ndarray, dh_dt: np.ndarray):
        """E_w(h) and its derivative density along fields composed on h (at the best rotation field)."""
        energy = self._targeted(h)
        _, grad = super().gradient(np.eye(3), h, dh_dr, dh_dt)
        return energy, grad

    def linearize(self, rotation: np.ndarray, h: np.ndarray, dh_dr: np.ndarray, dh_dt: np.ndarray):
        """Residuals of the fixed-target energy at h (target refreshed from h) and their Jacobian."""
        self._targeted(h)
        return super().linearize(np.eye(3), h, dh_dr, dh_dt)

    def rotation_jacobian(self, rotation: np.ndarray) -> np.ndarray:
        """Zero: a global rotation does not change E_w."""
        return np.zeros((3 * self.q1.shape[0] * self.q1.shape[1], 3))
