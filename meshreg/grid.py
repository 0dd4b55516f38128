"""Grid surfaces: points sampled on a (possibly non-uniform) grid over the unit square.

A grid surface is ``points[i, j] = c(r[i], t[j])`` with axis 0 the r direction and axis 1 the t
direction, ``r`` and ``t`` increasing partitions of [0, 1] (inputs on other intervals are rescaled).

File formats read by :func:`read_grid`:

* ``.npy``: an array of shape (M, N, 3), uniform partitions.
* ``.npz``: key ``points`` of shape (M, N, 3), optional keys ``r`` (M,) and ``t`` (N,).
* text (any other suffix): the paper's format, one point ``x y z`` per line with r running fastest,
  i.e. the lines are c(r_1,t_1), c(r_2,t_1), ..., c(r_M,t_1), c(r_1,t_2), ...  The grid size comes
  from ``shape=(M, N)`` (the command line's ``--grid M N``) or from a first line holding the two
  integers ``M N``. Lines starting with ``#`` are ignored.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np

from .errors import InputError
from .spline import GridInterpolator

MIN_NODES = 3


def _partition(values, n: int, name: str) -> np.ndarray:
    """Validate a partition of length ``n`` and rescale it to [0, 1]."""
    if values is None:
        return np.linspace(0.0, 1.0, n)
    p = np.asarray(values, dtype=float).ravel()
    if p.shape != (n,):
        raise InputError(f"partition {name} has {p.size} values but the grid has {n} nodes along {name}")
    if not np.all(np.isfinite(p)):
        raise InputError(f"partition {name} contains NaN or infinite values")
    if np.any(np.diff(p) <= 0):
        raise InputError(f"partition {name} must be strictly increasing")
    return (p - p[0]) / (p[-1] - p[0])


@dataclass(frozen=True)
class GridSurface:
    """A surface sampled on a grid over the unit square.

    Parameters
    ----------
    points : ndarray, shape (M, N, 3)
        ``points[i, j] = c(r[i], t[j])``.
    r : ndarray, shape (M,)
        Increasing partition of [0, 1] (r direction, axis 0).
    t : ndarray, shape (N,)
        Increasing partition of [0, 1] (t direction, axis 1).

    Use :meth:`from_array` to build one from raw arrays with validation.

    Examples
    --------
    >>> import numpy as np
    >>> r = t = np.linspace(0, 1, 5)
    >>> R, T = np.meshgrid(r, t, indexing="ij")
    >>> s = GridSurface.from_array(np.stack([R, T, 0 * R], axis=-1))
    >>> round(s.area(), 6)
    1.0
    """

    points: np.ndarray
    r: np.ndarray
    t: np.ndarray

    @classmethod
    def from_array(cls, points, r=None, t=None) -> GridSurface:
        """Validate ``points`` (M, N, 3) and optional partitions; rescale partitions to [0, 1].

        Raises
        ------
        InputError
            On a wrong shape, a grid smaller than 3x3, NaN/inf values, bad partitions or zero area.
        """
        p = np.asarray(points, dtype=float)
        if p.ndim != 3 or p.shape[2] != 3:
            raise InputError(f"grid points must have shape (M, N, 3), got {p.shape}")
        m, n = p.shape[:2]
        if m < MIN_NODES or n < MIN_NODES:
            raise InputError(f"grid is {m}x{n}; at least {MIN_NODES}x{MIN_NODES} nodes are needed")
        if not np.all(np.isfinite(p)):
            raise InputError(f"grid points contain {int(np.sum(~np.isfinite(p)))} NaN or infinite values")
        surface = cls(p, _partition(r, m, "r"), _partition(t, n, "t"))
        if not surface.area() > 0:
            raise InputError("surface has zero area (all points collinear or equal)")
        return surface

    @property
    def shape(self) -> tuple[int, int]:
        """Grid size (M, N)."""
        return self.points.shape[0], self.points.shape[1]

    def area(self) -> float:
        """Area as the sum of two triangles per cell (the paper's rule).

        Triangles (c_ij, c_i+1,j+1, c_i,j+1) and (c_ij, c_i+1,j, c_i+1,j+1).
        """
        c = self.points
        c00, c10, c01, c11 = c[:-1, :-1], c[1:, :-1], c[:-1, 1:], c[1:, 1:]
        a1 = np.linalg.norm(np.cross(c11 - c00, c01 - c00), axis=-1)
        a2 = np.linalg.norm(np.cross(c10 - c00, c11 - c00), axis=-1)
        return 0.5 * float(np.sum(a1) + np.sum(a2))

    def scaled(self) -> GridSurface:
        """The surface divided by sqrt(area), so that its area is 1."""
        return GridSurface(self.points / np.sqrt(self.area()), self.r, self.t)

    @cached_property
    def interpolator(self) -> GridInterpolator:
        """The bicubic interpolant of the points (made once per surface)."""
        return GridInterpolator(self.points, self.r, self.t)

    def at(self, h: np.ndarray) -> np.ndarray:
        """The surface at a reparametrization: c(h(...)) for h of shape (..., 2) in [0, 1]^2, shape (..., 3).

        This is the one way meshreg evaluates a surface between its nodes (bicubic interpolation); the
        registered second surface is ``second.scaled().at(result.h)``.
        """
        return self.interpolator(h[..., 0], h[..., 1])[0]

    def resampled(self, m: int, n: int) -> GridSurface:
        """The surface on a uniform m x n grid (bicubic interpolation)."""
        r, t = np.linspace(0, 1, m), np.linspace(0, 1, n)
        return GridSurface(self.at(np.stack(np.meshgrid(r, t, indexing="ij"), axis=-1)), r, t)

    def save(self, path) -> None:
        """Write ``points``, ``r`` and ``t`` to an ``.npz`` file."""
        np.savez(path, points=self.points, r=self.r, t=self.t)


def as_surface(surface) -> GridSurface:
    """A GridSurface from a GridSurface, an (M, N, 3) array, or a grid file path."""
    if isinstance(surface, GridSurface):
        return surface
    if isinstance(surface, (str, Path)):
        return read_grid(surface)
    return GridSurface.from_array(surface)


def read_grid(path, shape: tuple[int, int] | None = None) -> GridSurface:
    """Read a grid surface from ``.npy``, ``.npz`` or the paper's text format.

    Parameters
    ----------
    path : str or Path
        The file.
    shape : (int, int), optional
        (M, N) for text files without a ``M N`` first line.

    Returns
    -------
    GridSurface

    Raises
    ------
    InputError
        When the file is missing or unreadable, or its contents are not a valid grid.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such file")
    suffix = path.suffix.lower()
    try:
        if suffix == ".npy":
            return GridSurface.from_array(np.load(path, allow_pickle=False))
        if suffix == ".npz":
            with np.load(path, allow_pickle=False) as data:
                if "points" not in data:
                    raise InputError(f"{path}: .npz grid files need a 'points' array of shape (M, N, 3)")
                r = data["r"] if "r" in data else None
                t = data["t"] if "t" in data else None
                return GridSurface.from_array(data["points"], r, t)
        return _read_text(path, shape)
    except InputError as err:
        raise InputError(f"{path}: {err}") from None
    except (OSError, ValueError, UnicodeDecodeError) as err:
        raise InputError(f"{path}: cannot read grid file ({err})") from None


def _read_text(path: Path, shape: tuple[int, int] | None) -> GridSurface:
    lines = [ln.split() for ln in path.read_text().splitlines()]
    lines = [ln for ln in lines if ln and not ln[0].startswith("#")]
    if lines and len(lines[0]) == 2:
        header = tuple(int(v) for v in lines[0])
        lines = lines[1:]
        shape = shape or header
    if shape is None:
        raise InputError("grid size unknown: give --grid M N or start the file with a line 'M N'")
    if any(len(ln) != 3 for ln in lines):
        raise InputError("every line of a text grid must hold three numbers 'x y z'")
    m, n = shape
    values = np.array(lines, dtype=float)
    if values.shape[0] != m * n:
        raise InputError(f"file has {values.shape[0]} points but the grid is {m}x{n} = {m * n}")
    return GridSurface.from_array(values.reshape(n, m, 3).transpose(1, 0, 2))


def write_text_grid(path, surface: GridSurface) -> None:
    """Write a surface in the paper's text format with a ``M N`` first line (r running fastest)."""
    m, n = surface.shape
    rows = surface.points.transpose(1, 0, 2).reshape(-1, 3)
    np.savetxt(path, rows, header=f"{m} {n}", comments="")
