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

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg
import scipy.sparse as sp
import scipy.sparse.linalg  # noqa: F401  (sp.linalg)
from scipy.spatial.transform import Rotation

from .banded import banded_system
from .diffeo import enforce_boundary, is_valid, largest_step
from .fields import TensorBasis, riseth_basis
from .normal_system import NodeSystem
from .objective import Objective
from .options import StepParams
from .spline import GridInterpolator

DENSE_LIMIT = 2000
ROTATION_UNKNOWNS = 3  # the last unknowns of every step (omega), coupled with all others
# an additive (node) step that would fold h is shortened to this fraction of the largest step that does not, before
# the damping grows: each growth of the damping costs another solve of the normal equations (on the paper's pairs at
# 101 x 101, 10 of the node level's 16 solves were such re-solves)
FOLD_FRACTION = 0.9
_UNIT_R = np.array([1.0, 0.0])
_UNIT_T = np.array([0.0, 1.0])


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


@dataclass
class DescentState:
    """h, its energy, the rotation (when the solver moves it) and the accepted energies."""

    h: np.ndarray
    energy: float
    rotation: np.ndarray | None = None
    history: list = field(default_factory=list)
    iterations: int = 0


def _accept(state: DescentState, h, rotation, energy: float, params: StepParams, callback) -> bool:
    """Record an accepted step; True when the decrease was too small to go on."""
    previous = state.energy
    state.h, state.rotation, state.energy = h, rotation, energy
    state.history.append(energy)
    state.iterations += 1
    if callback is not None:
        callback(state.iterations, energy)
    return previous - energy < params.rel_tol * previous + params.abs_tol


def descend(
    objective: Objective,
    rotation: np.ndarray,
    h: np.ndarray,
    params: StepParams | None = None,
    basis: TensorBasis | None = None,
    callback: Callable[[int, float], None] | None = None,
) -> DescentState:
    """One round of gradient descent in h for a fixed rotation (Step 2 of the outline).

    Parameters
    ----------
    objective : Objective
    rotation : ndarray, shape (3, 3)
    h : ndarray, shape (M, N, 2)
        Starting reparametrization h^(0) (valid).
    params : StepParams
    basis : TensorBasis, optional
        The fields to descend along; default the Riseth basis with KL = ``params.basis``.
    callback : callable, optional
        Called as ``callback(iteration, E)`` after every accepted step.

    Returns
    -------
    DescentState
        The last h, E(h, R) (never above the starting E) and the accepted energies.
    """
    params = params or StepParams()
    basis = basis or riseth_basis(params.basis, objective.r, objective.t)
    ident = objective.identity
    state = DescentState(h.copy(), objective.energy(rotation, h))
    state.history.append(state.energy)
    for _ in range(params.max_iterations):
        if state.energy <= params.zero_energy:
            break
        interp = GridInterpolator(state.h, objective.r, objective.t)
        _, dh_dr, dh_dt = interp(ident[..., 0], ident[..., 1])
        _, density = objective.gradient(rotation, state.h, dh_dr, dh_dt)
        coef = basis.project(density)
        if np.linalg.norm(coef) < params.grad_tol:
            break
        field_, jac = basis.synthesize(coef)
        bound = max_step(jac)
        if not np.isfinite(bound):
            break
        delta = params.step_fraction * bound
        accepted = None
        for _ in range(params.max_backtracks):
            g = enforce_boundary(ident - delta * field_)
            candidate = enforce_boundary(interp.values(g[..., 0], g[..., 1]))
            if is_valid(candidate):
                e = objective.energy(rotation, candidate)
                if e < state.energy:
                    if objective.within_stretch(candidate, params.max_stretch):
                        accepted = (candidate, e)
                    break  # E drops only by stretching beyond the bound: the round ends
            delta *= 0.5
        if accepted is None or _accept(state, accepted[0], rotation, accepted[1], params, callback):
            break
    return state


def gauss_newton(
    objective: Objective,
    rotation: np.ndarray,
    h: np.ndarray,
    params: StepParams | None = None,
    basis: TensorBasis | None = None,
    callback: Callable[[int, float], None] | None = None,
    additive: bool = False,
    stretch_masks: int = 0,
    area_charge: float = 0.0,
) -> DescentState:
    """Joint descent in h and R along Gauss-Newton directions (Levenberg-Marquardt).

    E is a sum of squares, ``|res|^2``. The step (v = sum c_i w_i, omega) solves
    ``(J^T J + lam diag(J^T J)) x = -J^T res``, where the columns of J are the derivatives of res
    along the basis fields (the directional derivatives of Theorem 2) and along the three
    infinitesimal rotations of R q1; so it is the paper's gradient preconditioned by the
    Gauss-Newton metric, with R moving at the same time instead of only in Kabsch steps. The
    update is h o (id + delta v) with delta = 1 capped by ``step_fraction`` times the
    det / Gale-Nikaido bound, and R <- exp([omega]x) R; lam grows while E does not drop or h stops
    being valid. With ``additive=True`` the update of h is h + v instead (no interpolation of h,
    so that local fields move single nodes exactly), shortened when it folds h
    (:data:`FOLD_FRACTION`), and, with ``stretch_masks`` > 0, dropped at the nodes of the edges it stretches beyond
    the bound (:func:`_held`). With ``area_charge`` = k > 0, a step must also lower E + k (1 - A), E charged k
    times the share of the second surface's area that the chords of its cells lose
    (:meth:`~meshreg.objective.Objective.carried_area`): one that lowers E mostly by hiding area ends the round,
    as one beyond the stretch bound does. Other arguments as for :func:`descend`.

    Returns
    -------
    DescentState
        With ``rotation`` set to the final R.
    """
    params = params or StepParams()
    basis = basis or riseth_basis(params.basis, objective.r, objective.t)
    fields = basis.matrix()
    ident = objective.identity
    state = DescentState(h.copy(), objective.energy(rotation, h), rotation=rotation.copy())
    state.history.append(state.energy)
    area = area_charge * objective.carried_area(h) if area_charge else 0.0  # k A of state.h
    lam = params.damping
    for _ in range(params.max_iterations):
        if state.energy <= params.zero_energy:
            break
        if additive:
            dh_dr, dh_dt = _UNIT_R, _UNIT_T
        else:
            interp = GridInterpolator(state.h, objective.r, objective.t)
            _, dh_dr, dh_dt = interp(ident[..., 0], ident[..., 1])
        res, node_jac = objective.linearize(state.rotation, state.h, dh_dr, dh_dt)
        rot_jac = objective.rotation_jacobian(state.rotation)
        normal, rhs = _normal_equations(node_jac, basis, rot_jac, res)
        if 2 * np.linalg.norm(rhs) < params.grad_tol:
            break
        diag = normal.diagonal()
        scale = diag + 1e-12 * diag.sum() / (basis.size + 3)
        accepted = None
        solve = _solver(normal, rhs, params.cg_iterations)
        for _ in range(params.max_backtracks):
            step = solve(lam * scale)
            within = None  # whether the candidate keeps the stretch bound, when already known
            if additive:
                candidate = _unfolded(state.h, (fields @ step[:-3]).reshape(state.h.shape))
                candidate, within = _held(objective, state.h, candidate, params.max_stretch, stretch_masks)
            else:
                field_, jac_v = basis.synthesize(step[:-3])
                delta = min(1.0, params.step_fraction * max_step(-jac_v))
                g = enforce_boundary(ident + delta * field_)
                candidate = enforce_boundary(interp.values(g[..., 0], g[..., 1]))
                candidate, within = _held(objective, state.h, candidate, params.max_stretch, stretch_masks)
            if is_valid(candidate):
                new_rotation = Rotation.from_rotvec(step[-3:]).as_matrix() @ state.rotation
                e = objective.energy(new_rotation, candidate)
                if e < state.energy:
                    new_area = area_charge * objective.carried_area(candidate) if area_charge else 0.0
                    if (objective.within_stretch(candidate, params.max_stretch) if within is None else within) and (
                        e - new_area < state.energy - area
                    ):
                        accepted, area = (candidate, new_rotation, e), new_area
                    break  # E drops only by stretching beyond the bound: the round ends (no damping finds more)
            lam = max(lam, 1e-6) * 4.0
        if accepted is None or _accept(state, *accepted, params, callback):
            break
        lam = max(lam / 3.0, 1e-9)
    return state


def _unfolded(h: np.ndarray, field_: np.ndarray) -> np.ndarray:
    """h + s v: s = 1 when that keeps h valid, else FOLD_FRACTION of the largest step that does."""
    candidate = enforce_boundary(h + field_)
    if is_valid(candidate):
        return candidate
    step = FOLD_FRACTION * largest_step(h, field_)
    return enforce_boundary(h + step * field_) if step < 1.0 else candidate


def _held(objective: Objective, h: np.ndarray, candidate: np.ndarray, max_stretch: float, masks: int):
    """``candidate`` (h moved node by node) with the move dropped at both nodes of every edge that it stretches
    beyond ``max_stretch`` (:meth:`~meshreg.objective.Objective.over_stretch`), ``masks`` times at most (dropping
    moves changes the stretch of the neighbouring edges): the rest of the grid still moves when a few edges would
    stretch too far, instead of the whole step being refused.

    Returns the candidate and whether it keeps the bound (None, without looking, when ``masks`` is 0).
    """
    if masks == 0 or not np.isfinite(max_stretch):
        return candidate, None
    moving = np.ones(h.shape[:2], dtype=bool)
    for dropped in range(masks + 1):
        along_r, along_t = objective.over_stretch(candidate, max_stretch)
        if not (along_r.any() or along_t.any()):
            return candidate, True
        if dropped == masks:
            return candidate, False
        moving[:-1] &= ~along_r
        moving[1:] &= ~along_r
        moving[:, :-1] &= ~along_t
        moving[:, 1:] &= ~along_t
        candidate = np.where(moving[..., None], candidate, h)


def _normal_equations(node_jac, basis: TensorBasis, rot_jac: np.ndarray, res: np.ndarray):
    """J^T J and -J^T res for J = [node_jac @ fields, rot_jac] (node_jac: :class:`CellJacobian`; fields: the columns
    of ``basis.matrix()``).

    For local (sparse) fields J is not formed: J^T J goes through node_jac^T node_jac, assembled from
    per-cell blocks on a cached pattern, then onto the fields (:meth:`~meshreg.fields.TensorBasis.normal_matrix`).
    For the node basis (``selection``: fields = columns of the identity) beyond ``DENSE_LIMIT`` unknowns it is a
    :class:`~meshreg.normal_system.NodeSystem` (solved by CG), whose right-hand side is on all node values.
    """
    fields, selection = basis.matrix(), basis.selection
    if not sp.issparse(fields):
        normal, rhs = node_jac.normal_dense(fields, rot_jac, res, basis.row_ranges())
        return normal, -rhs
    if selection is not None and len(selection) + 3 > DENSE_LIMIT:
        system = NodeSystem(node_jac, rot_jac, res, selection)
        return system, system.rhs
    nn = node_jac.gram()
    nr = node_jac.rmatvec(rot_jac)
    g_nodes = node_jac.rmatvec(res)
    corner = rot_jac.T @ rot_jac
    if selection is None:
        normal = np.empty((basis.size + 3, basis.size + 3))
        basis.normal_matrix(nn, node_jac.pattern.shape[1], out=normal[:-3, :-3])
        normal[:-3, -3:] = fields.T @ nr
        normal[-3:, :-3] = normal[:-3, -3:].T
        normal[-3:, -3:] = corner
        return normal, -np.concatenate([fields.T @ g_nodes, rot_jac.T @ res])
    # fields = columns of the identity: select instead of multiplying
    fr, top = nr[selection], nn[selection][:, selection]
    normal = sp.bmat([[top, sp.csr_matrix(fr)], [sp.csr_matrix(fr.T), sp.csr_matrix(corner)]], format="csr")
    return normal, -np.concatenate([g_nodes[selection], rot_jac.T @ res])


def _solver(normal, rhs: np.ndarray, cg_iterations: int):
    """``solve(shift)``: x with (normal + diag(shift)) x = rhs (symmetric positive definite), x on the basis'
    coefficients and R; what does not depend on the shift is prepared once (the damping loop tries several).

    Up to ``DENSE_LIMIT`` unknowns by Cholesky (banded after reordering where the fields couple locally:
    :func:`~meshreg.banded.banded_system`); beyond (the node basis, a :class:`NodeSystem`; a global basis of
    KL >= 23, dense), by Jacobi-preconditioned CG stopped after ``cg_iterations``: the result is only a
    Gauss-Newton step, which the energy test accepts or rejects, so an inexact solve is enough.
    """
    if isinstance(normal, NodeSystem):
        return lambda shift: normal.solve(shift, cg_iterations)
    if normal.shape[0] > DENSE_LIMIT:
        return lambda shift: _cg(normal, shift, rhs, cg_iterations)
    dense = normal.toarray() if sp.issparse(normal) else normal
    banded = banded_system(dense, ROTATION_UNKNOWNS)

    def solve(shift: np.ndarray) -> np.ndarray:
        try:
            if banded is not None:
                return banded.solve(shift, rhs)
            return scipy.linalg.cho_solve(scipy.linalg.cho_factor(dense + np.diag(shift)), rhs)
        except np.linalg.LinAlgError:
            return np.linalg.lstsq(dense + np.diag(shift), rhs, rcond=None)[0]

    return solve


def _cg(normal, shift: np.ndarray, rhs: np.ndarray, cg_iterations: int) -> np.ndarray:
    """x with (normal + diag(shift)) x = rhs by Jacobi-preconditioned CG, at most ``cg_iterations``."""
    if sp.issparse(normal):
        matrix = (normal + sp.diags(shift)).tocsr()
    else:
        matrix = np.array(normal)
        matrix[np.diag_indices_from(matrix)] += shift
    x, _ = sp.linalg.cg(matrix, rhs, M=sp.diags(1.0 / matrix.diagonal()), maxiter=cg_iterations, rtol=1e-10)
    return x
