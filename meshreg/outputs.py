"""Read two surfaces, register them and write every output: the library function behind ``meshreg register`` and
``meshreg demo`` (the command line only parses arguments and prints what this returns).

Outputs in the directory ``out``:

- grids: ``result.npz`` (:meth:`meshreg.Registration.save`), ``registration.png`` (boundaries of R c1 and
  c2 o h, E per step), with ``symmetric`` also ``result_reverse.npz``;
- meshes: the same, plus ``first.ply`` and ``second.ply`` (the input vertices and faces, coloured so that
  corresponding points share a colour), ``registered.ply`` (the second surface on the first's grid, in the
  first's frame), ``meshes.png``, each mesh's uv and matched points in ``result.npz``, and with ``html`` the
  interactive page ``view.html``.

The output place is checked before any computation, the outputs of an earlier run there are removed, and the new
ones are written all together or not at all (:func:`meshreg.files.staged`). While it registers and writes, BLAS
runs with :data:`BLAS_THREADS` threads (threadpoolctl; the process's setting is restored after). See
docs/outputs.md.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import InputError
from .files import output_dir, read_npz, remove_outputs, staged, surface_kind, write_atomic
from .options import Options
from .ownership import refuse_foreign, writing
from .painter import Painter
from .result import Registration
from .schedule import Progress

RESULT_FILE = "result.npz"
REVERSE_FILE = "result_reverse.npz"
FIGURE_FILE = "registration.png"
MESH_FILES = ("first.ply", "second.ply", "registered.ply", "meshes.png")
VIEW_FILE = "view.html"
# every file a run may write: those of an earlier run are removed before this run computes, so that none of them
# can pass for this run's
OUTPUT_FILES = (RESULT_FILE, REVERSE_FILE, FIGURE_FILE, *MESH_FILES, VIEW_FILE)
DEMO_INPUTS = ("inputs/terrain_a.ply", "inputs/terrain_b.ply")
# BLAS threads of a registration written to files, as in the distance matrix's workers: the figure worker takes the
# other core, and OpenBLAS's default of one thread per core made `meshreg register` on two 100k-triangle meshes about
# twice as slow on a busy 2-core machine (OPENBLAS_NUM_THREADS unset: 10-14 s against 5-7 s)
BLAS_THREADS = 1


@dataclass
class Written:
    """What :func:`register_files` did: the result, the files written and what the mesh cleanup reported."""

    result: Registration
    files: list[Path]
    notes: list[str] = field(default_factory=list)
    reverse: Registration | None = None


def prepare_output(path, inputs: list[Path], names=OUTPUT_FILES) -> Path:
    """The output directory, checked before any computation (:func:`meshreg.files.output_dir`: made if missing;
    refused when it is a file, under a file, not writable, or an output would overwrite an input, a directory or a
    file meshreg did not write), with the outputs of an earlier run removed."""
    out = output_dir(path, names, inputs)
    remove_outputs(out, names)
    return out


def register_files(
    first,
    second,
    out,
    options: Options | None = None,
    *,
    grid_shape=None,
    symmetric: bool = False,
    html: bool = False,
    callback: Progress | None = None,
) -> Written:
    """Register two files (two grid files or two disk meshes, by suffix) and write the outputs to ``out``.

    Parameters
    ----------
    first, second : str or Path
    out : str or Path
        Output directory (made if missing; never an input's place).
    options : Options, optional
    grid_shape : (int, int), optional
        (M, N) of text grid files without a header line.
    symmetric : bool
        Grids: also register the second onto the first (``result_reverse.npz``).
    html : bool
        Meshes: also write the interactive page ``view.html``.
    callback : callable, optional
        Progress, as for :func:`meshreg.register`.
    """
    from .grid import read_grid
    from .mesh.topology import load_mesh
    from .surfaces import Mesh

    options = options or Options()
    paths = [Path(first), Path(second)]
    kinds = {surface_kind(p) for p in paths}
    if len(kinds) > 1:
        raise InputError("give two meshes or two grid files, not one of each")
    if kinds == {"mesh"}:
        if symmetric:
            raise InputError("--symmetric registers grid files both ways; for meshes, run register twice")
        meshes = [Mesh(*load_mesh(p), name=str(p)) for p in paths]
        side = (options.resolution, options.resolution)
        options.check_grids(side, side)
        return write_mesh_registration(*meshes, prepare_output(out, paths), options, callback, html)
    grids = [read_grid(p, grid_shape) for p in paths]
    options.check_grids(grids[0].shape, grids[1].shape)
    if symmetric:
        options.check_grids(grids[1].shape, grids[0].shape)
    written = write_grid_registration(grids[0], grids[1], prepare_output(out, paths), options, symmetric, callback)
    if html:
        written.notes.append("--html draws meshes: grids get no view.html")
    return written


def write_grid_registration(
    first, second, out: Path, options: Options, symmetric: bool = False, callback: Progress | None = None
) -> Written:
    """Register two GridSurfaces and write ``result.npz`` and ``registration.png`` (and the reverse result) into
    the prepared directory ``out``, all together or not at all."""
    from threadpoolctl import threadpool_limits

    from .pipeline import register_with

    _set_up_numba()
    with Painter() as painter, threadpool_limits(BLAS_THREADS):
        result = register_with(first, second, options, callback)
        reverse = register_with(second, first, options) if symmetric else None
        names = [RESULT_FILE, FIGURE_FILE] + ([REVERSE_FILE] if symmetric else [])
        with staged(out, names) as stage:
            title = f"{options.mode}: E = {result.energy:.3g}"
            _registration_figure(painter, result, first, second, stage / FIGURE_FILE, title)
            result.save(stage / RESULT_FILE)
            if reverse is not None:
                reverse.save(stage / REVERSE_FILE)
            painter.finish()
    return Written(result, [out / name for name in names], reverse=reverse)


def write_mesh_registration(
    first, second, out: Path, options: Options, callback: Progress | None = None, html: bool = False
) -> Written:
    """Register two meshes (:class:`meshreg.surfaces.Mesh`) and write coloured meshes, ``result.npz``, both
    figures and, with ``html``, the interactive page ``view.html``. The figures are drawn by a
    :class:`~meshreg.painter.Painter` (in worker processes where it can) while the other files are written."""
    from threadpoolctl import threadpool_limits

    from .mesh.correspond import register_meshes
    from .mesh.export import colored_outputs, write_ply

    _set_up_numba()
    with Painter(workers=2) as painter, threadpool_limits(BLAS_THREADS):
        mr = register_meshes(first, second, options, callback)
        result = mr.result
        title = f"E = {result.energy:.3g}"
        names = [RESULT_FILE, FIGURE_FILE, *MESH_FILES] + ([VIEW_FILE] if html else [])
        with staged(out, names) as stage:
            # queued first: the painter draws it while the coloured meshes and the correspondence are computed
            _registration_figure(painter, result, *mr.grids, stage / FIGURE_FILE, title)
            (v1, f1), (v2, f2) = (first.vertices, first.faces), (second.vertices, second.faces)
            c1, c2, registered = colored_outputs(mr, len(v1), len(v2))
            # queued as soon as its data is there: the worker is still drawing registration.png
            painter.draw(
                "plot_meshes",
                stage / "meshes.png",
                v1,
                f1,
                c1,
                v2,
                f2,
                c2,
                title=f"{title}: corresponding points share a colour and a checkerboard square",
                second_to_first=np.linalg.inv(result.transform),
                distance=result.distances() / np.sqrt(result.second.area()),
            )
            on_second = result.correspondence()
            # result.correspondence_on_first(), from the second's matches on the first's square already found
            on_first = result.first.at_uv(mr.second.to_input(mr.matched_uv2, len(v2), [np.nan, np.nan]))[0]
            uv = {"uv_first": result.first.input_uv(), "uv_second": result.second.input_uv()}
            write_ply(stage / "first.ply", v1, f1, c1)
            write_ply(stage / "second.ply", v2, f2, c2)
            write_ply(stage / "registered.ply", *registered)
            result.save(stage / RESULT_FILE, **uv, matched_first=on_second, matched_second=on_first)
            if html:
                from .view import write_view

                write_view(
                    stage / VIEW_FILE,
                    (v1, f1, c1),
                    (v2, f2, c2),
                    (on_second, on_first),
                    np.linalg.inv(result.transform),
                    title=f"{title}: hover a point to see its match",
                )
            painter.finish()
    return Written(result, [out / name for name in names], _mesh_notes(mr.info))


def _written_mesh(path: Path):
    """A coloured mesh that ``meshreg register`` wrote (trimesh, as stored), or InputError when it cannot be read."""
    import trimesh

    try:
        mesh = trimesh.load(path, process=False, maintain_order=True)
    except Exception as err:  # noqa: BLE001 - trimesh's readers raise many kinds on a damaged file
        raise InputError(
            f"{path}: cannot read this mesh ({type(err).__name__}: {err}): rerun meshreg register"
        ) from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise InputError(f"{path}: not a triangle mesh: rerun meshreg register")
    return mesh


def _set_up_numba() -> None:
    """Run one small B-spline evaluation (the bicubic values kernel, which every registration loads) before the
    figure worker forks: numba's own set-up (0.2-0.5 s once per process, the first time a cached kernel is loaded)
    is then done once, here, and inherited by the worker instead of done again there beside the registration; the
    other kernels are loaded where they are first called."""
    from .spline import GridInterpolator

    nodes = np.linspace(0.0, 1.0, 4)
    GridInterpolator(np.zeros((4, 4, 1)), nodes, nodes).values(nodes, nodes)


def _mesh_notes(info: dict) -> list[str]:
    """What the cleanup, the parametrization and the overlap check reported, one line each."""
    notes = []
    for name in ("first", "second"):
        notes += [f"{name} mesh cleanup: {line}" for line in info[name]["cleanup"]]
        if info[name]["flipped"]:
            notes.append(f"{name} mesh: {info[name]['flipped']} triangles flipped by the parametrization")
    if "overlap" in info:
        notes.append(overlap_note(info["overlap"]))
    if info.get("pose_check", {}).get("kept") == "pose":
        whole = info["pose_check"]
        notes.append(
            f"registered at the overlap's pose: the whole registration did not fit the points (residual "
            f"{whole['residual']:.4f}, E {whole['energy']:.4g}; docs/overlap.md)"
        )
    return notes


def _registration_figure(painter: Painter, result: Registration, first, second, path: Path, title: str) -> None:
    """``registration.png`` of a result of the grids ``first`` and ``second`` (as given; both drawn at area 1)."""
    painter.draw(
        "plot_registration",
        result.apply(first.scaled().points),
        second.scaled().at(result.h),
        result.energy_history,
        path,
        title=f"{title}, residual = {result.residual:.3g}",
        stages=result.energy_stages,
        **({"minimized": "E_w (E with local similarities)"} if "bend_energy" in result.params else {}),
        notes=result.correspondence_notes(),
    )


def overlap_note(overlap: dict) -> str:
    """One line saying how much of each mesh overlaps the other and what was registered."""
    share = f"first {overlap['first_fraction']:.1%}, second {overlap['second_fraction']:.1%} of their area"
    if overlap["regime"] == "full":
        return f"overlap: the meshes cover the same region ({share}); registered whole"
    if overlap["regime"] == "whole":
        return f"overlap: {share} at the best pose, not trusted ({overlap['reason']}); registered whole"
    how = "the same surface" if overlap["regime"] == "rigid" else "a deformed surface"
    unused = f"; not used for it: {', '.join(overlap['unused'])}" if overlap.get("unused") else ""
    return f"overlap: {share} ({how}); only the common region registered, vertices outside it unmatched (grey){unused}"


def run_demo(out, options: Options | None = None, callback: Progress | None = None, html: bool = True) -> Written:
    """``meshreg demo``: a terrain patch (matplotlib's Jacksboro DEM) meshed twice with different random vertices,
    the second rotated, scaled and shifted; both written to ``out/inputs`` and registered into ``out``. The notes
    compare the answer with the motion applied and with the true correspondence."""
    from scipy.interpolate import LinearNDInterpolator

    from .mesh.samples import DEMO_ROTATION, DEMO_SCALE, demo_pair, write_demo_meshes
    from .rotation import angle_between
    from .surfaces import Mesh

    out = prepare_output(out, [], OUTPUT_FILES + DEMO_INPUTS)
    pair = (v1, f1, p1), (v2, f2, p2) = demo_pair()
    with writing(out, DEMO_INPUTS):
        inputs = write_demo_meshes(out / "inputs", pair)[0].parent
    meshes = Mesh(v1, f1, "terrain_a"), Mesh(v2, f2, "terrain_b")
    written = write_mesh_registration(*meshes, out, options or Options(), callback, html)
    result = written.result
    angle = angle_between(result.transform[:3, :3] / result.scale, DEMO_ROTATION)
    # true partner of each first-mesh vertex: the second mesh at the same patch parameter (linear in its triangles)
    error = np.linalg.norm(result.correspondence() - LinearNDInterpolator(p2, v2)(p1), axis=1)
    written.notes[:0] = [
        f"inputs in {inputs}: {len(v1)} and {len(v2)} vertices",
        f"check: rotation {angle:.2f} deg from the one applied, scale {result.scale:.4f} (applied {DEMO_SCALE}), "
        f"corresponding points {np.nanmedian(error) / np.sqrt(result.second.area()):.2%} of sqrt(area) from the "
        "true ones (median)",
    ]
    return written


def view_outputs(out) -> Path:
    """``meshreg view OUT``: the interactive page ``OUT/view.html`` of a mesh registration written to ``OUT``."""
    from .view import write_view

    out = Path(out)
    if not out.is_dir():
        raise InputError(f"{out}: no such directory: give the -o directory of a meshreg register run")
    names = [out / "first.ply", out / "second.ply", out / RESULT_FILE]
    missing = [str(p) for p in names if not p.is_file()]
    if missing:
        raise InputError(f"{out} holds no mesh registration (missing {', '.join(missing)}): run meshreg register first")
    refuse_foreign(out, [VIEW_FILE], "move or delete it first")
    meshes = [_written_mesh(p) for p in names[:2]]
    data = read_npz(names[2], "result")
    missing = sorted({"matched_first", "matched_second", "transform", "energy"} - set(data))
    if missing:
        raise InputError(f"{names[2]} lacks {', '.join(missing)} (not a mesh registration's): rerun meshreg register")
    matches = (data["matched_first"], data["matched_second"])
    transform, energy = data["transform"], float(data["energy"])
    for path, mesh, matched in zip(names[:2], meshes, matches, strict=True):
        if len(matched) != len(mesh.vertices):
            raise InputError(
                f"{path} has {len(mesh.vertices)} vertices, {names[2]} matches {len(matched)}: the files are not of "
                "one run; rerun meshreg register"
            )
    first, second = ((m.vertices, m.faces, m.visual.vertex_colors[:, :3] / 255.0) for m in meshes)
    title = f"E = {energy:.3g}: hover a point to see its match"
    with writing(out, [VIEW_FILE]):
        return write_atomic(
            out / VIEW_FILE, lambda tmp: write_view(tmp, first, second, matches, np.linalg.inv(transform), title=title)
        )
