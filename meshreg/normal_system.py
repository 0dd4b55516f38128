"""The Gauss-Newton normal equations of the node level and the conjugate-gradient solver of the large ones.

The node level moves every free node value of h (the node basis, :func:`meshreg.fields.node_basis`) and R: its
normal matrix is J^T J of the cell residuals on the free node values, bordered by the three rotation unknowns.
:class:`NodeSystem` keeps it on all 2 M N node values (the fixed boundary values masked to zero) so that J^T J
is used on the pattern it is assembled on, instead of copying out the free rows and columns and stacking the
border onto them (at 401 x 401 that copying took as long as assembling J^T J).
"""

from __future__ import annotations

import numba
import numpy as np

from .cell_jacobian import CellJacobian

CG_RTOL = 1e-10  # CG stops when the residual is below this fraction of the right-hand side's norm (rarely before)


class NodeSystem:
    """``[[J^T J, J^T Jr], [Jr^T J, Jr^T Jr]]`` on the free node values and the rotation, and ``-[J, Jr]^T res``.

    Parameters
    ----------
    node_jac : CellJacobian
        J, the derivatives of the cell residuals along the 2 M N node values.
    rot_jac : ndarray, shape (3 cells, 3)
        Jr, the derivatives along the infinitesimal rotations.
    res : ndarray, shape (3 cells,)
    selection : ndarray of int
        The free node values (indices into the 2 M N), in the order of the basis' coefficients.

    Attributes
    ----------
    rhs : ndarray, shape (2 M N + 3,)
        ``-[J, Jr]^T res``, 0 at the fixed node values.
    """

    def __init__(self, node_jac: CellJacobian, rot_jac: np.ndarray, res: np.ndarray, selection: np.ndarray):
        self.selection = selection
        self.free = np.zeros(node_jac.shape[1])
        self.free[selection] = 1.0
        self.nodes = node_jac.gram(upper=True)  # symmetric: the matrix-vector product reads half the entries
        self.border = node_jac.rmatvec(rot_jac) * self.free[:, None]
        self.corner = rot_jac.T @ rot_jac
        self.rhs = -np.concatenate([node_jac.rmatvec(res) * self.free, rot_jac.T @ res])

    def diagonal(self) -> np.ndarray:
        """The diagonal (0 at the fixed node values)."""
        return np.concatenate([self.nodes.diagonal() * self.free, np.diag(self.corner)])

    def solve(self, shift: np.ndarray, max_iterations: int) -> np.ndarray:
        """(normal + diag(shift)) x = rhs by Jacobi-preconditioned CG (:func:`_conjugate_gradients`); x on the
        free node values (the basis' coefficients) and the rotation."""
        diagonal = self.diagonal() + shift
        inverse = np.divide(1.0, diagonal, out=np.zeros_like(diagonal), where=np.r_[self.free, 1, 1, 1] > 0)
        matrix = self.nodes
        x = _conjugate_gradients(
            matrix.indptr.view(np.uint32),  # unsigned: numba then skips the test for negative indices (2x faster)
            matrix.indices.view(np.uint32),
            matrix.data,
            self.border,
            self.corner,
            self.free,
            shift,
            inverse,
            self.rhs,
            max_iterations,
            CG_RTOL,
        )
        return np.concatenate([x[:-3][self.selection], x[-3:]])


@numba.njit(cache=True)
def _matvec(indptr, indices, data, border, corner, free, shift, x, out):
    """out = ([[N, B], [B^T, C]] + diag(shift)) x, N symmetric given by its upper triangle (CSR, each row's
    diagonal first), the rows of N masked by ``free`` (x is 0 where free is 0)."""
    size = len(indptr) - 1
    x0, x1, x2 = x[size], x[size + 1], x[size + 2]
    r0, r1, r2 = 0.0, 0.0, 0.0
    out[:size] = 0.0
    for row in range(size):
        xr = x[row]
        start = indptr[row]
        s = out[row] + data[start] * xr + border[row, 0] * x0 + border[row, 1] * x1 + border[row, 2] * x2
        for k in range(start + 1, indptr[row + 1]):
            j = indices[k]
            s += data[k] * x[j]
            out[j] += data[k] * xr
        out[row] = s * free[row] + shift[row] * xr
        r0 += border[row, 0] * xr
        r1 += border[row, 1] * xr
        r2 += border[row, 2] * xr
    out[size] = r0 + corner[0, 0] * x0 + corner[0, 1] * x1 + corner[0, 2] * x2 + shift[size] * x0
    out[size + 1] = r1 + corner[1, 0] * x0 + corner[1, 1] * x1 + corner[1, 2] * x2 + shift[size + 1] * x1
    out[size + 2] = r2 + corner[2, 0] * x0 + corner[2, 1] * x1 + corner[2, 2] * x2 + shift[size + 2] * x2


@numba.njit(cache=True)
def _conjugate_gradients(indptr, indices, data, border, corner, free, shift, inverse, rhs, max_iterations, rtol):
    """Preconditioned CG (preconditioner diag(inverse)) on the bordered system of :func:`_matvec`; stops after
    ``max_iterations`` or when |residual| < rtol |rhs|."""
    x = np.zeros_like(rhs)
    residual = rhs.copy()
    direction = inverse * residual
    product = np.empty_like(rhs)
    rz = residual @ direction
    stop = (rtol * rtol) * (rhs @ rhs)
    for _ in range(max_iterations):
        _matvec(indptr, indices, data, border, corner, free, shift, direction, product)
        curvature = direction @ product
        if rz <= 0.0 or curvature <= 0.0:
            break
        alpha = rz / curvature
        rr, rz_new = 0.0, 0.0
        for i in range(len(x)):
            x[i] += alpha * direction[i]
            residual[i] -= alpha * product[i]
            rr += residual[i] * residual[i]
            rz_new += residual[i] * inverse[i] * residual[i]
        if rr < stop:
            break
        beta, rz = rz_new / rz, rz_new
        for i in range(len(x)):
            direction[i] = inverse[i] * residual[i] + beta * direction[i]
    return x
