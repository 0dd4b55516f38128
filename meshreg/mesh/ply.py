"""Binary PLY triangle meshes read and written with numpy alone: the common layout of a scan or of meshreg's own
outputs costs a few milliseconds, where going through trimesh costs its import (about 0.2 s, networkx with it)
on top of the parse. Any other layout (ASCII, polygons, elements besides vertices and faces, face properties
besides the vertex list) is left to trimesh (:func:`meshreg.mesh.topology.load_mesh`), which reads it to the
same arrays.

- :func:`read_ply`: vertices (n, 3) and triangles (m, 3) of a binary PLY file, or None for another layout.
- :func:`write_ply_bytes`: the bytes of a binary little-endian PLY file with per-vertex RGBA colours: double
  positions (trimesh's ``export_ply`` writes float32), uchar RGBA, uchar counts and int32 indices.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

# PLY's scalar type names (both spellings) and their numpy codes, without byte order
SCALARS = {
    "char": "i1",
    "int8": "i1",
    "uchar": "u1",
    "uint8": "u1",
    "short": "i2",
    "int16": "i2",
    "ushort": "u2",
    "uint16": "u2",
    "int": "i4",
    "int32": "i4",
    "uint": "u4",
    "uint32": "u4",
    "float": "f4",
    "float32": "f4",
    "double": "f8",
    "float64": "f8",
}
ORDERS = {"binary_little_endian": "<", "binary_big_endian": ">"}
MAX_HEADER = 1 << 16  # bytes of a PLY header read at most before giving the file to trimesh


def _header(data: bytes):
    """(byte order, elements [(name, count, properties)], offset of the body) of a binary PLY file, or None."""
    end = data.find(b"end_header", 0, MAX_HEADER)
    if not data.startswith(b"ply") or end < 0:
        return None
    body = data.find(b"\n", end) + 1
    if body == 0:
        return None
    lines = [line.split() for line in data[:end].decode("ascii", "replace").splitlines()[1:]]
    order, elements = None, []
    for words in lines:
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "format" and len(words) == 3:
            order = ORDERS.get(words[1])
        elif words[0] == "element" and len(words) == 3 and words[2].isdigit():
            elements.append((words[1], int(words[2]), []))
        elif words[0] == "property" and elements:
            elements[-1][2].append(words[1:])
        else:
            return None
    return (order, elements, body) if order is not None else None


def read_ply(path) -> tuple[np.ndarray, np.ndarray] | None:
    """Vertices (n, 3) float64 and triangles (m, 3) int64 of a binary PLY file whose elements are ``vertex`` (scalar
    properties, x, y and z among them) and then ``face`` (one list property, ``vertex_indices`` or ``vertex_index``,
    every face a triangle), in file order; None for any other file (ASCII, polygons, other elements, a short or
    malformed file)."""
    data = Path(path).read_bytes()
    header = _header(data)
    if header is None:
        return None
    order, elements, offset = header
    if [e[0] for e in elements] != ["vertex", "face"]:
        return None
    (_, n_vertices, vertex_props), (_, n_faces, face_props) = elements
    names = [p[-1] for p in vertex_props]
    if any(len(p) != 2 or p[0] not in SCALARS for p in vertex_props) or not {"x", "y", "z"} <= set(names):
        return None
    if len(names) != len(set(names)) or len(face_props) != 1:
        return None
    face = face_props[0]
    if len(face) != 4 or face[0] != "list" or face[1] not in SCALARS or face[2] not in SCALARS:
        return None
    if face[3] not in ("vertex_indices", "vertex_index"):  # the names trimesh reads faces from
        return None
    vertex_type = np.dtype([(name, order + SCALARS[p[0]]) for name, p in zip(names, vertex_props, strict=True)])
    face_type = np.dtype([("count", order + SCALARS[face[1]]), ("index", order + SCALARS[face[2]], (3,))])
    end = offset + n_vertices * vertex_type.itemsize + n_faces * face_type.itemsize
    if n_faces == 0 or len(data) < end:
        return None
    vertex_data = np.frombuffer(data, vertex_type, n_vertices, offset)
    faces = np.frombuffer(data, face_type, n_faces, offset + n_vertices * vertex_type.itemsize)
    if np.any(faces["count"] != 3):
        return None
    vertices = np.stack([vertex_data[axis] for axis in "xyz"], axis=1).astype(float)
    return vertices, faces["index"].astype(np.int64)


def write_ply_bytes(vertices: np.ndarray, faces: np.ndarray, rgba: np.ndarray) -> bytes:
    """A binary little-endian PLY file of vertices (n, 3), triangles (m, 3) and vertex colours ``rgba`` (n, 4)
    uint8: float64 positions, uchar RGBA, a uchar count (3) and int32 indices per face."""
    vertex = np.zeros(len(vertices), dtype=[("xyz", "<f8", (3,)), ("rgba", "<u1", (4,))])
    vertex["xyz"], vertex["rgba"] = vertices, rgba
    face = np.zeros(len(faces), dtype=[("count", "<u1"), ("index", "<i4", (3,))])
    face["count"], face["index"] = 3, faces
    header = (
        "ply\nformat binary_little_endian 1.0\ncomment written by meshreg\n"
        f"element vertex {len(vertices)}\n"
        + "".join(f"property double {axis}\n" for axis in "xyz")
        + "".join(f"property uchar {channel}\n" for channel in ("red", "green", "blue", "alpha"))
        + f"element face {len(faces)}\nproperty list uchar int vertex_indices\nend_header\n"
    )
    return header.encode("ascii") + vertex.tobytes() + face.tobytes()
