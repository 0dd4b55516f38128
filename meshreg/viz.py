"""Figures (PNG): boundaries of the registered surfaces, as in the paper, and the energy curve."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402


def _boundary(points: np.ndarray) -> np.ndarray:
    """The boundary loop of a grid surface (M, N, 3) as a closed polyline (K, 3)."""
    return np.concatenate([points[:, 0], points[-1, 1:], points[::-1, -1][1:], points[0, ::-1][1:]])


def plot_registration(first_rotated: np.ndarray, second_registered: np.ndarray, history, path, title: str = "") -> Path:
    """Write a PNG: boundaries of R c1 (solid blue) and c2 o h (dashed red), and E per step.

    Parameters
    ----------
    first_rotated : ndarray, shape (M, N, 3)
        The rotated first surface (area 1).
    second_registered : ndarray, shape (M, N, 3)
        The second surface resampled at h (area 1).
    history : sequence of float
        E after each accepted step.
    path : str or Path
        Output file.
    """
    fig = plt.figure(figsize=(11, 4.8))
    ax = fig.add_subplot(1, 2, 1, projection="3d")
    for pts, style, label in ((first_rotated, "b-", "R c1"), (second_registered, "r--", "c2 o h")):
        loop = _boundary(pts)
        ax.plot(loop[:, 0], loop[:, 1], loop[:, 2], style, label=label)
        for j in np.linspace(0, pts.shape[1] - 1, 5).astype(int)[1:-1]:
            ax.plot(*pts[:, j].T, style, lw=0.6, alpha=0.6)
    ax.legend(loc="upper left")
    ax.set_title(title or "boundaries after registration")
    ax2 = fig.add_subplot(1, 2, 2)
    ax2.semilogy(np.maximum(np.asarray(history, dtype=float), 1e-16), "k.-")
    ax2.set_xlabel("accepted step")
    ax2.set_ylabel("E (squared elastic distance)")
    ax2.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
