"""Every figure meshreg writes (PNG), drawn on :class:`matplotlib.figure.Figure` objects: no pyplot state and no
backend switch, so importing this module changes nothing in a notebook.

- :func:`plot_registration`: boundaries of R c1 and c2 o h, as in the paper, and the energy per accepted step;
- :func:`plot_meshes`: two meshes side by side, coloured so that corresponding points share a colour;
- :func:`plot_matrix`: a distance matrix as a heat map ordered by a dendrogram, and its MDS embedding.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure
from mpl_toolkits.mplot3d import Axes3D  # noqa: F401  (registers the "3d" projection)


def _boundary(points: np.ndarray) -> np.ndarray:
    """The boundary loop of a grid surface (M, N, 3) as a closed polyline (K, 3)."""
    return np.concatenate([points[:, 0], points[-1, 1:], points[::-1, -1][1:], points[0, ::-1][1:]])


def plot_registration(first_rotated: np.ndarray, second_registered: np.ndarray, history, path, title: str = "") -> Path:
    """Write a PNG: boundaries of R c1 (solid blue) and c2 o h (dashed red), each centred, and E per step.

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
    fig = Figure(figsize=(11, 4.8))
    ax = fig.add_subplot(1, 2, 1, projection="3d")
    for pts, style, label in ((first_rotated, "b-", "R c1"), (second_registered, "r--", "c2 o h")):
        pts = pts - pts.reshape(-1, 3).mean(axis=0)  # E does not see translations: overlay the two
        loop = _boundary(pts)
        ax.plot(loop[:, 0], loop[:, 1], loop[:, 2], style, label=label)
        for j in np.linspace(0, pts.shape[1] - 1, 5).astype(int)[1:-1]:
            ax.plot(*pts[:, j].T, style, lw=0.6, alpha=0.6)
    ax.legend(loc="upper left")
    ax.set_box_aspect(np.ptp(second_registered.reshape(-1, 3), axis=0) + 1e-9)
    ax.set_title(title or "boundaries after registration")
    ax2 = fig.add_subplot(1, 2, 2)
    ax2.semilogy(np.maximum(np.asarray(history, dtype=float), 1e-16), "k.-")
    ax2.set_xlabel("accepted step")
    ax2.set_ylabel("E (squared elastic distance)")
    ax2.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    return path


def plot_matrix(names, distance: np.ndarray, embedding: np.ndarray, path, title: str = "") -> Path:
    """Write a PNG: the distance matrix as a heat map ordered by an average-linkage dendrogram (drawn above it),
    and a 2D embedding (classical MDS) of the collection. Failed pairs (NaN) show blank."""
    from scipy.cluster.hierarchy import dendrogram, linkage
    from scipy.spatial.distance import squareform

    d = np.where(np.isfinite(distance), distance, np.nanmax(distance))
    fig = Figure(figsize=(13, 6.5))
    grid = fig.add_gridspec(2, 2, height_ratios=[1, 4], width_ratios=[1.1, 1], hspace=0.02, wspace=0.25)
    top, heat, emb = fig.add_subplot(grid[0, 0]), fig.add_subplot(grid[1, 0]), fig.add_subplot(grid[:, 1])
    labels = [Path(str(n)).stem for n in names]
    if len(d) > 2:
        tree = dendrogram(
            linkage(squareform(d, checks=False), method="average"), ax=top, no_labels=True, color_threshold=0
        )
        order = tree["leaves"]
    else:
        order = list(range(len(d)))
    n = len(d)
    top.set_xlim(0, 10 * n)  # dendrogram leaves sit at 5, 15, 25, ...: give the heat map the same axis
    top.axis("off")
    shown = distance[np.ix_(order, order)]
    image = heat.imshow(shown, cmap="viridis", interpolation="nearest", aspect="auto", extent=(0, 10 * n, 10 * n, 0))
    fig.colorbar(image, ax=heat, location="bottom", fraction=0.05, pad=0.18, label="elastic distance sqrt(E)")
    ticks = 5 + 10 * np.arange(n)
    heat.set_xticks(ticks, [labels[k] for k in order], rotation=90, fontsize=7)
    heat.set_yticks(ticks, [labels[k] for k in order], fontsize=7)
    emb.scatter(embedding[:, 0], embedding[:, 1], c="tab:blue")
    for k, label in enumerate(labels):
        emb.annotate(label, embedding[k], fontsize=7, xytext=(3, 3), textcoords="offset points")
    emb.set_title("classical MDS of the distances")
    emb.set_aspect("equal", adjustable="datalim")
    fig.suptitle(title or f"{len(names)} surfaces, {len(names) * (len(names) - 1) // 2} pairs")
    path = Path(path)
    fig.savefig(path, dpi=120, bbox_inches="tight")
    return path


def _view_rotation(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    """A rotation (3, 3) taking the mesh's mean (area-weighted) normal to +z: the camera then faces the surface."""
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]).sum(axis=0)
    z = n / max(np.linalg.norm(n), 1e-300)
    x = np.cross([0.0, 1.0, 0.0] if abs(z[1]) < 0.9 else [1.0, 0.0, 0.0], z)
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(z, x), z])


def plot_meshes(path, v1, f1, c1, v2, f2, c2, title: str = "", second_to_first: np.ndarray | None = None) -> None:
    """PNG: the two meshes side by side, coloured by correspondence, both seen from the first's mean normal.

    ``second_to_first`` (4, 4), the similarity from the second's frame to the first's, puts the second
    mesh in the first's pose so that the two pictures can be compared point by point.
    """
    if second_to_first is not None:
        v2 = v2 @ second_to_first[:3, :3].T + second_to_first[:3, 3]
    view = _view_rotation(v1, f1)
    fig = Figure(figsize=(11, 5))
    for k, (v, f, c, name) in enumerate(((v1, f1, c1, "first"), (v2, f2, c2, "second"))):
        ax = fig.add_subplot(1, 2, k + 1, projection="3d")
        p = (v - v.mean(axis=0)) @ view.T
        ax.plot_trisurf(p[:, 0], p[:, 1], p[:, 2], triangles=f, color="w", linewidth=0, shade=False).set_facecolor(
            c[f].mean(1)
        )
        ax.set_title(
            f"{name} mesh ({len(v)} vertices)" + (", in the first's pose" if k and second_to_first is not None else "")
        )
        ax.set_box_aspect(np.ptp(p, axis=0) + 1e-9)
        ax.view_init(elev=65, azim=-90)
        ax.set_axis_off()
    fig.suptitle(title or "corresponding points share a colour")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def classical_mds(distance: np.ndarray, dims: int = 2) -> np.ndarray:
    """Classical (Torgerson) multidimensional scaling: points (N, dims) whose Euclidean distances best match
    ``distance`` (N, N) (failed pairs, NaN, are set to the largest finite distance)."""
    d = np.where(np.isfinite(distance), distance, np.nanmax(distance))
    n = len(d)
    centre = np.eye(n) - 1.0 / n
    b = -0.5 * centre @ (d**2) @ centre
    vals, vecs = np.linalg.eigh(b)
    top = np.argsort(vals)[::-1][:dims]
    return vecs[:, top] * np.sqrt(np.maximum(vals[top], 0.0))
