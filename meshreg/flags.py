"""The command line's view of :class:`~meshreg.options.Options`: one row per flag (:data:`FLAGS`), from which
:func:`add_flags` builds the argparse options and :func:`options_from_args` reads them back, so that the flags
cannot drift from the fields. Adding an option is one field of Options (or Advanced) plus one row here."""

from __future__ import annotations

from dataclasses import dataclass

from .options import MESH_BLUR_DEFAULT, MODES, OVERLAPS, REFINEMENTS, SOLVERS, WEIGHTS, Advanced, Options


@dataclass(frozen=True)
class Flag:
    """One command-line flag: the option field it sets (``advanced.x`` for an :class:`Advanced` field)."""

    flag: str
    field: str
    help: str
    type: type | None = None
    nargs: int | str | None = None
    metavar: str | tuple | None = None
    choices: tuple | None = None
    group: str = "registration"
    const: object = None  # a flag without a value sets this (e.g. --no-cleanup sets cleanup False)


FLAGS: tuple[Flag, ...] = (
    Flag("--mode", "mode", "how to register (default auto)", str, choices=MODES),
    Flag("--window", "window", "DP window W (default 10)", int, metavar="W"),
    Flag("--basis", "basis", "KL of the Riseth basis, 2 (KL + 2 KL^2) fields (default 5)", int, metavar="KL"),
    Flag("--solver", "solver", "direction of the basis descent (default gauss-newton)", str, choices=SOLVERS),
    Flag("--refine", "refine", "refinement after the basis descent (default nodes)", str, choices=REFINEMENTS),
    Flag(
        "--max-starts",
        "max_starts",
        "mode auto: most ranked starts registered in full (default 3; 1 = the best-ranked only)",
        int,
        metavar="K",
    ),
    Flag(
        "--keep-orientation",
        "keep_orientation",
        "mode auto: only the 4 symmetries of the square that keep each surface's front side (meshes wound "
        "consistently)",
        const=True,
    ),
    Flag(
        "--symmetry",
        "symmetry",
        "pin the symmetry of the square applied to the second surface (0-7, as listed among the alternatives; "
        "default: searched in mode auto)",
        int,
        metavar="K",
    ),
    Flag(
        "--max-rounds", "advanced.max_rounds", "most descent + Kabsch rounds per stage (default 10)", int, metavar="N"
    ),
    Flag(
        "--dp-radius",
        "advanced.dp_radius",
        "mode auto: later DP passes search within this many nodes of the identity path (default 20; 0 = whole table)",
        int,
        metavar="N",
    ),
    Flag(
        "--smoothing",
        "smoothing",
        "mode gd: Gaussian scale-space levels of its third path, in side lengths, "
        "largest first (default 0.1; give none to turn it off)",
        float,
        nargs="*",
        metavar="SIGMA",
    ),
    Flag(
        "--start-basis",
        "start_basis",
        "mode gd: KL of the coarse basis its second path starts in (default 3)",
        int,
        metavar="KL",
    ),
    Flag(
        "--resolution",
        "resolution",
        "meshes are resampled on N x N grids (default 101)",
        int,
        metavar="N",
        group="meshes",
    ),
    Flag(
        "--weights",
        "weights",
        "Laplacian weights of the map to the square (default mean-value)",
        str,
        choices=WEIGHTS,
        group="meshes",
    ),
    Flag(
        "--antialias",
        "antialias",
        "grid nodes average the mesh sampled K times finer (default 3; 1 = point samples)",
        int,
        metavar="K",
        group="meshes",
    ),
    Flag(
        "--mesh-blur",
        "mesh_blur",
        f"mode auto, pairs whose maps nearly agree: register grids blurred over S median edges of the coarser "
        f"mesh (default {MESH_BLUR_DEFAULT}; 0 = off)",
        float,
        metavar="S",
        group="meshes",
    ),
    Flag(
        "--overlap",
        "overlap",
        "auto: register only where the meshes overlap when they cover different regions; off: always the whole "
        "meshes (default auto)",
        str,
        choices=OVERLAPS,
        group="meshes",
    ),
    Flag(
        "--overlap-quick",
        "advanced.overlap_quick",
        "overlap auto: meshes whose principal-axes pose leaves at most this fraction of each beyond the other's rim "
        "cover the same region, without the feature search (default 0.01; 0 = always search)",
        float,
        metavar="F",
        group="meshes",
    ),
    Flag(
        "--processes",
        "advanced.processes",
        "processes one registration may use: 2 maps two large meshes to the square in a forked process while their "
        "overlap is checked (when a core is idle); 1 = serial (default 2)",
        int,
        metavar="N",
        group="meshes",
    ),
    Flag(
        "--no-cleanup",
        "cleanup",
        "refuse to repair meshes (holes, pieces, ears, pinched vertices)",
        group="meshes",
        const=False,
    ),
    Flag(
        "--force",
        "force",
        "run even when the grid size, --window, --resolution, --corner-search or --jobs exceed the limits on "
        "memory and time (the refusal states the estimate); matrix: recompute a finished matrix",
        const=True,
    ),
    Flag(
        "--corners1",
        "corners1",
        "corner vertex ids of the first mesh's boundary, in order around it (the first becomes (0, 0))",
        int,
        nargs=4,
        metavar="ID",
        group="corners",
    ),
    Flag(
        "--corners2",
        "corners2",
        "corner vertex ids of the second mesh's boundary, in order around it (matched with --corners1)",
        int,
        nargs=4,
        metavar="ID",
        group="corners",
    ),
    Flag(
        "--corner-search",
        "corner_search",
        "trial corner placements on round boundaries, 0 = off (default 8)",
        int,
        metavar="K",
        group="meshes",
    ),
    Flag(
        "--bend-window",
        "bend_window",
        "two meshes, mode auto: width (side lengths of the square) of the windows in which E_w lets the surface "
        "bend at no cost; 0 = minimize E itself (default 0.05)",
        float,
        metavar="W",
        group="bending",
    ),
)


def _dest(row: Flag) -> str:
    return "opt_" + row.field.replace(".", "__")


def add_flags(parser, groups=("registration", "meshes", "corners", "bending")) -> None:
    """Add the flags of :data:`FLAGS` in ``groups`` to an argparse parser (defaults left to :class:`Options`)."""
    sections = {}
    for row in FLAGS:
        if row.group not in groups:
            continue
        if row.group not in sections:
            sections[row.group] = parser if row.group == "registration" else parser.add_argument_group(row.group)
        kwargs = {"dest": _dest(row), "default": None, "help": row.help}
        if row.const is not None:
            kwargs.update(action="store_const", const=row.const)
        else:
            kwargs.update(
                {
                    k: v
                    for k, v in (
                        ("type", row.type),
                        ("nargs", row.nargs),
                        ("metavar", row.metavar),
                        ("choices", row.choices),
                    )
                    if v is not None
                }
            )
        sections[row.group].add_argument(row.flag, **kwargs)


def options_from_args(args, **fixed) -> Options:
    """The :class:`Options` of parsed arguments: each flag given sets its field; ``fixed`` sets others."""
    top, advanced = dict(fixed), {}
    for row in FLAGS:
        value = getattr(args, _dest(row), None)
        if value is None:
            continue
        if isinstance(value, list):
            value = tuple(value)
        if row.field.startswith("advanced."):
            advanced[row.field.split(".", 1)[1]] = value
        else:
            top[row.field] = value
    return Options(**top, advanced=Advanced(**advanced))
