"""Shape atlas: known answers (one shape in many poses gives itself and no variance; a two-parameter family gives
modes that follow its parameters), one connectivity, resume bit for bit, failures left out, pool and Dask agree."""

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from meshreg import register
from meshreg.atlas_result import Atlas
from meshreg.atlas_settings import ATLAS_OPTIONS, AtlasSettings
from meshreg.errors import InputError
from meshreg.grid import GridSurface
from meshreg.mesh.samples import random_disk_mesh
from meshreg.samples import bump, sample, warp
from meshreg.search import ORIENTATION_PRESERVING, apply_symmetry
from meshreg.shape_atlas import atlas
from meshreg.shape_stats import canonical_correlations, principal_modes

# a coarse, quick registration for the tests that check bookkeeping rather than accuracy
QUICK = ATLAS_OPTIONS.replace(refine="none", max_starts=1)


def bowl(r, t):
    """Curved everywhere (no flat part along which E would let h slide), no symmetry of the square."""
    return np.stack([r, t, 0.6 * r**2 + 0.4 * t**2 + 0.3 * r * t - 0.2 * r], axis=-1)


def posed(surface: GridSurface, seed: int, scale: float) -> GridSurface:
    rotation = Rotation.random(random_state=seed).as_matrix()
    return GridSurface.from_array(scale * surface.points @ rotation.T + seed, surface.r, surface.t)


def bump_sheets(params, n=21):
    """Grids of a sheet with a bump of height a at (b, 0.3) on a skewed dome, in random poses."""
    grids = []
    for k, (a, b) in enumerate(params):
        sheet = sample(dome_with_bump(a, b), n, n, gamma=warp(0.03 * (k % 3)))
        grids.append(posed(sheet, k, 1.0 + 0.5 * k))
    return grids


def dome_with_bump(a: float, b: float, width: float = 0.02):
    """A skewed dome (no symmetry of the square) with a bump of height a at (b, 0.3)."""
    return lambda u, v: np.stack(
        [
            u,
            v,
            0.4 * np.sin(np.pi * u) * np.sin(np.pi * v) * (0.6 + 0.8 * u)
            + a * np.exp(-((u - b) ** 2 + (v - 0.3) ** 2) / width),
        ],
        axis=-1,
    )


def test_one_shape_in_many_poses_and_samplings_gives_itself_and_no_variance():
    grids = [
        posed(sample(bowl, n, n, gamma=warp(a)), seed, scale)
        for seed, (n, a, scale) in enumerate([(17, 0.0, 1.0), (23, 0.05, 3.0), (19, -0.06, 0.5), (21, 0.08, 2.0)])
    ]
    result = atlas(grids, jobs=1)
    template = GridSurface.from_array(result.template.reshape(*result.grid, 3))
    truth = sample(bowl, 23, 23)
    assert register(truth, template).energy <= 1e-6 and register(template, truth).energy <= 1e-6
    assert np.all(result.energies <= 1e-6)
    # zero variance: the aligned shapes agree node by node to 1e-4 of their size
    spread = np.sqrt(np.sum(result.variances) * (len(grids) - 1) / len(grids) / len(result.template))
    assert spread <= 1e-4 * result.scale
    assert result.aligned.shape == (4, len(result.template), 3) and len(result.faces) == 2 * (result.grid[0] - 1) ** 2
    # each member keeps its size and is rotated into the template's frame
    np.testing.assert_allclose(result.sizes / result.sizes[0], [1.0, 3.0, 0.5, 2.0], rtol=1e-3)


def test_principal_modes_and_canonical_correlations_known_answer():
    rng = np.random.default_rng(0)
    mean = rng.normal(size=(50, 3))
    m1, m2 = np.linalg.qr(rng.normal(size=(150, 2)))[0].T
    coefficients = rng.normal(size=(20, 2))
    a, b = (np.linalg.qr(coefficients - coefficients.mean(axis=0))[0] * [6.0, 2.0]).T  # uncorrelated, centred
    shapes = mean + (a[:, None] * m1 + b[:, None] * m2).reshape(20, 50, 3)
    got_mean, modes, variances, explained, scores = principal_modes(shapes, 5)
    assert modes.shape == (5, 50, 3) and scores.shape == (20, 5)
    np.testing.assert_allclose(variances[:2], [np.var(a, ddof=1), np.var(b, ddof=1)], rtol=1e-9)
    np.testing.assert_allclose(explained[:2].sum(), 1.0, atol=1e-12)
    assert abs(abs(modes[0].ravel() @ m1) - 1) < 1e-9 and abs(abs(modes[1].ravel() @ m2) - 1) < 1e-9
    np.testing.assert_allclose(np.abs(scores[:, 0]), np.abs(a), atol=1e-9)
    np.testing.assert_allclose(got_mean + (scores @ modes.reshape(5, -1)).reshape(20, 50, 3), shapes, atol=1e-9)
    assert np.allclose(canonical_correlations(scores[:, :2], np.c_[b, 2 * a + 1]), 1.0)
    noise = rng.normal(size=(20, 2))
    assert canonical_correlations(noise, np.c_[a, b])[0] < 0.9
    # held out 2026-12-02 (a fuzz): an atlas of three copies of one file reported "mode 1 100.0%" of a variance of 1e-30
    same = np.repeat(shapes[:1] * 1e3, 3, axis=0) + np.array([0.0, 1e-13, -1e-13])[:, None, None]
    _, _, variances, explained, _ = principal_modes(same, 2)
    assert np.all(variances == 0) and np.all(explained == 0)
    # ... while terrain in map coordinates (4e6 m) keeps a mode of micrometres (a review's case)
    far = 4e6 + np.repeat(shapes[:1], 12, axis=0) + 1e-5 * rng.normal(size=(12, 1, 1)) * m1.reshape(50, 3)
    _, _, variances, explained, _ = principal_modes(far, 2)
    assert variances[0] > 1e-12 and explained[0] > 0.99


def test_keep_orientation_matches_front_to_front_only():
    surface = sample(bump(), 21, 21)
    turned = posed(apply_symmetry(surface, 3), 7, 2.0)  # a half turn of the square: orientation kept
    result = register(surface, turned, keep_orientation=True)
    assert result.symmetry == 3 and result.energy < 1e-6
    mirrored = apply_symmetry(surface, 4)  # r and t swapped: the same points, the other side up
    assert 4 not in ORIENTATION_PRESERVING and register(surface, mirrored).energy < 1e-6
    kept = register(surface, mirrored, keep_orientation=True)
    assert kept.symmetry in ORIENTATION_PRESERVING and kept.energy > 1e-3


def test_settings_are_validated():
    for changes, name in (
        ({"tolerance": -1.0}, "tolerance"),
        ({"max_iterations": 0}, "max_iterations"),
        ({"modes": 0}, "modes"),
        ({"medoid_grid": 2}, "medoid_grid"),
    ):
        with pytest.raises(InputError, match=name):
            AtlasSettings(**changes)
    with pytest.raises(InputError, match="at least 2"):
        atlas([sample(bowl, 11, 11)])


def test_interrupted_run_resumes_to_the_same_atlas_bit_for_bit(tmp_path):
    grids = bump_sheets([(0.1, 0.4), (0.25, 0.6), (0.0, 0.5), (0.2, 0.35)], n=15)
    settings = AtlasSettings(tolerance=0.0, max_iterations=3, medoid_grid=11)
    fresh = atlas(grids, QUICK, settings, jobs=1)

    class Stop(KeyboardInterrupt):
        pass

    def interrupt(stage, done, total):
        if stage == "iteration 2" and done == 2:
            raise Stop

    with pytest.raises(Stop):
        atlas(grids, QUICK, settings, jobs=1, checkpoint=tmp_path, progress=interrupt)
    lines = (tmp_path / "iteration-2.jsonl").read_text().splitlines()
    kept = [json.loads(x) for x in lines[1:]]
    assert len(kept) == 2 and (tmp_path / "medoid.jsonl").exists()
    seen = []
    resumed = atlas(grids, QUICK, settings, jobs=1, checkpoint=tmp_path, progress=lambda *a: seen.append(a))
    assert ("iteration 2", 2, 4) in seen and ("iteration 1", 4, 4) in seen  # resumed, not redone
    for field in ("template", "aligned", "rotations", "energies", "h", "modes", "variances", "scores", "objective"):
        assert np.array_equal(getattr(resumed, field), getattr(fresh, field)), field
    for record in kept:  # the checkpointed registrations were reused, with their times
        assert resumed.seconds[record["j"] - 1, 1] == record["seconds"]
    assert resumed.params["iterations"] == fresh.params["iterations"] >= 2


def test_save_load_round_trip(tmp_path):
    result = atlas(bump_sheets([(0.1, 0.4), (0.25, 0.6), (0.0, 0.5)]), QUICK, AtlasSettings(medoid_grid=11), jobs=1)
    result.save(tmp_path / "atlas.npz")
    back = Atlas.load(tmp_path / "atlas.npz")
    assert back.names == result.names and back.params == result.params and back.grid == result.grid
    assert np.array_equal(back.h, result.h) and np.array_equal(back.modes, result.modes)
    np.testing.assert_allclose(back.shapes().mean(axis=0), back.mean, atol=1e-12)
    with pytest.raises(InputError, match="meshreg atlas file .No such file"):
        Atlas.load(tmp_path / "missing.npz")
    # held out 2026-12-02 (a fuzz): a single array (meshreg morph GRID.npy --mode 1) and a cut archive gave tracebacks
    np.save(tmp_path / "grid.npy", np.zeros((3, 3, 3)))
    (tmp_path / "cut.npz").write_bytes((tmp_path / "atlas.npz").read_bytes()[:5000])
    (tmp_path / "junk.npz").write_text("not numpy")
    np.savez(tmp_path / "other.npz", modes=np.zeros(3), template=np.zeros(3))
    for name, words in [("grid.npy", "a single array"), ("cut", "not a NumPy .npz"), ("junk", "not a NumPy .npz")]:
        with pytest.raises(InputError, match=f"not a meshreg atlas file .{words}"):
            Atlas.load(tmp_path / (name if "." in name else f"{name}.npz"))
    with pytest.raises(InputError, match="not a meshreg atlas file .no aligned"):
        Atlas.load(tmp_path / "other.npz")


def _write_grids(tmp_path, grids):
    files = []
    for k, g in enumerate(grids):
        files.append(tmp_path / f"sheet{k}.npy")
        np.save(files[-1], g.points)
    return files


@pytest.mark.slow
def test_cli_writes_one_connectivity_reports_failures_and_morphs(tmp_path):
    files = _write_grids(tmp_path, bump_sheets([(0.1, 0.4), (0.25, 0.6), (0.0, 0.5)]))
    trimesh.creation.icosphere().export(tmp_path / "closed.stl")
    out = tmp_path / "out"
    cli = [sys.executable, "-m", "meshreg.cli"]
    quick = ["--refine", "none", "--max-starts", "1", "--medoid-grid", "11", "-q"]
    proc = subprocess.run(
        [*cli, "atlas", *map(str, files), str(tmp_path / "closed.stl"), "-o", str(out), "--jobs", "2", *quick],
        capture_output=True,
        text=True,
    )
    assert proc.returncode == 0, proc.stderr
    assert "left out       closed: the surface is closed" in proc.stdout
    template = trimesh.load(out / "template.ply", process=False)
    aligned = sorted((out / "aligned").glob("*.ply"))
    assert [p.stem for p in aligned] == ["sheet0", "sheet1", "sheet2"]
    for path in aligned:
        mesh = trimesh.load(path, process=False)
        assert np.array_equal(mesh.faces, template.faces) and len(mesh.vertices) == len(template.vertices)
    result = Atlas.load(out / "atlas.npz")
    assert "closed" in result.failures and result.names == ["sheet0", "sheet1", "sheet2"]
    assert (out / "modes.png").stat().st_size > 0 and (out / "scores.png").stat().st_size > 0
    assert not (out / ".checkpoint").exists()
    from PIL import Image

    proc = subprocess.run(
        [*cli, "morph", str(out / "atlas.npz"), "--mode", "1", "-o", str(tmp_path / "m.gif"), "--frames", "5"],
        capture_output=True,
        text=True,
    )
    assert proc.returncode == 0, proc.stderr
    assert Image.open(tmp_path / "m.gif").n_frames == 8
    proc = subprocess.run(
        [*cli, "morph", str(aligned[0]), str(aligned[1]), "-o", str(tmp_path / "a.gif"), "--frames", "3"],
        capture_output=True,
        text=True,
    )
    assert proc.returncode == 0, proc.stderr
    rerun = [*cli, "atlas", *map(str, files[:2]), "-o", str(out), "--jobs", "1", *quick]
    assert subprocess.run(rerun, capture_output=True, text=True).returncode == 0
    assert sorted(p.stem for p in (out / "aligned").glob("*.ply")) == ["sheet0", "sheet1"]  # sheet2 was the last run's
    for bad in (
        [*cli, "atlas", str(files[0]), str(tmp_path / "closed.stl"), "-o", str(tmp_path / "x")],
        [*cli, "atlas", *map(str, files), "-o", str(tmp_path / "y"), "--tolerance", "-1"],
        [*cli, "morph", str(out / "atlas.npz"), "--mode", "9", "-o", str(tmp_path / "b.gif")],
    ):
        proc = subprocess.run(bad, capture_output=True, text=True)
        assert proc.returncode == 2 and "Traceback" not in proc.stderr and proc.stderr.count("\n") == 1, proc.stderr


def test_a_face_lit_head_on_keeps_its_colour_in_range():
    """The light is a unit vector: a face turned to it, at the brightest colour of the map, stays within 0-1 (an atlas
    of four held-out members failed in matplotlib with the light 1.0034 long)."""
    from matplotlib import colormaps
    from matplotlib.figure import Figure

    from meshreg import viz

    assert np.linalg.norm(viz.LIGHT) == pytest.approx(1.0, abs=1e-15)
    x = np.linspace(0, 1, 2001)
    brightest = x[colormaps["coolwarm"](x)[:, :3].max(axis=1).argmax()]
    a = np.cross(viz.LIGHT, [1.0, 0, 0])
    a /= np.linalg.norm(a)
    face = np.array([[0.0, 0, 0], a, np.cross(viz.LIGHT, a)])
    ax = Figure().add_subplot(projection="3d")
    box = np.array([[-1.0, -1, -1], [1, 1, 1]])
    viz._draw_surface(ax, face, np.array([[0, 1, 2]]), np.full(3, 2 * brightest - 1), 1.0, box)


def test_an_interrupted_atlas_says_where_its_work_is_and_a_morph_is_whole_or_absent(tmp_path, monkeypatch):
    from meshreg.atlas_outputs import atlas_files, morph_files

    files = _write_grids(tmp_path, bump_sheets([(0.1, 0.4), (0.25, 0.6), (0.0, 0.5)]))

    def interrupt(*_):
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt) as stopped:  # the command line exits 130 / 143, not 2
        atlas_files(files, tmp_path / "out", QUICK, progress=interrupt)
    assert "rerun the same command to resume" in " ".join(stopped.value.__notes__)
    gif = tmp_path / "m.gif"
    gif.write_bytes(b"an earlier morph")

    def cut_short(frames, faces, path, **_):
        Path(path).write_bytes(b"GIF89a, three frames of 46")
        raise KeyboardInterrupt

    monkeypatch.setattr("meshreg.viz.write_morph", cut_short)
    with pytest.raises(KeyboardInterrupt):
        morph_files(files[0], files[1], gif, frames=3, options=QUICK)
    assert gif.read_bytes() == b"an earlier morph" and list(tmp_path.glob("*.gif")) == [gif]


@pytest.mark.slow
def test_family_modes_recover_its_two_parameters():
    """12 random triangulations of about 2k triangles (all vertex counts different), in random poses and sizes, of a
    sheet whose bump height a and position b vary: the aligned meshes share one connectivity, and the first two modes
    follow (a, b)."""
    rng = np.random.default_rng(1)
    params = np.c_[rng.uniform(0.1, 0.3, 12), rng.uniform(0.35, 0.65, 12)]
    meshes = []
    for k, (a, b) in enumerate(params):
        rotation = Rotation.random(random_state=100 + k).as_matrix()
        sheet = dome_with_bump(a, b, width=0.03)
        v, f, _ = random_disk_mesh(
            sheet, 900 + int(rng.integers(225)), 10 + k, rotation=rotation, scale=rng.uniform(0.5, 2)
        )
        meshes.append((v, f))
    assert len({len(v) for v, _ in meshes}) == 12 and all(1900 < len(f) < 2500 for _, f in meshes)
    result = atlas(meshes, jobs=2)
    assert not result.failures and result.aligned.shape == (12, 41 * 41, 3) and result.faces.shape == (3200, 3)
    assert np.all(canonical_correlations(result.scores[:, :2], params) >= 0.9)
    assert result.explained[:2].sum() >= 0.8
    assert result.objective[result.params["kept_iteration"] - 1] < result.objective[0]  # better than the medoid
    assert result.seconds.shape == (12, result.params["iterations"]) and result.timings["per_member"] > 0


@pytest.mark.slow
def test_killed_cli_run_resumes_to_the_same_atlas(tmp_path):
    files = _write_grids(tmp_path, bump_sheets([(0.1, 0.4), (0.25, 0.6), (0.0, 0.5), (0.2, 0.35), (0.15, 0.55)]))
    cli = [sys.executable, "-m", "meshreg.cli", "atlas", *map(str, files), "--jobs", "1", "-q"]
    quick = ["--refine", "none", "--max-starts", "1", "--medoid-grid", "11", "--tolerance", "0"]
    out = tmp_path / "out"
    checkpoint = out / ".checkpoint" / "iteration-2.jsonl"
    proc = subprocess.Popen([*cli, "-o", str(out), *quick], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    deadline = time.time() + 300
    while time.time() < deadline and (not checkpoint.exists() or len(checkpoint.read_text().splitlines()) < 3):
        time.sleep(0.05)
    proc.send_signal(signal.SIGKILL)  # no clean-up at all
    proc.wait()
    assert not (out / "atlas.npz").exists()
    resumed = subprocess.run([*cli, "-o", str(out), *quick], capture_output=True, text=True)
    assert resumed.returncode == 0, resumed.stderr
    fresh = subprocess.run([*cli, "-o", str(tmp_path / "fresh"), *quick], capture_output=True, text=True)
    assert fresh.returncode == 0, fresh.stderr
    a, b = Atlas.load(out / "atlas.npz"), Atlas.load(tmp_path / "fresh" / "atlas.npz")
    for field in ("template", "aligned", "h", "modes", "scores", "objective"):
        assert np.array_equal(getattr(a, field), getattr(b, field)), field
    assert (out / "template.ply").read_bytes() == (tmp_path / "fresh" / "template.ply").read_bytes()


@pytest.mark.slow
def test_dask_cluster_gives_the_same_atlas():
    from distributed import Client, LocalCluster

    grids = bump_sheets([(0.1, 0.4), (0.25, 0.6), (0.0, 0.5), (0.2, 0.35)])
    settings = AtlasSettings(medoid_grid=11, max_iterations=2)
    local = atlas(grids, QUICK, settings, jobs=2)
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1", dashboard_address=None) as c:
        with Client(c) as client:
            clustered = atlas(grids, QUICK, settings, client=client)
    for field in ("template", "aligned", "h", "modes", "scores"):
        assert np.array_equal(getattr(local, field), getattr(clustered, field)), field
