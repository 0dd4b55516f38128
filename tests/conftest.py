import os

import numpy as np
import pytest
from scipy.spatial import Delaunay

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("MPLBACKEND", "Agg")


def _outlined_mesh(rim: np.ndarray, area: float, points: int, seed: int, box: float = 1.0):
    """A planar mesh of about ``points`` vertices inside the closed polygon ``rim`` (k, 2) of the given ``area``:
    boundary points every 0.7 spacings, random points inside (drawn in [-box, box]^2), Delaunay triangles whose
    centroid and side points lie inside; (u, v) (n, 2) and faces (m, 3). (A probe's domains, /tmp/h3/gen.py of
    2026-12-02.)"""
    from matplotlib.path import Path as Outline

    closed = np.vstack([rim, rim[:1]])
    length = np.r_[0, np.cumsum(np.linalg.norm(np.diff(closed, axis=0), axis=1))]
    spacing = np.sqrt(area / points)
    at = np.linspace(0, length[-1], int(length[-1] / (0.7 * spacing)), endpoint=False)
    edge = np.c_[np.interp(at, length, closed[:, 0]), np.interp(at, length, closed[:, 1])]
    outline, rng = Outline(rim), np.random.default_rng(seed)
    inner = rng.uniform(-box, box, (4 * points, 2))
    inner = inner[outline.contains_points(inner, radius=-1e-9)]
    inner = inner[np.min(np.linalg.norm(inner[:, None] - edge[None, ::4], axis=2), axis=1) > 0.5 * spacing]
    uv = np.vstack([edge, inner[: points - len(edge)]])
    faces = Delaunay(uv).simplices
    probes = [uv[faces].mean(axis=1)] + [
        (1 - a) * uv[faces[:, i]] + a * uv[faces[:, (i + 1) % 3]] for i in range(3) for a in np.linspace(0.04, 0.96, 24)
    ]
    inside = np.all(
        [outline.contains_points(q, radius=1e-9) | outline.contains_points(q, radius=-1e-9) for q in probes], axis=0
    )
    faces = faces[inside]
    used = np.unique(faces)
    return uv[used], np.searchsorted(used, faces)


def _bitten_disk(points: int, seed: int):
    """A relief over the unit disk with a square bite out of its rim (:func:`_outlined_mesh`); vertices (n, 3),
    faces, (u, v)."""
    turn = np.linspace(0, 2 * np.pi, 2000, endpoint=False)
    half = np.arcsin(0.18)
    turn = np.sort(np.mod(turn[np.abs(np.angle(np.exp(1j * turn))) > half] - half, 2 * np.pi)) + half
    corners = np.array([[np.cos(half), -0.18], [0.75, -0.18], [0.75, 0.18], [np.cos(half), 0.18]])
    bite = np.vstack([np.linspace(corners[i], corners[i + 1], 40, endpoint=False) for i in range(3)] + [corners[3:]])
    uv, faces = _outlined_mesh(np.vstack([np.c_[np.cos(turn), np.sin(turn)], bite]), np.pi, points, seed)
    bumps = np.random.default_rng(1046)
    z = np.zeros(len(uv))
    for _ in range(5):
        c, h, w = bumps.uniform(-0.8, 0.8, 2), bumps.uniform(0.05, 0.3) * bumps.choice([-1, 1]), bumps.uniform(0.2, 0.5)
        z += h * np.exp(-np.sum((uv - c) ** 2, axis=1) / (2 * w * w))
    return np.c_[uv, z], faces, uv


def _lobed(points: int, seed: int, lobes: int = 5, depth: float = 0.25, phase: float = 0.0, relief=None, box=1.25):
    """A relief z = ``relief``(x, y) (default the saddle 0.4 (x^2 - y^2)) over the lobed rim
    r = 1 + ``depth`` cos(``lobes`` t + ``phase``) (:func:`_outlined_mesh`, random points in [-box, box]^2);
    vertices (n, 3), faces, (u, v)."""
    turn = np.linspace(0, 2 * np.pi, 3000, endpoint=False)
    radius = 1 + depth * np.cos(lobes * turn + phase)
    rim = np.c_[radius * np.cos(turn), radius * np.sin(turn)]
    area = 0.5 * abs(np.sum(rim[:, 0] * np.roll(rim[:, 1], -1) - np.roll(rim[:, 0], -1) * rim[:, 1]))
    uv, faces = _outlined_mesh(rim, area, points, seed, box=box)
    z = 0.4 * (uv[:, 0] ** 2 - uv[:, 1] ** 2) if relief is None else relief(uv[:, 0], uv[:, 1])
    return np.c_[uv, z], faces, uv


def _star_saddle(points: int, seed: int):
    """The saddle z = 0.4 (x^2 - y^2) over a five-lobed star r = 1 + 0.25 cos 5t (:func:`_lobed`); vertices
    (n, 3), faces, (u, v). Turned by half a turn the saddle is the same and the star puts lobes on notches."""
    return _lobed(points, seed)


@pytest.fixture
def bitten_disk():
    """:func:`_bitten_disk`: a relief over the unit disk with a square bite out of its rim (four clear turns bunched
    in a tenth of the rim at low resolution, none at high)."""
    return _bitten_disk


@pytest.fixture
def lobed():
    """:func:`_lobed`: a relief over a lobed rim."""
    return _lobed


@pytest.fixture
def star_saddle():
    """:func:`_star_saddle`: a saddle over a five-lobed star (nearly the same under half a turn)."""
    return _star_saddle
