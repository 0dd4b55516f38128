"""The registration pipeline: DP-surface-min, gradient descent and Kabsch, and its result.

Modes
-----
``"dp"``
    DP-surface-min alone (h = (gamma(r), t)), alternated with Kabsch.
``"gd"``
    Gradient descent from R = I and h = id, alternated with Kabsch (the paper's "without DP" runs).
``"dp+gd"``
    The paper's method: DP-surface-min, then gradient descent from its R and h, alternated with Kabsch.

References
----------
Bernal & Lawrence, Section 4 (Simplified Outline of Optimization Procedure, Steps 1-4).
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from .descent import DescentParams, RisethBasis, descend
from .dp import DEFAULT_DP_ROUNDS, DEFAULT_WINDOW, dp_surface_min
from .errors import InputError
from .grid import GridSurface, read_grid
from .objective import Objective
from .rotation import kabsch

MODES = ("dp", "gd", "dp+gd")
DEFAULT_MODE = "dp+gd"
DEFAULT_ROUNDS = 10
DEFAULT_ROUND_TOL = 1e-4

Progress = Callable[[str, int, float], None]


@dataclass(frozen=True)
class Registration:
    """The result of registering two surfaces.

    Attributes
    ----------
    rotation : ndarray, shape (3, 3)
        R, applied to the first surface (det +1).
    h : ndarray, shape (M, N, 2)
        h(r_i, t_j) in [0, 1]^2 at the first surface's nodes; the registered second surface is c2 o h.
    energy : float
        E(h, R) = int int |R q1 - (q2, h)|^2 with both surfaces at area 1 (the squared distance).
    energy_dp : float
        E after the DP stage (NaN when the mode has none).
    energy_history : ndarray, shape (K,)
        E after every accepted descent step and Kabsch step, starting from the initial E.
    r : ndarray, shape (M,)
    t : ndarray, shape (N,)
        The first surface's partitions.
    mode : str
    params : dict
        Every parameter that produced the result.
    timings : dict
        Seconds per stage (``dp``, ``gd``, ``total``).
    """

    rotation: np.ndarray
    h: np.ndarray
    energy: float
    energy_dp: float
    energy_history: np.ndarray
    r: np.ndarray
    t: np.ndarray
    mode: str
    params: dict = field(default_factory=dict)
    timings: dict = field(default_factory=dict)

    @property
    def distance(self) -> float:
        """The elastic shape distance sqrt(E)."""
        return float(np.sqrt(max(self.energy, 0.0)))

    def apply(self, points: np.ndarray) -> np.ndarray:
        """Rotate points (..., 3) of the first surface by R."""
        return np.asarray(points) @ self.rotation.T

    def save(self, path) -> None:
        """Write the result to ``path`` (``.npz``; keys as in architecture.md)."""
        np.savez(
            path,
            R=self.rotation,
            h=self.h,
            energy=self.energy,
            distance=self.distance,
            energy_dp=self.energy_dp,
            energy_history=self.energy_history,
            r=self.r,
            t=self.t,
            mode=self.mode,
            params=json.dumps(self.params),
            timings=json.dumps(self.timings),
        )

    @classmethod
    def load(cls, path) -> "Registration":
        """Read a result written by :meth:`save`."""
        try:
            with np.load(path, allow_pickle=False) as data:
                return cls(
                    rotation=data["R"],
                    h=data["h"],
                    energy=float(data["energy"]),
                    energy_dp=float(data["energy_dp"]),
                    energy_history=data["energy_history"],
                    r=data["r"],
                    t=data["t"],
                    mode=str(data["mode"]),
                    params=json.loads(str(data["params"])),
                    timings=json.loads(str(data["timings"])),
                )
        except (OSError, KeyError, ValueError) as err:
            raise InputError(f"{path}: not a meshreg result file ({err})") from None


def as_surface(surface) -> GridSurface:
    """A GridSurface from a GridSurface, an (M, N, 3) array, or a grid file path."""
    if isinstance(surface, GridSurface):
        return surface
    if isinstance(surface, (str, Path)):
        return read_grid(surface)
    return GridSurface.from_array(surface)


def register(
    first,
    second,
    mode: str = DEFAULT_MODE,
    *,
    window: int = DEFAULT_WINDOW,
    dp_rounds: int = DEFAULT_DP_ROUNDS,
    max_rounds: int = DEFAULT_ROUNDS,
    round_tol: float = DEFAULT_ROUND_TOL,
    descent: DescentParams | None = None,
    callback: Progress | None = None,
    **descent_params,
) -> Registration:
    """Register two grid surfaces: rotate the first, reparametrize the second.

    Parameters
    ----------
    first, second : GridSurface, ndarray (M, N, 3) or path
        The surfaces; grid sizes may differ. Both are scaled to area 1.
    mode : {"dp", "gd", "dp+gd"}
        See the module docstring. Default "dp+gd".
    window : int
        DP window W (steps (dk, dl) with 1 <= dk, dl <= W). Default 10.
    dp_rounds : int
        Most DP + Kabsch rounds. Default 10.
    max_rounds : int
        Most descent + Kabsch rounds (Step 3 of the outline). Default 10.
    round_tol : float
        Rounds stop when Kabsch lowers E by less than ``round_tol * E``. Default 1e-4.
    descent : DescentParams, optional
        Descent parameters; keyword arguments named like its fields (``basis``, ``rel_tol``, ...)
        override single fields.
    callback : callable, optional
        ``callback(stage, iteration, E)`` after every accepted step (stage "dp", "gd" or "kabsch").

    Returns
    -------
    Registration

    Examples
    --------
    >>> from meshreg.samples import paper_pairs
    >>> pair = paper_pairs(31, 31)[0]
    >>> result = register(pair.first, pair.second, mode="dp")
    >>> result.energy < 0.01
    True
    """
    if mode not in MODES:
        raise InputError(f"unknown mode {mode!r}: choose one of {', '.join(MODES)}")
    if window < 1:
        raise InputError("window must be a positive integer")
    descent = DescentParams(**{**asdict(descent or DescentParams()), **descent_params})
    start = time.perf_counter()
    objective = Objective(as_surface(first), as_surface(second))
    notify = callback or (lambda stage, iteration, e: None)
    timings = {}
    rotation, h = np.eye(3), objective.identity.copy()
    energy_dp = float("nan")
    history = []
    if "dp" in mode:
        tic = time.perf_counter()
        q2 = objective.second_on_first_grid()
        result = dp_surface_min(objective.q1, q2, objective.r, objective.r, objective.t, window=window, max_rounds=dp_rounds)
        rotation = result.rotation
        h[..., 0] = result.gamma[:, None]
        energy_dp = objective.energy(rotation, h)
        history.append(energy_dp)
        notify("dp", len(result.history), energy_dp)
        timings["dp"] = time.perf_counter() - tic
    if "gd" in mode:
        tic = time.perf_counter()
        rotation, h = _alternate(objective, rotation, h, descent, max_rounds, round_tol, history, notify)
        timings["gd"] = time.perf_counter() - tic
    energy = objective.energy(rotation, h)
    if not history:
        history.append(energy)
    timings["total"] = time.perf_counter() - start
    params = {
        "mode": mode,
        "window": window,
        "dp_rounds": dp_rounds,
        "max_rounds": max_rounds,
        "round_tol": round_tol,
        **asdict(descent),
        "grid_first": list(objective.first.shape),
        "grid_second": list(objective.second.shape),
    }
    return Registration(
        rotation=rotation,
        h=h,
        energy=energy,
        energy_dp=energy_dp,
        energy_history=np.array(history),
        r=objective.r,
        t=objective.t,
        mode=mode,
        params=params,
        timings=timings,
    )


def _alternate(objective, rotation, h, params, max_rounds, round_tol, history, notify):
    """Steps 2-3 of the outline: descent in h, then Kabsch in R, until Kabsch stops helping."""
    basis = RisethBasis(params.basis, objective.r, objective.t)
    energy = objective.energy(rotation, h)
    if not history:
        history.append(energy)
    for _ in range(max_rounds):
        state = descend(objective, rotation, h, params, basis, lambda i, e: (history.append(e), notify("gd", i, e)))
        h = state.h
        new_rotation = kabsch(objective.best_rotation_covariance(h))
        new_energy = objective.energy(new_rotation, h)
        if new_energy < state.energy:
            rotation = new_rotation
            history.append(new_energy)
            notify("kabsch", 0, new_energy)
        energy_before, energy = state.energy, min(new_energy, state.energy)
        if energy <= params.zero_energy or energy_before - energy < round_tol * energy_before:
            break
    return rotation, h
