"""Mesh correspondences against known material maps (meshreg.mesh.deform), one small pair per kind of bend and
overlap.

Error: distance from the point meshreg matches each vertex of the second mesh with to its true point on the first,
in units of sqrt(area), median (p90) over vertices. The bounds are what today's code achieves (measured on these
seeded pairs, with some margin) and the targets of issue 14 (bending) and issue 19 (partial overlap).
``benchmarks/bench_peers.py`` runs the same kinds at full size beside the peers; the tests at the end run its bent
pairs at that size with the command line's defaults.
"""

from functools import cache

import numpy as np
import pytest

from meshreg import Options
from meshreg.mesh import deform
from meshreg.mesh.correspond import register_meshes
from meshreg.mesh.harmonic import HarmonicMap, choose_corners
from meshreg.mesh.topology import prepare_disk
from meshreg.search import symmetry_map

pytestmark = pytest.mark.slow  # one registration each (cached across the tests of a pair): 5-10 s

SHEET = {"n_first": 500, "n_second": 700}
PAIRS = {
    "remeshed": lambda: deform.remeshed_pair(**SHEET),
    "bend-72": lambda: deform.bent_pair("bend-72", 72.0, **SHEET),
    "fold-90": lambda: deform.bent_pair(
        "fold-90", 90.0, start=0.45, width=0.1, surface=deform.relief_sheet(0.5), **SHEET
    ),
    "roll-90": lambda: deform.bent_pair("roll-90", 90.0, **SHEET),
    "roll-180": lambda: deform.bent_pair("roll-180", 180.0, **SHEET),
    "stretch": lambda: deform.stretched_pair("stretch", 0.5, **SHEET),
    "sheet-90%": lambda: deform.partial_pair("sheet-90%", deform.centred_region(0.9), **SHEET),
    "corner-64%": lambda: deform.partial_pair("corner-64%", (0.0, 0.8, 0.0, 0.8), **SHEET),
    "strip-60%": lambda: deform.partial_pair("strip-60%", (0.0, 1.0, 0.2, 0.8), **SHEET),
    "face-crops-5mm": lambda: deform.scan_pair("face-crops-5mm", radius=30.0, offset=5.0, n_second=2000),
    "face-crops-5mm-bent": lambda: deform.scan_pair(
        "face-crops-5mm-bent", radius=30.0, offset=5.0, bend_angle=72.0, n_second=2000
    ),
}


def material_corner_param(pair: deform.Pair, corners: tuple) -> tuple[float, float]:
    """The parametrization alone with the material corners (``corners``: input ids, first's and second's) under
    the symmetry of the square closest to the truth: median and p90 error."""
    disks, uvs = [], []
    for (v, f), ids in zip((pair.first, pair.second), corners, strict=True):
        disk = prepare_disk(v, f)
        disks.append(disk)
        uvs.append(HarmonicMap(disk)(choose_corners(disk, disk.input_ids(ids)))[0])
    uv2 = disks[1].to_input(uvs[1], len(pair.second[0]), [np.nan, np.nan])
    tried = [pair.errors(deform.surface_points(disks[0], uvs[0], symmetry_map(k, uv2))) for k in range(8)]
    return min((float(np.median(e)), float(np.percentile(e, 90))) for e in tried)


@cache
def registered(name: str):
    pair = PAIRS[name]()
    return pair, register_meshes(pair.first, pair.second, Options(resolution=41))


@cache
def scores(name: str) -> dict:
    """Median and p90 errors of meshreg, of the parametrization alone (h = the symmetry meshreg chose), of the
    parametrization under the symmetry of the square closest to the truth (an oracle), and of that with the
    material corners."""
    pair, mr = registered(name)
    n = len(pair.second[0])

    def stats(points):
        err = pair.errors(points)
        return float(np.median(err)), float(np.percentile(err, 90))

    return {
        "meshreg": stats(deform.matched_points(mr, n)),
        "param": stats(deform.parametrization_points(mr, n)),
        "oracle": min(stats(deform.parametrization_points(mr, n, k)) for k in range(8)),
        "material": material_corner_param(pair, deform.material_corners(pair, mr)),
        "energy": mr.result.energy,
    }


def meshreg_error(name: str) -> tuple[float, float]:
    """Median and p90 error of meshreg alone (a partial pair's common region has no material corners to score)."""
    pair, mr = registered(name)
    err = pair.errors(deform.matched_points(mr, len(pair.second[0])))
    return float(np.median(err)), float(np.percentile(err, 90))


def test_remeshed_same_surface():
    s = scores("remeshed")
    assert s["meshreg"][0] <= 0.008 and s["meshreg"][1] <= 0.02  # measured 0.0039 / 0.0083
    assert s["energy"] <= 0.01  # 0.0079


@pytest.mark.parametrize(
    "name, bound", [("bend-72", 0.015), ("fold-90", 0.018), ("roll-90", 0.018), ("roll-180", 0.03)]
)
def test_isometric_bend_keeps_the_harmonic_map_with_material_corners(name, bound):
    # the harmonic map of an isometric bend barely changes: measured 0.0109, 0.0081, 0.0133, 0.0256
    assert scores(name)["material"][0] <= bound


@pytest.mark.parametrize("name", ["remeshed", "bend-72", "fold-90", "roll-90", "roll-180", "stretch"])
def test_corners_and_symmetry_are_the_material_ones(name):
    """Corners chosen by the turning within the surface and the square's symmetry by E_w: the parametrization
    alone is then the one under the symmetry closest to the truth, with the material corners."""
    s = scores(name)
    assert s["param"] == s["oracle"] and s["material"] == pytest.approx(s["param"], rel=1e-9)


@pytest.mark.parametrize("name, bound", [("bend-72", 0.01), ("roll-90", 0.01), ("roll-180", 0.02)])
def test_meshreg_beats_the_parametrization_on_a_bend(name, bound):
    s = scores(name)
    assert s["meshreg"][0] <= bound  # measured 0.0054, 0.0062, 0.0147
    assert s["meshreg"][0] < 0.7 * s["param"][0]  # the parametrization alone: 0.0109, 0.0133, 0.0256


@pytest.mark.parametrize("name, target", [("fold-90", 0.04), ("roll-180", 0.08)])
def test_fold_and_half_roll_reach_the_issue_targets(name, target):
    assert scores(name)["meshreg"][0] <= target  # measured 0.0168, 0.0147 (before issue 14: 0.44, 0.41)


def test_stretch_is_where_the_optimization_helps():
    s = scores("stretch")
    assert s["meshreg"][0] <= 0.03  # 0.0149
    assert s["meshreg"][0] < 0.5 * s["param"][0]  # the parametrization alone: 0.0566


@pytest.mark.parametrize("name", ["sheet-90%", "corner-64%", "strip-60%", "face-crops-5mm"])
def test_partial_overlap_reaches_the_issue_targets(name):
    # issue 19: the common region found and registered; the same surface matched by closest points (measured
    # 1e-5 to 1e-4 at most); the overlap fraction reported within 5% of the truth (measured within 1%)
    if name.startswith("face"):
        pytest.importorskip("pymeshlab")  # the face scan
    pair, mr = registered(name)
    median, p90 = meshreg_error(name)
    assert median <= 0.002 and p90 <= 0.006
    overlap = mr.result.info["overlap"]
    assert overlap["regime"] == "rigid" and abs(overlap["first_fraction"] - pair.overlap) <= 0.05


def test_bent_partial_pair_reaches_the_issue_target():
    # issue 19: two face crops 5 mm apart, the second bent by 72 degrees: median <= 0.02 (measured 0.0114 / 0.039;
    # Open3D's FPFH + RANSAC + ICP gives 0.058 / 0.115 on the full-size pair, see benchmarks/bench_peers.py)
    pytest.importorskip("pymeshlab")
    pair, mr = registered("face-crops-5mm-bent")
    median, p90 = meshreg_error("face-crops-5mm-bent")
    assert median <= 0.02 and p90 <= 0.06
    overlap = mr.result.info["overlap"]
    assert overlap["regime"] == "elastic" and abs(overlap["first_fraction"] - pair.overlap) <= 0.05


def test_remeshed_same_surface_at_benchmark_size_and_cli_defaults():
    pair = deform.remeshed_pair()  # 2600 and 3600 vertices, as in benchmarks/bench_peers.py
    mr = register_meshes(pair.first, pair.second, Options())
    err = pair.errors(deform.matched_points(mr, len(pair.second[0])))
    assert np.median(err) <= 0.0025 and np.percentile(err, 90) <= 0.007  # measured 0.0019 / 0.0044 (issue 14)


BENCH_SHEET = {"n_first": 2500, "n_second": 3500}  # as in benchmarks/bench_peers.py
BENCH_PAIRS = {
    "fold-90": lambda: deform.bent_pair(
        "fold-90", 90.0, start=0.45, width=0.1, surface=deform.relief_sheet(0.5), **BENCH_SHEET
    ),
    "roll-90": lambda: deform.bent_pair("roll-90", 90.0, **BENCH_SHEET),
    "roll-180": lambda: deform.bent_pair("roll-180", 180.0, **BENCH_SHEET),
    "stretch": lambda: deform.stretched_pair("stretch", 0.5, **BENCH_SHEET),
    "face-bend-72": lambda: deform.scan_pair("face-bend-72", bend_angle=72.0, radius=45.0, n_second=8000),
}


@pytest.mark.parametrize(
    "name, target",
    [("fold-90", 0.04), ("roll-90", 0.05), ("roll-180", 0.08), ("stretch", 0.01), ("face-bend-72", 0.015)],
)
def test_benchmark_pairs_reach_the_targets_below_the_parametrization(name, target):
    """Issue 14's targets at the benchmark's size with the command line's defaults, and below the parametrization
    alone. Measured (median; the parametrization alone): fold 0.0076 (0.0090), roll 90 0.0036 (0.0131), roll 180
    0.0074 (0.0258), stretch 0.0090 (0.0569; before issue 14: 0.0091), face bent 72 degrees 0.0038 (0.0230)."""
    if name.startswith("face"):
        pytest.importorskip("pymeshlab")  # the face scan
    pair = BENCH_PAIRS[name]()
    n = len(pair.second[0])
    mr = register_meshes(pair.first, pair.second, Options())
    err = np.median(pair.errors(deform.matched_points(mr, n)))
    assert err <= target
    assert err < np.median(pair.errors(deform.parametrization_points(mr, n)))
