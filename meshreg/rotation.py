"""Rotations: Kabsch-Umeyama (KU3), proper rotations only.

References
----------
Bernal & Lawrence, Section 4, Step 3 of the outline (KU3 algorithm); Kabsch (1976), Umeyama (1991).
"""

from __future__ import annotations

import numpy as np

SCALE_FIT = 0.5  # a rotation whose least-squares scale falls below this share of the size ratio does not fit


def kabsch(h: np.ndarray) -> np.ndarray:
    """The rotation R (det +1) that maximizes trace(R H).

    With ``H = sum w q1 q2^T`` this R minimizes ``sum w |R q1 - q2|^2``.

    Parameters
    ----------
    h : ndarray, shape (3, 3)

    Returns
    -------
    R : ndarray, shape (3, 3)
        ``R = V diag(1, 1, d) U^T`` with ``H = U S V^T`` and ``d = sign det(V U^T)``: never a reflection.

    Examples
    --------
    >>> import numpy as np
    >>> P = np.array([[0., 1, 0], [0, 0, 1], [1, 0, 0]])
    >>> q1 = np.random.default_rng(0).normal(size=(50, 3))
    >>> R = kabsch(q1.T @ (q1 @ P.T))
    >>> bool(np.allclose(R, P))
    True
    """
    u, vt = _proper_factors(h)
    return vt.T @ u.T


def kabsch_stack(h: np.ndarray) -> np.ndarray:
    """:func:`kabsch` for a stack of matrices: the rotations (t, 3, 3) maximizing trace(R_k H_k), H (t, 3, 3).

    Examples
    --------
    >>> import numpy as np
    >>> h = np.random.default_rng(0).normal(size=(4, 3, 3))
    >>> bool(np.allclose(kabsch_stack(h), [kabsch(m) for m in h]))
    True
    """
    u, vt = _proper_factors(h)
    return np.einsum("nji,nkj->nik", vt, u)  # V U^T by einsum: matmul rounds differently, and the callers' bits stay


def _proper_factors(h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """U and V^T of the SVD ``H = U S V^T`` of a matrix or a stack of them (..., 3, 3), the last row of V^T negated
    where ``det(V U^T) < 0``: ``V^T U^T`` is then the rotation (never a reflection) that maximizes trace(R H)."""
    u, _, vt = np.linalg.svd(h)
    reflection = np.linalg.det(np.swapaxes(vt, -1, -2) @ np.swapaxes(u, -1, -2)) < 0
    vt[..., 2, :] *= np.where(reflection, -1.0, 1.0)[..., None]
    return u, vt


def angle_between(r1: np.ndarray, r2: np.ndarray) -> float | np.ndarray:
    """Angle in degrees of the rotation r1 r2^T (0 when r1 == r2); for stacks of rotations (..., 3, 3), which
    broadcast, the angles (...)."""
    c = (np.einsum("...ij,...ij->...", r1, r2) - 1.0) / 2.0  # trace(r1 r2^T)
    angle = np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))
    return float(angle) if np.ndim(angle) == 0 else angle


def similarity(rotation: np.ndarray, source: np.ndarray, target: np.ndarray) -> np.ndarray:
    """The similarity x -> s R x + b (4 x 4) with R = ``rotation`` fixed and s, b the least-squares fit of the
    points ``source`` (..., 3) onto their counterparts ``target`` (..., 3).

    When R does not fit the points (a strongly bent pair, or a rotation the shapes leave free, as a flat sheet's
    about its normal), the fitted s is negative, which would make the transform a reflection, or below
    :data:`SCALE_FIT` times the ratio of the two point sets' RMS radii, which would shrink the first surface
    towards a point (a flat sheet against a bumpy one: s = 0.014 for sheets of one size); R is then the best
    rotation for the points themselves (Kabsch)."""
    p, q = np.asarray(source, dtype=float).reshape(-1, 3), np.asarray(target, dtype=float).reshape(-1, 3)
    pc, qc = p - p.mean(axis=0), q - q.mean(axis=0)
    rp = pc @ rotation.T
    scale = float(np.sum(rp * qc) / np.sum(rp * rp))
    if not scale > SCALE_FIT * np.sqrt(np.sum(qc * qc) / np.sum(pc * pc)):
        rotation = kabsch(pc.T @ qc)
        rp = pc @ rotation.T
        scale = float(np.sum(rp * qc) / np.sum(rp * rp))
    out = np.eye(4)
    out[:3, :3] = scale * rotation
    out[:3, 3] = q.mean(axis=0) - scale * rotation @ p.mean(axis=0)
    return out
