"""The coordinate residual of a registration: how far the aligned first surface lies from the second, point by point.

E cannot tell a surface from its point reflection: ``q(-c) = q(c)`` for ``q = n / sqrt|n|``, ``n = c_u x c_v``.
So a correspondence whose aligned first surface sits on the point reflection of the second (a mirror image) can
reach E = 0 exactly as the right one does. The residual sees the difference: it is the area-weighted RMS of
``R c1 - c2 o h`` after centring both, on area-1 surfaces, and its twin against ``-(c2 o h)`` is small when
the match is mirrored.

Both are distances on surfaces of area 1, so 0.01 is 1% of sqrt(area): a residual well below the surfaces'
own size means the correspondence is right as a map of points, not only as a match of normals.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .srnf import cell_normals

# a match is mirrored when the aligned first surface is at most this fraction as far from the point reflection of
# the second as from the second: a same-shape mirror trap has a reflected residual near 0; two very different
# shapes are about equally far from both (0.85 and 0.86 measured on a sine sheet against a helicoid), and which of
# the two is smaller says nothing about orientation
MIRROR_RATIO = 0.5


@dataclass(frozen=True)
class Residual:
    """The coordinate residual of one correspondence and its mirror twin.

    Attributes
    ----------
    plus : float
        Area-weighted RMS of ``R c1 - c2 o h`` (both centred, area 1).
    minus : float
        The same against the point reflection: RMS of ``R c1 + c2 o h``.
    """

    plus: float
    minus: float

    @property
    def mirrored(self) -> bool:
        """Whether the aligned first surface sits on the point reflection of the second: at most MIRROR_RATIO
        times as far from it as from the second itself."""
        return is_mirrored(self.plus, self.minus)


def is_mirrored(plus: float, minus: float) -> bool:
    """The rule of :attr:`Residual.mirrored` for the two residuals."""
    return bool(minus < MIRROR_RATIO * plus)


def node_weights(points: np.ndarray) -> np.ndarray:
    """Area weights (M, N) of a grid surface's nodes, summing to 1: each cell's area shared by its four corners.

    Parameters
    ----------
    points : ndarray, shape (M, N, 3)
    """
    cells = np.linalg.norm(cell_normals(points), axis=-1)
    w = np.zeros(points.shape[:2])
    for di in (0, 1):
        for dj in (0, 1):
            w[di : w.shape[0] - 1 + di, dj : w.shape[1] - 1 + dj] += cells
    return w / w.sum()


def coordinate_residual(first: np.ndarray, second: np.ndarray, weights: np.ndarray) -> Residual:
    """The residual of corresponding points.

    Parameters
    ----------
    first : ndarray, shape (M, N, 3)
        The aligned first surface, ``R c1`` (area 1).
    second : ndarray, shape (M, N, 3)
        The second surface at the corresponding points, ``c2 o h`` (area 1).
    weights : ndarray, shape (M, N)
        Node weights summing to 1 (:func:`node_weights` of the first surface).

    Returns
    -------
    Residual

    Examples
    --------
    >>> import numpy as np
    >>> r = np.linspace(0, 1, 5)
    >>> c = np.stack([*np.meshgrid(r, r, indexing="ij"), np.outer(r, r) ** 2], axis=-1)
    >>> w = node_weights(c)
    >>> res = coordinate_residual(c, -c + 3.0, w)
    >>> bool(res.minus < 1e-12 < res.plus and res.mirrored)
    True
    """
    w = weights[..., None]
    a = first - np.sum(w * first, axis=(0, 1))
    b = second - np.sum(w * second, axis=(0, 1))
    plus = float(np.sqrt(np.sum(w * (a - b) ** 2)))
    minus = float(np.sqrt(np.sum(w * (a + b) ** 2)))
    return Residual(plus, minus)


def metric_residual(first: np.ndarray, second: np.ndarray) -> float:
    """How far two grid surfaces' first fundamental forms are apart at corresponding cells, relative to the first's:
    the RMS over cells of the difference of (E, F, G) = (c_u . c_u, c_u . c_v, c_v . c_v), by index steps, both
    surfaces scaled to area 1, over the RMS of the first's (F counted twice, as in the Frobenius norm of the form).

    The form is intrinsic: a surface bent without stretching keeps it, while its points move (its coordinate
    residual grows with the bend) and its normals turn. So among matches of one surface bent isometrically, the
    right correspondence has a metric residual near 0 however strong the bend; a match turned or slid along the
    surface compares its relief's slopes at the wrong places.

    Parameters
    ----------
    first, second : ndarray, shape (M, N, 3)
        Points at corresponding nodes (the second under the symmetry of the square being judged).

    Examples
    --------
    >>> import numpy as np
    >>> r = np.linspace(0.0, 1.0, 21)
    >>> u, v = np.meshgrid(r, r, indexing="ij")
    >>> flat = np.stack([u, v, 0.1 * np.sin(3 * u) * v], axis=-1)
    >>> bent = np.stack([np.sin(u), v, 1.0 - np.cos(u)], axis=-1)  # the plane rolled about an axis: no stretch
    >>> plane = np.stack([u, v, 0.0 * u], axis=-1)
    >>> metric_residual(plane, bent) < 0.01 < metric_residual(flat, bent)
    True
    """
    forms = []
    for points in (first, second):
        du = 0.5 * (points[1:, :-1] - points[:-1, :-1] + points[1:, 1:] - points[:-1, 1:])
        dv = 0.5 * (points[:-1, 1:] - points[:-1, :-1] + points[1:, 1:] - points[1:, :-1])
        form = np.stack([np.sum(du * du, -1), np.sum(du * dv, -1), np.sum(dv * dv, -1)], axis=-1)
        area = np.sum(np.linalg.norm(np.cross(du, dv), axis=-1))
        forms.append(form / area if area > 0 else np.full_like(form, np.nan))
    weight = np.array([1.0, 2.0, 1.0])
    own = np.sum(weight * forms[0] ** 2)
    return float(np.sqrt(np.sum(weight * (forms[0] - forms[1]) ** 2) / own)) if own > 0 else np.nan
