"""The paper's analytic test surfaces and perturbations, and the ten registration pairs of its tables.

Each surface kind has a type 2 (the first surface of a pair) and a type 1 = P (type 2) with
P = [[0, 1, 0], [0, 0, 1], [1, 0, 0]]. The second surface of a pair is a type 1 surface sampled at
gamma(r_i, t_j): ``c2(r_i, t_j) = c2_hat(gamma(r_i, t_j))``, so for same-shape pairs the true answer is
R = P and h = gamma^-1.

References
----------
Bernal & Lawrence, Section 5 (surfaces of the sine, helicoid and cosine-sine kind; gamma = (r^5/4, t)
and (r^5/4, t^5/4)).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .grid import GridSurface

P = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])

Param = Callable[[np.ndarray, np.ndarray], np.ndarray]


def sine(k: int) -> Param:
    """Type 2 sine surface (sin k pi r, r, t)."""
    return lambda r, t: np.stack([np.sin(k * np.pi * r), r, t], axis=-1)


def helicoid(k: int) -> Param:
    """Type 2 helicoid (k pi t, r cos k pi t, r sin k pi t)."""
    return lambda r, t: np.stack([k * np.pi * t, r * np.cos(k * np.pi * t), r * np.sin(k * np.pi * t)], axis=-1)


def cos_sin() -> Param:
    """Type 2 cosine-sine surface (cos(pi r / 2) sin(pi t / 2), r, t)."""
    return lambda r, t: np.stack([np.cos(0.5 * np.pi * r) * np.sin(0.5 * np.pi * t), r, t], axis=-1)


def type1(c: Param) -> Param:
    """The type 1 surface of a kind: P applied to the type 2 surface."""
    return lambda r, t: c(r, t) @ P.T


PERTURBATIONS: dict[str, tuple[Callable, Callable]] = {
    # name: (gamma, gamma^-1), each mapping (r, t) -> (r', t')
    "g1": (lambda r, t: (r**1.25, t), lambda r, t: (r**0.8, t)),
    "g2": (lambda r, t: (r**1.25, t**1.25), lambda r, t: (r**0.8, t**0.8)),
}


def bump() -> Param:
    """A graph with two Gaussian bumps and a tilt, not symmetric under any symmetry of the square."""
    return lambda r, t: np.stack(
        [
            r,
            t,
            0.6 * np.exp(-((r - 0.3) ** 2 + (t - 0.6) ** 2) / 0.05)
            - 0.3 * np.exp(-((r - 0.7) ** 2 + (t - 0.3) ** 2) / 0.02)
            + 0.2 * r,
        ],
        axis=-1,
    )


def saddle() -> Param:
    """A saddle z = (r - 1/2)(t - 1/3) with a cubic term (no symmetry of the square maps it to itself)."""
    return lambda r, t: np.stack([r, t, 1.5 * (r - 0.5) * (t - 0.33) + 0.4 * r**3], axis=-1)


def wave() -> Param:
    """A travelling wave z = 0.15 sin(2 pi (1.3 r + 0.7 t)) on a slightly sheared base."""
    return lambda r, t: np.stack([r + 0.2 * t, t, 0.15 * np.sin(2 * np.pi * (1.3 * r + 0.7 * t))], axis=-1)


def terrain(seed: int = 0, modes: int = 6) -> Param:
    """A smooth random terrain: a sum of ``modes`` random Fourier modes with decaying amplitudes."""
    rng = np.random.default_rng(seed)
    freq = rng.uniform(0.5, 3.0, size=(modes, 2))
    phase = rng.uniform(0, 2 * np.pi, size=modes)
    amp = 0.25 / (1 + np.arange(modes))
    return lambda r, t: np.stack(
        [
            r,
            t,
            sum(a * np.sin(2 * np.pi * (f[0] * r + f[1] * t) + p) for a, f, p in zip(amp, freq, phase, strict=True)),
        ],
        axis=-1,
    )


# height z(u, v) over the square centred at the origin (u = r - 1/2, v = t - 1/2) of each symmetric_sheet kind
_SHEET_HEIGHTS = {
    "none": lambda u, v: (
        (
            0.6 * np.exp(-((u + 0.2) ** 2 + (v - 0.1) ** 2) / 0.05)
            - 0.3 * np.exp(-((u - 0.2) ** 2 + (v + 0.2) ** 2) / 0.02)
        )
        + 0.2 * u
    ),
    "point": lambda u, v: 0.8 * u**3 + 0.5 * u * v**2 + 0.3 * v + 0.4 * np.sin(2 * np.pi * u) * np.exp(-(v**2) / 0.1),
    "axis": lambda u, v: 0.6 * np.exp(-(u**2 + (v - 0.15) ** 2) / 0.05) + 0.2 * v,
    "diagonal": lambda u, v: (
        0.6 * np.exp(-((u - 0.15) ** 2 + (v - 0.15) ** 2) / 0.05)
        - 0.3 * np.exp(-((u + 0.2) ** 2 + (v + 0.2) ** 2) / 0.02)
    ),
    "two-fold": lambda u, v: (
        0.5 * np.exp(-((u - 0.2) ** 2 + (v - 0.1) ** 2) / 0.03)
        + 0.5 * np.exp(-((u + 0.2) ** 2 + (v + 0.1) ** 2) / 0.03)
    ),
    "four-fold": lambda u, v: 0.6 * np.exp(-(u**2 + v**2) / 0.05),
}
SHEET_KINDS = tuple(_SHEET_HEIGHTS)


def symmetric_sheet(kind: str) -> Param:
    """A graph (u, v, z(u, v)) over the square centred at the origin with one kind of symmetry.

    ``"none"``: two different bumps and a tilt. ``"point"``: z odd, so c o rho = -c for the half turn rho of the
    square (a point reflection). ``"axis"``: a bump on the v axis, mirror symmetric across it. ``"diagonal"``:
    mirror symmetric across the diagonal u = v. ``"two-fold"``: two equal bumps, c o rho = S c with S the half
    turn about z. ``"four-fold"``: a centred bump, invariant under the quarter turns (and the mirrors) of the square.

    A mirror symmetry (point, axis, diagonal) gives a second match of zero E on the mirror image, never a second
    correspondence; a rotation symmetry (two-fold: one more, four-fold: three more) gives equally good
    correspondences (see :mod:`meshreg.alternatives`).
    """
    z = _SHEET_HEIGHTS[kind]
    return lambda r, t: np.stack([r - 0.5, t - 0.5, z(r - 0.5, t - 0.5)], axis=-1)


def warp(a: float = 0.08) -> Callable:
    """A non-separable smooth diffeomorphism of the square that keeps each side on itself (|a| < 0.2).

    gamma(r, t) = (r + a sin(pi r) sin(2 pi t), t + a sin(pi t) sin(2 pi r)).
    """
    return lambda r, t: (
        r + a * np.sin(np.pi * r) * np.sin(2 * np.pi * t),
        t + a * np.sin(np.pi * t) * np.sin(2 * np.pi * r),
    )


def sample(c: Param, m: int = 101, n: int = 101, gamma: Callable | None = None) -> GridSurface:
    """Sample ``c`` on a uniform m x n grid, at gamma(r_i, t_j) when gamma is given."""
    r, t = np.meshgrid(np.linspace(0, 1, m), np.linspace(0, 1, n), indexing="ij")
    if gamma is not None:
        r, t = gamma(r, t)
    return GridSurface.from_array(c(r, t))


@dataclass(frozen=True)
class Pair:
    """A registration problem with what is known of its answer.

    Attributes
    ----------
    name : str
    first, second : GridSurface
    same_shape : bool
        Whether the true elastic distance is 0.
    rotation : ndarray (3, 3) or None
        True R for same-shape pairs.
    h_true : callable or None
        (r, t) -> h(r, t), the true reparametrization for same-shape pairs.
    exact_second : callable
        The analytic parametrization of the second surface, (r, t) -> points.
    paper : dict
        The paper's numbers for this pair: E after DP, after DP+GD, and GD alone; rotation after DP+GD.
    """

    name: str
    first: GridSurface
    second: GridSurface
    same_shape: bool
    rotation: np.ndarray | None
    h_true: Callable | None
    exact_second: Callable
    paper: dict


# (first kind, second kind, k2, perturbation): paper's E after DP, DP+GD, GD alone (Section 5).
_PAPER = {
    "sine2-2 g1": (0.00031, 0.00029, 0.25),
    "sine2-3 g1": (0.3479, 0.3421, 1.02),
    "sine2-4 g1": (0.3192, 0.3190, 0.7058),
    "sine2-2 g2": (0.0126, 0.00302, 0.32),
    "sine2-3 g2": (0.3565, 0.3493, 0.70),
    "sine2-4 g2": (0.3282, 0.3234, 0.6262),
    "helicoid4 g1": (0.00019, 0.00018, 0.11),
    "helicoid4 g2": (0.0796, 0.00876, 0.0943),
    "cossin g1": (0.00021, 0.00019, 0.47),
    "cossin g2": (0.0143, 0.0033, 0.4791),
}


def paper_pairs(m: int = 101, n: int = 101) -> list[Pair]:
    """The paper's ten pairs in its table order, on m x n uniform grids."""
    pairs = []
    for name, (e_dp, e_dpgd, e_gd) in _PAPER.items():
        kind, pert = name.split()
        if kind.startswith("sine"):
            k2 = int(kind[-1])
            c1, c2 = sine(2), type1(sine(k2))
            same = k2 == 2
        elif kind.startswith("helicoid"):
            c1, c2, same = helicoid(4), type1(helicoid(4)), True
        else:
            c1, c2, same = cos_sin(), type1(cos_sin()), True
        gamma, gamma_inv = PERTURBATIONS[pert]
        pairs.append(
            Pair(
                name=name,
                first=sample(c1, m, n),
                second=sample(c2, m, n, gamma),
                same_shape=same,
                rotation=P.copy() if same else None,
                h_true=(lambda r, t, g=gamma_inv: np.stack(g(r, t), axis=-1)) if same else None,
                exact_second=lambda r, t, c=c2, g=gamma: c(*g(r, t)),
                paper={"dp": e_dp, "dp+gd": e_dpgd, "gd": e_gd},
            )
        )
    return pairs
