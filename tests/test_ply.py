"""The numpy PLY reader and writer (meshreg/mesh/ply.py) against trimesh, which reads and writes any layout."""

import numpy as np
import pytest
import trimesh

from meshreg.mesh import load_mesh
from meshreg.mesh.export import write_ply
from meshreg.mesh.ply import read_ply


def _mesh(seed=0):
    rng = np.random.default_rng(seed)
    vertices = rng.normal(size=(40, 3)) * 10.0
    faces = np.array([rng.choice(40, 3, replace=False) for _ in range(60)])
    return vertices, faces


def _header_and_body(vertex_props, vertex_data, face_count_type, face_index_type, faces, order="<", more="", n=3):
    """A binary PLY file of the given layout, written by hand."""
    fmt = {"<": "binary_little_endian", ">": "binary_big_endian"}[order]
    lines = ["ply", f"format {fmt} 1.0", "comment made by a test", f"element vertex {len(vertex_data)}"]
    lines += [f"property {kind} {name}" for name, kind, _ in vertex_props]
    lines += [f"element face {len(faces)}", f"property list {face_count_type[0]} {face_index_type[0]} vertex_indices"]
    lines += [more] if more else []
    lines += ["end_header"]
    vertex = np.zeros(len(vertex_data), dtype=[(name, order + code) for name, _, code in vertex_props])
    for k, (name, _, _) in enumerate(vertex_props):
        vertex[name] = vertex_data[:, k]
    face = np.zeros(len(faces), dtype=[("n", order + face_count_type[1]), ("i", order + face_index_type[1], (3,))])
    face["n"], face["i"] = n, faces
    return ("\n".join(lines) + "\n").encode() + vertex.tobytes() + face.tobytes()


XYZ_FLOAT = [("x", "float", "f4"), ("y", "float", "f4"), ("z", "float", "f4")]
WITH_NORMALS = [("nx", "float", "f4"), ("x", "double", "f8"), ("y", "double", "f8"), ("z", "double", "f8")]
WITH_NORMALS += [("red", "uchar", "u1"), ("quality", "float32", "f4")]


@pytest.mark.parametrize(
    ("props", "count", "index", "order"),
    [
        (XYZ_FLOAT, ("uchar", "u1"), ("int", "i4"), "<"),
        (WITH_NORMALS, ("uint8", "u1"), ("uint", "u4"), "<"),
        (XYZ_FLOAT, ("int", "i4"), ("int", "i4"), ">"),
        (WITH_NORMALS, ("uchar", "u1"), ("int32", "i4"), ">"),
    ],
)
def test_binary_ply_files_read_as_trimesh_reads_them(tmp_path, props, count, index, order):
    vertices, faces = _mesh()
    columns = {"x": 0, "y": 1, "z": 2}
    data = np.stack([vertices[:, columns[p[0]]] if p[0] in columns else np.arange(40) % 7 for p in props], 1)
    path = tmp_path / "m.ply"
    path.write_bytes(_header_and_body(props, data, count, index, faces, order))
    ours = read_ply(path)
    assert ours is not None
    theirs = trimesh.load(path, process=False, force="mesh")
    np.testing.assert_array_equal(ours[0], np.asarray(theirs.vertices, dtype=float))
    np.testing.assert_array_equal(ours[1], np.asarray(theirs.faces, dtype=np.int64))
    assert ours[0].dtype == np.float64 and ours[1].dtype == np.int64


def test_other_ply_layouts_are_left_to_trimesh(tmp_path):
    vertices, faces = _mesh()
    path = tmp_path / "m.ply"
    trimesh.Trimesh(vertices, faces, process=False).export(path, encoding="ascii")
    assert read_ply(path) is None  # ASCII
    np.testing.assert_allclose(load_mesh(path)[0], vertices, rtol=1e-6)
    path.write_bytes(_header_and_body(XYZ_FLOAT, vertices, ("uchar", "u1"), ("int", "i4"), faces, n=4))
    assert read_ply(path) is None  # a face that is not a triangle
    edges = _header_and_body(XYZ_FLOAT, vertices, ("uchar", "u1"), ("int", "i4"), faces, more="element edge 0")
    path.write_bytes(edges)
    assert read_ply(path) is None  # another element
    renamed = _header_and_body(XYZ_FLOAT, vertices, ("uchar", "u1"), ("int", "i4"), faces).replace(b"indices", b"list")
    path.write_bytes(renamed)
    assert read_ply(path) is None  # faces under a name trimesh does not read them from
    path.write_bytes(_header_and_body(XYZ_FLOAT, vertices, ("uchar", "u1"), ("int", "i4"), faces)[:-5])
    assert read_ply(path) is None  # cut short: trimesh says what is wrong


def test_written_ply_is_trimesh_layout_and_reads_back(tmp_path):
    vertices, faces = _mesh(1)
    vertices = vertices + 1e6  # far from the origin: float32 would keep about 0.06 of a unit
    colors = np.random.default_rng(2).random((len(vertices), 3))
    write_ply(tmp_path / "ours.ply", vertices, faces, colors)
    rgba = np.hstack([np.clip(colors, 0, 1) * 255, np.full((len(colors), 1), 255)]).astype(np.uint8)
    trimesh.Trimesh(vertices, faces, vertex_colors=rgba, process=False).export(tmp_path / "trimesh.ply")
    ours, theirs = ((tmp_path / name).read_bytes().split(b"\n") for name in ("ours.ply", "trimesh.ply"))
    assert ours[2].startswith(b"comment") and theirs[2].startswith(b"comment")
    # trimesh's layout but for the comment naming the writer and double positions (trimesh writes float)
    header = [line.replace(b"double", b"float") for line in ours[: ours.index(b"end_header")]]
    assert header[:2] + header[3:] == theirs[:2] + theirs[3 : theirs.index(b"end_header")]
    back = trimesh.load(tmp_path / "ours.ply", process=False)
    np.testing.assert_array_equal(back.vertices, vertices)  # every bit of the positions
    np.testing.assert_array_equal(back.faces, faces)
    np.testing.assert_array_equal(back.visual.vertex_colors, rgba)
    np.testing.assert_array_equal(read_ply(tmp_path / "ours.ply")[0], vertices)
    np.testing.assert_array_equal(read_ply(tmp_path / "ours.ply")[1], faces)
