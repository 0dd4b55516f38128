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
from .files import output_dir, remove_outputs, staged, surface_kind, write_atomic
from .options import Options
from .result import Registration
from .schedule import Progress

RESULT_FILE = "result.npz"
REVERSE_FILE = "result_reverse.npz"
FIGURE_FILE = "registration.png"
MESH_FILES = ("first.ply", "second.ply", "registered.ply", "meshes.png")
# every file a run may write: those of an earlier run are removed before this run computes, so that none of them
# can pass for this run's
OUTPUT_FILES = (RESULT_FILE, REVERSE_FILE, FIGURE_FILE, *MESH_FILES)
DEMO_INPUTS = ("inputs/terrain_a.ply", "inputs/terrain_b.ply")


@dataclass
class Written:
    """What :func:`register_files` did: the result, the files written and what the mesh cleanup reported."""

    result: Registration
    files: list[Path]
    notes: list[str] = field(default_factory=list)
    reverse: Registration | None = None


def prepare_output(path, inputs: list[Path], names=OUTPUT_FILES) -> Path:
    """The output directory, checked before any computation (:func:`meshreg.files.output_dir`: made if missing;
    refused when it is a file, under a file, not writable, or an output would overwrite an input or a directory),
    with the outputs of an earlier run removed."""
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
    callback: Progress | None = None,
) -> Written:
    """Register two files (two grid files or two disk meshes, by suffix) and write the outputs to ``out``.

    Everything that can be checked before the registration is: the inputs are read, the grid sizes and the DP
    window checked against the limits (:mod:`meshreg.limits`), and the output place prepared (:func:`prepare_output`)
    before any computation. The outputs are written all together or not at all (:func:`meshreg.files.staged`); the
    inputs are never written.

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

    Raises
    ------
    InputError
        Bad inputs, parameters or output place (before any computation).
    RunError
        The outputs could not be written (nothing is then left of them).
    """
    from .grid import read_grid
    from .mesh.topology import load_mesh

    options = options or Options()
    paths = [Path(first), Path(second)]
    kinds = {surface_kind(p) for p in paths}
    if len(kinds) > 1:
        raise InputError("give two meshes or two grid files, not one of each")
    if kinds == {"mesh"}:
        meshes = [load_mesh(p) for p in paths]
        side = (options.resolution, options.resolution)
        options.check_grids(side, side)
        out = prepare_output(out, paths)
        return write_mesh_registration(meshes[0], meshes[1], out, options, callback, names=[str(p) for p in paths])
    grids = [read_grid(p, grid_shape) for p in paths]
    options.check_grids(grids[0].shape, grids[1].shape)
    if symmetric:
        options.check_grids(grids[1].shape, grids[0].shape)
    return write_grid_registration(grids[0], grids[1], prepare_output(out, paths), options, symmetric, callback)


def write_grid_registration(
    first, second, out: Path, options: Options, symmetric: bool = False, callback: Progress | None = None
) -> Written:
    """Register two GridSurfaces and write ``result.npz`` and ``registration.png`` (and the reverse result) into
    the prepared directory ``out``, all together or not at all."""
    from .register import register_with
    from .viz import plot_registration

    result = register_with(first, second, options, callback)
    reverse = register_with(second, first, options) if symmetric else None
    names = [RESULT_FILE, FIGURE_FILE] + ([REVERSE_FILE] if symmetric else [])
    with staged(out, names) as stage:
        result.save(stage / RESULT_FILE)
        plot_registration(
            result.apply(first.scaled().points),
            second.scaled().at(result.h),
            result.energy_history,
            stage / FIGURE_FILE,
            title=f"{options.mode}: E = {result.energy:.3g}",
        )
        if reverse is not None:
            reverse.save(stage / REVERSE_FILE)
    return Written(result, [out / name for name in names], reverse=reverse)


def write_mesh_registration(
    first, second, out: Path, options: Options, callback: Progress | None = None, names=("first mesh", "second mesh")
) -> Written:
    """Register two (vertices, faces) meshes and write coloured meshes, ``result.npz`` and both figures into the
    prepared directory ``out``, all together or not at all (``names``: the meshes in error messages)."""
    from .mesh.correspond import register_meshes, similarity_transform
    from .mesh.export import colored_outputs, write_ply
    from .viz import plot_meshes, plot_registration

    mr = register_meshes(first, second, options, callback, names)
    (v1, f1), (v2, f2) = first, second
    c1, c2, registered = colored_outputs(mr, len(v1), len(v2))
    uv1 = mr.first.to_input(mr.uv1, len(v1), [np.nan, np.nan])
    uv2 = mr.second.to_input(mr.uv2, len(v2), [np.nan, np.nan])
    energy = mr.result.energy
    g1, g2 = mr.grids
    names = [RESULT_FILE, FIGURE_FILE, *MESH_FILES]
    with staged(out, names) as stage:
        write_ply(stage / "first.ply", v1, f1, c1)
        write_ply(stage / "second.ply", v2, f2, c2)
        write_ply(stage / "registered.ply", *registered)
        mr.result.save(stage / RESULT_FILE, uv_first=uv1, uv_second=uv2)
        plot_meshes(
            stage / "meshes.png",
            v1,
            f1,
            c1,
            v2,
            f2,
            c2,
            title=f"E = {energy:.3g}: corresponding points share a colour",
            second_to_first=np.linalg.inv(similarity_transform(mr)),
        )
        plot_registration(
            mr.result.apply(g1.scaled().points),
            g2.scaled().at(mr.result.h),
            mr.result.energy_history,
            stage / FIGURE_FILE,
            title=f"E = {energy:.3g}",
        )
    notes = []
    for name, info in mr.info.items():
        notes += [f"{name} mesh cleanup: {line}" for line in info["cleanup"]]
        if info["flipped"]:
            notes.append(f"{name} mesh: {info['flipped']} triangles flipped by the parametrization")
    return Written(mr.result, [out / name for name in names], notes)


def run_demo(out, options: Options | None = None, callback: Progress | None = None) -> Written:
    """``meshreg demo``: a terrain patch (matplotlib's Jacksboro DEM) meshed twice with different random vertices,
    the second rotated, scaled and shifted; both written to ``out/inputs`` and registered into ``out``."""
    from .mesh.export import write_ply
    from .mesh.samples import demo_pair

    out = prepare_output(out, [], OUTPUT_FILES + DEMO_INPUTS)
    (v1, f1, _), (v2, f2, _) = demo_pair()
    for name, (v, f) in zip(DEMO_INPUTS, ((v1, f1), (v2, f2)), strict=True):
        (out / name).parent.mkdir(exist_ok=True)
        write_atomic(out / name, lambda tmp, v=v, f=f: write_ply(tmp, v, f, np.full((len(v), 3), 0.8)))
    written = write_mesh_registration((v1, f1), (v2, f2), out, options or Options(), callback)
    written.notes.insert(0, f"inputs in {out / 'inputs'} ({len(v1)} and {len(v2)} vertices)")
    return written
