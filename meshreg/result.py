"""The result of a registration and its file format (``result.npz``)."""

from __future__ import annotations

import json
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import InputError
from .files import write_atomic


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
        E after every accepted descent step and Kabsch step, starting from the initial E (in mode
        "gd", of the path kept; a scale-space path starts at E of the original pair at the end of the
        smoothed levels).
    r : ndarray, shape (M,)
    t : ndarray, shape (N,)
        The first surface's partitions.
    mode : str
    params : dict
        Every parameter that produced the result.
    timings : dict
        Seconds per stage (``search``, ``dp``, ``gd``, ``smoothing`` (mode "gd": the smoothed levels),
        ``refine``, ``total``).
    symmetry : int
        Index into :data:`meshreg.search.SQUARE_SYMMETRIES` of the symmetry of the square applied
        to the second surface first (0: none). h includes it: h = sigma o h', with h' the
        orientation-preserving reparametrization found for the symmetric copy, so h itself
        reverses orientation when sigma does.
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
    symmetry: int = 0

    @property
    def distance(self) -> float:
        """The elastic shape distance sqrt(E)."""
        return float(np.sqrt(max(self.energy, 0.0)))

    def apply(self, points: np.ndarray) -> np.ndarray:
        """Rotate points (..., 3) of the first surface by R."""
        return np.asarray(points) @ self.rotation.T

    def save(self, path, **extra) -> None:
        """Write the result to ``path`` (``.npz``; keys listed in docs/outputs.md), plus ``extra`` arrays, atomically
        (a temporary name in the same directory, then a rename); like numpy, ``.npz`` is appended to a path
        without it."""
        path = Path(path)
        if path.suffix != ".npz":
            path = path.with_name(path.name + ".npz")
        write_atomic(path, lambda tmp: self._save(tmp, **extra))

    def _save(self, path, **extra) -> None:
        np.savez(
            path,
            **extra,
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
            symmetry=self.symmetry,
        )

    @classmethod
    def load(cls, path) -> Registration:
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
                    symmetry=int(data["symmetry"]) if "symmetry" in data else 0,
                )
        except OSError as err:
            raise InputError(f"{path}: cannot read it ({err.strerror or err})") from None
        except (KeyError, ValueError, EOFError, zipfile.BadZipFile) as err:
            raise InputError(f"{path}: not a meshreg result file ({type(err).__name__}: {err})") from None
