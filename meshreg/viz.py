"""Every figure meshreg writes (PNG), drawn on :class:`matplotlib.figure.Figure` objects: no pyplot state and no
backend switch, so importing this module changes nothing in a notebook.

- :func:`plot_registration`: boundaries of R c1 and c2 o h, as in the paper (projected by an orthographic camera),
  and the energy per accepted step;
- :func:`plot_meshes`: two meshes side by side, coloured so that corresponding points share a colour (rendered to
  images with a depth buffer, :func:`render_mesh`);
- :func:`plot_matrix`: a distance matrix as a heat map ordered by a dendrogram, and its MDS embedding.
"""

from __future__ import annotations

import functools
import os
from pathlib import Path

import matplotlib
import numba
import numpy as np
from matplotlib.figure import Figure
from PIL import Image, ImageDraw, ImageFont

from .mesh.graph import face_normals

# mesh panels are rendered to images with a depth buffer (:func:`render_mesh`; matplotlib's 3D axes drew one path
# per triangle: two 100k-triangle meshes took 4 s, 1.2-2 s from copies simplified to 20000 triangles), the mesh
# filling all but this fraction of the panel on each side
RENDER_MARGIN = 0.03


def _boundary(points: np.ndarray) -> np.ndarray:
    """The boundary loop of a grid surface (M, N, 3) as a closed polyline (K, 3)."""
    return np.concatenate([points[:, 0], points[-1, 1:], points[::-1, -1][1:], points[0, ::-1][1:]])


def plot_registration(
    first_rotated: np.ndarray,
    second_registered: np.ndarray,
    history,
    path,
    title: str = "",
    stages=(),
    minimized: str = "E (squared elastic distance)",
    notes=(),
) -> Path:
    """Write a PNG: R c1 and c2 o h overlaid (boundaries and iso-lines, each centred), where on the square they
    differ, and E (or what was minimized) per accepted step with the stages marked.

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
    title : str
    stages : sequence of str, optional
        The stage of each entry of ``history`` (:attr:`meshreg.Registration.energy_stages`); stage changes are
        marked on the energy curve.
    minimized : str
        What ``history`` holds, for the curve's axis (meshes in the bending path: E_w, :mod:`meshreg.bending`).
    notes : sequence of str, optional
        Lines written under the panels (:meth:`meshreg.Registration.correspondence_notes`: an ambiguous or
        mirrored correspondence).
    """
    first = first_rotated - first_rotated.reshape(-1, 3).mean(axis=0)  # E does not see translations: overlay them
    second = second_registered - second_registered.reshape(-1, 3).mean(axis=0)
    fig = Figure(figsize=(15, 4.8), dpi=FIGURE_DPI)
    bottom = 0.12 + 0.035 * len(notes)
    fig.subplots_adjust(left=0.02, right=0.98, bottom=bottom, top=0.9, wspace=0.42)
    ax = fig.add_subplot(1, 3, 1)
    turn = camera(ELEVATION, AZIMUTH)[:2]  # the curves drawn as an orthographic camera sees them
    for pts, style, label in ((first, "b-", "R c1"), (second, "r--", "c2 o h")):
        ax.plot(*(_boundary(pts) @ turn.T).T, style, label=label)
        for j in np.linspace(0, pts.shape[1] - 1, 5).astype(int)[1:-1]:
            ax.plot(*(pts[:, j] @ turn.T).T, style, lw=0.6, alpha=0.6)
    ax.legend(loc="upper left")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_axis_off()
    ax.set_title(title or "after registration (both centred, area 1)", fontsize=10)
    gap = fig.add_subplot(1, 3, 2)
    image = gap.imshow(np.linalg.norm(first - second, axis=-1).T, origin="lower", extent=(0, 1, 0, 1), cmap="magma")
    fig.colorbar(image, ax=gap, label="|R c1 - c2 o h| (area 1, centred)")
    gap.set_xlabel("r (first surface)")
    gap.set_ylabel("t (first surface)")
    gap.set_title("where the registered surfaces differ", fontsize=10)
    curve = fig.add_subplot(1, 3, 3)
    values = np.maximum(np.asarray(history, dtype=float), 1e-16)
    energies = np.log10(values)  # log10 on a linear axis: the log axis's labels took 0.2-0.5 s of mathtext
    curve.plot(energies, "k.-", ms=3)
    stages = list(stages)
    if len(stages) == len(energies):
        for k, level in _level_starts(stages):
            curve.axvline(k, color="tab:blue", lw=0.8, alpha=0.6)
            curve.annotate(level, (k, energies.max()), rotation=90, va="top", ha="right", fontsize=8, color="tab:blue")
    curve.set_xlabel("accepted step")
    curve.set_ylabel(f"log10 {minimized}")
    descent = f"{values[0]:.3g} -> {values[-1]:.3g}" if len(values) > 1 else f"{values[0]:.3g}, no descent"
    curve.set_title(f"energy: {descent}", fontsize=10)
    curve.grid(True, alpha=0.3)
    for k, line in enumerate(notes):
        fig.text(0.01, 0.01 + 0.035 * k, line, fontsize=9, color="tab:red", wrap=True)
    path = Path(path)
    fig.savefig(path, dpi=FIGURE_DPI, pil_kwargs={"compress_level": PNG_COMPRESSION})
    return path


def warm_up() -> None:
    """Draw a tiny figure with everything :func:`plot_registration` and :func:`plot_meshes` use (lines, a
    rendered mesh image, a colour bar, titles, a PNG written to nowhere), so that their first call in this process
    does not pay for matplotlib's lazy set-up (fonts, the PNG writer) and for loading the renderer's numba kernel:
    about 0.5 s of a 100k-triangle ``meshes.png`` drawn first. A figure worker (:mod:`meshreg.painter`) runs it
    while the caller registers."""
    from matplotlib.colors import Normalize

    points = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    fig = Figure(figsize=(2, 1), dpi=20)
    ax = fig.add_subplot(1, 2, 1)
    ax.plot(points[:, 0], points[:, 1], "b-", label="a")
    ax.legend(loc="upper left")
    ax.set_title("warm", fontsize=10)
    image = fig.add_subplot(1, 2, 2).imshow(np.eye(2), origin="lower", extent=(0, 1, 0, 1), cmap="magma")
    fig.colorbar(image, ax=image.axes, label="warm")
    _paint(_mesh_picture(points, np.array([[0, 1, 2]]), 8, 8)[0], np.full((1, 3), 0.5))
    _mesh_figure_text(["warm"], "warm", Normalize(0.0, 1.0))  # its fonts (PIL) and colour bar
    fig.suptitle("warm")
    fig.text(0.0, 0.0, "warm", fontsize=9)
    fig.savefig(os.devnull, format="png", pil_kwargs={"compress_level": PNG_COMPRESSION})


def _save(fig: Figure, path, title: str, dpi: int) -> Path:
    """Title the figure, lay it out and write it to ``path`` (PNG)."""
    fig.suptitle(title)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=dpi)
    return path


def _level_starts(stages) -> list[tuple[int, str]]:
    """(index, level) where each level of a run begins in its energy history; Kabsch steps belong to the level
    around them, and E on arrival at the full grid to the refinement that follows."""
    out, previous = [], None
    for k, stage in enumerate(stages):
        level = {"full grid": "refine"}.get(stage, stage)
        if level not in ("kabsch", "start") and level != previous:
            out.append((k, level))
            previous = level
    return out


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
    emb.set_xlabel("MDS axis 1 (elastic distance units)")
    emb.set_ylabel("MDS axis 2 (elastic distance units)")
    emb.set_aspect("equal", adjustable="datalim")
    fig.suptitle(title or f"{len(names)} surfaces, {len(names) * (len(names) - 1) // 2} pairs")
    path = Path(path)
    fig.savefig(path, dpi=120, bbox_inches="tight")
    return path


def _view_rotation(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    """A rotation (3, 3) taking the mesh's mean (area-weighted) normal to +z: the camera then faces the surface."""
    n = face_normals(v, f).sum(axis=0)
    z = n / max(np.linalg.norm(n), 1e-300)
    x = np.cross([0.0, 1.0, 0.0] if abs(z[1]) < 0.9 else [1.0, 0.0, 0.0], z)
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(z, x), z])


ELEVATION, AZIMUTH = 35.0, -60.0  # oblique camera of the mesh pictures, degrees
MESH_DPI = 110  # pixels per inch of meshes.png (each panel 5.5 x 5.2 inches)
FIGURE_DPI = 110  # pixels per inch of registration.png (15 x 4.8 inches)
# zlib level of meshes.png and registration.png: 1 writes them in two thirds of the time of the default 6, 15-25% larger
PNG_COMPRESSION = 1


def plot_meshes(
    path,
    v1,
    f1,
    c1,
    v2,
    f2,
    c2,
    title: str = "",
    second_to_first: np.ndarray | None = None,
    distance: np.ndarray | None = None,
) -> Path:
    """PNG: the two meshes side by side, coloured by correspondence, lit and seen obliquely from the first's side.

    Parameters
    ----------
    path : str or Path
    v1, f1, c1, v2, f2, c2 : ndarray
        Vertices (n, 3), faces (m, 3) and colours (n, 3) in [0, 1] of each mesh.
    title : str
    second_to_first : ndarray, shape (4, 4), optional
        The similarity from the second's frame to the first's: the second mesh is drawn in the first's pose, so
        the pictures compare point by point.
    distance : ndarray, shape (n1,), optional
        Per vertex of the first mesh, the distance to its corresponding point (relative to sqrt(area)); drawn as a
        third panel with a colour bar.
    """
    if second_to_first is not None:
        v2 = v2 @ second_to_first[:3, :3].T + second_to_first[:3, 3]
    view = _view_rotation(v1, f1)
    first, second = ((v - v1.mean(axis=0)) @ view.T for v in (v1, v2))
    panels = [(first, f1, _face_means(c1, f1), f"first mesh ({len(v1)} vertices)")]
    pose = ", in the first's pose" if second_to_first is not None else ""
    panels.append((second, f2, _face_means(c2, f2), f"second mesh ({len(v2)} vertices){pose}"))
    norm = None
    if distance is not None:
        norm, colors = _distance_colors(distance, f1)
        panels.append((first, f1, colors, "distance to the corresponding point"))
    pixels, places = _mesh_figure_text([name for *_, name in panels], title, norm)
    pictures = {}  # the first mesh's picture (triangle per pixel, shading) serves its two panels, all equally sized
    for (rows, columns), (v, f, c, _) in zip(places, panels, strict=True):
        if id(v) not in pictures:
            pictures[id(v)] = _mesh_picture(v, f, columns.stop - columns.start, rows.stop - rows.start)
        ids, shade = pictures[id(v)]
        pixels[rows, columns] = _paint(ids, np.clip(c * shade[:, None], 0, 1))
    path = Path(path)
    Image.fromarray(pixels).save(path, format="png", compress_level=PNG_COMPRESSION)
    return path


def _mesh_figure_text(names: list[str], title: str, norm) -> tuple[np.ndarray, list[tuple[slice, slice]]]:
    """The text of ``meshes.png`` (panel names, title and, with the distance's ``norm``, its colour bar) as 8-bit RGB
    pixels (h, w, 3), and where each panel's picture goes: (rows, columns), every panel as wide (one picture can
    serve two). Laid out as matplotlib lays out a figure of one row of ``len(names)`` axes (5.5 x 5.2 inches each,
    MESH_DPI) and drawn with PIL in matplotlib's font: a matplotlib figure of it took 0.12 s, most of it making the
    colour bar's ticks."""
    count = len(names)
    width, height = round(5.5 * count * MESH_DPI), round(5.2 * MESH_DPI)
    right = 0.99 - 0.06 * (norm is not None)  # room for the colour bar
    bottom, top, left, gap = 0.02, 0.88, 0.01, 0.04  # as GridSpec(left, right, bottom, top, wspace=gap)
    cell = (right - left) / (count + gap * (count - 1))
    lefts = left + np.arange(count) * cell * (1 + gap)
    image = Image.new("RGB", (width, height), "white")
    draw = ImageDraw.Draw(image)
    across = int((lefts[0] + cell) * width) - int(round(lefts[0] * width))
    places = []
    for k, name in enumerate(names):
        x0, y0 = int(round(lefts[k] * width)), int(round((1 - top) * height))
        places.append((slice(y0, int((1 - bottom) * height)), slice(x0, x0 + across)))
        baseline = (1 - top) * height - _pixels(6)  # 6 points above the panel, where matplotlib puts an axes title
        draw.text(((lefts[k] + cell / 2) * width, baseline), name, fill="black", font=_font(10), anchor="ms")
    draw.text((width / 2, 0.02 * height), title or MESH_TITLE, fill="black", font=_font(12), anchor="mt")
    if norm is not None:
        x, y, w, h = right + 0.005, bottom + 0.2 * (top - bottom), 0.008, 0.6 * (top - bottom)  # figure fractions
        box = [round(x * width), round((1 - y - h) * height), round((x + w) * width), round((1 - y) * height)]
        _colour_bar(image, draw, norm, box)
    return np.asarray(image).copy(), places


MESH_TITLE = "corresponding points share a colour and a checkerboard square"
BAR_LABEL = "fraction of sqrt(area)"


def _pixels(points: float) -> float:
    """A length in points (1/72 inch) in pixels of meshes.png."""
    return points * MESH_DPI / 72


@functools.cache
def _font(points: float):
    """DejaVu Sans, matplotlib's default font (from its data directory), at ``points`` on meshes.png."""
    path = Path(matplotlib.get_data_path()) / "fonts" / "ttf" / "DejaVuSans.ttf"
    return ImageFont.truetype(str(path), round(_pixels(points)))


def _colour_bar(image, draw, norm, box: list[int]) -> None:
    """A vertical viridis bar for ``norm`` (vmin at the bottom) in ``box`` (x0, y0, x1, y1 pixels), outlined, with
    ticks at matplotlib's default places (:class:`~matplotlib.ticker.MaxNLocator`), their values and BAR_LABEL (with
    the values' power of ten) on its right."""
    from matplotlib import cm
    from matplotlib.ticker import MaxNLocator

    x0, y0, x1, y1 = box
    shades = cm.viridis(np.linspace(1.0, 0.0, y1 - y0))[:, :3]  # top row first
    image.paste(Image.fromarray(np.round(np.repeat(shades[:, None], x1 - x0, axis=1) * 255).astype(np.uint8)), (x0, y0))
    draw.rectangle((x0, y0, x1, y1), outline="black", width=1)
    lo, hi = float(norm.vmin), float(norm.vmax)
    if not hi > lo:  # one value (every distance 0): spread around it, as matplotlib's colour bar does
        lo, hi = lo - (0.1 * abs(lo) or 0.1), hi + (0.1 * abs(hi) or 0.1)
    places = MaxNLocator(nbins=6, steps=[1, 2, 2.5, 5, 10]).tick_values(lo, hi)
    ticks = [v for v in places if lo - 1e-9 * (hi - lo) <= v <= hi + 1e-9 * (hi - lo)]
    labels, power = _tick_labels(np.array(ticks))
    reach = x1
    for value, label in zip(ticks, labels, strict=True):
        y = y1 - (value - lo) / (hi - lo) * (y1 - y0)
        draw.line((x1, y, x1 + _pixels(3.5), y), fill="black", width=1)
        draw.text((x1 + _pixels(5.5), y), label, fill="black", font=_font(10), anchor="lm")
        reach = max(reach, x1 + _pixels(5.5) + draw.textlength(label, font=_font(10)))
    label = BAR_LABEL + power
    text = Image.new("L", (round(draw.textlength(label, font=_font(10))) + 4, round(_pixels(14))), 0)
    ImageDraw.Draw(text).text((2, 0), label, fill=255, font=_font(10))
    text = text.rotate(90, expand=True)
    image.paste((0, 0, 0), (round(reach + _pixels(4)), round((y0 + y1 - text.height) / 2)), text)


def _tick_labels(ticks: np.ndarray) -> tuple[list[str], str]:
    """Labels of tick values with the fewest decimals that keep them apart, and the power of ten they are given in
    ("" or, for values below 0.001 or from 10,000 on, like " (x 1e-05)", as matplotlib's offset text)."""
    top = float(np.max(np.abs(ticks))) if len(ticks) else 0.0
    power = int(np.floor(np.log10(top))) if top > 0 and not 1e-3 <= top < 1e4 else 0
    scaled = ticks / 10.0**power
    step = float(np.min(np.diff(scaled))) if len(scaled) > 1 else 1.0
    decimals = next((d for d in range(16) if np.allclose(np.round(scaled, d), scaled, rtol=0, atol=step * 1e-6)), 16)
    return [f"{v:.{decimals}f}" for v in scaled], f" (x 1e{power:+03d})" if power else ""


def _face_means(values: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """The mean (m, k) of per-vertex values (n, k) over each triangle's corners."""
    return (values[faces[:, 0]] + values[faces[:, 1]] + values[faces[:, 2]]) / 3


def _distance_colors(distance: np.ndarray, faces: np.ndarray):
    """The colour scale (0 to the 98th percentile) and face colours (m, 3) of per-vertex distances ``distance``
    (n,), grey where no vertex of a face has one (NaN: outside the overlap, dropped)."""
    from matplotlib import cm
    from matplotlib.colors import Normalize

    finite = distance[np.isfinite(distance)]
    norm = Normalize(0.0, float(np.percentile(finite, 98)) if len(finite) else 1.0)
    known = np.isfinite(distance[faces])
    total = np.where(known, distance[faces], 0.0).sum(axis=1)
    face_value = np.where(known.any(axis=1), total / np.maximum(known.sum(axis=1), 1), np.nan)
    colors = cm.viridis(norm(np.nan_to_num(face_value, nan=0.0)))[:, :3]
    colors[np.isnan(face_value)] = 0.6
    return norm, colors


def _mesh_picture(points: np.ndarray, faces: np.ndarray, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """The triangle seen at each pixel (height, width; -1 for none) of a mesh seen by an orthographic camera at
    ELEVATION and AZIMUTH (:func:`render_mesh`), and each triangle's shade (m,) in LIGHT (Lambert, with an ambient
    floor; both sides lit: the winding of a scan is arbitrary)."""
    normal = face_normals(points, faces)
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)
    shade = 0.45 + 0.55 * np.abs(normal @ LIGHT)
    return _face_ids(points @ camera(ELEVATION, AZIMUTH).T, faces, width, height), shade


def _paint(ids: np.ndarray, colors: np.ndarray) -> np.ndarray:
    """8-bit RGB pixels (h, w, 3) of a picture of triangle ids (h, w) in the triangles' colours (m, 3) in [0, 1],
    white where no triangle is seen."""
    palette = np.round(np.vstack([colors, np.ones((1, 3))]) * 255).astype(np.uint8)
    return palette[ids]  # id -1 picks the last row, white


def camera(elevation: float, azimuth: float) -> np.ndarray:
    """Rows: the screen's right, its up and the direction towards the viewer (3, 3) of a camera at ``elevation``
    and ``azimuth`` (degrees, as matplotlib's 3D axes)."""
    e, a = np.radians(elevation), np.radians(azimuth)
    towards = np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])
    right = np.array([-np.sin(a), np.cos(a), 0.0])
    return np.stack([right, np.cross(towards, right), towards])


def render_mesh(points: np.ndarray, faces: np.ndarray, colors: np.ndarray, width: int, height: int) -> np.ndarray:
    """An RGB image (height, width, 3) of triangles (points (n, 3) in screen coordinates: x right, y up, z towards
    the viewer; faces (m, 3); one colour (m, 3) each) drawn orthographically with a depth buffer: each pixel
    whose centre lies in a triangle takes the colour of the nearest such triangle; the rest is white. The mesh is
    scaled to fit with a margin of RENDER_MARGIN, the same scale along x and y."""
    palette = np.vstack([np.asarray(colors, float).reshape(-1, 3), np.ones((1, 3))])  # id -1: white
    return palette[_face_ids(points, faces, width, height)]


def _face_ids(points: np.ndarray, faces: np.ndarray, width: int, height: int) -> np.ndarray:
    """The nearest triangle (its index) whose face covers each pixel's centre, -1 where none does: (height, width),
    for points in screen coordinates as :func:`render_mesh` takes them, fitted as it describes."""
    xy = points[:, :2] - 0.5 * (points[:, :2].min(axis=0) + points[:, :2].max(axis=0))
    extent = np.maximum(np.ptp(xy, axis=0), 1e-300)
    scale = (1 - 2 * RENDER_MARGIN) * min(width / extent[0], height / extent[1])
    screen = np.c_[xy[:, 0] * scale + 0.5 * width - 0.5, 0.5 * height - 0.5 - xy[:, 1] * scale, points[:, 2]]
    ids = np.full((height, width), -1, dtype=np.int64)
    _rasterize(np.ascontiguousarray(screen), np.ascontiguousarray(faces, dtype=np.int64), ids)
    return ids


@numba.njit(cache=True)
def _rasterize(screen, faces, ids):  # pragma: no cover (numba)
    """Write into ``ids`` (height, width) the nearest triangle covering each pixel (pixel x, pixel y with row 0 at
    the top, depth towards the viewer)."""
    height, width = ids.shape[0], ids.shape[1]
    depth = np.full((height, width), -np.inf)
    for f in range(faces.shape[0]):
        ax, ay, az = screen[faces[f, 0], 0], screen[faces[f, 0], 1], screen[faces[f, 0], 2]
        bx, by, bz = screen[faces[f, 1], 0], screen[faces[f, 1], 1], screen[faces[f, 1], 2]
        cx, cy, cz = screen[faces[f, 2], 0], screen[faces[f, 2], 1], screen[faces[f, 2], 2]
        area = (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)
        if abs(area) < 1e-12:
            continue
        x0, x1 = max(int(np.ceil(min(ax, bx, cx))), 0), min(int(np.floor(max(ax, bx, cx))), width - 1)
        y0, y1 = max(int(np.ceil(min(ay, by, cy))), 0), min(int(np.floor(max(ay, by, cy))), height - 1)
        for y in range(y0, y1 + 1):
            for x in range(x0, x1 + 1):
                wb = ((x - ax) * (cy - ay) - (y - ay) * (cx - ax)) / area
                wc = ((bx - ax) * (y - ay) - (by - ay) * (x - ax)) / area
                wa = 1.0 - wb - wc
                if wa < -1e-9 or wb < -1e-9 or wc < -1e-9:
                    continue
                z = wa * az + wb * bz + wc * cz
                if z > depth[y, x]:
                    depth[y, x] = z
                    ids[y, x] = f


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


# unit direction of the light in the turned frame (the camera looks down -z); normalized: at 1.0034 long it lit a
# face turned to it above full brightness, and matplotlib refused the colour (an atlas of four held-out members)
LIGHT = np.array([-0.4, -0.3, 0.87]) / np.linalg.norm([-0.4, -0.3, 0.87])


def _draw_surface(ax, points: np.ndarray, faces: np.ndarray, values: np.ndarray, limit: float, box) -> None:
    """One mesh on a 3D axis, faces coloured by ``values`` (per vertex) on a diverging scale of +-``limit``."""
    from matplotlib import colormaps

    colors = colormaps["coolwarm"](np.clip(0.5 + 0.5 * values[faces].mean(axis=1) / max(limit, 1e-300), 0, 1))
    n = np.cross(points[faces[:, 1]] - points[faces[:, 0]], points[faces[:, 2]] - points[faces[:, 0]])
    light = np.minimum(np.abs(n @ LIGHT) / np.maximum(np.linalg.norm(n, axis=1), 1e-300), 1.0)  # two-sided
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
    from mpl_toolkits.mplot3d import Axes3D  # noqa: F401  (registers the "3d" projection)

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
    return _save(fig, path, title or "modes of variation", dpi=80)


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
    return _save(fig, path, title or f"{len(labels)} members: scores on the principal modes", dpi=90)


def write_morph(frames: np.ndarray, faces: np.ndarray, path, fps: int = 12, title: str = "") -> Path:
    """GIF (Pillow, through matplotlib's PillowWriter): the meshes ``frames`` (S, V, 3) in turn, seen from the first
    one's mean normal, faces coloured by the displacement from the first frame along its normals."""
    from matplotlib.animation import PillowWriter
    from mpl_toolkits.mplot3d import Axes3D  # noqa: F401  (registers the "3d" projection)

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
