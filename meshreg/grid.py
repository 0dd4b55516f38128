"""Grid surfaces: points sampled on a (possibly non-uniform) grid over the unit square.

A grid surface is ``points[i, j] = c(r[i], t[j])`` with axis 0 the r direction and axis 1 the t
direction, ``r`` and ``t`` increasing partitions of [0, 1] (inputs on other intervals are rescaled).

File formats read by :func:`read_grid`:

* ``.npy``: an array of shape (M, N, 3), uniform partitions.
* ``.npz``: key ``points`` of shape (M, N, 3), optional keys ``r`` (M,) and ``t`` (N,).
* text (``.txt``, ``.dat``): the paper's format, one point ``x y z`` per line with r running fastest,
  i.e. the lines are c(r_1,t_1), c(r_2,t_1), ..., c(r_M,t_1), c(r_1,t_2), ...  The grid size comes
  from ``shape=(M, N)`` (the command line's ``--grid M N``) or from a first line holding the two
  integers ``M N``. Lines starting with ``#`` are ignored.
"""

from __future__ import annotations

import zipfile
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np

from .errors import InputError
from .files import GRID_SUFFIXES, existing_file
from .spline import GridInterpolator

MIN_NODES = 3
# Coordinates are refused beyond these magnitudes: areas come from products of four lengths (|a x b|), which
# overflow float64 beyond about 1e77 and underflow below 1e-77; E, R and h do not depend on the scale, so a
# surface outside the range only needs rescaling.
MAX_COORDINATE = 1e50
MIN_EXTENT = 1e-50
# ... and when float64 steps by more than this fraction of the surface's extent at its distance from the origin: its
# shape then keeps fewer than six digits (a mesh registered against its own copy, both moved 1e12 from the origin, gave
# E 8e-5, 1e14 away E 1.1; 1e15 away the closest-point search divided by zero)
COORDINATE_STEP = 1e-6
# A surface whose area is below this fraction of its bounding box's squared diameter is a degenerate sliver:
# its cell normals are differences of nearly equal products and carry fewer than 6 significant digits.
MIN_AREA_RATIO = 1e-10
# Grid files with more nodes than this are refused before they are read (5000 x 5000 nodes, 600 MB of points).
MAX_FILE_NODES = 25_000_000


def coordinates(values, what: str) -> np.ndarray:
    """Real float64 coordinates of an array-like: InputError when they are complex, booleans, text, ragged or
    not finite (the message names ``what``)."""
    try:
        array = np.asarray(values)
    except ValueError as err:  # ragged nested lists
        raise InputError(f"{what} are not an array of numbers ({err})") from None
    kind = array.dtype.kind
    if kind == "c":
        raise InputError(f"{what} are complex numbers: give real coordinates (the imaginary parts would be lost)")
    if kind == "b":
        raise InputError(f"{what} are booleans (True/False), not coordinates")
    if kind not in "fiuO":
        raise InputError(f"{what} are not numbers (dtype {array.dtype})")
    try:
        array = array.astype(float)
    except (TypeError, ValueError) as err:
        raise InputError(f"{what} are not numbers ({err})") from None
    bad = int(np.sum(~np.isfinite(array)))
    if bad:
        raise InputError(f"{what} contain {bad} NaN or infinite values: drop or repair those points first")
    return array


def check_scale(points: np.ndarray, what: str) -> float:
    """The diameter of the bounding box of ``points`` (..., 3); InputError when the coordinates are too large or
    the extent too small for float64 areas (see MAX_COORDINATE, MIN_EXTENT), or too far from the origin for the
    digits of the shape (COORDINATE_STEP)."""
    flat = points.reshape(-1, 3)
    largest = float(np.abs(flat).max()) if flat.size else 0.0
    if largest > MAX_COORDINATE:
        raise InputError(
            f"{what} reach {largest:.1e}: areas overflow beyond {MAX_COORDINATE:.0e}; rescale the surface "
            "(E, R and h do not depend on its scale)"
        )
    diameter = float(np.linalg.norm(np.ptp(flat, axis=0))) if flat.size else 0.0
    if 0 < diameter < MIN_EXTENT:
        raise InputError(
            f"{what} span only {diameter:.1e}: areas underflow below {MIN_EXTENT:.0e}; rescale the surface "
            "(E, R and h do not depend on its scale)"
        )
    if diameter > 0 and np.spacing(largest) > COORDINATE_STEP * diameter:
        raise InputError(
            f"{what} lie {largest:.1e} from the origin but span only {diameter:.1e}: float64 steps by "
            f"{np.spacing(largest):.1e} there, so the shape keeps fewer than six digits; move the surface to the "
            "origin (subtract its centre) where it is made, before its coordinates are rounded"
        )
    return diameter


def _partition(values, n: int, name: str) -> np.ndarray:
    """Validate a partition of length ``n`` and rescale it to [0, 1]."""
    if values is None:
        return np.linspace(0.0, 1.0, n)
    p = coordinates(values, f"partition {name} values")
    if p.ndim != 1:
        raise InputError(f"partition {name} must be one list of {n} values, got an array of shape {p.shape}")
    if p.shape != (n,):
        raise InputError(f"partition {name} has {p.size} values but the grid has {n} nodes along {name}")
    if np.any(np.diff(p) <= 0):
        raise InputError(f"partition {name} must be strictly increasing")
    return (p - p[0]) / (p[-1] - p[0])


def _check_unit_partition(p, n: int, name: str) -> None:
    """A partition as GridSurface holds it: n values increasing strictly from 0 to 1."""
    ok = isinstance(p, np.ndarray) and p.shape == (n,) and p.dtype.kind == "f" and bool(np.all(np.isfinite(p)))
    if not ok or np.any(np.diff(p) <= 0) or abs(p[0]) > 1e-9 or abs(p[-1] - 1) > 1e-9:
        raise InputError(
            f"partition {name} must be {n} finite values increasing strictly from 0 to 1 "
            "(GridSurface.from_array checks and rescales any partition)"
        )


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

    def __post_init__(self):
        p = self.points
        if not (isinstance(p, np.ndarray) and p.ndim == 3 and p.shape[2] == 3 and p.dtype.kind == "f"):
            raise InputError(
                "GridSurface points must be a float array of shape (M, N, 3) (GridSurface.from_array converts "
                f"and checks any array), got {getattr(p, 'dtype', type(p).__name__)} {np.shape(p)}"
            )
        if p.shape[0] < MIN_NODES or p.shape[1] < MIN_NODES:
            raise InputError(f"grid is {p.shape[0]}x{p.shape[1]}; at least {MIN_NODES}x{MIN_NODES} nodes are needed")
        _check_unit_partition(self.r, p.shape[0], "r")
        _check_unit_partition(self.t, p.shape[1], "t")
        if not np.all(np.isfinite(p)):
            raise InputError(f"grid points contain {int(np.sum(~np.isfinite(p)))} NaN or infinite values")

    @classmethod
    def from_array(cls, points, r=None, t=None) -> GridSurface:
        """Validate ``points`` (M, N, 3) and optional partitions; rescale partitions to [0, 1].

        Raises
        ------
        InputError
            On a wrong shape, a grid smaller than 3x3, values that are not finite real numbers, coordinates
            beyond MAX_COORDINATE or spanning less than MIN_EXTENT, bad partitions, zero area or a degenerate
            sliver (area below MIN_AREA_RATIO of the bounding box's squared diameter).
        """
        p = coordinates(points, "grid points")
        if p.ndim != 3 or p.shape[2] != 3:
            raise InputError(f"grid points must have shape (M, N, 3), got {p.shape}")
        m, n = p.shape[:2]
        if m < MIN_NODES or n < MIN_NODES:
            raise InputError(f"grid is {m}x{n}; at least {MIN_NODES}x{MIN_NODES} nodes are needed")
        diameter = check_scale(p, "grid points")
        surface = cls(p, _partition(r, m, "r"), _partition(t, n, "t"))
        area = surface.area()
        if not area > 0:
            raise InputError("surface has zero area (all points collinear or equal)")
        if area < MIN_AREA_RATIO * diameter**2:
            raise InputError(
                f"surface is a degenerate sliver: its area is {area / diameter**2:.1e} of its bounding box's squared "
                f"diameter (below {MIN_AREA_RATIO:.0e}), too thin for its normals, hence E, to mean anything"
            )
        return surface

    @property
    def shape(self) -> tuple[int, int]:
        """Grid size (M, N)."""
        return self.points.shape[0], self.points.shape[1]

    def area(self) -> float:
        """Area as the sum of two triangles per cell (the paper's rule), averaged over the two diagonals.

        Triangles (c_ij, c_i+1,j+1, c_i,j+1) and (c_ij, c_i+1,j, c_i+1,j+1), and (c_ij, c_i+1,j, c_i,j+1)
        and (c_i+1,j, c_i+1,j+1, c_i,j+1). One diagonal alone (the paper) makes the area depend on which
        corner of the grid is (0, 0): a warped 33 x 29 sample of a bump, flipped, had a 0.36% larger area, and
        registered against a 31 x 31 sample of the same bump it stopped at E = 4e-6 instead of 5e-8. The
        average is the same under every symmetry of the square; the paper's pairs give the same E as before.
        """
        c = self.points
        c00, c10, c01, c11 = c[:-1, :-1], c[1:, :-1], c[:-1, 1:], c[1:, 1:]
        diagonal, r_side, t_side = c11 - c00, c10 - c00, c01 - c00
        doubled = (
            _cross_norm(diagonal, t_side)  # (c00, c11, c01)
            + _cross_norm(r_side, diagonal)  # (c00, c10, c11)
            + _cross_norm(r_side, t_side)  # (c00, c10, c01)
            + _cross_norm(c11 - c10, c01 - c10)  # (c10, c11, c01)
        )
        return 0.25 * float(doubled.sum())

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
        return self.interpolator.values(h[..., 0], h[..., 1])

    def resampled(self, m: int, n: int) -> GridSurface:
        """The surface on a uniform m x n grid (bicubic interpolation)."""
        r, t = np.linspace(0, 1, m), np.linspace(0, 1, n)
        return GridSurface(self.at(np.stack(np.meshgrid(r, t, indexing="ij"), axis=-1)), r, t)

    def save(self, path) -> None:
        """Write ``points``, ``r`` and ``t`` to an ``.npz`` file."""
        np.savez(path, points=self.points, r=self.r, t=self.t)


def _cross_norm(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """|u x v| for arrays of vectors (..., 3) (twice the area of the triangle they span; written out, it takes
    half the time of np.cross and np.linalg.norm)."""
    x = u[..., 1] * v[..., 2] - u[..., 2] * v[..., 1]
    y = u[..., 2] * v[..., 0] - u[..., 0] * v[..., 2]
    z = u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]
    return np.sqrt(x * x + y * y + z * z)


def as_surface(surface) -> GridSurface:
    """A GridSurface from a GridSurface, an (M, N, 3) array, or a grid file path."""
    if isinstance(surface, GridSurface):
        return surface
    if isinstance(surface, (str, Path)):
        return read_grid(surface)
    if isinstance(surface, tuple) and len(surface) == 2:
        raise InputError(
            "got a pair (vertices, faces)? register takes grid surfaces: register meshes with "
            "meshreg.mesh.correspond.register_meshes or `meshreg register a.ply b.ply`"
        )
    if not isinstance(surface, (np.ndarray, list, tuple)):
        raise InputError(
            f"a surface must be a GridSurface, an (M, N, 3) array or a grid file path, got {surface!r:.60}"
        )
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
    path = existing_file(path)
    suffix = path.suffix.lower()
    if suffix not in GRID_SUFFIXES:
        raise InputError(
            f"{path}: unknown grid file type {suffix or '(no suffix)'!r}: grids are {' '.join(GRID_SUFFIXES)} "
            "(.txt/.dat: the text format 'x y z' per line)"
        )
    if shape is not None:
        shape = _grid_size(shape, "--grid")
    try:
        if suffix == ".npy":
            with open(path, "rb") as stream:
                _check_file_size(_npy_shape(stream))  # the header's shape, before any data is read
            return GridSurface.from_array(np.load(path, allow_pickle=False))
        if suffix == ".npz":
            with np.load(path, allow_pickle=False) as data:
                if "points" not in data:
                    raise InputError(".npz grid files need a 'points' array of shape (M, N, 3)")
                if "points.npy" in data.zip.namelist():
                    with data.zip.open("points.npy") as member:
                        _check_file_size(_npy_shape(member))
                r = data["r"] if "r" in data else None
                t = data["t"] if "t" in data else None
                return GridSurface.from_array(data["points"], r, t)
        return _read_text(path, shape)
    except InputError as err:
        raise InputError(f"{path}: {err}") from None
    except UnicodeDecodeError:
        raise InputError(f"{path}: not a text grid (not UTF-8 text): give .npy, .npz or 'x y z' lines") from None
    except MemoryError:
        raise InputError(f"{path}: too large to read into memory") from None
    except OSError as err:
        raise InputError(f"{path}: cannot read grid file ({err.strerror or err})") from None
    except (ValueError, EOFError, KeyError, zipfile.BadZipFile) as err:
        if "pickle" in str(err):  # numpy's advice to load it unsafely does not apply: meshreg never unpickles
            raise InputError(
                f"{path}: not a NumPy {suffix} file of numbers (.npy: np.save of an (M, N, 3) array; .npz: np.savez "
                "with 'points')"
            ) from None
        raise InputError(f"{path}: cannot read grid file ({type(err).__name__}: {err})") from None


def _npy_shape(member) -> tuple:
    """The shape in the header of an .npy stream (an .npz member), read without its data."""
    version = np.lib.format.read_magic(member)
    header = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
    return header(member)[0]


def _check_file_size(shape: tuple) -> None:
    nodes = int(np.prod(shape[:2], dtype=np.float64)) if len(shape) >= 2 else 0
    if nodes > MAX_FILE_NODES:
        raise InputError(
            f"the file holds a {' x '.join(map(str, shape))} array ({nodes:.1e} nodes), above the {MAX_FILE_NODES:.1e} "
            "nodes meshreg reads: resample it"
        )


def _grid_size(shape, what: str) -> tuple[int, int]:
    """(M, N) of a grid size given by the user: two integers of at least MIN_NODES, at most MAX_FILE_NODES nodes."""
    try:
        m, n = (int(v) for v in shape)
    except (TypeError, ValueError):
        raise InputError(f"{what} must be two integers M N, got {shape!r}") from None
    if m < MIN_NODES or n < MIN_NODES or m * n > MAX_FILE_NODES:
        raise InputError(
            f"{what} must be two integers >= {MIN_NODES} (at most {MAX_FILE_NODES:.1e} nodes), got {m} {n}"
        )
    return m, n


def _read_text(path: Path, shape: tuple[int, int] | None) -> GridSurface:
    lines = [ln.split() for ln in path.read_text(encoding="utf-8").splitlines()]
    lines = [ln for ln in lines if ln and not ln[0].startswith("#")]
    if lines and len(lines[0]) == 2:
        header = _grid_size(lines[0], "the first line 'M N'")
        lines = lines[1:]
        if shape is not None and tuple(shape) != header:
            given = f"{shape[0]}x{shape[1]}"
            raise InputError(
                f"the file says its grid is {header[0]}x{header[1]} (first line) but --grid gives {given}: --grid is "
                "for text files without that line; drop it"
            )
        shape = header
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
