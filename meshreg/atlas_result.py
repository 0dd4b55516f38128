"""The result of a shape atlas (:func:`meshreg.atlas`) and its file format (``atlas.npz``)."""

from __future__ import annotations

import json
import os
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path

import numpy as np

from .errors import InputError
from .files import read_npz


@dataclass
class Atlas:
    """A collection in one template and one connectivity, with its principal modes.

    Coordinates are in the *template's frame*: the frame of the medoid as given (the iteration runs there), at the
    members' mean size. K members were kept; V = M N grid nodes; F = 2 (M - 1)(N - 1) triangles.

    Attributes
    ----------
    names : list of str, length K
    template : ndarray (V, 3)
        The mean shape, at size ``scale``, centred at ``centre``.
    faces : ndarray (F, 3)
        The template grid's triangles (two per cell, :func:`meshreg.mesh.export.grid_faces`), shared by all.
    grid : (int, int)
        (M, N); vertex i N + j is grid node (r[i], t[j]).
    r, t : ndarray (M,), (N,)
    aligned : ndarray (K, V, 3)
        Each member on the template's grid (vertex k the same point on all), rotated into the template's frame,
        at its own size, centred at ``centre``.
    sizes : ndarray (K,)
        sqrt(area) of each member (as given).
    scale : float
        The template's size: the mean of ``sizes``.
    centre : ndarray (3,)
        The centroid (node mean) of the medoid as given; every shape here is centred there.
    centroids : ndarray (K, 3)
        Node mean of each member resampled on the template's grid, in its own frame: that resampled member is
        ``(aligned[k] - centre) @ rotations[k].T + centroids[k]``.
    rotations : ndarray (K, 3, 3)
        R of each member's registration (the template rotated onto the member).
    energies : ndarray (K,)
        E(template, member), both at area 1.
    h : ndarray (K, M, N, 2)
        Each member's reparametrization: its parameter point at each template grid node (symmetry included).
    symmetries, placements : ndarray (K,) int
        The symmetry of the square in h, and the corner placement (round-boundary meshes, and meshes with four
        clear turns in a collection with round-boundary ones, placed at quarter arc lengths; else 0).
    mean, modes, variances, explained, scores
        PCA of the shapes (aligned members scaled to the template's size: shape, not size): mean (V, 3), unit
        modes (k, V, 3), variances (k,) in squared units, explained variance fractions (k,), scores (K, k) with
        shape k ~ mean + sum_m scores[k, m] modes[m].
    objective : ndarray (I,)
        F = mean E to the template at each iteration; the template kept is the iterate with the least F.
    seconds : ndarray (K, I)
        Each member's registration time (wall clock in its worker) at each iteration (NaN: not run).
    failures : dict
        name -> why a member was left out.
    medoid : str
    params : dict
        Options, settings, iterations run and kept, convergence, ``karcher_gap`` (see the module) and ``spread``
        (RMS distance of the shapes' vertices from the mean's, as a fraction of ``scale``).
    timings : dict
        Seconds of each stage (``prepare``, ``medoid``, ``iterations``, ``pca``, ``total``) and ``per_member``
        (total / members given).
    """

    names: list
    template: np.ndarray
    faces: np.ndarray
    grid: tuple
    r: np.ndarray
    t: np.ndarray
    aligned: np.ndarray
    sizes: np.ndarray
    scale: float
    centre: np.ndarray
    centroids: np.ndarray
    rotations: np.ndarray
    energies: np.ndarray
    h: np.ndarray
    symmetries: np.ndarray
    placements: np.ndarray
    mean: np.ndarray
    modes: np.ndarray
    variances: np.ndarray
    explained: np.ndarray
    scores: np.ndarray
    objective: np.ndarray
    seconds: np.ndarray
    failures: dict = field(default_factory=dict)
    medoid: str = ""
    params: dict = field(default_factory=dict)
    timings: dict = field(default_factory=dict)

    def save(self, path) -> None:
        """Write ``.npz`` atomically (the keys are the attribute names; dicts as JSON strings)."""
        path = Path(path)
        tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp.npz")
        arrays = {k: v for k, v in asdict(self).items() if k not in ("names", "failures", "params", "timings")}
        np.savez(
            tmp,
            **arrays,
            names=np.array(self.names, dtype=str),
            failures=json.dumps(self.failures),
            params=json.dumps(self.params),
            timings=json.dumps(self.timings),
        )
        os.replace(tmp, path)

    @classmethod
    def load(cls, path) -> Atlas:
        """Read an atlas written by :meth:`save`."""
        values = read_npz(path, "atlas")
        missing = sorted({f.name for f in fields(cls)} - set(values))
        if missing:
            raise InputError(f"{path}: not a meshreg atlas file (no {', '.join(missing[:3])})")
        values["names"] = values["names"].tolist()
        for key in ("failures", "params", "timings"):
            values[key] = json.loads(str(values[key]))
        values["grid"] = tuple(int(x) for x in values["grid"])
        values["scale"] = float(values["scale"])
        values["medoid"] = str(values["medoid"])
        return cls(**values)

    def shapes(self) -> np.ndarray:
        """The aligned members at the template's size (K, V, 3): what the PCA is of."""
        return (self.aligned - self.centre) * (self.scale / self.sizes)[:, None, None] + self.centre
