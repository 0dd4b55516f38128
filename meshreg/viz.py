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


LIGHT = np.array([-0.4, -0.3, 0.87])  # unit direction of the light in the turned frame (the camera looks down -z)


def _draw_surface(ax, points: np.ndarray, faces: np.ndarray, values: np.ndarray, limit: float, box) -> None:
    """One mesh on a 3D axis, faces coloured by ``values`` (per vertex) on a diverging scale of +-``limit``."""
    from matplotlib import colormaps

    colors = colormaps["coolwarm"](np.clip(0.5 + 0.5 * values[faces].mean(axis=1) / max(limit, 1e-300), 0, 1))
    n = np.cross(points[faces[:, 1]] - points[faces[:, 0]], points[faces[:, 2]] - points[faces[:, 0]])
    light = np.abs(n @ LIGHT) / np.maximum(np.linalg.norm(n, axis=1), 1e-300)  # two-sided, from above the camera
    colors[:, :3] *= (0.45 + 0.55 * light)[:, None]
    surf = ax.plot_trisurf(points[:, 0], points[:, 1], points[:, 2], triangles=faces, linewidth=0, shade=False)
    surf.set_facecolor(colors)
    ax.set_xlim(box[0, 0], box[1, 0])
    ax.set_ylim(box[0, 1], box[1, 1])
    ax.set_zlim(box[0, 2], box[1, 2])
    ax.set_box_aspect(box[1] - box[0] + 1e-9, zoom=1.5)
    ax.view_init(elev=35, azim=-70)
    ax.set_axis_off()


def _vertex_normals(points: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals (V, 3)."""
    n = np.cross(points[faces[:, 1]] - points[faces[:, 0]], points[faces[:, 2]] - points[faces[:, 0]])
    out = np.zeros_like(points)
    for k in range(3):
        np.add.at(out, faces[:, k], n)
    return out / np.maximum(np.linalg.norm(out, axis=1, keepdims=True), 1e-300)


def _viewed(shapes: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Shapes (S, V, 3) turned so that the first one's mean normal faces the camera, and their common box (2, 3)."""
    view = _view_rotation(shapes[0], faces)
    centre = shapes[0].mean(axis=0)
    turned = (shapes - centre) @ view.T
    return turned, np.array([turned.reshape(-1, 3).min(axis=0), turned.reshape(-1, 3).max(axis=0)])


def plot_modes(mean: np.ndarray, modes: np.ndarray, deviations: np.ndarray, faces: np.ndarray, path, title="") -> Path:
    """PNG: each mode (rows) at -2, 0 and +2 standard deviations from the mean (columns), coloured by the signed
    displacement along the mean's normals (red out, blue in).

    Parameters
    ----------
    mean : ndarray (V, 3)
    modes : ndarray (k, V, 3)
        Unit modes (at most the first three are drawn).
    deviations : ndarray (k,)
        Standard deviation of each mode's scores.
    faces : ndarray (F, 3)
    """
    shown = min(3, len(modes))
    steps = (-2.0, 0.0, 2.0)
    shapes = np.array([mean + s * deviations[m] * modes[m] for m in range(shown) for s in steps] or [mean])
    turned, box = _viewed(shapes, faces)
    normals = _vertex_normals(mean, faces)
    fig = Figure(figsize=(9, 2.4 * max(shown, 1)))
    for m in range(shown):
        along = np.sum(2.0 * deviations[m] * modes[m] * normals, axis=1)
        limit = np.abs(along).max()
        for c, s in enumerate(steps):
            ax = fig.add_subplot(shown, 3, 3 * m + c + 1, projection="3d")
            _draw_surface(ax, turned[3 * m + c], faces, 0.5 * s * along, limit, box)
            ax.set_title(f"mode {m + 1}: {s:+.0f} sd" if s else f"mode {m + 1}: mean", fontsize=10)
    if not shown:
        ax = fig.add_subplot(1, 1, 1, projection="3d")
        _draw_surface(ax, turned[0], faces, np.zeros(len(mean)), 1.0, box)
        ax.set_title("mean (no variation)")
    fig.suptitle(title or "modes of variation")
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=80)
    return path


def plot_scores(scores: np.ndarray, explained: np.ndarray, names, path, title: str = "") -> Path:
    """PNG: the members' scores on modes 1 and 2 (and 1 and 3), labelled, and the explained variance per mode."""
    fig = Figure(figsize=(14, 4.5))
    labels = [Path(str(n)).stem for n in names]
    pairs = [(0, 1), (0, 2)] if scores.shape[1] > 2 else [(0, min(1, scores.shape[1] - 1))]
    for k, (a, b) in enumerate(pairs if scores.shape[1] else []):
        ax = fig.add_subplot(1, 3, k + 1)
        ax.scatter(scores[:, a], scores[:, b], c="tab:blue")
        for row, label in enumerate(labels):
            ax.annotate(label, (scores[row, a], scores[row, b]), fontsize=7, xytext=(3, 3), textcoords="offset points")
        ax.set_xlabel(f"mode {a + 1} ({100 * explained[a]:.1f}%)")
        ax.set_ylabel(f"mode {b + 1} ({100 * explained[b]:.1f}%)")
        ax.axhline(0, color="0.8", lw=0.8)
        ax.axvline(0, color="0.8", lw=0.8)
    bars = fig.add_subplot(1, 3, 3)
    shown = np.arange(1, len(explained) + 1)
    bars.bar(shown, 100 * explained, color="tab:blue")
    bars.plot(shown, 100 * np.cumsum(explained), "k.-", label="cumulative")
    bars.set_xlabel("mode")
    bars.set_ylabel("explained variance (%)")
    bars.set_ylim(0, 100)
    bars.legend(loc="center right")
    fig.suptitle(title or f"{len(labels)} members: scores on the principal modes")
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=90)
    return path


def write_morph(frames: np.ndarray, faces: np.ndarray, path, fps: int = 12, title: str = "") -> Path:
    """GIF (Pillow, through matplotlib's PillowWriter): the meshes ``frames`` (S, V, 3) in turn, seen from the first
    one's mean normal, faces coloured by the displacement from the first frame along its normals."""
    from matplotlib.animation import PillowWriter

    turned, box = _viewed(frames, faces)
    normals = _vertex_normals(turned[0], faces)
    along = np.sum((turned - turned[0]) * normals, axis=2)
    limit = np.abs(along).max()
    fig = Figure(figsize=(5, 4.2))
    ax = fig.add_subplot(1, 1, 1, projection="3d")
    path = Path(path)
    writer = PillowWriter(fps=fps)
    with writer.saving(fig, str(path), dpi=80):
        for k, frame in enumerate(turned):
            ax.clear()
            _draw_surface(ax, frame, faces, along[k], limit, box)
            ax.set_title(title, fontsize=9)
            writer.grab_frame()
    return path
