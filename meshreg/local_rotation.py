"""E with rotations that vary over the square: the comparison of normals that bending does not change.

E compares the shape functions of two surfaces after one rotation of the whole first surface. Bending a surface
turns its normals by an amount that varies from place to place, so the true correspondence of a bent copy pays for
the bending, and minimizing E slides the correspondence until normals that point the same way meet. Bending a
sheet with relief also stretches the relief by a factor that varies from place to place (a point at height z over
a cylinder of radius rho by (rho - z) / rho), which changes |q|^2, the area element. Two energies with rotations
fitted in Gaussian windows of width ``window`` (in side lengths of the square) therefore serve the bending path
(:mod:`meshreg.bending`), with

    K(x, y) = g(x - y) / kappa(y),  g a Gaussian of standard deviation ``window``,  kappa(y) = sum_x w_x g(x - y),

w the cell weights dr dt (so that sum_x w_x K(x, y) = 1: every cell counts once, also near the sides), and R(x)
the rotation of the polar decomposition of the windowed cross-covariance C(x) = sum_y K(x, y) w_y (q2, h)(y)
q1(y)^T (Kabsch at every x; nu(C) = trace(R^T C), the singular values' sum, the last one signed).

The descent's E_w (:class:`LocalObjective`) compares each cell y under its own similarity s(y) R(y):

    E_w(h) = sum_y w_y |s(y) R(y) q1(y) - (q2, h)(y)|^2,
    s(x)^2 = sum_y L(x, y) w_y |(q2, h)(y)|^2 / sum_y L(x, y) w_y |q1(y)|^2,

L as K with windows SCALE_WIDTH times wider. Bending that turns the normals smoothly and stretching that changes the
area smoothly, over lengths above the windows, cost (almost) nothing; the relief's shape within a window decides
where each point goes. s is the windows' area ratio, not the least-squares scale nu(C) / sum_y K w |q1|^2, which a
rotation's misfit lowers: where a window straddles a crease, that scale let the descent squeeze the crease (the
benchmark's quick fold pair: median error 0.0075 -> 0.0165). The descent linearizes
``sum_y w_y |T(y) - (q2, h)(y)|^2`` with the target T(y) = s(y) R(y) q1(y) held fixed and refits the similarities
at every linearization (:meth:`LocalObjective.linearize`), as ICP alternates matching and fitting: the slope it
uses leaves out how the fitted similarities move with h (they average over a window), and every accepted step is
checked against E_w itself, so every accepted step lowers E_w.

The ranking's E_w (:func:`local_energy`: the square's symmetries and corner placements at h = the symmetry)
compares each cell under the rotations of all the windows around it, with no scale:

    E_w(h) = min_R sum_x w_x sum_y w_y K(x, y) |R(x) q1(y) - (q2, h)(y)|^2
           = sum_y w_y (|q1(y)|^2 + |(q2, h)(y)|^2) - 2 sum_x w_x nu(C(x)),

which tends to E as ``window`` grows. Until 2026-12-01 the descent minimized it too; it charged the turning of a
rolled sheet's normals within a window and the relief's stretch (four held-out Gaussian reliefs, peak to peak
0.18, rolled 90 degrees: E_w at the true map 0.0050-0.0066 and 20-37% above that at the answer, which was
0.011-0.021 of sqrt(area) from the truth; the descent's E_w at the true map: 0.00027-0.00056). For ranking, the
area distribution it compares tells symmetric placements apart: ranked by the descent's E_w, a nearly
point-symmetric sheet came back half a turn off (E 0.0199 instead of 0.0062) and the face scan crop's corner
placement was worse (median error 0.0089 instead of 0.0049).

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
# the windows of the descent's area ratio (its scale) are this many times wider than those of the rotations: on the
# benchmark's quick pairs (600 / 900 vertices), median errors, 1 -> 2: fold 0.0096 -> 0.0071, remeshed 0.0043 ->
# 0.0039, roll 90 / 180 0.0051 / 0.0069 -> 0.0050 / 0.0066, stretch 0.0053 -> 0.0052; about 4: fold 0.0058, but
# stretch 0.0066 and roll 180 0.0075 (wider windows absorb less of the stretch; 1 and 4 measured in prototypes that
# also ranked the symmetries by this E_w)
SCALE_WIDTH = 2.0


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


def local_similarities(q1: np.ndarray, q2: np.ndarray, win: Window, wide: Window) -> tuple[float, np.ndarray]:
    """E_w(h) for shape functions q1 and (q2, h) (M-1, N-1, 3), and the similarity field S = s R (M-1, N-1, 3, 3):
    each cell's best rotation in the window ``win`` around it, and the square root of the area ratio in the window
    ``wide`` around it (SCALE_WIDTH times wider)."""
    w = win.weights
    rotations = local_rotations(q1, q2, win)[1]
    area1, area2 = (wide.apply(np.sum(q * q, axis=-1) * (w / wide.kappa)) for q in (q1, q2))
    scale = np.sqrt(area2 / np.where(area1 > 0, area1, np.inf))
    similarities = rotations * scale[..., None, None]
    return float(np.sum(w * np.sum((cell_target(q1, similarities) - q2) ** 2, axis=-1))), similarities


def cell_target(q1: np.ndarray, similarities: np.ndarray) -> np.ndarray:
    """The target S q1 (M-1, N-1, 3) of each cell under its own similarity S (M-1, N-1, 3, 3)."""
    return np.einsum("ijab,ijb->ija", similarities, q1)


def local_rotations(q1: np.ndarray, q2: np.ndarray, win: Window) -> tuple[float, np.ndarray]:
    """The rotations-only E_w (see the module's docstring) for shape functions q1 and (q2, h) (M-1, N-1, 3): every
    cell under the rotations of all the windows around it, no scale (closed form: the sum over windows of nu(C));
    and the best rotation field R (M-1, N-1, 3, 3)."""
    w = win.weights
    a = np.einsum("ija,ijb->ijab", q2, q1) * (w / win.kappa)[..., None, None]
    rotations, nu = polar_rotations(win.apply(a))
    energy = float(np.sum(w * (np.sum(q1 * q1, axis=-1) + np.sum(q2 * q2, axis=-1))) - 2.0 * np.sum(w * nu))
    return max(energy, 0.0), rotations


def fixed_target(q1: np.ndarray, rotations: np.ndarray, win: Window) -> np.ndarray:
    """The target M q1 (M-1, N-1, 3) of the rotations-only E_w's fixed-target form, M(y) = sum_x w_x K(x, y) R(x) the
    averaged rotations of the best field R (M-1, N-1, 3, 3) of :func:`local_rotations`: its derivative in h is that
    of E_w (the best R does not move to first order), and its value differs from E_w by a constant."""
    averaged = win.apply(rotations * win.weights[..., None, None]) / win.kappa[..., None, None]
    return np.einsum("ijab,ijb->ija", averaged, q1)


def local_energy(first_points: np.ndarray, second_points: np.ndarray, r, t, window: float) -> float:
    """The ranking's E_w at h = identity of two surfaces sampled on one grid (points (M, N, 3), both at area 1)."""
    win = Window(r, t, window)
    return local_rotations(shape_function(first_points, r, t), shape_function(second_points, r, t), win)[0]


class LocalObjective(Objective):
    """E_w(h), each cell under the similarity fitted around it (see the module's docstring), in the interface of
    :class:`~meshreg.objective.Objective`, so that the descent and refinement levels run on it unchanged.

    The global rotation the solvers move is redundant here (the similarity field absorbs it): :meth:`energy`
    ignores it and :meth:`rotation_jacobian` is zero.

    With ``scaled`` False it is the rotations-only E_w (the ranking's) with its exact derivative (the fixed target
    of :func:`fixed_target`): one unbent surface has no bending or stretch for a scale to absorb,
    and there the rotations-only descent was more accurate (random relief sheets remeshed at 800-3000 vertices,
    rotated and scaled: median errors 0.0003-0.0030 of the diameter with scales against 0.0002-0.0019 without).

    Parameters
    ----------
    first, second, second_area
        As for :class:`~meshreg.objective.Objective`.
    window : float
        Width of the windows, in side lengths of the square.
    scaled : bool
        Each cell under its own rotation and scale (default), or the rotations-only E_w.
    """

    def __init__(self, first, second, second_area: float | None = None, *, window: float, scaled: bool = True):
        super().__init__(first, second, second_area)
        self.shape_q1 = self.q1
        self._win = Window(self.r, self.t, window)
        self._wide = Window(self.r, self.t, SCALE_WIDTH * window) if scaled else None

    def _fitted(self, h: np.ndarray) -> dict:
        """E_w(h) and the target of the fixed-target energy at h (the cells' fitted similarities, or the averaged
        rotations, applied to q1), kept with the second surface's values at h (the descent asks for the energy of
        an accepted step and then linearizes at the same h: one fit serves both)."""
        last = self._at(h)
        if "target" not in last:
            if self._wide is None:
                last["energy"], rotations = local_rotations(self.shape_q1, self.q2(h), self._win)
                last["target"] = fixed_target(self.shape_q1, rotations, self._win)
            else:
                last["energy"], fitted = local_similarities(self.shape_q1, self.q2(h), self._win, self._wide)
                last["target"] = cell_target(self.shape_q1, fitted)
        return last

    def energy(self, rotation: np.ndarray, h: np.ndarray) -> float:
        """E_w(h) (the rotation is absorbed by the similarity field)."""
        return self._fitted(h)["energy"]

    def _targeted(self, h: np.ndarray) -> float:
        """Refresh the target from h (the fixed-target energy's q1); returns E_w(h)."""
        last = self._fitted(h)
        self.q1 = last["target"]
        return last["energy"]

    def best_rotation_covariance(self, h: np.ndarray) -> np.ndarray:
        """A covariance whose Kabsch rotation is the identity (the similarity field needs no global rotation)."""
        return np.eye(3)

    def gradient(self, rotation: np.ndarray, h: np.ndarray, dh_dr: np.ndarray, dh_dt: np.ndarray):
        """E_w(h) and the derivative density of the fixed-target energy along fields composed on h (the similarity
        field held at its fit at h)."""
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
