"""Every bad input, parameter and fault gets one clear line, and a collection run never loses work (issue 15).

Each test names the defect it covers. Command-line tests check the exit status (2 bad input, 1 a run that did not
finish its work), one line on stderr naming the problem and what to do, no traceback, inputs unchanged and no
stale or partial output.
"""

import json
import multiprocessing
import os
import shutil
import signal
import subprocess
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import pytest
import trimesh

import meshreg
from meshreg import files, ownership
from meshreg.atlas_outputs import atlas_files
from meshreg.batch import CHECKPOINT_SUFFIX, DistanceMatrix, distance_matrix
from meshreg.cli import main
from meshreg.errors import InputError, RunError
from meshreg.grid import GridSurface, read_grid
from meshreg.mesh.correspond import register_meshes
from meshreg.mesh.samples import random_disk_mesh
from meshreg.mesh.topology import prepare_disk
from meshreg.options import Options
from meshreg.ownership import RECORD_FILE
from meshreg.result import Registration
from meshreg.samples import bump, helicoid, paper_pairs, sample, sine


def _cli(*args, timeout=120):
    return subprocess.run(
        [sys.executable, "-m", "meshreg.cli", *map(str, args)], capture_output=True, text=True, timeout=timeout
    )


def _one_line(stderr: str, status: int, code: int, *words: str) -> None:
    """Exit status ``status`` (got ``code``), exactly one line on stderr holding every word, no traceback."""
    assert code == status, stderr
    assert "Traceback" not in stderr and len(stderr.strip().splitlines()) == 1, stderr
    for word in words:
        assert word in stderr, stderr


def _run_main(capsys, *args) -> tuple[int, str]:
    code = main([str(a) for a in args])
    return code, capsys.readouterr().err


@pytest.fixture(scope="module")
def grids(tmp_path_factory):
    """Two 11 x 11 grid files of a same-shape pair, and a directory for the rest."""
    d = tmp_path_factory.mktemp("grids")
    pair = paper_pairs(11, 11)[6]
    np.save(d / "a.npy", pair.first.points)
    np.save(d / "b.npy", pair.second.points)
    return d


def _collection(directory: Path, n: int = 11) -> list[Path]:
    files = []
    for k, g in enumerate(
        [sample(sine(2), n, n), sample(helicoid(1), n, n), sample(bump(), n, n), sample(sine(3), n, n)]
    ):
        files.append(directory / f"s{k}.npy")
        np.save(files[-1], g.points)
    return files


# 1. size-like parameters are checked against the grid and against stated limits; force lifts them


def test_limits_refuse_with_the_figure_and_force_lifts_them():
    with pytest.raises(InputError, match=r"resolution 1000 gives 1000000 nodes.*limit.*--resolution 401.*--force"):
        Options(resolution=1000)
    assert Options(resolution=1000, force=True).resolution == 1000
    with pytest.raises(InputError, match=r"corner_search 500 costs about 80 s per pair.*--force"):
        Options(corner_search=500)
    big = sample(sine(2), 200, 200)
    with pytest.raises(
        InputError, match=r"window 199 on a grid of 200 nodes.*one DP solve would take about \d+ s"
    ) as err:
        meshreg.register(big, big, mode="dp", window=199)
    suggested = int(str(err.value).split("give --window ")[1].split()[0])
    assert 10 <= suggested < 199  # the default window fits; the message names the widest that does
    huge = sample(sine(2), 402, 402)
    with pytest.raises(InputError, match=r"402 x 402 grid has 161604 nodes, above the limit"):
        meshreg.register(huge, huge, mode="dp")


def test_a_basis_beyond_the_memory_limit_is_refused_and_a_wide_one_solves():
    from meshreg.descent import DENSE_LIMIT, _solver

    pair = paper_pairs(101, 101)[0]
    with pytest.raises(
        InputError, match=r"basis 40 on a 101 x 101 grid: its 6480 fields need about 4.2 GB.*--basis 27"
    ):
        meshreg.register(pair.first, pair.second, basis=40)  # before: 4.3 GB, then a crash
    rng = np.random.default_rng(0)
    a = rng.normal(size=(DENSE_LIMIT + 10, DENSE_LIMIT + 10))
    normal, rhs = a @ a.T / len(a), rng.normal(size=len(a))  # a dense system: a global basis of KL >= 23
    x = _solver(normal, rhs, 500)(np.full(len(a), 1.0))
    assert np.allclose((normal + np.eye(len(a))) @ x, rhs, atol=1e-6)


def test_window_wider_than_the_grid_is_the_same_dp_at_its_cost():
    pair = paper_pairs(21, 21)[1]
    tic = time.perf_counter()
    wide = meshreg.register(pair.first, pair.second, mode="dp", window=9000)
    seconds = time.perf_counter() - tic
    exact = meshreg.register(pair.first, pair.second, mode="dp", window=20)
    assert wide.energy == exact.energy and np.array_equal(wide.h, exact.h)
    assert seconds < 30  # before: steps(9000) alone built 5e7 Python tuples (the 24 GB of --window 100000)


def test_cli_refuses_a_resolution_beyond_the_limit_before_any_work(tmp_path):
    v, f, _ = random_disk_mesh(bump(), 300, seed=1)
    trimesh.Trimesh(v, f, process=False).export(tmp_path / "a.ply")
    before = (tmp_path / "a.ply").read_bytes()
    proc = _cli("register", tmp_path / "a.ply", tmp_path / "a.ply", "-o", tmp_path / "out", "--resolution", 1000, "-q")
    _one_line(proc.stderr, 2, proc.returncode, "resolution 1000", "--force")
    assert not (tmp_path / "out").exists() and (tmp_path / "a.ply").read_bytes() == before


# 2. a lost pool worker costs only the pair it held; the checkpoint is kept until every pair has a value


def _dies_on_three(x):
    if x == 3:
        os._exit(7)  # a crash in native code: no exception, no clean-up
    return {"value": x * x}


def _record(function, args):
    return function(*args)


def test_worker_pool_replaces_a_lost_worker_and_loses_only_its_task():
    from meshreg.workers import run_tasks

    got = {}
    run_tasks(_dies_on_three, [(k, (k,)) for k in range(8)], 2, got.__setitem__, _record)
    assert set(got) == set(range(8))
    assert got[3] == {"error": "worker process lost: it exited with status 7"}
    assert all(got[k] == {"value": k * k} for k in range(8) if k != 3)


FAULT_SCRIPT = """
import os, sys
from pathlib import Path
import multiprocessing
multiprocessing.set_start_method("fork")
import meshreg.batch as batch
marker, original = Path(sys.argv[1]), batch.register_pair

def dying(first, second, options):
    if first.shape == (13, 13):  # the first pair with surface 1 as its first surface: (1, 2) and (1, 3) may run at
        try:  # once in the two workers, so the marker is claimed atomically and only one of them dies
            claim = os.open(marker, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
        except FileExistsError:
            return original(first, second, options)
        os.write(claim, str(os.getpid()).encode())
        os.close(claim)
        os.kill(os.getpid(), 9)  # what the out-of-memory killer does
    return original(first, second, options)

batch.register_pair = dying
from meshreg.cli import main
sys.exit(main(sys.argv[2:]))
"""


def test_killed_worker_costs_one_pair_and_the_rerun_completes_the_matrix(tmp_path):
    files = _collection(tmp_path)
    np.save(files[1], sample(helicoid(1), 13, 13).points)  # the surface whose pair's worker is killed
    out, checkpoint = tmp_path / "D.npz", tmp_path / ("D.npz" + CHECKPOINT_SUFFIX)
    (tmp_path / "fault.py").write_text(FAULT_SCRIPT)
    args = ["matrix", *map(str, files), "-o", str(out), "--jobs", "2", "--mode", "dp", "-q"]
    proc = subprocess.run(
        [sys.executable, str(tmp_path / "fault.py"), str(tmp_path / "marker"), *args],
        capture_output=True,
        text=True,
        timeout=300,
    )
    _one_line(proc.stderr, 1, proc.returncode, "1 of 6 pairs have no value", str(checkpoint), "rerun")
    assert "worker process lost: killed by SIGKILL" in proc.stdout
    first = DistanceMatrix.load(out)
    (lost,) = first.failures
    assert lost[0] == 1 and np.isnan(first.distance[lost]) and np.isfinite(first.distance[0, 2])
    records = [json.loads(line) for line in checkpoint.read_text().splitlines()[1:]]
    assert len(records) == 6 and sum("error" in r for r in records) == 1  # kept, with the lost pair's reason
    again = _cli(*args)  # the same command: retries the lost pair, keeps the five others
    assert again.returncode == 0 and again.stderr == "", again.stderr
    result = DistanceMatrix.load(out)
    uninterrupted = distance_matrix(files, Options(mode="dp"), jobs=1)
    np.testing.assert_allclose(result.distance, uninterrupted.distance, rtol=1e-9, atol=1e-12)
    for r in records:
        if "error" not in r:  # finished pairs were taken from the checkpoint, not recomputed
            assert result.seconds[r["i"], r["j"]] == r["seconds"]
    assert not result.failures and not checkpoint.exists()


def test_failed_pairs_are_retried_on_resume_unless_asked_not_to(tmp_path, finished_checkpoint):
    files, lines = finished_checkpoint
    path = tmp_path / "c.jsonl"
    failed = {**json.loads(lines[2]), "error": "worker process lost: killed by SIGKILL"}
    for key in ("energy", "rotation", "seconds"):
        failed.pop(key)
    path.write_text("\n".join([lines[0], lines[1], json.dumps(failed), lines[3]]) + "\n")
    kept = distance_matrix(files, jobs=1, checkpoint=path, retry_failed=False)
    assert kept.failures == {(failed["i"], failed["j"]): failed["error"]}
    retried = distance_matrix(files, jobs=1, checkpoint=path)
    assert not retried.failures and np.isfinite(retried.distance).all()
    assert retried.energy[failed["i"], failed["j"]] == json.loads(lines[2])["energy"]


# 3. an unreadable item is reported and skipped; the rest goes on


def test_unreadable_items_are_skipped_and_the_rest_is_computed(tmp_path, monkeypatch):
    files = _collection(tmp_path)[:2]
    (tmp_path / "cut.npz").write_bytes(b"PK\x03\x04" + b"\0" * 20)  # a truncated .npz
    with open(tmp_path / "huge.npy", "wb") as stream:  # a header claiming 3e10 values
        np.lib.format.write_array_header_1_0(
            stream, {"descr": "<f8", "fortran_order": False, "shape": (10**5, 10**5, 3)}
        )
    v, f, _ = random_disk_mesh(bump(), 200, seed=3)
    flat = np.c_[np.arange(len(v)), np.zeros((len(v), 2))]  # every triangle degenerate
    trimesh.Trimesh(flat, f, process=False).export(tmp_path / "flat.ply")
    items = [*files, tmp_path / "cut.npz", tmp_path / "huge.npy", tmp_path / "flat.ply"]
    d = distance_matrix(items, jobs=1)
    assert np.isfinite(d.distance[0, 1]) and set(d.skipped) == {2, 3, 4}
    assert "BadZipFile" in d.skipped[2] and "100000 x 100000 x 3 array" in d.skipped[3]
    assert "degenerate" in d.skipped[4] and len(d.failures) == 9
    drawn = {}

    def plot(names, distance, embedding, path, title=""):
        drawn.update(names=names, title=title)
        Path(path).write_bytes(b"png")

    monkeypatch.setattr("meshreg.viz.plot_matrix", plot)
    from meshreg.matrix_run import _figure

    _figure(d, tmp_path / "D.png")  # the skipped surfaces are not drawn as points at the largest distance
    assert drawn["names"] == d.names[:2] and drawn["title"].endswith("without any value: cut, huge, flat")


# 4. meshes without usable triangles are refused with one line


def test_meshes_without_usable_triangles_are_refused(tmp_path):
    v, f, _ = random_disk_mesh(bump(), 300, seed=1)
    far = trimesh.Trimesh((1e-3 * v + 1e5).astype(np.float32), f, process=False)
    far.export(tmp_path / "far32.ply", encoding="binary")
    trimesh.Trimesh(v, f, process=False).export(tmp_path / "ok.ply")
    proc = _cli("register", tmp_path / "far32.ply", tmp_path / "ok.ply", "-o", tmp_path / "out", "-q")
    _one_line(proc.stderr, 2, proc.returncode, "far32.ply", "triangles collapsed", "float32", "move it to the origin")
    with pytest.raises(InputError, match="no triangles"):
        prepare_disk(v, np.zeros((0, 3), dtype=int))
    with pytest.raises(InputError, match="all .* triangles of the mesh are degenerate"):
        prepare_disk(np.c_[np.arange(len(v)), np.zeros((len(v), 2))], f)


def test_a_mesh_the_cleanup_would_mostly_remove_is_refused():
    """A float32 copy 1e6 from the origin (float32 steps by 0.06 there) lost a third of its triangles to the collapse,
    and the cleanup of the rest (pinched vertices, a largest piece) kept 2% of it and registered that."""
    v, f, _ = random_disk_mesh(bump(), 1000, seed=2)
    collapsed = (v + 1e6).astype(np.float32).astype(float)
    with pytest.raises(
        InputError, match=r"collapsed: .* float32 values 1.0e\+06 from the origin.*move it to the origin"
    ):
        prepare_disk(collapsed, f)
    assert len(prepare_disk((v + 10).astype(np.float32).astype(float), f).faces) == len(f)  # near: kept as it is
    # five separate sheets: the largest piece is a fifth of the mesh, not the surface given
    pieces = np.vstack([v + [3.0 * k, 0, 0] for k in range(5)]), np.vstack([f + k * len(v) for k in range(5)])
    with pytest.raises(InputError, match=r"the cleanup kept only \d+ of the mesh's \d+ triangles .*largest of 5"):
        prepare_disk(*pieces)


# 5. a corrupt checkpoint says what is wrong and how to start over or salvage


@pytest.fixture(scope="module")
def finished_checkpoint(tmp_path_factory):
    d = tmp_path_factory.mktemp("checkpoint")
    files = _collection(d)[:3]
    distance_matrix(files, jobs=1, checkpoint=d / "full.jsonl")
    return files, (d / "full.jsonl").read_text().splitlines()


def _damaged(lines: list, case: str) -> bytes:
    header, first, *rest = lines
    record = json.loads(first)
    bodies = {
        "not json": [header, "{not json", *rest],
        "wrong type": [header, json.dumps({**record, "energy": "small"}), *rest],
        "no pair": [header, json.dumps({**record, "i": 2, "j": 1}), *rest],
        "bad rotation": [header, json.dumps({**record, "rotation": [[1, 0], [0, 1]]}), *rest],
        "header": ["[1, 2]", first, *rest],
    }
    if case == "not utf-8":
        return (header + "\n").encode() + b"\xff\xfe\n" + "\n".join(rest).encode() + b"\n"
    if case == "a binary file":  # someone's file given as the checkpoint (a fuzz gave an input grid, 2026-12-03)
        return b"\x93NUMPY\x01\x00v\x00{'descr': '<f8'}\n" + bytes(range(256))
    return ("\n".join(bodies[case]) + "\n").encode()


@pytest.mark.parametrize(
    "case, words",
    [
        ("not json", ["line 2 is not a pair record", "delete that line", "to start over"]),
        ("wrong type", ["line 2 holds no energy", "delete that line"]),
        ("no pair", ["line 2 names no pair of surfaces", "delete that line"]),
        ("bad rotation", ["line 2 holds no 3 x 3 rotation"]),
        ("not utf-8", ["line 2 is not UTF-8 text", "delete that line", "to start over"]),
        ("header", ["is not a meshreg checkpoint", "to start over"]),
        ("a binary file", ["is not a meshreg checkpoint (line 1 is not UTF-8 text): write the output elsewhere"]),
    ],
)
def test_corrupt_checkpoint_says_what_is_wrong_and_how_to_salvage(tmp_path, finished_checkpoint, case, words):
    files, lines = finished_checkpoint
    path = tmp_path / "c.jsonl"
    path.write_bytes(_damaged(lines, case))
    before = path.read_bytes()
    with pytest.raises(InputError) as err:
        distance_matrix(files, jobs=1, checkpoint=path)
    assert all(w in str(err.value) for w in words) and "\n" not in str(err.value), str(err.value)
    assert path.read_bytes() == before  # refused before anything is written


@pytest.mark.parametrize("content", ["", '{"key": "0a'])
def test_checkpoint_of_a_run_killed_before_its_header_starts_afresh(tmp_path, finished_checkpoint, content):
    files, lines = finished_checkpoint
    path = tmp_path / "c.jsonl"
    path.write_text(content)
    seen = []
    d = distance_matrix(files, jobs=1, checkpoint=path, progress=lambda done, total: seen.append(done))
    assert seen[0] == 0 and not d.failures
    assert path.read_text().splitlines()[0] == lines[0] and len(path.read_text().splitlines()) == 4


def test_cli_corrupt_checkpoint_one_line(tmp_path, finished_checkpoint):
    files, lines = finished_checkpoint
    out = tmp_path / "D.npz"
    Path(str(out) + CHECKPOINT_SUFFIX).write_bytes(_damaged(lines, "no pair"))
    proc = _cli("matrix", *files, "-o", out, "--jobs", 1, "-q")
    _one_line(proc.stderr, 2, proc.returncode, "line 2 names no pair", "delete that line")
    assert not out.exists()


# 6. the output place is checked before computing; outputs are written all together or not at all


@pytest.mark.parametrize(
    "where, words",
    [
        ("a.npy/out", ["cannot make the output directory", "give another -o"]),
        ("a.npy", ["exists and is not a directory"]),
        ("blocked", ["result.npz is a directory where an output file goes"]),
        ("unwritable", ["give another -o"]),
        ("listed", [".meshreg-outputs (where meshreg lists its outputs) is not a file"]),  # was exit 1 after the work
        ("", ["an empty name"]),  # was the current directory
    ],
)
def test_bad_output_place_is_refused_before_computing(tmp_path, grids, where, words):
    a, b = tmp_path / "a.npy", tmp_path / "b.npy"
    a.write_bytes((grids / "a.npy").read_bytes())
    b.write_bytes((grids / "b.npy").read_bytes())
    (tmp_path / "blocked" / "result.npz").mkdir(parents=True)
    (tmp_path / "listed" / RECORD_FILE).mkdir(parents=True)
    if where == "unwritable":
        if os.geteuid() == 0:  # root writes anywhere but in /sys
            out = Path("/sys/kernel/meshreg-out")
            if not Path("/sys/kernel").is_dir():
                pytest.skip("no unwritable directory for root here")
        else:
            (tmp_path / "ro").mkdir()
            (tmp_path / "ro").chmod(0o555)
            out = tmp_path / "ro" / "out"
    else:
        out = tmp_path / where if where else ""
    before, listing = a.read_bytes(), sorted(tmp_path.rglob("*"))
    proc = _cli("register", a, b, "-o", out, "-q")
    _one_line(proc.stderr, 2, proc.returncode, *words)
    assert a.read_bytes() == before and sorted(tmp_path.rglob("*")) == listing  # nothing written anywhere


def test_atlas_and_morph_refuse_a_place_they_cannot_write_before_computing(tmp_path, grids, monkeypatch):
    """Held out 2026-12-02 (a fuzz): ``meshreg atlas`` into a read-only place computed everything and then failed
    with a traceback from mkdir, and ``meshreg morph`` into one failed the same way after drawing its frames."""
    import meshreg.atlas_outputs as outputs

    def computed(*args, **kwargs):
        raise AssertionError("computed before the output place was checked")

    monkeypatch.setattr(outputs, "atlas", computed)
    monkeypatch.setattr(outputs, "morph_frames", computed)
    inputs = [grids / "a.npy", grids / "b.npy"]
    places = [(grids / "a.npy" / "out", "cannot make the output directory")]
    if os.geteuid() == 0 and Path("/sys/kernel").is_dir():  # root writes anywhere but in /sys
        places.append((Path("/sys/kernel/meshreg-out"), "give another -o"))
    for out, words in places:
        with pytest.raises(InputError, match=words):
            atlas_files(inputs, out)
        with pytest.raises(InputError, match=words):
            outputs.morph_files(*inputs, out / "m.gif")


def test_a_temporary_that_cannot_be_removed_leaves_the_write_error(tmp_path, monkeypatch):
    """On a read-only file system removing write_atomic's temporary fails too: the error is still the write's."""

    def read_only(*args, **kwargs):
        raise OSError(30, "Read-only file system")

    monkeypatch.setattr(Path, "unlink", read_only)
    with pytest.raises(RunError, match="cannot write .*Read-only file system"):
        files.write_atomic(tmp_path / "x.gif", read_only)


def test_a_failed_write_leaves_neither_partial_nor_older_outputs(tmp_path, grids, capsys, monkeypatch):
    out = tmp_path / "out"
    args = ["register", grids / "a.npy", grids / "b.npy", "-o", out, "-q", "--mode", "dp"]
    assert _run_main(capsys, *args, "--symmetric")[0] == 0
    assert {p.name for p in out.iterdir()} == {"result.npz", "result_reverse.npz", "registration.png", RECORD_FILE}

    def full_disk(self, path, **extra):
        Path(path).write_bytes(b"half a file")
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(Registration, "_save", full_disk)
    code, err = _run_main(capsys, *args)
    _one_line(err, 1, code, "No space left on device", "no output was written")
    assert list(out.iterdir()) == []  # no partial file, no staging directory, no older result passing for this run's
    monkeypatch.undo()
    assert _run_main(capsys, *args, "--symmetric")[0] == 0
    assert _run_main(capsys, *args)[0] == 0
    # the older reverse result is gone
    assert {p.name for p in out.iterdir()} == {"result.npz", "registration.png", RECORD_FILE}


def test_files_meshreg_did_not_write_are_never_replaced(tmp_path, grids, capsys):
    out = tmp_path / "out"
    out.mkdir()
    (out / "view.html").write_text("my notes")
    (out / "result.npz").write_bytes(b"my result")
    args = ["register", grids / "a.npy", grids / "b.npy", "-o", out, "-q", "--mode", "dp"]
    code, err = _run_main(capsys, *args)
    _one_line(err, 2, code, "result.npz is not on meshreg's list of its outputs", "your file", "give another -o")
    assert (out / "view.html").read_text() == "my notes" and (out / "result.npz").read_bytes() == b"my result"
    (out / "result.npz").unlink()
    code, err = _run_main(capsys, *args)
    _one_line(err, 2, code, "view.html is not on meshreg's list")
    (out / "view.html").unlink()
    assert _run_main(capsys, *args)[0] == 0
    assert _run_main(capsys, *args)[0] == 0  # its own outputs are replaced
    (out / "registration.png").touch()  # touched, or the folder copied: the content still says it is meshreg's
    shutil.copytree(out, tmp_path / "copy")
    assert _run_main(capsys, *args)[0] == 0
    assert _run_main(capsys, *args[:3], "-o", tmp_path / "copy", "-q", "--mode", "dp")[0] == 0
    (out / "registration.png").write_bytes(b"my drawing over meshreg's")  # changed since meshreg wrote it
    code, err = _run_main(capsys, *args)
    _one_line(err, 2, code, "registration.png is not on meshreg's list")
    assert (out / "registration.png").read_bytes() == b"my drawing over meshreg's"
    (tmp_path / "atlas").mkdir()
    (tmp_path / "atlas" / "template.ply").write_text("mine")
    with pytest.raises(InputError, match="template.ply is not on meshreg's list"):
        atlas_files([grids / "a.npy", grids / "b.npy"], tmp_path / "atlas")
    (tmp_path / "D.png").write_text("my figure")  # the matrix's figure: not named by the user
    code, err = _run_main(capsys, "matrix", grids / "a.npy", grids / "b.npy", "-o", tmp_path / "D.npz", "-q")
    _one_line(err, 2, code, "D.png is not on meshreg's list")
    assert (tmp_path / "D.png").read_text() == "my figure"


def test_a_run_stopped_between_writing_and_recording_leaves_a_usable_folder(tmp_path, grids, capsys, monkeypatch):
    """The record is written before the outputs move in (staged), and a file is claimed before it is written
    (atlas, demo inputs, view): a run killed in between leaves only files the next run takes as its own."""
    out = tmp_path / "out"
    args = ["register", grids / "a.npy", grids / "b.npy", "-o", out, "-q", "--mode", "dp"]
    recorded_first = []

    def record_then_check(folder, names, written=None):
        recorded_first.append(not any((Path(folder) / name).exists() for name in names))
        ownership.record(folder, names, written)

    monkeypatch.setattr(files, "record", record_then_check)
    assert _run_main(capsys, *args)[0] == 0 and recorded_first == [True]
    monkeypatch.undo()
    ownership.claim(out, ["view.html"])
    (out / "view.html").write_text("half a page")  # a view run stopped while writing it
    assert not ownership.not_ours(out, ["view.html"])
    assert _run_main(capsys, *args)[0] == 0


def test_two_runs_recording_at_once_keep_every_entry(tmp_path):
    names = [[f"a{k}" for k in range(60)], [f"b{k}" for k in range(60)]]
    for name in names[0] + names[1]:
        (tmp_path / name).write_text(name)
    with ProcessPoolExecutor(2, mp_context=multiprocessing.get_context("spawn")) as pool:
        list(pool.map(_record_one_by_one, [tmp_path, tmp_path], names))
    assert set(ownership.recorded(tmp_path)) == set(names[0] + names[1])


def _record_one_by_one(folder, names):
    for name in names:
        ownership.record(folder, [name])


# 7. every parameter is validated once, up front, naming its valid range


@pytest.mark.parametrize(
    "flags, words",
    [
        (["--basis", "0"], ["basis must be an integer from 1 to 40"]),
        (["--basis", "60"], ["basis must be an integer from 1 to 40"]),
        (["--start-basis", "0"], ["start_basis"]),
        (["--smoothing", "1e9"], ["smoothing must be standard deviations in (0, 1]"]),
        (["--resolution", "-5"], ["resolution must be an integer from 3"]),
        (["--max-rounds", "-1"], ["max_rounds must be an integer from 1"]),
        (["--window", "abc"], ["--window: invalid int value", "--help"]),
        (["--grid", "-5", "3"], ["--grid must be two integers >= 3"]),
    ],
)
def test_bad_register_parameters_one_line_before_any_work(tmp_path, grids, capsys, flags, words):
    args = ["register", grids / "a.npy", grids / "b.npy", "-o", tmp_path / "out", "-q", *flags]
    if flags[0] == "--window":
        with pytest.raises(SystemExit) as exit_:
            main([str(a) for a in args])
        code, err = exit_.value.code, capsys.readouterr().err
    else:
        code, err = _run_main(capsys, *args)
    _one_line(err, 2, code, *words)
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(
    "flags, words",
    [
        (["--jobs", "0"], ["jobs must be a whole number of worker processes, 1 or more"]),
        (["--jobs", "100000"], ["100000 worker processes", "--force"]),
        (["--scheduler", "notaurl"], ["--scheduler must be a Dask scheduler address like tcp://host:8786"]),
    ],
)
def test_bad_matrix_parameters_one_line_before_any_work(tmp_path, grids, capsys, flags, words):
    code, err = _run_main(capsys, "matrix", grids / "a.npy", grids / "b.npy", "-o", tmp_path / "D.npz", "-q", *flags)
    _one_line(err, 2, code, *words)
    assert list(tmp_path.iterdir()) == []


def test_other_api_parameters_are_checked():
    for changes in ({"search": "no"}, {"corners1": (1, 1, 2, 3)}, {"force": 1}, {"smoothing": None}):
        with pytest.raises(InputError, match=next(iter(changes))):
            Options(**changes)
    assert Options(smoothing=0.2).smoothing == (0.2,)  # one number for one level (held out 2026-12-02: TypeError)
    with pytest.raises(InputError, match="callback must be a function"):
        meshreg.register(sample(sine(2), 11, 11), sample(sine(2), 11, 11), callback=5)
    v, f, _ = random_disk_mesh(bump(), 200, seed=0)
    for options in ({}, {"resolution": 21}):  # {} passed for the defaults before the check
        with pytest.raises(TypeError, match="options must be a meshreg.Options"):
            register_meshes((v, f), (v, f), options)
    with pytest.raises(InputError, match="jobs"):
        distance_matrix([sample(sine(2), 11, 11)] * 2, jobs=0)
    with pytest.raises(InputError, match="grid must be an integer from 3"):
        from meshreg.paper import run_paper

        run_paper(-5)


# 8. a matrix run in which no pair has a value exits 1, writes and plots nothing


def test_all_failed_matrix_exits_1_and_writes_nothing(tmp_path, grids):
    trimesh.creation.icosphere().export(tmp_path / "closed.stl")
    out = tmp_path / "D.npz"
    out.write_bytes(b"an older matrix")
    out.with_suffix(".png").write_bytes(b"an older figure")
    ownership.record(tmp_path, ["D.png"])  # written by an earlier run
    proc = _cli("matrix", grids / "a.npy", tmp_path / "closed.stl", "-o", out, "--plot", "-q")
    _one_line(proc.stderr, 1, proc.returncode, "1 of 1 pairs have no value")
    assert "skipped" in proc.stdout and "closed" in proc.stdout
    assert not out.exists() and not out.with_suffix(".png").exists()  # neither new nor older ones


# 9. SIGTERM stops every process of the run and keeps the finished pairs


def _children(pid: int) -> list[int]:
    try:
        return [int(x) for x in Path(f"/proc/{pid}/task/{pid}/children").read_text().split()]
    except FileNotFoundError:
        return []


@pytest.mark.skipif(not Path("/proc/self/task").exists(), reason="needs /proc")
def test_sigterm_leaves_no_process_behind(tmp_path):
    files = _collection(tmp_path, 21)
    out, checkpoint = tmp_path / "D.npz", tmp_path / ("D.npz" + CHECKPOINT_SUFFIX)
    cmd = [sys.executable, "-m", "meshreg.cli", "matrix", *map(str, files), "-o", str(out), "--jobs", "2", "-q"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    workers, deadline = [], time.time() + 120
    while time.time() < deadline and proc.poll() is None:
        workers = _children(proc.pid)
        if len(workers) == 2 and checkpoint.exists() and len(checkpoint.read_text().splitlines()) >= 2:
            break
        time.sleep(0.02)
    assert len(workers) == 2, "the run ended before it could be interrupted"
    proc.send_signal(signal.SIGTERM)
    stdout, stderr = proc.communicate(timeout=60)  # returns only once no process holds the pipes
    _one_line(stderr, 143, proc.returncode, "interrupted", str(checkpoint), "rerun the same command to resume")
    assert not any(Path(f"/proc/{pid}").exists() for pid in workers)
    assert len(checkpoint.read_text().splitlines()) >= 2 and not out.exists()


# 10. values that would register silently wrong are refused


@pytest.mark.parametrize(
    "points, words",
    [
        (sample(sine(2), 5, 5).points + 1j, "complex"),
        (sample(sine(2), 5, 5).points > 0, "booleans"),
        (1e80 * sample(sine(2), 5, 5).points, r"reach 1\.0e\+80: areas overflow"),
        (1e-60 * sample(sine(2), 5, 5).points, "span only"),
        (1e15 + sample(sine(2), 5, 5).points, "float64 steps by 1.2e-01 there"),
        (np.stack([*np.meshgrid(np.linspace(0, 1, 5), np.linspace(0, 1e-12, 5)), np.zeros((5, 5))], -1), "sliver"),
        ([[[0, 0, 0]] * 3, [[1, 0, 0]] * 2], "not an array of numbers"),
    ],
)
def test_values_that_would_register_wrong_are_refused(points, words):
    with pytest.raises(InputError, match=words):
        meshreg.register(points, sample(sine(2), 5, 5))


def test_a_missing_morph_input_is_named(tmp_path):
    from meshreg.atlas_outputs import morph_files

    with pytest.raises(InputError, match="nope.ply: no such file"):
        morph_files(tmp_path / "nope.ply", None, tmp_path / "m.gif")
    with pytest.raises(InputError, match="is a directory"):
        morph_files(tmp_path, tmp_path, tmp_path / "m.gif")
    with pytest.raises(InputError, match="100000 frames would take about"):  # held out 2026-12-02: hours of drawing
        morph_files(tmp_path / "nope.ply", None, tmp_path / "m.gif", frames=100_000)


@pytest.mark.parametrize(
    "vertices, words",
    [(1j, "complex"), (True, "booleans"), ("x", "not numbers")],
)
def test_mesh_vertices_that_are_not_real_numbers_are_refused(vertices, words):
    v, f, _ = random_disk_mesh(bump(), 200, seed=0)
    bad = np.asarray(v + vertices) if not isinstance(vertices, (bool, str)) else np.full(v.shape, vertices)
    with pytest.raises(InputError, match=f"first: mesh vertex coordinates are {words}"):
        meshreg.register((bad, f), (v, f))


def test_hand_built_grid_surfaces_are_checked():
    good = sample(sine(2), 5, 5)
    with pytest.raises(InputError, match="partition r must be 5 finite values increasing strictly from 0 to 1"):
        GridSurface(good.points, good.r[::-1].copy(), good.t)
    with pytest.raises(InputError, match="NaN"):
        GridSurface(np.where(good.points > 0.5, np.nan, good.points), good.r, good.t)
    with pytest.raises(InputError, match=r"partition r must be one list of 5 values, got an array of shape \(5, 2\)"):
        GridSurface.from_array(good.points, np.zeros((5, 2)), None)  # held out 2026-12-02: "has 10 values"


def test_scale_and_position_do_not_change_e():
    pair = paper_pairs(21, 21)[0]
    unit = meshreg.register(pair.first, pair.second, mode="dp")
    far = meshreg.register(1e40 * pair.first.points, 1e-40 * pair.second.points + 3.0e-40, mode="dp")
    assert far.energy == pytest.approx(unit.energy, rel=1e-6, abs=1e-12)


# 11. unreadable files never escape as BadZipFile or MemoryError


def test_truncated_and_huge_files_are_input_errors(tmp_path, grids):
    good = (grids / "a.npy").read_bytes()
    (tmp_path / "cut.npy").write_bytes(good[: len(good) // 2])
    np.savez(tmp_path / "whole.npz", points=np.load(grids / "a.npy"))
    whole = (tmp_path / "whole.npz").read_bytes()
    (tmp_path / "cut.npz").write_bytes(whole[: len(whole) // 2])
    with open(tmp_path / "huge.npy", "wb") as stream:
        np.lib.format.write_array_header_1_0(
            stream, {"descr": "<f8", "fortran_order": False, "shape": (10**5, 10**5, 3)}
        )
    (tmp_path / "junk.npz").write_text("not numpy")  # held out 2026-12-02: numpy's advice to unpickle it was shown
    cases = (("cut.npy", "cannot read"), ("cut.npz", "BadZipFile"), ("huge.npy", "above the"))
    for name, words in (*cases, ("junk.npz", "not a NumPy .npz file of numbers")):
        with pytest.raises(InputError, match=words):
            read_grid(tmp_path / name)
    with pytest.raises(InputError, match="not a meshreg result file"):
        Registration.load(tmp_path / "cut.npz")
    result = meshreg.register(read_grid(grids / "a.npy"), read_grid(grids / "a.npy"), mode="dp")
    with pytest.raises(InputError, match="is a directory: give a file name"):  # not written as tmp_path.npz beside it
        result.save(tmp_path)
    with pytest.raises(InputError, match="not a meshreg distance matrix"):
        DistanceMatrix.load(tmp_path / "cut.npz")
    for load in (Registration.load, DistanceMatrix.load):  # held out 2026-12-02 (a review): TypeError tracebacks
        with pytest.raises(InputError, match="a single array, not an .npz archive"):
            load(grids / "a.npy")


# 12. messages name the problem once and list what is supported


def test_messages_for_unknown_suffix_folder_and_grid_size(tmp_path, grids, capsys):
    (tmp_path / "points.xyz").write_bytes(b"\xff\xfe garbage")
    code, err = _run_main(capsys, "register", tmp_path / "points.xyz", grids / "b.npy", "-o", tmp_path / "o", "-q")
    _one_line(err, 2, code, "unknown file type '.xyz'", ".npy .npz .txt .dat", ".ply")
    assert err.count("points.xyz") == 1
    code, err = _run_main(capsys, "register", tmp_path, grids / "b.npy", "-o", tmp_path / "o", "-q")
    _one_line(err, 2, code, "is a directory: give a file")
    (tmp_path / "g.txt").write_text("-5 3\n" + "0 0 0\n" * 15)
    code, err = _run_main(capsys, "register", tmp_path / "g.txt", grids / "b.npy", "-o", tmp_path / "o", "-q")
    _one_line(err, 2, code, "the first line 'M N' must be two integers >= 3")
    assert err.count("g.txt") == 1 and not (tmp_path / "o").exists()
    (tmp_path / "h.txt").write_text("3 5\n" + "0 0 0\n" * 15)  # --grid would reshape it: 5 x 3 is not its grid
    code, err = _run_main(capsys, "register", tmp_path / "h.txt", grids / "b.npy", "--grid", "5", "3", "-o", "o", "-q")
    _one_line(err, 2, code, "the file says its grid is 3x5 (first line) but --grid gives 5x3")
    with pytest.raises(InputError, match="^second: grid points contain 5 NaN"):  # which surface
        meshreg.register(sample(sine(2), 5, 5).points, np.where(np.eye(5)[..., None] * [1, 0, 0], np.nan, 1.0))


# 13. adapters: MeshLab prepare keeps a clean disk's boundary and leaves the MeshSet as it was; Open3D types


def _meshset(*meshes):
    import pymeshlab

    ms = pymeshlab.MeshSet()
    for v, f in meshes:
        ms.add_mesh(pymeshlab.Mesh(vertex_matrix=v) if f is None else pymeshlab.Mesh(vertex_matrix=v, face_matrix=f))
    return ms


def test_meshlab_prepare_keeps_the_outer_boundary_of_a_clean_disk():
    from meshreg.plugins import meshlab

    v1, f1, _ = random_disk_mesh(bump(), 400, seed=1)
    v2, f2, _ = random_disk_mesh(bump(), 500, seed=2)
    assert len(trimesh.Trimesh(v1, f1, process=False).outline().entities[0].points) < 300
    ms = _meshset((v1, f1), (v2, f2))
    info = meshlab.apply(ms, 0, 1, prepare=True, options=Options(resolution=21))
    assert info["energy"] < 0.02 and ms.mesh_number() == 5


def test_meshlab_failure_leaves_the_meshset_as_it_was():
    from meshreg.plugins import meshlab

    v, f, _ = random_disk_mesh(bump(), 300, seed=1)
    sphere = trimesh.creation.icosphere(2)
    ms = _meshset((v, f), (v, None), (sphere.vertices, sphere.faces))
    for second, prepare, words in (
        (1, True, "layer 1 has no triangles"),
        (1, False, "point cloud"),
        (2, True, "closed"),
    ):
        ms.set_current_mesh(0)
        with pytest.raises(InputError, match=words):
            meshlab.apply(ms, 0, second, prepare=prepare, options=Options(resolution=21))
        assert ms.mesh_number() == 3 and ms.current_mesh_id() == 0


def _history(ms, tmp_path) -> str:
    """The MeshSet's record of applied filters, as MeshLab writes it."""
    ms.save_filter_script(str(tmp_path / "history.mlx"))
    return (tmp_path / "history.mlx").read_text()


def test_meshlab_keeps_the_filter_record_and_names_what_is_wrong(tmp_path):
    """Held out 2026-12-02 (a fuzz of the adapters): prepare=True replaced the MeshSet's record of applied filters,
    also on failure; a small disk was called a point cloud after preparing; numpy layer ids and wrong types gave
    misleading errors."""
    from meshreg.plugins import meshlab

    v1, f1, _ = random_disk_mesh(bump(), 400, seed=1)
    v2, f2, _ = random_disk_mesh(bump(), 500, seed=2)
    sphere = trimesh.creation.icosphere(2)
    ms = _meshset((v1, f1), (v2, f2), (sphere.vertices, sphere.faces), (v1[:4], np.array([[0, 1, 2], [0, 2, 3]])))
    ms.apply_filter("compute_normal_per_vertex")
    before = _history(ms, tmp_path)
    info = meshlab.apply(ms, np.int64(0), np.int64(1), prepare=True, options=Options(resolution=21))
    assert info["energy"] < 0.02 and _history(ms, tmp_path) == before
    with pytest.raises(InputError, match="closed"):
        meshlab.apply(ms, 0, 2, prepare=True, options=Options(resolution=21))
    assert _history(ms, tmp_path) == before
    with pytest.raises(InputError, match="layer 3: preparing removed every triangle .* give prepare=False"):
        meshlab.apply(ms, 0, 3, prepare=True)
    for call, words in (
        (lambda: meshlab.apply(None), "takes a pymeshlab.MeshSet"),
        (lambda: meshlab.apply(ms, prepare="no"), "prepare must be True or False"),
        (lambda: meshlab.apply(ms, options={"resolution": 21}), "options must be a meshreg.Options"),
    ):
        with pytest.raises(TypeError, match=words):
            call()
    with pytest.raises(InputError, match="a layer id is an integer"):
        meshlab.apply(ms, 0, 1.0)


def test_open3d_wrong_types_are_type_errors():
    import open3d as o3d
    from meshreg.plugins import open3d as mo3d

    v, f, _ = random_disk_mesh(bump(), 300, seed=1)
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(v), o3d.utility.Vector3iVector(f.astype(np.int32)))
    for bad in (None, o3d.geometry.PointCloud(o3d.utility.Vector3dVector(v)), (v, f)):
        with pytest.raises(TypeError, match="must be an open3d.geometry.TriangleMesh, got"):
            mo3d.register(bad, mesh)
    empty = o3d.geometry.TriangleMesh(mesh.vertices, o3d.utility.Vector3iVector(np.zeros((0, 3), np.int32)))
    with pytest.raises(InputError, match="source: the mesh has no triangles"):
        mo3d.register(empty, mesh)
    with pytest.raises(InputError, match="vertex ids are integers"):  # held out 2026-12-02: int() ValueError
        mo3d.parametrize(mesh, corners="abcd")


def test_run_error_is_exit_status_1(capsys, monkeypatch):
    import meshreg.paper

    def fails(*args, **kwargs):
        raise RunError("a run that could not finish")

    monkeypatch.setattr(meshreg.paper, "run_paper", fails)
    code, err = _run_main(capsys, "paper", "-q")
    _one_line(err, 1, code, "a run that could not finish")


def test_a_singular_laplacian_is_named_with_what_to_try(monkeypatch):
    """SuperLU's "exactly singular" (weights that vanish or cancel: slivers beside large triangles, cotangent weights
    of obtuse triangles) becomes an InputError that names the mesh and the other weights."""
    from meshreg.mesh import harmonic

    def singular(*args, **kwargs):
        raise RuntimeError("Factor is exactly singular")

    monkeypatch.setattr(harmonic, "Factorization", singular)
    v, f, _ = random_disk_mesh(bump(), 300, seed=1)
    with pytest.raises(InputError, match="first mesh: its Laplacian .* is singular.*--weights cotangent"):
        register_meshes((v, f), (v, f), Options(resolution=21))


def test_mesh_inputs_that_crashed_deep_inside_get_clear_answers():
    """Found by a fuzz of the command line (2026-12-03): each raised a traceback from numpy, SuperLU or numba."""
    square = (np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]]), np.array([[0, 1, 3], [0, 3, 2]]))
    v, f, _ = random_disk_mesh(lambda x, y: np.c_[x, y, 0.2 * np.sin(3 * x) * y], 400, seed=1)
    # two triangles folded onto each other over one square: their tiled areas cancel (the scale was 0)
    folded = (square[0], np.array([[3, 2, 1], [0, 1, 3]]))
    assert np.isfinite(register_meshes(folded, (v, f), Options(resolution=21)).result.energy)
    x, y = np.meshgrid(np.linspace(-1, 1, 20), np.linspace(-1, 1, 20), indexing="ij")
    spike = np.c_[x.ravel(), y.ravel(), 0.2 * np.sin(3 * x.ravel()) * np.cos(2 * y.ravel())]
    spike[210, 2] = 1e8  # a scanner outlier inside: its mean-value weights are tiny (1e-17), but not zero
    cells = np.arange(19 * 20).reshape(19, 20)[:, :19].ravel()
    grid = np.vstack([np.c_[cells, cells + 20, cells + 1], np.c_[cells + 1, cells + 20, cells + 21]])
    # the map puts the outlier among its neighbours (the half-angle tangents from cross products: with arccos they
    # underflowed to 0 and the Laplacian was singular); the answer says that the pair does not fit
    result = register_meshes((spike, grid), (v, f), Options(resolution=21)).result
    assert np.isfinite(result.energy) and result.residual > 1
    with pytest.raises(InputError, match="lie 1.0e\\+15 from the origin"):
        register_meshes((v + 1e15, f), (v, f), Options(resolution=21))
    with pytest.raises(InputError, match="not one str"):
        distance_matrix("surfaces.npy")
    with pytest.raises(InputError, match="not one mesh"):  # was a 2 x 2 matrix of two skipped "grids"
        distance_matrix((v, f))
    grid = sample(bump(), 21, 21)
    with pytest.raises(InputError, match="corners1 and corners2 are vertex ids of meshes"):  # were ignored for grids
        meshreg.register(grid, grid, corners1=(0, 1, 2, 3))
