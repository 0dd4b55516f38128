"""The result of a registration, what a user does with it (correspondence, transform, distances), and its file
format (``result.npz``)."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np

from .correspondence import Side, h_at, inverse_uv
from .errors import InputError
from .files import read_npz, write_atomic
from .residual import is_mirrored

INLIER_DISTANCE = 0.01  # default inlier threshold of fitness and inlier_rmse, as a fraction of sqrt(area of second)
_SIDE_KEYS = ("vertices", "faces", "uv", "input_index", "source_ids")


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
        smoothed levels). Meshes registered in the bending path (``params["bend_energy"]`` present): E_w, the
        energy with local similarities that was minimized (:mod:`meshreg.bending`).
    r : ndarray, shape (M,)
    t : ndarray, shape (N,)
        The first surface's partitions.
    mode : str
    params : dict
        Every parameter that produced the result; in mode "auto" also ``starts`` (each registered start's
        symmetry, coarse E, E and residual) and ``mirror`` (the best start the search dropped as mirrored: its
        symmetry, coarse E and ``fits_better``, whether it beat the chosen start's coarse E by half while the answer
        does not fit the second's points, :data:`meshreg.choice.MIRROR_FIT_RESIDUAL`); on grids ``stalled_polish``,
        what the second refinement pass of a stalled answer did (None when it did not run;
        :func:`meshreg.stalled.polish_stalled`).
    timings : dict
        Seconds per stage (``search``, ``dp``, ``gd``, ``smoothing`` (mode "gd": the smoothed levels),
        ``refine``, ``stalled_polish`` (when that pass ran), ``alternatives`` (mode "auto"), ``total``).
    energy_stages : tuple of str, length K
        The stage of each entry of ``energy_history`` ("start", "dp", "gd", "kabsch", "refine", "full grid": E on
        the full grid on arrival from the work grid, "polish": the second pass of a stalled answer,
        :mod:`meshreg.stalled`).
    symmetry : int
        Index into :data:`meshreg.search.SQUARE_SYMMETRIES` of the symmetry of the square applied
        to the second surface first (0: none). h includes it: h = sigma o h', with h' the
        orientation-preserving reparametrization found for the symmetric copy, so h itself
        reverses orientation when sigma does.
    transform : ndarray, shape (4, 4)
        The similarity x -> s R x + b taking the first surface into the second's frame (R the rotation; s and b
        fitted by least squares to the corresponding points).
    first, second : Side or None
        Each surface as a triangle mesh laid out on the square, and how its vertices relate to the surface as
        given (:class:`meshreg.correspondence.Side`); they make :meth:`correspondence` and the methods after it.
    info : dict
        What the mesh preparation did, per surface ("first", "second"): cleanup report, flipped triangles, ...

    residual : float
        The coordinate residual: area-weighted RMS of ``R c1 - c2 o h`` after centring both, both surfaces at
        area 1 (so 0.01 is 1% of sqrt(area)); E alone cannot tell a match from its mirror image
        (:mod:`meshreg.residual`). NaN for results saved before it was recorded.
    residual_mirrored : float
        The same against the point reflection, RMS of ``R c1 + c2 o h``: far below ``residual`` when the
        aligned first surface lies on the mirror image of the second (:attr:`mirrored`).
    alternatives : list of dict
        Mode "auto": the other correspondences as good as this one (a symmetric shape), each with
        ``symmetry`` (pin it with ``Options.symmetry``), ``angle`` (degrees of its rotation from R),
        ``energy``, ``residual`` and ``rotation``; empty when the correspondence is unambiguous.

    Examples
    --------
    >>> import meshreg
    >>> from meshreg.samples import paper_pairs
    >>> pair = paper_pairs(21, 21)[6]
    >>> result = meshreg.register(pair.first, pair.second, mode="dp+gd")
    >>> result.correspondence([0, 220]).shape        # points of the second matched with first vertices 0 and 220
    (2, 3)
    >>> bool(result.fitness() > 0.99), result.vertex_pairs().shape
    (True, (441, 2))
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
    energy_stages: tuple = ()
    transform: np.ndarray = field(default_factory=lambda: np.eye(4))
    first: Side | None = None
    second: Side | None = None
    info: dict = field(default_factory=dict)
    residual: float = float("nan")
    residual_mirrored: float = float("nan")
    alternatives: list = field(default_factory=list)

    @property
    def distance(self) -> float:
        """The elastic shape distance sqrt(E)."""
        return float(np.sqrt(max(self.energy, 0.0)))

    @property
    def mirrored(self) -> bool:
        """Whether the aligned first surface sits on the mirror image (point reflection) of the second
        (:attr:`meshreg.residual.Residual.mirrored`)."""
        return is_mirrored(self.residual, self.residual_mirrored)

    @property
    def ambiguous(self) -> bool:
        """Whether other correspondences are as good as this one (:attr:`alternatives`)."""
        return bool(self.alternatives)

    def correspondence_notes(self) -> list[str]:
        """What a user must know about the correspondence beyond E, one line each (none for most results): it
        is mirrored (possible only in the modes that do not search), a mirror image of the second surface fits
        clearly better than any correspondence that keeps orientation, or it is ambiguous."""
        notes = []
        if self.mirrored:
            notes.append(
                f"mirrored: R c1 lies on the mirror image of the second surface (residual {self.residual:.3g}, "
                f"{self.residual_mirrored:.3g} against the mirror image); mode auto never returns such a match"
            )
        mirror = self.params.get("mirror") or {}
        if mirror.get("fits_better"):
            notes.append(
                f"a mirror image of the second surface fits better (coarse E {mirror['coarse_energy']:.3g}, symmetry "
                f"{mirror['symmetry']}): are the surfaces mirror images of each other? This correspondence keeps "
                "orientation"
            )
        if self.alternatives:
            others = ", ".join(f"{a['symmetry']} ({a['angle']:.0f} deg)" for a in self.alternatives)
            notes.append(
                f"ambiguous: {len(self.alternatives) + 1} equally good correspondences (the shape is symmetric); "
                f"this one has symmetry {self.symmetry}, the others {others}: pin one with symmetry=K (--symmetry K)"
            )
        return notes

    def apply(self, points: np.ndarray) -> np.ndarray:
        """Rotate points (..., 3) of the first surface by R."""
        return np.asarray(points) @ self.rotation.T

    @property
    def scale(self) -> float:
        """s of :attr:`transform`: the size of the second surface relative to the first."""
        return float(np.cbrt(np.linalg.det(self.transform[:3, :3])))

    def aligned(self, points: np.ndarray) -> np.ndarray:
        """Points (..., 3) of the first surface moved into the second's frame by :attr:`transform`."""
        return np.asarray(points, dtype=float) @ self.transform[:3, :3].T + self.transform[:3, 3]

    def correspondence(self, where=None, barycentric: bool = False):
        """Points of the second surface matched with points of the first (on its triangles, not snapped).

        Parameters
        ----------
        where : None, int array (k,) or float array (k, 3)
            Which points of the first surface: every vertex as given (default), vertex ids, or points near the
            first surface in its own coordinates (each taken at the surface's closest point).
        barycentric : bool
            Also return, for each match, the vertex ids of the second surface's triangle that holds it (as given;
            -1 for a vertex cleanup added) and the barycentric weights.

        Returns
        -------
        points : ndarray, shape (k, 3)
            In the second surface's coordinates; NaN where a point has no match (dropped by cleanup).
        ids, weights : ndarray, shape (k, 3)
            With ``barycentric``.
        """
        second = self._sides()[1]
        points, ids, weights = self._matches if where is None else second.at_uv(self._h(self._first_uv(where)))
        return (points, ids, weights) if barycentric else points

    def correspondence_on_first(self) -> np.ndarray:
        """For each vertex of the second surface as given, its matched point on the first (first's coordinates),
        shape (n2, 3); NaN where cleanup dropped the vertex (a removed boundary ear's apex is matched at its foot
        on the ear's base)."""
        first, second = self._sides()
        return first.at_uv(inverse_uv(self.h, self.r, self.t, second.input_uv()))[0]

    def vertex_pairs(self) -> np.ndarray:
        """(k, 2) vertex ids (first, second): each vertex of the first with a match, and the vertex of the second
        nearest to its matched point (like Open3D's ``correspondence_set``)."""
        from scipy.spatial import cKDTree

        points, second = self.correspondence(), self._sides()[1]
        has = np.flatnonzero(np.all(np.isfinite(points), axis=1))
        kept = np.flatnonzero(second.input_index >= 0)
        _, nearest = cKDTree(second.vertices[second.input_index[kept]]).query(points[has])
        return np.c_[has, kept[nearest]]

    def distances(self) -> np.ndarray:
        """Per vertex of the first surface as given, the distance (second's units) from the vertex moved by
        :attr:`transform` to its matched point, shape (n1,); NaN where there is no match. Near 0 everywhere for
        two meshes of one surface; large where the shapes differ."""
        first = self._sides()[0]
        return np.linalg.norm(
            self.aligned(first.vertices[np.maximum(first.input_index, 0)]) - self.correspondence(), axis=1
        )

    def inlier_threshold(self, fraction: float = INLIER_DISTANCE) -> float:
        """``fraction`` of sqrt(area of the second surface): the default distance of an inlier."""
        return fraction * np.sqrt(self._sides()[1].area())

    def fitness(self, threshold: float | None = None) -> float:
        """Fraction of the first surface's vertices whose :meth:`distances` is at most ``threshold`` (default
        :meth:`inlier_threshold`), as Open3D's ``RegistrationResult.fitness``."""
        d = self.distances()
        return float(np.mean(d <= (self.inlier_threshold() if threshold is None else threshold)))

    def inlier_rmse(self, threshold: float | None = None) -> float:
        """Root mean square of :meth:`distances` over the inliers (NaN when there are none), as Open3D's
        ``RegistrationResult.inlier_rmse``."""
        d = self.distances()
        inliers = d[d <= (self.inlier_threshold() if threshold is None else threshold)]
        return float(np.sqrt(np.mean(inliers**2))) if len(inliers) else float("nan")

    def _first_uv(self, where) -> np.ndarray:
        first = self._sides()[0]
        where = np.asarray(where)
        if where.ndim == 2 and where.shape[1] == 3 and where.dtype.kind in "fiu":  # integer coordinates too
            if not np.all(np.isfinite(where)):
                raise InputError("correspondence takes finite points: drop the rows with NaN or inf")
            return first.uv_of_points(where.astype(float))[0]
        if where.ndim != 1 or not np.issubdtype(where.dtype, np.integer):
            raise InputError("correspondence takes vertex ids (k,) or points (k, 3) of the first surface")
        if len(where) and (where.min() < 0 or where.max() >= first.n_input):
            raise InputError(f"vertex ids must be in 0..{first.n_input - 1}")
        return first.input_uv(where)

    def _sides(self) -> tuple[Side, Side]:
        """The two surfaces the correspondence methods need; InputError when the result has none attached."""
        if self.first is None or self.second is None:
            raise InputError("this result has no surfaces attached (made by an older meshreg): register again")
        return self.first, self.second

    def _h(self, uv: np.ndarray) -> np.ndarray:
        return h_at(self.h, self.r, self.t, uv)

    @cached_property
    def _matches(self):
        first, second = self._sides()
        return second.at_uv(self._h(first.input_uv()))

    def save(self, path, **extra) -> None:
        """Write the result to ``path`` (``.npz``; keys listed in docs/outputs.md), plus ``extra`` arrays, atomically
        (a temporary name in the same directory, then a rename); like numpy, ``.npz`` is appended to a path
        without it."""
        given = path = Path(path)
        if path.suffix != ".npz":
            path = path.with_name(path.name + ".npz")
        if given.is_dir() or path.is_dir():  # numpy's rule would write PATH.npz beside a directory PATH
            raise InputError(f"{path if path.is_dir() else given} is a directory: give a file name")
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
            energy_stages=np.array(self.energy_stages, dtype=str),
            transform=self.transform,
            info=json.dumps(self.info),
            **self._side_arrays(),
            residual=self.residual,
            residual_mirrored=self.residual_mirrored,
            alternatives=json.dumps(self.alternatives),
        )

    def _side_arrays(self) -> dict:
        out = {}
        for name, side in (("first", self.first), ("second", self.second)):
            if side is not None:
                out.update({f"{name}_{key}": getattr(side, key) for key in _SIDE_KEYS})
        return out

    @classmethod
    def load(cls, path) -> Registration:
        """Read a result written by :meth:`save`."""
        data = read_npz(path, "result")
        try:
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
                energy_stages=tuple(data["energy_stages"].tolist()) if "energy_stages" in data else (),
                transform=data["transform"] if "transform" in data else np.eye(4),
                first=_side(data, "first"),
                second=_side(data, "second"),
                info=json.loads(str(data["info"])) if "info" in data else {},
                residual=float(data["residual"]) if "residual" in data else float("nan"),
                residual_mirrored=float(data["residual_mirrored"]) if "residual_mirrored" in data else float("nan"),
                alternatives=json.loads(str(data["alternatives"])) if "alternatives" in data else [],
            )
        except (KeyError, ValueError, TypeError) as err:
            raise InputError(f"{path}: not a meshreg result file ({type(err).__name__}: {err})") from None


def with_stage(timings: dict, stage: str, seconds: float) -> dict:
    """``timings`` (a result's, seconds by stage) with ``stage``'s ``seconds`` recorded and added to ``"total"``."""
    return {**timings, stage: seconds, "total": timings.get("total", 0.0) + seconds}


def _side(data, name: str) -> Side | None:
    keys = [f"{name}_{key}" for key in _SIDE_KEYS]
    return Side(*(data[k] for k in keys)) if all(k in data for k in keys) else None
