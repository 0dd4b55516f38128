"""Build an atlas from files and write it, morph between shapes: the library functions behind ``meshreg atlas`` and
``meshreg morph`` (the command line only parses arguments and prints what these return).

Outputs of an atlas in the directory ``out``:

- ``template.ply``: the template on its grid (M N vertices, two triangles per cell), coloured by grid position;
- ``aligned/<name>.ply``: every member on the template's grid and in its frame, same faces and colours, so vertex k
  is the same point on every file and on the template;
- ``atlas.npz``: :class:`meshreg.Atlas` (template, aligned vertices, rotations, energies, reparametrizations,
  PCA, parameters, timings);
- ``modes.png``: the first three modes at -2, 0, +2 standard deviations; ``scores.png``: the members' scores and the
  explained variance.

They are written all together (none of them when the run fails), replacing those of an earlier atlas there. While it
runs, ``out/.checkpoint/`` holds one JSON-lines file per stage; the same command resumes from it.
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .atlas_result import Atlas
from .atlas_settings import ATLAS_OPTIONS, AtlasSettings
from .errors import InputError
from .files import existing_file, output_dir, remove_outputs, staged, write_atomic
from .limits import check_frames
from .options import Options
from .ownership import recorded, refuse_foreign, writing
from .shape_atlas import atlas
from .shape_stats import canonical_correlations

ATLAS_FILE = "atlas.npz"
TEMPLATE_FILE = "template.ply"
ALIGNED_DIR = "aligned"
MODES_FILE = "modes.png"
SCORES_FILE = "scores.png"
CHECKPOINT_DIR = ".checkpoint"


@dataclass
class WrittenAtlas:
    """What :func:`atlas_files` did: the atlas, the files written and, for the demo, the known parameters and their
    canonical correlations with the first modes' scores."""

    atlas: Atlas
    files: list[Path]
    known: np.ndarray | None = None
    correlations: np.ndarray | None = None


def member_names(files: list[Path]) -> list[str]:
    """Distinct names for the members: file stems, with ``-2``, ``-3`` ... after repeated stems."""
    names, seen = [], {}
    for f in files:
        seen[f.stem] = seen.get(f.stem, 0) + 1
        names.append(f.stem if seen[f.stem] == 1 else f"{f.stem}-{seen[f.stem]}")
    return names


def write_atlas(result: Atlas, out) -> list[Path]:
    """Write the atlas's meshes, ``atlas.npz`` and figures into ``out`` (made if missing)."""
    from .mesh.export import uv_colors, write_ply
    from .viz import plot_modes, plot_scores

    out = Path(out)
    (out / ALIGNED_DIR).mkdir(parents=True, exist_ok=True)
    uv = np.stack(np.meshgrid(result.r, result.t, indexing="ij"), axis=-1).reshape(-1, 2)
    colors = uv_colors(uv)
    files = [out / TEMPLATE_FILE]
    write_ply(files[0], result.template, result.faces, colors)
    for name, vertices in zip(result.names, result.aligned, strict=True):
        files.append(out / ALIGNED_DIR / f"{_file_stem(name)}.ply")
        write_ply(files[-1], vertices, result.faces, colors)
    result.save(out / ATLAS_FILE)
    deviations = np.sqrt(result.variances)
    files.append(out / ATLAS_FILE)
    files.append(
        plot_modes(
            result.mean,
            result.modes,
            deviations,
            result.faces,
            out / MODES_FILE,
            title="modes of variation at -2, 0, +2 sd ("
            + ", ".join(f"{100 * e:.0f}%" for e in result.explained[:3])
            + " of the variance)",
        )
    )
    files.append(plot_scores(result.scores[:, :3], result.explained, result.names, out / SCORES_FILE))
    return files


def _replace_outputs(result: Atlas, out: Path) -> list[Path]:
    """The atlas's outputs written into ``out`` all together (:func:`meshreg.files.staged`), after removing those
    of an earlier atlas there (the files meshreg recorded: a member left out this time leaves no aligned mesh behind).
    Returns the files written."""
    names = [TEMPLATE_FILE, *(f"{ALIGNED_DIR}/{_file_stem(name)}.ply" for name in result.names)]
    names += [ATLAS_FILE, MODES_FILE, SCORES_FILE]
    earlier = [name for name in recorded(out) if name in names or name.startswith(f"{ALIGNED_DIR}/")]
    remove_outputs(out, earlier)
    with staged(out, [ATLAS_FILE, *(n for n in names if n != ATLAS_FILE)]) as stage:
        write_atlas(result, stage)
    return [out / name for name in names]


def _file_stem(name: str) -> str:
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in name) or "member"


def atlas_files(
    files,
    out,
    options: Options | None = None,
    settings: AtlasSettings | None = None,
    *,
    jobs: int | None = None,
    scheduler: str | None = None,
    progress=None,
) -> WrittenAtlas:
    """``meshreg atlas``: the atlas of grid files and/or meshes, checkpointed in ``out/.checkpoint`` (resumed from
    there; removed when done) and written to ``out`` (see the module). ``scheduler`` is the address of a
    dask.distributed scheduler (default: a local process pool of ``jobs`` processes)."""
    from .matrix_run import scheduler_client

    files, out = [Path(f) for f in files], Path(out)
    missing = [str(f) for f in files if not f.is_file()]
    if missing:
        raise InputError(f"no such file: {', '.join(missing)}")
    names = member_names(files)
    written = [Path(n) for n in (TEMPLATE_FILE, ATLAS_FILE, MODES_FILE, SCORES_FILE)]
    written += [Path(ALIGNED_DIR) / f"{_file_stem(name)}.ply" for name in names]
    output_dir(out, written, files)  # before the registrations: a place that cannot take the atlas is refused now
    checkpoint = out / CHECKPOINT_DIR
    with scheduler_client(scheduler, f"finished registrations are kept in {checkpoint}") as client:
        result = atlas(
            files,
            options or ATLAS_OPTIONS,
            settings,
            names=names,
            client=client,
            jobs=jobs,
            checkpoint=checkpoint,
            progress=progress,
        )
    written = WrittenAtlas(result, _replace_outputs(result, out))
    shutil.rmtree(checkpoint, ignore_errors=True)
    return written


def atlas_demo(out, *, count: int = 12, jobs: int | None = None, progress=None) -> WrittenAtlas:
    """``meshreg atlas --demo``: a family of ``count`` deformed terrain patches with known parameters
    (:func:`meshreg.mesh.samples.terrain_family`: random triangulations of about 2k triangles, random poses), written
    to ``out/inputs`` with ``parameters.csv``, and its atlas in ``out``; also the canonical correlations between the
    first two modes' scores and the two parameters."""
    from .mesh.export import write_ply
    from .mesh.samples import terrain_family

    out = Path(out)
    inputs = out / "inputs"
    made = [f"inputs/terrain_{k:02d}.ply" for k in range(count)] + ["inputs/parameters.csv"]
    refuse_foreign(out, made)
    inputs.mkdir(parents=True, exist_ok=True)
    meshes, params = terrain_family(count)
    files = []
    with writing(out, made):
        for k, (v, f) in enumerate(meshes):
            files.append(inputs / f"terrain_{k:02d}.ply")
            write_ply(files[-1], v, f, np.full((len(v), 3), 0.8))
        np.savetxt(
            inputs / "parameters.csv",
            np.c_[np.arange(count), params],
            fmt=["%d", "%.6f", "%.6f"],
            delimiter=",",
            header="member,relief,uplift",
            comments="",
        )
    written = atlas_files(files, out, jobs=jobs, progress=progress)
    kept = [int(name.split("_")[-1]) for name in written.atlas.names]
    written.known = params[kept]
    written.correlations = canonical_correlations(written.atlas.scores[:, :2], written.known)
    return written


def morph_frames(first, second=None, *, mode: int | None = None, frames: int = 24, options: Options | None = None):
    """The frames (S, V, 3) and faces of a morph, there and back (S = 2 ``frames`` - 2).

    - ``first`` an atlas (``atlas.npz``) and ``mode`` k (from 1): the mean moving along mode k from -2 to +2
      standard deviations;
    - two meshes with the same faces (two ``aligned/*.ply`` of an atlas): the straight path between their
      vertices, the second rigidly fitted onto the first (rotation and translation, vertex k to vertex k);
    - two surfaces (meshes and/or grid files): the second registered to the first, then the straight path from the
      first to the second resampled at h on the first's grid, in the first's frame, both at area 1.
    """
    s = np.linspace(0.0, 1.0, frames)
    there_and_back = np.concatenate([s, s[-2:0:-1]])
    path = Path(first)
    if mode is not None:
        if second is not None:
            raise InputError("give an atlas file and --mode, or two surfaces")
        result = Atlas.load(path)
        if not 1 <= mode <= len(result.modes):
            raise InputError(f"{path} has {len(result.modes)} modes: --mode must be from 1 to {len(result.modes)}")
        step = 2.0 * np.sqrt(result.variances[mode - 1]) * result.modes[mode - 1]
        return np.array([result.mean + (2 * a - 1) * step for a in there_and_back]), result.faces
    if second is None:
        raise InputError("give two surfaces, or an atlas file and --mode")
    start, end, faces = _morph_ends(path, Path(second), options or ATLAS_OPTIONS)
    return np.array([(1 - a) * start + a * end for a in there_and_back]), faces


def _morph_ends(first: Path, second: Path, options: Options):
    """The two ends of a straight morph, in correspondence: vertices (V, 3) x 2 and faces."""
    from .batch import pair_grids, prepare_collection, registered_pair
    from .mesh.export import grid_faces
    from .mesh.topology import MESH_SUFFIXES, load_mesh
    from .rotation import kabsch

    if all(p.suffix.lower() in MESH_SUFFIXES for p in (first, second)):
        (v1, f1), (v2, f2) = load_mesh(first), load_mesh(second)
        if len(v1) == len(v2) and np.array_equal(f1, f2):
            a, b = v1 - v1.mean(axis=0), v2 - v2.mean(axis=0)
            return v1, b @ kabsch(b.T @ a).T + v1.mean(axis=0), f1
    ends = prepare_collection([first, second], [str(first), str(second)], options)
    for p in ends:
        if p.error:
            raise InputError(f"{p.name}: {p.error}")
    g1, offered = pair_grids(*ends)
    result, record = registered_pair(g1, offered, options)
    candidates = offered if isinstance(offered, list) else [offered]
    a = g1.scaled().points.reshape(-1, 3)
    b = (candidates[record.get("placement", 0)].scaled().at(result.h) @ result.rotation).reshape(-1, 3)
    return a, b - b.mean(axis=0) + a.mean(axis=0), grid_faces(*g1.shape)


def morph_files(first, second, out, *, mode: int | None = None, frames: int = 24, options=None) -> Path:
    """``meshreg morph``: write the GIF of :func:`morph_frames` to ``out``."""
    from .viz import write_morph

    out = Path(out)
    if out.suffix.lower() != ".gif":
        raise InputError(f"{out}: the morph is written as a GIF: give a file name ending in .gif")
    check_frames(frames, options is not None and options.force)
    given = [existing_file(f) for f in (first, second) if f is not None]
    output_dir(out.parent, [out.name], given, own_only=False)  # the file is the user's to name, as a matrix's
    shapes, faces = morph_frames(first, second, mode=mode, frames=frames, options=options)
    title = f"mode {mode}: -2 to +2 sd" if mode else f"{Path(first).stem} to {Path(second).stem}"
    # whole or not at all: matplotlib's writer saves the frames grabbed so far when it is interrupted
    return write_atomic(out, lambda tmp: write_morph(shapes, faces, tmp, title=title))
