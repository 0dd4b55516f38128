"""Gradient descent over reparametrizations of the square (Step 2 of the paper's outline).

At iteration k the gradient of H_k+1 (E along fields composed on the right of h^(k)) is expanded in
the orthonormal L^2 basis of Riseth, truncated at KL (2 (KL + 2 KL^2) fields, 110 for KL = 5). The
update is h_k+1 = id - delta grad H, h^(k+1) = h^(k) o h_k+1, where delta is a fraction of the
largest step keeping det(I - delta A) > 0 and the Gale-Nikaido minors 1 - delta a11, 1 - delta a22
positive on the grid (A is the Jacobian of grad H), halved while E does not drop or the new h
is not a valid reparametrization.

References
----------
Bernal & Lawrence, Section 4: Theorem 2, the basis B, the outline's Step 2 and the step-size rule;
Riseth, "Elastic shape analysis of surfaces" (the basis).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from .diffeo import enforce_boundary, is_valid
from .objective import Objective
from .spline import GridInterpolator

DEFAULT_BASIS = 5


class RisethBasis:
    """The L^2-orthonormal basis of vector fields tangent to the square's sides, truncated at KL.

    First components: (eta(r, t), 0) with eta = sqrt2 sin(pi k r), 2 sin(pi k r) cos(2 pi l t),
    2 sin(pi k r) sin(2 pi l t), k, l = 1..KL; second components: (0, eta(t, r)). Every field is
    separable, so projections and syntheses are small matrix products.

    Parameters
    ----------
    kl : int
        KL (>= 1).
    r : ndarray, shape (M,)
    t : ndarray, shape (N,)

    Examples
    --------
    >>> import numpy as np
    >>> RisethBasis(5, np.linspace(0, 1, 11), np.linspace(0, 1, 11)).size
    110
    """

    def __init__(self, kl: int, r: np.ndarray, t: np.ndarray):
        if kl < 1:
            raise ValueError("the basis size KL must be at least 1")
        self.kl = kl
        self.size = 2 * (kl + 2 * kl * kl)
        self.phi_r, self.dphi_r = self._sines(r)
        self.phi_t, self.dphi_t = self._sines(t)
        self.psi_r, self.dpsi_r = self._fourier(r)
        self.psi_t, self.dpsi_t = self._fourier(t)

    def _sines(self, x):
        k = np.pi * np.arange(1, self.kl + 1)
        return np.sqrt(2) * np.sin(np.outer(x, k)), np.sqrt(2) * k * np.cos(np.outer(x, k))

    def _fourier(self, x):
        w = 2 * np.pi * np.arange(1, self.kl + 1)
        c, s = np.cos(np.outer(x, w)), np.sin(np.outer(x, w))
        one = np.ones((len(x), 1))
        zero = np.zeros((len(x), 1))
        values = np.hstack([one, np.sqrt(2) * c, np.sqrt(2) * s])
        derivs = np.hstack([zero, -np.sqrt(2) * w * s, np.sqrt(2) * w * c])
        return values, derivs

    def project(self, density: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Directional derivatives along every basis field from a node density G (M, N, 2).

        Returns the coefficients of the first-component fields (KL, 2KL+1) and of the
        second-component fields (2KL+1, KL).
        """
        g1 = self.phi_r.T @ density[..., 0] @ self.psi_t
        g2 = self.psi_r.T @ density[..., 1] @ self.phi_t
        return g1, g2

    def synthesize(self, g1: np.ndarray, g2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The field sum g_i w_i at the nodes (M, N, 2) and its Jacobian A (M, N, 2, 2)."""
        v1 = self.phi_r @ g1 @ self.psi_t.T
        v2 = self.psi_r @ g2 @ self.phi_t.T
        jac = np.empty(v1.shape + (2, 2))
        jac[..., 0, 0] = self.dphi_r @ g1 @ self.psi_t.T
        jac[..., 0, 1] = self.phi_r @ g1 @ self.dpsi_t.T
        jac[..., 1, 0] = self.dpsi_r @ g2 @ self.phi_t.T
        jac[..., 1, 1] = self.psi_r @ g2 @ self.dphi_t.T
        return np.stack([v1, v2], axis=-1), jac


def max_step(jac: np.ndarray) -> float:
    """Largest delta keeping det(I - delta A) > 0 and 1 - delta a11, 1 - delta a22 > 0 at all nodes.

    Parameters
    ----------
    jac : ndarray, shape (..., 2, 2)
        A, the Jacobian of the gradient field.

    Returns
    -------
    float
        The bound (``inf`` when no node limits the step).
    """
    a = jac[..., 0, 0] * jac[..., 1, 1] - jac[..., 0, 1] * jac[..., 1, 0]
    b = -(jac[..., 0, 0] + jac[..., 1, 1])
    bound = np.full(a.shape, np.inf)
    small = np.abs(a) < 1e-12 * (1.0 + b * b)
    lin = small & (b < 0)
    bound[lin] = -1.0 / b[lin]
    quad = ~small
    disc = b * b - 4.0 * a
    real = quad & (disc >= 0)
    sq = np.sqrt(np.where(real, disc, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        roots = np.stack([(-b - sq) / (2 * a), (-b + sq) / (2 * a)])
    roots = np.where(real & (roots > 0), roots, np.inf)
    bound = np.minimum(bound, roots.min(axis=0))
    for diag in (jac[..., 0, 0], jac[..., 1, 1]):
        pos = diag > 0
        bound[pos] = np.minimum(bound[pos], 1.0 / diag[pos])
    return float(bound.min())


@dataclass(frozen=True)
class DescentParams:
    """Numerical parameters of the gradient descent.

    Attributes
    ----------
    basis : int
        KL; the gradient is expanded in 2 (KL + 2 KL^2) fields. Default 5 (110 fields).
    max_iterations : int
        Most descent iterations per round (between two Kabsch steps). Default 200.
    rel_tol : float
        A round stops when an iteration lowers E by less than ``rel_tol * E``. Default 1e-4.
    grad_tol : float
        A round stops when the L^2 norm of the gradient is below this. Default 1e-10.
    zero_energy : float
        E at or below this is "equal or close to zero": stop. Default 1e-12.
    step_fraction : float
        delta starts at this fraction of the Jacobian/Gale-Nikaido bound. Default 0.5.
    max_backtracks : int
        Most halvings of delta in one iteration before the round stops. Default 30.
    """

    basis: int = DEFAULT_BASIS
    max_iterations: int = 200
    rel_tol: float = 1e-4
    grad_tol: float = 1e-10
    zero_energy: float = 1e-12
    step_fraction: float = 0.5
    max_backtracks: int = 30


@dataclass
class DescentState:
    """h, its energy and the history of accepted energies during a descent."""

    h: np.ndarray
    energy: float
    history: list = field(default_factory=list)
    iterations: int = 0


def descend(
    objective: Objective,
    rotation: np.ndarray,
    h: np.ndarray,
    params: DescentParams = DescentParams(),
    basis: RisethBasis | None = None,
    callback: Callable[[int, float], None] | None = None,
) -> DescentState:
    """One round of gradient descent in h for a fixed rotation (Step 2 of the outline).

    Parameters
    ----------
    objective : Objective
    rotation : ndarray, shape (3, 3)
    h : ndarray, shape (M, N, 2)
        Starting reparametrization h^(0) (valid).
    params : DescentParams
    basis : RisethBasis, optional
        Reused across rounds when given.
    callback : callable, optional
        Called as ``callback(iteration, E)`` after every accepted step.

    Returns
    -------
    DescentState
        The last h, E(h, R) (never above the starting E) and the accepted energies.
    """
    basis = basis or RisethBasis(params.basis, objective.r, objective.t)
    ident = objective.identity
    state = DescentState(h.copy(), objective.energy(rotation, h))
    state.history.append(state.energy)
    for _ in range(params.max_iterations):
        if state.energy <= params.zero_energy:
            break
        interp = GridInterpolator(state.h, objective.r, objective.t)
        _, dh_dr, dh_dt = interp(ident[..., 0], ident[..., 1])
        _, density = objective.gradient(rotation, state.h, dh_dr, dh_dt)
        g1, g2 = basis.project(density)
        if np.sqrt(np.sum(g1 * g1) + np.sum(g2 * g2)) < params.grad_tol:
            break
        field_, jac = basis.synthesize(g1, g2)
        bound = max_step(jac)
        if not np.isfinite(bound):
            break
        delta = params.step_fraction * bound
        accepted = None
        for _ in range(params.max_backtracks):
            g = enforce_boundary(ident - delta * field_)
            candidate = enforce_boundary(interp(g[..., 0], g[..., 1])[0])
            if is_valid(candidate):
                e = objective.energy(rotation, candidate)
                if e < state.energy:
                    accepted = (candidate, e)
                    break
            delta *= 0.5
        if accepted is None:
            break
        previous = state.energy
        state.h, state.energy = accepted
        state.history.append(state.energy)
        state.iterations += 1
        if callback is not None:
            callback(state.iterations, state.energy)
        if previous - state.energy < params.rel_tol * previous:
            break
    return state
