"""Read two surfaces, register them and write every output: the library function behind ``meshreg register`` and
``meshreg demo`` (the command line only parses arguments and prints what this returns).

Outputs in the directory ``out``:

- grids: ``result.npz`` (:meth:`meshreg.Registration.save`), ``registration.png`` (boundaries of R c1 and
  c2 o h, E per step), with ``symmetric`` also ``result_reverse.npz``;
- meshes: the same, plus ``first.ply`` and ``second.ply`` (the input vertices and faces, coloured so that
  corresponding points share a colour), ``registered.ply`` (the second surface on the first's grid, in the
  first's frame), ``meshes.png``, and each mesh's uv in ``result.npz`` (``uv_first``, ``uv_second``).

See docs/outputs.md.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import InputError
from .options import Options
from .result import Registration
from .schedule import Progress

RESULT_FILE = "result.npz"
REVERSE_FILE = "result_reverse.npz"
FIGURE_FILE = "registration.png"
MESH_FILES = ("first.ply", "second.ply", "registered.ply", "meshes.png")


@dataclass
class Written:
    """What :func:`register_files` did: the result, the files written and what the mesh cleanup reported."""

    result: Registration
    files: list[Path]
    notes: list[str] = field(default_factory=list)
    reverse: Registration | None = None


def output_dir(path, inputs: list[Path]) -> Path:
    """The output directory, made if missing; refused when it is a file or would overwrite an input."""
    out = Path(path)
    if out.exists() and not out.is_dir():
        raise InputError(f"{out} exists and is not a directory: give another -o")
    resolved = {p.resolve() for p in inputs}
    for name in (RESULT_FILE, REVERSE_FILE, FIGURE_FILE, *MESH_FILES):
        if (out / name).resolve() in resolved:
            raise InputError(f"{out / name} is an input file: choose another output directory")
    out.mkdir(parents=True, exist_ok=True)
    return out


def register_files(
    first,
    second,
    out,
    options: Options | None = None,
    *,
    grid_shape=None,
    symmetric: bool = False,
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
    callback : callable, optional
        Progress, as for :func:`meshreg.register`.
    """
    from .grid import read_grid
    from .mesh.topology import MESH_SUFFIXES, load_mesh

    options = options or Options()
    paths = [Path(first), Path(second)]
    is_mesh = [p.suffix.lower() in MESH_SUFFIXES for p in paths]
    if any(is_mesh):
        if not all(is_mesh):
            raise InputError("give two meshes or two grid files, not one of each")
        meshes = [load_mesh(p) for p in paths]
        return write_mesh_registration(meshes[0], meshes[1], output_dir(out, paths), options, callback)
    grids = [read_grid(p, grid_shape) for p in paths]
    return write_grid_registration(grids[0], grids[1], output_dir(out, paths), options, symmetric, callback)


def write_grid_registration(
    first, second, out: Path, options: Options, symmetric: bool = False, callback: Progress | None = None
) -> Written:
    """Register two GridSurfaces and write ``result.npz`` and ``registration.png`` (and the reverse result)."""
    from .register import register_with
    from .viz import plot_registration

    result = register_with(first, second, options, callback)
    result.save(out / RESULT_FILE)
    plot_registration(
        result.apply(first.scaled().points),
        second.scaled().at(result.h),
        result.energy_history,
        out / FIGURE_FILE,
        title=f"{options.mode}: E = {result.energy:.3g}",
    )
    written = Written(result, [out / RESULT_FILE, out / FIGURE_FILE])
    if symmetric:
        written.reverse = register_with(second, first, options)
        written.reverse.save(out / REVERSE_FILE)
        written.files.append(out / REVERSE_FILE)
    return written


def write_mesh_registration(first, second, out: Path, options: Options, callback: Progress | None = None) -> Written:
    """Register two (vertices, faces) meshes and write coloured meshes, ``result.npz`` and both figures."""
    from .mesh.correspond import register_meshes, similarity_transform
    from .mesh.export import colored_outputs, write_ply
    from .viz import plot_meshes, plot_registration

    mr = register_meshes(first, second, options, callback)
    (v1, f1), (v2, f2) = first, second
    c1, c2, registered = colored_outputs(mr, len(v1), len(v2))
    write_ply(out / "first.ply", v1, f1, c1)
    write_ply(out / "second.ply", v2, f2, c2)
    write_ply(out / "registered.ply", *registered)
    uv1 = mr.first.to_input(mr.uv1, len(v1), [np.nan, np.nan])
    uv2 = mr.second.to_input(mr.uv2, len(v2), [np.nan, np.nan])
    mr.result.save(out / RESULT_FILE, uv_first=uv1, uv_second=uv2)
    energy = mr.result.energy
    plot_meshes(
        out / "meshes.png",
        v1,
        f1,
        c1,
        v2,
        f2,
        c2,
        title=f"E = {energy:.3g}: corresponding points share a colour",
        second_to_first=np.linalg.inv(similarity_transform(mr)),
    )
    g1, g2 = mr.grids
    plot_registration(
        mr.result.apply(g1.scaled().points),
        g2.scaled().at(mr.result.h),
        mr.result.energy_history,
        out / FIGURE_FILE,
        title=f"E = {energy:.3g}",
    )
    notes = []
    for name, info in mr.info.items():
        notes += [f"{name} mesh cleanup: {line}" for line in info["cleanup"]]
        if info["flipped"]:
            notes.append(f"{name} mesh: {info['flipped']} triangles flipped by the parametrization")
    files = [out / RESULT_FILE, out / FIGURE_FILE, *(out / name for name in MESH_FILES)]
    return Written(mr.result, files, notes)


def run_demo(out, options: Options | None = None, callback: Progress | None = None) -> Written:
    """``meshreg demo``: a terrain patch (matplotlib's Jacksboro DEM) meshed twice with different random vertices,
    the second rotated, scaled and shifted; both written to ``out/inputs`` and registered into ``out``."""
    from .mesh.export import write_ply
    from .mesh.samples import demo_pair

    out = output_dir(out, [])
    (v1, f1, _), (v2, f2, _) = demo_pair()
    inputs = out / "inputs"
    inputs.mkdir(exist_ok=True)
    write_ply(inputs / "terrain_a.ply", v1, f1, np.full((len(v1), 3), 0.8))
    write_ply(inputs / "terrain_b.ply", v2, f2, np.full((len(v2), 3), 0.8))
    written = write_mesh_registration((v1, f1), (v2, f2), out, options or Options(), callback)
    written.notes.insert(0, f"inputs in {inputs} ({len(v1)} and {len(v2)} vertices)")
    return written
