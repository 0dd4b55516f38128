"""Side by side: meshreg and the tools a user would pick instead, on mesh pairs with a known material map.

    python benchmarks/bench_peers.py                       # every pair and tool: 24 min, 9 min of CPU
    python benchmarks/bench_peers.py --quick               # small meshes: 9 min, 5 min of CPU
    python benchmarks/bench_peers.py --pairs roll-90 fold-90 --tools meshreg param open3d
    python benchmarks/bench_peers.py --pairs sheet-90% face-crops-5mm-bent --tools meshreg meshreg-whole open3d
    python benchmarks/bench_peers.py --diagnose --tools meshreg param --pairs fold-90 roll-90 roll-180
    python benchmarks/bench_peers.py --tools meshreg param --option bend_window=0.03 advanced.refine_triangles=0
    python benchmarks/bench_peers.py --list

Pairs (:mod:`meshreg.mesh.deform`): each gives, for every vertex of the second mesh, its true corresponding point on
the first. Every tool predicts that point; the error is the distance from the predicted to the true point in units
of sqrt(area) (of the first mesh; of the second's region for partial pairs), median and 90th percentile over the
second's vertices that have a true point (those over the first: the overlap, for partial pairs).

Tools, all on the same meshes:

- ``meshreg``: the command line's default (``register_meshes(a, b, Options())``: corners by the boundary's turning
  within the surface, the square's symmetry by E_w, E_w descended from the parametrization; docs/bending.md; where
  the meshes cover different regions, only the common region, docs/overlap.md), each vertex of the second mapped
  through the registration to the first's square and onto the first mesh; E (at the answer), E_w (what was
  minimized) and the overlap meshreg found (its verdict and the share of each mesh's area in the common region,
  :mod:`meshreg.mesh.overlap`) are printed beside it. A vertex of the second that meshreg leaves out (outside the
  overlap it found) counts as an infinite error.
- ``meshreg-whole``: the same with ``overlap="off"``: the whole meshes registered, as before issue 19.
- ``param``: the parametrization alone, no optimization: the two harmonic maps to the square with the corners
  meshreg chose, corresponding points sharing uv up to the symmetry of the square meshreg chose (h = sigma; the
  boundary loops start at arbitrary corners, so h = identity alone means nothing); seconds: the mesh preparation.
  For a pair meshreg registers by its common region, the second's layout is the first's pulled back through the
  match (h = identity), so ``param`` repeats ``meshreg``.
- ``open3d``: FPFH features + RANSAC, then point-to-plane ICP (rigid, global: no start needed); voxel 0.03 or the
  meshes' median edge length if larger (features within 5 voxels, normals from the triangles).
- ``icp``: ``trimesh.registration.icp`` from the 24 rotations of the cube (600 vertices onto the first's
  vertices), the start with the lowest own cost refined on every vertex against the first's triangles (rigid).
- ``nricp-amberg``, ``nricp-sumner``: trimesh's non-rigid ICP of the second mesh onto the first, from the ``icp``
  pose (its seconds included).
- ``cpd``: pycpd rigid CPD (with scale) from the 24 cube rotations (300 onto 500 points, 50 iterations), the
  start with the lowest own objective refined (600 onto 1000 points), then deformable CPD from its sigma^2 (1000
  points, kernel width beta = 0.5, alpha = 2: unit-area data).
- ``bcpd``: probreg's BCPD (rigid + non-rigid, lambda = 20) on 800 points, 100 iterations, from the rigid CPD
  pose (its seconds included).

Fair help for the peers: both meshes centred (area centroid) and scaled to unit area (partial pairs, which are at
one scale: both by the same factor, the second to unit area); point-set tools deform a subsample, carried to every
vertex by inverse-distance weighting of the 8 nearest subsample displacements. A point-set or rigid result gives
each vertex of the second its closest point on the first (that projection is not timed). A peer that is not
installed (``pip install 'meshreg[bench]'``) is skipped with a line that says so.

``--diagnose`` adds, on full-overlap pairs: meshreg minimizing E itself (``bend_window=0``, the method before issue
14); the parametrization under the symmetry closest to the truth (an oracle); meshreg and the parametrization
without the square's symmetries; both with the true corners (the first's
corners as meshreg chose them, the second's at the boundary vertices whose true points are nearest to those,
:func:`meshreg.mesh.deform.material_corners`), the parametrization also with the oracle symmetry; and E at
meshreg's answer, at h = the symmetry it chose and at the true map (each at its best rotation).

Timings: wall-clock seconds and CPU seconds of the process (all its threads) on a shared machine: compare them
within one run, not across runs.
"""

from __future__ import annotations

import argparse
import ast
import datetime
import os
import platform
import sys
import time
from dataclasses import dataclass, field

import numpy as np
from peers import PEERS, frames, missing
from scipy.interpolate import NearestNDInterpolator
from scipy.spatial import cKDTree

from meshreg import Advanced, Options
from meshreg.mesh import deform, plane
from meshreg.mesh.correspond import MeshRegistration, register_meshes
from meshreg.objective import Objective
from meshreg.rotation import kabsch
from meshreg.search import symmetry_map

SEED = 0
TOOLS = ("meshreg", "meshreg-whole", "param", *PEERS)


def pair_builders(quick: bool) -> dict:
    """Name -> function making the pair; ``quick``: small meshes (sheets of 600/900 vertices, 30 mm scan crops)."""
    n1, n2 = (600, 900) if quick else (2500, 3500)
    scan = {"radius": 30.0, "n_second": 2500} if quick else {"radius": 45.0, "n_second": 8000}
    sheet = {"n_first": n1, "n_second": n2}
    folded = {"start": 0.45, "width": 0.1, "surface": deform.relief_sheet(0.5)}
    return {
        "remeshed": lambda: deform.remeshed_pair("remeshed", **sheet),
        "face-bend-72": lambda: deform.scan_pair("face-bend-72", bend_angle=72.0, **scan),
        "fold-90": lambda: deform.bent_pair("fold-90", 90.0, **folded, **sheet),
        "roll-90": lambda: deform.bent_pair("roll-90", 90.0, **sheet),
        "roll-180": lambda: deform.bent_pair("roll-180", 180.0, **sheet),
        "stretch": lambda: deform.stretched_pair("stretch", 0.5, **sheet),
        "sheet-90%": lambda: deform.partial_pair("sheet-90%", deform.centred_region(0.9), **sheet),
        "sheet-81%": lambda: deform.partial_pair("sheet-81%", deform.centred_region(0.81), **sheet),
        "corner-64%": lambda: deform.partial_pair("corner-64%", (0.0, 0.8, 0.0, 0.8), **sheet),
        "strip-60%": lambda: deform.partial_pair("strip-60%", (0.0, 1.0, 0.2, 0.8), **sheet),
        "face-crops-5mm": lambda: deform.scan_pair("face-crops-5mm", offset=5.0, **scan),
        "face-crops-12mm": lambda: deform.scan_pair("face-crops-12mm", offset=12.0, **scan),
        "face-crops-5mm-bent": lambda: deform.scan_pair("face-crops-5mm-bent", offset=5.0, bend_angle=72.0, **scan),
    }


@dataclass
class Outcome:
    """One tool's prediction on one pair: points (n2, 3) on the first mesh (NaN: none), wall and CPU seconds, a
    note."""

    points: np.ndarray | None
    seconds: float
    note: str = ""
    extra: dict = field(default_factory=dict)
    cpu: float = float("nan")


# ---- meshreg and the parametrization alone


def run_meshreg(pair: deform.Pair, options: Options) -> tuple[Outcome, Outcome, MeshRegistration]:
    """meshreg's prediction and the parametrization-alone baseline from the same run."""
    n2 = len(pair.second[0])
    t0, c0 = time.perf_counter(), time.process_time()
    mr = register_meshes(pair.first, pair.second, options)
    seconds, cpu = time.perf_counter() - t0, time.process_time() - c0
    energy = mr.result.energy
    note = f"E = {energy:.3g}"
    if "bend_energy" in mr.result.params:
        note += f", E_w = {mr.result.params['bend_energy']:.3g}"
        ranking = mr.result.params["symmetry_ranking"]
        chosen = next(s["choice_energy"] for s in ranking if s["symmetry"] == mr.result.symmetry)
        others = [s["choice_energy"] for s in ranking if not s["mirrored"] and s["symmetry"] != mr.result.symmetry]
        if others:  # how clearly E_w at the start picked the square's symmetry (below 1: the residual overrode it)
            note += f", symmetry {mr.result.symmetry}: next E_w {min(others) / chosen:.2f} x"
    if "overlap" in mr.result.info:
        o = mr.result.info["overlap"]
        note += f"; overlap {o['regime']}, {o['first_fraction']:.3f} / {o['second_fraction']:.3f}"
    found = Outcome(deform.matched_points(mr, n2), seconds, note, {"E": energy}, cpu)
    note = f"h = symmetry {mr.result.symmetry} of the square (meshreg's)"
    baseline = Outcome(deform.parametrization_points(mr, n2), seconds - mr.result.timings["total"], note)
    return found, baseline, mr


# ---- diagnostics


def disk_params(disk, params: np.ndarray) -> np.ndarray:
    """Material coordinates of every vertex of a cleaned disk (a hole-filling vertex takes its nearest one's)."""
    k = len(disk.vertex_map)
    out = np.empty((len(disk.vertices), 2))
    out[:k] = params[disk.vertex_map]
    if len(disk.vertices) > k:
        out[k:] = params[disk.vertex_map[cKDTree(disk.vertices[:k]).query(disk.vertices[k:])[1]]]
    return out


def energies(pair: deform.Pair, mr: MeshRegistration) -> dict:
    """E (each at its best rotation) at meshreg's h, at h = the symmetry of the square it chose (the
    parametrization alone) and at the true map h_true, on meshreg's grids: h_true sends each node of the first's
    square to the second's uv of the same material point."""
    g1, g2 = mr.grids
    objective = Objective(g1, g2)
    nodes = np.stack(np.meshgrid(g1.r, g1.t, indexing="ij"), axis=-1).reshape(-1, 2)
    face, bary, _ = plane.locate(mr.uv1, mr.first.faces, nodes)
    material = plane.interpolate(disk_params(mr.first, pair.first_params), mr.first.faces, face, bary)
    p2 = disk_params(mr.second, pair.second_params)
    face, bary, inside = plane.locate(p2, mr.second.faces, material)
    h_true = plane.interpolate(mr.uv2, mr.second.faces, face, bary)
    if not inside.all():  # nodes off the second (holes): nearest known value
        h_true[~inside] = NearestNDInterpolator(nodes[inside], h_true[inside])(nodes[~inside])
    h_true = np.clip(h_true.reshape(len(g1.r), len(g1.t), 2), 0, 1)

    def at(h):
        return objective.energy(kabsch(objective.best_rotation_covariance(h)), h)

    return {
        "E found": mr.result.energy,
        "E found (recomputed)": at(mr.result.h),
        f"E at h = symmetry {mr.result.symmetry}": at(symmetry_map(mr.result.symmetry, objective.identity)),
        "E true map": at(h_true),
    }


def oracle_param(pair: deform.Pair, mr: MeshRegistration) -> Outcome:
    """The parametrization alone under the symmetry of the square that is closest to the truth (an oracle)."""
    n2 = len(pair.second[0])
    tried = [deform.parametrization_points(mr, n2, k) for k in range(8)]
    k = int(np.argmin([np.median(pair.errors(p)) for p in tried]))
    return Outcome(tried[k], float("nan"), f"symmetry {k} (oracle)")


def diagnose(pair: deform.Pair, mr: MeshRegistration, rows: list, options: Options) -> list[str]:
    """Rows telling where meshreg's error comes from (corners, the symmetry, the optimization) and lines of E."""
    c1, c2 = deform.material_corners(pair, mr)
    found, _, _ = run_meshreg(pair, options.replace(bend_window=0.0))
    rows += [row(pair, "meshreg, bend_window=0 (minimizes E)", found)]
    rows.append(row(pair, "param, best symmetry", oracle_param(pair, mr)))
    found, baseline, _ = run_meshreg(pair, options.replace(symmetries=False))
    rows += [row(pair, "meshreg, symmetries=False", found), row(pair, "param, symmetries=False", baseline)]
    found, baseline, run = run_meshreg(pair, options.replace(corners1=c1, corners2=c2))
    rows += [row(pair, "meshreg, true corners", found), row(pair, "param, true corners", baseline)]
    rows.append(row(pair, "param, true corners, best symmetry", oracle_param(pair, run)))
    return [
        f"{pair.name}, meshreg's corners: {fmt_energies(energies(pair, mr))}",
        f"{pair.name}, true corners: {fmt_energies(energies(pair, run))}",
    ]


def fmt_energies(e: dict) -> str:
    return ", ".join(f"{k} = {v:.3g}" for k, v in e.items())


# ---- the table


def row(pair: deform.Pair, tool: str, outcome: Outcome) -> tuple:
    if outcome.points is None:
        return (pair.name, tool, "", "", "", "", outcome.note)
    err = pair.errors(outcome.points)
    med, p90 = np.percentile(err, [50, 90])
    seconds, cpu = ("" if np.isnan(x) else f"{x:.1f}" for x in (outcome.seconds, outcome.cpu))
    return (pair.name, tool, f"{med:.4f}", f"{p90:.4f}", seconds, cpu, outcome.note)


def machine_line() -> str:
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as info:
            cpu = next(line.split(":", 1)[1].strip() for line in info if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    today = datetime.date.today().isoformat()
    return f"{today}, {cpu}, {os.cpu_count()} cores, Python {platform.python_version()}, numpy {np.__version__}"


def meshreg_options(settings: list[str]) -> Options:
    """Options from NAME=VALUE strings (values as Python literals; ``advanced.NAME`` sets an Advanced field)."""
    top, advanced = {}, {}
    for setting in settings:
        name, _, value = setting.partition("=")
        target = advanced if name.startswith("advanced.") else top
        target[name.removeprefix("advanced.")] = ast.literal_eval(value)
    return Options(**top, advanced=Advanced(**advanced))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    builders_all = pair_builders(False)
    parser.add_argument("--pairs", nargs="+", choices=list(builders_all), default=list(builders_all))
    parser.add_argument("--tools", nargs="+", choices=TOOLS, default=list(TOOLS))
    parser.add_argument("--quick", action="store_true", help="small meshes (about 5 min of CPU)")
    parser.add_argument("--diagnose", action="store_true", help="meshreg without symmetries, with true corners; E")
    parser.add_argument("--list", action="store_true", help="list the pairs and how they are made, then stop")
    parser.add_argument(
        "--option",
        nargs="+",
        default=[],
        metavar="NAME=VALUE",
        help="meshreg's options (fields of meshreg.Options; advanced.NAME for meshreg.Advanced), e.g. bend_window=0",
    )
    args = parser.parse_args(argv)
    options = meshreg_options(args.option)
    builders = pair_builders(args.quick)
    print(f"# bench_peers{' --quick' if args.quick else ''}{''.join(' ' + o for o in args.option)}: {machine_line()}")
    if args.list:
        for name in args.pairs:
            p = builders[name]()
            print(f"- {name}: {p.info}, overlap {p.overlap:.3f}, same scale {p.same_scale}")
        return
    for tool in args.tools:
        if tool in PEERS and (why := missing(PEERS[tool][1])):
            print(f"{tool}: skipped, {why}")
    peers = [t for t in args.tools if t in PEERS and not missing(PEERS[t][1])]
    rows, notes = [], []
    for name in args.pairs:
        pair = builders[name]()
        notes.append(
            f"{name}: {len(pair.first[0])} and {len(pair.second[0])} vertices, overlap {pair.overlap:.3f}"
            f"{' (partial)' if pair.partial else ''}, "
            f"largest edge-length ratio of the deformation {pair.info['edge_ratio']:.3g}"
        )
        if {"meshreg", "param"} & set(args.tools) or args.diagnose:
            found, baseline, mr = run_meshreg(pair, options)
            rows += [row(pair, t, o) for t, o in (("meshreg", found), ("param", baseline)) if t in args.tools]
            if args.diagnose and not pair.partial:
                notes += diagnose(pair, mr, rows, options)
        if "meshreg-whole" in args.tools:
            rows.append(row(pair, "meshreg-whole", run_meshreg(pair, options.replace(overlap="off"))[0]))
        fr = frames(pair) if peers else None
        for tool in peers:
            t0, c0, fr.borrowed = time.perf_counter(), time.process_time(), np.zeros(2)
            try:
                moved = PEERS[tool][0](fr)
                seconds = time.perf_counter() - t0 + fr.borrowed[0]
                outcome = Outcome(fr.to_first(moved), seconds, cpu=time.process_time() - c0 + fr.borrowed[1])
            except Exception as err:  # a peer failing on a pair is a result, not a crash of the benchmark
                outcome = Outcome(None, time.perf_counter() - t0, f"failed: {type(err).__name__}: {err}"[:100])
            rows.append(row(pair, tool, outcome))
        print(f"{name} done", file=sys.stderr, flush=True)
    print()
    print("| pair | tool | median | p90 | seconds | CPU s | note |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        print("| " + " | ".join(r) + " |")
    print()
    for line in notes:
        print(f"- {line}")


if __name__ == "__main__":
    np.seterr(all="ignore")
    main()
