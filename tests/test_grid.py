import numpy as np
import pytest

from meshreg.errors import InputError
from meshreg.grid import GridSurface, read_grid, write_text_grid
from meshreg.samples import helicoid, sample


def plane(m=5, n=4):
    r, t = np.meshgrid(np.linspace(0, 1, m), np.linspace(0, 1, n), indexing="ij")
    return np.stack([2 * r, t, 0 * r], axis=-1)


def test_area_and_scaling():
    s = GridSurface.from_array(plane())
    assert s.area() == pytest.approx(2.0)
    assert s.scaled().area() == pytest.approx(1.0)


def test_partitions_are_rescaled_and_non_uniform_allowed():
    s = GridSurface.from_array(plane(), r=[0, 1, 3, 7, 10], t=[2, 3, 5, 6])
    assert s.r[0] == 0 and s.r[-1] == 1 and s.t[0] == 0 and s.t[-1] == 1
    assert s.r[2] == pytest.approx(0.3)


def test_text_roundtrip_r_runs_fastest(tmp_path):
    s = sample(helicoid(4), 7, 5)
    path = tmp_path / "g.txt"
    write_text_grid(path, s)
    lines = path.read_text().splitlines()
    assert lines[0] == "7 5"
    assert np.allclose(np.array(lines[2].split(), float), s.points[1, 0])  # second line: (r2, t1)
    assert np.allclose(read_grid(path).points, s.points)
    # headerless file with the size given
    np.savetxt(tmp_path / "h.txt", s.points.transpose(1, 0, 2).reshape(-1, 3))
    assert np.allclose(read_grid(tmp_path / "h.txt", (7, 5)).points, s.points)


def test_npy_and_npz(tmp_path):
    s = sample(helicoid(2), 6, 8)
    np.save(tmp_path / "a.npy", s.points)
    assert np.allclose(read_grid(tmp_path / "a.npy").points, s.points)
    np.savez(tmp_path / "b.npz", points=s.points, r=np.linspace(0, 2, 6) ** 2, t=np.arange(8))
    b = read_grid(tmp_path / "b.npz")
    assert b.r[1] == pytest.approx(0.04)


@pytest.mark.parametrize(
    "points, message",
    [
        (np.zeros((4, 4)), "shape"),
        (np.zeros((2, 5, 3)), "at least 3x3"),
        (np.full((4, 4, 3), np.nan), "NaN"),
        (np.zeros((4, 4, 3)), "zero area"),
    ],
)
def test_bad_arrays(points, message):
    with pytest.raises(InputError, match=message):
        GridSurface.from_array(points)


def test_bad_files(tmp_path):
    with pytest.raises(InputError, match="no such file"):
        read_grid(tmp_path / "missing.npy")
    (tmp_path / "bad.txt").write_text("1 2 3\n4 5 6\n")
    with pytest.raises(InputError, match="grid size unknown"):
        read_grid(tmp_path / "bad.txt")
    with pytest.raises(InputError, match="2 points but the grid is 3x3"):
        read_grid(tmp_path / "bad.txt", (3, 3))
    (tmp_path / "junk.npy").write_bytes(b"not numpy")
    with pytest.raises(InputError, match="cannot read"):
        read_grid(tmp_path / "junk.npy")
    with pytest.raises(InputError, match="decreasing|increasing"):
        GridSurface.from_array(plane(), r=[0, 2, 1, 3, 4])
