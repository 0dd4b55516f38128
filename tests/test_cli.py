import gc
import re
import subprocess
import sys

import numpy as np
import pytest

import meshreg.pipeline
from meshreg.cli import main
from meshreg.result import Registration
from meshreg.samples import paper_pairs


@pytest.fixture(scope="module")
def grid_files(tmp_path_factory):
    d = tmp_path_factory.mktemp("grids")
    pair = paper_pairs(21, 21)[6]
    np.save(d / "first.npy", pair.first.points)
    np.save(d / "second.npy", pair.second.points)
    return d


def test_register_writes_result_and_figure(grid_files, tmp_path, capsys):
    before = (grid_files / "first.npy").read_bytes()
    code = main(
        ["register", str(grid_files / "first.npy"), str(grid_files / "second.npy"), "-o", str(tmp_path / "out"), "-q"]
    )
    assert code == 0
    out = capsys.readouterr().out
    assert "energy E" in out and "rotation R" in out
    result = Registration.load(tmp_path / "out" / "result.npz")
    assert result.energy < 1e-6
    assert (tmp_path / "out" / "registration.png").stat().st_size > 1000
    assert (grid_files / "first.npy").read_bytes() == before


def test_console_script_runs_paper_mode(grid_files, tmp_path):
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "meshreg.cli",
            "register",
            str(grid_files / "first.npy"),
            str(grid_files / "second.npy"),
            "-o",
            str(tmp_path),
            "--mode",
            "dp",
            "--window",
            "7",
            "-q",
        ],
        capture_output=True,
        text=True,
    )
    assert proc.returncode == 0, proc.stderr
    assert "written" in proc.stdout  # printed, and flushed before run() ends the process without the teardown
    assert Registration.load(tmp_path / "result.npz").params["window"] == 7


def _write(path, array):
    np.save(path, array)
    return str(path)


@pytest.mark.parametrize(
    "make, message",
    [
        (lambda d: str(d / "missing.npy"), "no such file"),
        (lambda d: _write(d / "nan.npy", np.full((5, 5, 3), np.nan)), "NaN"),
        (lambda d: _write(d / "small.npy", np.random.rand(2, 5, 3)), "at least 3x3"),
        (lambda d: _write(d / "flat.npy", np.zeros((5, 5, 3))), "zero area"),
        (lambda d: _write(d / "shape.npy", np.zeros((5, 5))), "shape"),
    ],
)
def test_bad_input_exits_nonzero_with_one_line(grid_files, tmp_path, make, message):
    bad = make(tmp_path)
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "meshreg.cli",
            "register",
            bad,
            str(grid_files / "second.npy"),
            "-o",
            str(tmp_path / "o"),
            "-q",
        ],
        capture_output=True,
        text=True,
    )
    assert proc.returncode == 2
    assert message in proc.stderr and "Traceback" not in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "o" / "result.npz").exists()


def test_output_never_overwrites_an_input(tmp_path, capsys):
    pair = paper_pairs(11, 11)[0]
    np.savez(tmp_path / "result.npz", points=pair.first.points)
    np.save(tmp_path / "b.npy", pair.second.points)
    before = (tmp_path / "result.npz").read_bytes()
    assert main(["register", str(tmp_path / "result.npz"), str(tmp_path / "b.npy"), "-o", str(tmp_path), "-q"]) == 2
    assert "is an input file" in capsys.readouterr().err
    assert (tmp_path / "result.npz").read_bytes() == before


def test_symmetric_reports_both_directions(grid_files, tmp_path, capsys):
    code = main(
        [
            "register",
            str(grid_files / "first.npy"),
            str(grid_files / "second.npy"),
            "-o",
            str(tmp_path),
            "--symmetric",
            "-q",
        ]
    )
    assert code == 0
    out = capsys.readouterr().out
    assert "reverse E" in out and "mean E" in out
    forward, backward = Registration.load(tmp_path / "result.npz"), Registration.load(tmp_path / "result_reverse.npz")
    assert forward.energy < 1e-6 and backward.energy < 1e-6
    assert np.allclose(backward.rotation, forward.rotation.T, atol=1e-3)


def test_gd_scale_space_options_reach_the_result(grid_files, tmp_path):
    args = ["register", str(grid_files / "first.npy"), str(grid_files / "second.npy"), "--mode", "gd", "-q"]
    assert main(args + ["-o", str(tmp_path / "a"), "--smoothing", "0.2", "0.1", "--start-basis", "2"]) == 0
    assert main(args + ["-o", str(tmp_path / "b"), "--smoothing"]) == 0
    a, b = (Registration.load(tmp_path / d / "result.npz") for d in "ab")
    assert a.params["smoothing"] == [0.2, 0.1] and a.params["start_basis"] == 2
    assert a.params["gd_path"]["smoothing"] in ([], [0.2, 0.1])  # the kept path (tests/test_scale.py checks which)
    assert b.params["smoothing"] == [] and b.params["gd_path"]["smoothing"] == []
    assert "smoothing" in a.timings and "smoothing" not in b.timings


def test_max_starts_option(grid_files, tmp_path):
    args = ["register", str(grid_files / "first.npy"), str(grid_files / "second.npy"), "-q"]
    assert main(args + ["-o", str(tmp_path / "one"), "--max-starts", "1"]) == 0
    one = Registration.load(tmp_path / "one" / "result.npz")
    assert one.params["max_starts"] == 1 and len(one.params["starts"]) == 1
    assert main(args + ["-o", str(tmp_path / "zero"), "--max-starts", "0"]) == 2


def test_version_and_a_quick_help_that_loads_no_numerics():
    for module in ("meshreg.cli", "meshreg"):  # python -m meshreg as well (held out 2026-12-01: no __main__)
        proc = subprocess.run([sys.executable, "-m", module, "--version"], capture_output=True, text=True)
        assert proc.returncode == 0 and proc.stdout.startswith("meshreg ")
    code = (
        "import sys, meshreg.cli; meshreg.cli.build_parser(); "
        "print(sorted({'numba', 'scipy', 'numpy'} & set(sys.modules)))"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert proc.stdout.strip() == "[]"  # --help builds the parser without loading the numerical libraries


def test_the_command_defers_numpy_tools_that_scipy_touches_until_they_are_used():
    code = (
        "import sys; from meshreg.startup import defer_numpy_tools; defer_numpy_tools(); "
        "import scipy.sparse, numpy as np; "
        "print(sorted(n for n in ('numpy.f2py.crackfortran', 'numpy.ma.core', 'numpy.testing._private.utils') "
        "if n in sys.modules)); "
        "print(float(np.ma.masked_array([1.0, 2.0], mask=[0, 1]).sum())); np.testing.assert_allclose(1.0, 1.0); "
        "import numpy.f2py; print(callable(numpy.f2py.run_main), type(np.ma).__name__)"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    # not executed by SciPy's import; the real modules once used
    assert proc.stdout.split("\n")[:3] == ["[]", "1.0", "True module"]


@pytest.mark.slow
def test_demo_checks_its_own_answer(tmp_path):
    proc = subprocess.run(
        [sys.executable, "-m", "meshreg.cli", "demo", "-o", str(tmp_path / "d"), "-q"], capture_output=True, text=True
    )
    assert proc.returncode == 0, proc.stderr
    check = next(line for line in proc.stdout.splitlines() if line.startswith("check:"))
    angle, scale, error = (
        float(x) for x in re.findall(r"rotation ([\d.]+) deg.*scale ([\d.]+).* ([\d.]+)% of", check)[0]
    )
    assert angle < 1.0 and abs(scale - 2.5) < 0.025 and error < 1.0  # the motion applied and the true correspondence
    assert (tmp_path / "d" / "view.html").stat().st_size > 1_000_000


def _spy(function, note):
    def spied(*args, **kwargs):
        note()
        return function(*args, **kwargs)

    return spied


def test_register_prints_residual_and_an_ambiguous_correspondence(tmp_path, capsys, monkeypatch):
    from meshreg.samples import sample, symmetric_sheet

    c = symmetric_sheet("two-fold")
    np.save(tmp_path / "a.npy", sample(c, 21, 21).points)
    np.save(tmp_path / "b.npy", sample(lambda u, v: 2 * c(u, v)[..., [1, 2, 0]], 23, 19).points)
    collecting = []
    spied = _spy(meshreg.pipeline.register_with, lambda: collecting.append(gc.isenabled()))
    monkeypatch.setattr(meshreg.pipeline, "register_with", spied)
    assert main(["register", str(tmp_path / "a.npy"), str(tmp_path / "b.npy"), "-o", str(tmp_path / "o"), "-q"]) == 0
    assert collecting == [False] and gc.isenabled()  # the collector off during the registration, on again after
    out = capsys.readouterr().out
    assert "residual" in out and "against the mirror image" in out
    ambiguous = [line for line in out.splitlines() if "ambiguous" in line]
    assert len(ambiguous) == 1 and "2 equally good correspondences" in ambiguous[0]
    result = Registration.load(tmp_path / "o" / "result.npz")
    assert len(result.alternatives) == 1 and result.residual < 0.01
    assert (tmp_path / "o" / "registration.png").stat().st_size > 1000


@pytest.fixture(scope="module")
def mesh_files(tmp_path_factory):
    """Two small meshes of one bump sheet (300 and 400 random vertices), the second rotated and scaled."""
    from scipy.spatial.transform import Rotation

    from meshreg.mesh.export import write_ply
    from meshreg.mesh.samples import random_disk_mesh
    from meshreg.samples import bump

    d = tmp_path_factory.mktemp("meshes")
    v1, f1, _ = random_disk_mesh(bump(), 300, seed=1)
    v2, f2, _ = random_disk_mesh(bump(), 400, seed=2, rotation=Rotation.random(random_state=3).as_matrix(), scale=2.0)
    write_ply(d / "a.ply", v1, f1, np.full((len(v1), 3), 0.8))
    write_ply(d / "b.ply", v2, f2, np.full((len(v2), 3), 0.8))
    return d, v1, f1


def _boundary_corners(vertices, faces, k: int) -> list[int]:
    from meshreg.mesh.topology import prepare_disk

    disk = prepare_disk(vertices, faces)
    loop = disk.boundary
    return [int(disk.vertex_map[loop[i]]) for i in np.linspace(0, len(loop), 5).astype(int)[:4] + k]


# per flag of meshreg.flags.FLAGS: the arguments given, and what result.npz must then record; each row runs the
# command line on two small meshes (--resolution 13 and --corner-search 0 unless the row sets them)
MESH_FLAG_CASES = {
    "--mode": (["--mode", "dp+gd"], lambda r: r.mode == "dp+gd" and "search" not in r.timings),
    "--window": (["--window", "4"], lambda r: r.params["window"] == 4),
    "--basis": (["--basis", "3"], lambda r: r.params["basis"] == 3),
    "--solver": (["--solver", "gradient"], lambda r: r.params["solver"] == "gradient"),
    "--refine": (["--refine", "none"], lambda r: r.params["refine"] == "none" and "refine" not in r.timings),
    "--max-starts": (["--max-starts", "1"], lambda r: len(r.params["starts"]) == 1),
    "--keep-orientation": (
        ["--keep-orientation"],
        lambda r: (
            r.params["keep_orientation"] is True and all(s["symmetry"] in (0, 3, 5, 6) for s in r.params["starts"])
        ),
    ),
    "--force": (["--force"], lambda r: r.params["force"] is True),
    "--symmetry": (
        ["--symmetry", "0"],
        lambda r: r.symmetry == 0 and {s["symmetry"] for s in r.params["starts"]} == {0},
    ),
    "--max-rounds": (["--max-rounds", "2"], lambda r: r.params["max_rounds"] == 2),
    "--dp-radius": (["--dp-radius", "0"], lambda r: r.params["dp_radius"] == 0),
    "--smoothing": (
        ["--mode", "gd", "--smoothing", "0.2"],
        lambda r: r.params["smoothing"] == [0.2] and "smoothing" in r.timings,
    ),
    "--start-basis": (["--mode", "gd", "--start-basis", "2"], lambda r: r.params["start_basis"] == 2),
    "--resolution": (["--resolution", "11"], lambda r: r.h.shape == (11, 11, 2) and r.params["resolution"] == 11),
    "--weights": (["--weights", "cotangent"], lambda r: r.params["weights"] == "cotangent"),
    "--bend-window": (
        ["--bend-window", "0"],
        lambda r: r.params["bend_window"] == 0 and "bend_energy" not in r.params,
    ),
    "--antialias": (["--antialias", "1"], lambda r: r.params["antialias"] == 1),
    "--mesh-blur": (["--mesh-blur", "0"], lambda r: r.params["mesh_blur"] == 0 and r.params["mesh_blur_sigma"] == 0),
    "--no-cleanup": (["--no-cleanup"], lambda r: r.params["cleanup"] is False),
    "--corner-search": (["--corner-search", "2"], lambda r: r.params["corner_search"] == 2),
    "--overlap": (["--overlap", "off"], lambda r: r.params["overlap"] == "off" and "overlap" not in r.info),
    "--overlap-quick": (
        ["--overlap-quick", "0"],
        lambda r: r.params["overlap_quick"] == 0 and "quick" not in r.info["overlap"]["pose_source"],
    ),
    "--processes": (["--processes", "1"], lambda r: r.params["processes"] == 1),
    "--corners1": (["--corners1", "CORNERS1"], lambda r: len(r.params["corners1"]) == 4),
    "--corners2": (["--corners2", "CORNERS2"], lambda r: len(r.params["corners2"]) == 4),
}


def test_every_flag_has_a_mesh_case():
    from meshreg.flags import FLAGS

    assert {row.flag for row in FLAGS} == set(MESH_FLAG_CASES)


@pytest.mark.parametrize("flag", list(MESH_FLAG_CASES))
def test_each_flag_reaches_the_mesh_result(mesh_files, tmp_path, flag):
    d, v1, f1 = mesh_files
    args, check = MESH_FLAG_CASES[flag]
    corners = {"CORNERS1": _boundary_corners(v1, f1, 1), "CORNERS2": None}
    if "CORNERS2" in args:
        from meshreg.mesh.topology import load_mesh

        corners["CORNERS2"] = _boundary_corners(*load_mesh(d / "b.ply"), 2)
    args = [str(x) for a in args for x in (corners[a] if a in corners else [a])]
    for name, default in (("--resolution", "13"), ("--corner-search", "0")):
        if name not in args:
            args += [name, default]
    out = tmp_path / "out"
    assert main(["register", str(d / "a.ply"), str(d / "b.ply"), "-o", str(out), "-q", *args]) == 0
    result = Registration.load(out / "result.npz")
    assert check(result), (flag, result.params)


def test_every_key_of_a_mesh_result_is_documented(mesh_files, tmp_path):
    """docs/outputs.md names every array of result.npz, every key of its params and timings, and every file the
    command writes (a key added without its documentation fails here)."""
    import json
    from pathlib import Path

    d, _, _ = mesh_files
    out = tmp_path / "out"
    assert main(["register", str(d / "a.ply"), str(d / "b.ply"), "-o", str(out), "-q", "--resolution", "13"]) == 0
    outputs_doc = (Path(__file__).parents[1] / "docs" / "outputs.md").read_text()
    documented = set(re.findall(r"`([A-Za-z_0-9.-]+)`", outputs_doc))
    with np.load(out / "result.npz") as data:
        keys = set(data.files) | set(json.loads(str(data["params"]))) | set(json.loads(str(data["timings"])))
    files = {p.name for p in out.rglob("*") if p.is_file()}
    assert keys | files <= documented, sorted((keys | files) - documented)


@pytest.mark.parametrize("workers", [0, 1, 2])
def test_the_painter_writes_every_figure_by_finish_and_raises_a_figure_error_there(tmp_path, workers):
    from meshreg.painter import Painter

    points = np.random.default_rng(0).random((5, 6, 3))
    with Painter(workers) as painter:
        painter.draw("plot_registration", points, points, [1.0, 0.5], tmp_path / "r.png", title="same")
        painter.finish()
        assert (tmp_path / "r.png").stat().st_size > 1000
        painter.draw("plot_registration", points, points[:2], [1.0], tmp_path / "bad.png")
        with pytest.raises(ValueError):
            painter.finish()


def _slow_pid(path):
    import os
    import time

    time.sleep(0.5)
    with open(path, "w") as file:
        file.write(str(os.getpid()))


def test_two_painter_workers_draw_two_figures_at_once(monkeypatch, tmp_path):
    """The warmed worker forks the second; once it is ready, a figure queued while the first is busy goes to it."""
    import os
    import time

    import meshreg.painter
    from meshreg import viz
    from meshreg.painter import Painter

    monkeypatch.setattr(meshreg.painter, "may_fork", lambda: True)  # even if an earlier test left a thread running
    monkeypatch.setattr(viz, "slow_pid", _slow_pid, raising=False)  # the workers fork with it
    with Painter(workers=2) as painter:
        end = time.perf_counter() + 30
        while painter._free_worker() == 0 and not painter._ready[1] and time.perf_counter() < end:
            time.sleep(0.05)
        assert painter._ready[1], "the second worker never said it was ready"
        tic = time.perf_counter()
        painter.draw("slow_pid", tmp_path / "a")
        painter.draw("slow_pid", tmp_path / "b")
        painter.finish()
        took = time.perf_counter() - tic
    pids = {(tmp_path / name).read_text() for name in "ab"}
    assert len(pids) == 2 and str(os.getpid()) not in pids
    assert took < 0.95  # side by side, not one after the other


def test_a_painter_left_by_an_error_stops_its_worker_at_once(monkeypatch):
    import time

    import meshreg.painter
    from meshreg.painter import Painter

    monkeypatch.setattr(meshreg.painter, "may_fork", lambda: True)  # even if an earlier test left a thread running
    tic = time.perf_counter()
    with pytest.raises(RuntimeError), Painter() as painter:
        worker = painter._worker
        raise RuntimeError("bad input found after the fork")
    # stopped in its start-up (matplotlib's import, the warm-up figure), not left to end it
    worker.join(timeout=10)
    assert not worker.is_alive()
    assert time.perf_counter() - tic < 10


def test_the_figures_warm_up_draws_to_nowhere():
    from meshreg import viz

    viz.warm_up()


def test_the_painter_does_not_fork_while_another_thread_runs():
    import threading

    from meshreg.painter import Painter

    made = []
    thread = threading.Thread(target=lambda: made.append(Painter()))
    thread.start()
    thread.join()
    assert not made[0].forked


def test_the_first_run_check_looks_at_kernels_that_exist():
    from pathlib import Path

    import meshreg.cli as cli

    package = Path(cli.__file__).parent
    for name in cli.CORE_KERNELS:
        assert "@numba.njit(cache=True" in (package / f"{name}.py").read_text(), name


def test_a_registration_written_to_files_runs_blas_on_one_thread(tmp_path):
    """The figure worker takes the other core: BLAS threads are limited while the command registers and writes,
    and the caller's setting comes back after."""
    from threadpoolctl import threadpool_info, threadpool_limits

    from meshreg.outputs import register_files
    from meshreg.samples import paper_pairs

    pair = paper_pairs(21, 21)[6]
    np.save(tmp_path / "a.npy", pair.first.points)
    np.save(tmp_path / "b.npy", pair.second.points)
    seen = []

    def threads(*_):
        seen.append(max(pool["num_threads"] for pool in threadpool_info() if pool["user_api"] == "blas"))

    with threadpool_limits(2, user_api="blas"):
        register_files(tmp_path / "a.npy", tmp_path / "b.npy", tmp_path / "out", callback=threads)
        after = max(pool["num_threads"] for pool in threadpool_info() if pool["user_api"] == "blas")
    assert seen and set(seen) == {1}
    assert after == 2
