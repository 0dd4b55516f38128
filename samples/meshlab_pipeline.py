"""A whole pymeshlab pipeline: load a raw range scan, prepare it with meshreg's MeshLab script, register it
with a re-triangulated, rotated copy, and save the MeshSet's layers.

    pip install -e ".[meshlab]" && python samples/meshlab_pipeline.py [OUT_DIR]

The scan is pymeshlab's own ``tests/sample_meshes/rangemaps/face000.ply`` (read from the installed wheel; it
is GPL, so it is not copied into this project), cropped to 50 mm around its centre.
"""

import sys
from pathlib import Path

import numpy as np
import pymeshlab
from meshreg.plugins import meshlab

from meshreg.mesh.samples import face_scan_pair


def main(out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    (v, f), (v2, f2, _), _ = face_scan_pair()
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=v, face_matrix=f), mesh_name="face000 crop (raw)")
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=v2, face_matrix=f2), mesh_name="remeshed rotated copy (raw)")
    info = meshlab.apply(ms, 0, 1, prepare=True)
    for layer in info["layers"].values():
        ms.set_current_mesh(layer)
        path = out / (ms.current_mesh().label().replace(" ", "_").replace("(", "").replace(")", "") + ".ply")
        ms.save_current_mesh(str(path), save_vertex_color=True)
        print("wrote", path)
    print(f"E = {info['energy']:.4g}, distance = {info['distance']:.4g}")
    print("transformation (first -> second):\n", np.array2string(info["transformation"], precision=4))


if __name__ == "__main__":
    main(Path(sys.argv[1] if len(sys.argv) > 1 else "meshlab-pipeline"))
