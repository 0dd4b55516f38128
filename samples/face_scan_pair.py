"""Write two meshes of one real surface: a raw 50 mm crop of pymeshlab's face000 range scan (holes, a pinched
boundary vertex, a round boundary) and a re-triangulated copy of it (20000 random points, its own holes),
rotated, scaled by 0.01 and shifted. Then register them with the command line:

    pip install -e ".[meshlab]" && python samples/face_scan_pair.py DIR
    meshreg register DIR/face_crop.ply DIR/face_copy.ply -o DIR/out

The scan is read from the installed pymeshlab wheel (GPL): nothing of it is copied into this project.
"""

import sys
from pathlib import Path

import numpy as np

from meshreg.mesh.export import write_ply
from meshreg.mesh.samples import face_scan_pair


def main(out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    (v, f), (v2, f2, _), rotation = face_scan_pair()
    for name, (vv, ff) in (("face_crop.ply", (v, f)), ("face_copy.ply", (v2, f2))):
        write_ply(out / name, vv, ff, np.full((len(vv), 3), 0.8))
        print("wrote", out / name, f"({len(vv)} vertices, {len(ff)} triangles)")
    print("true rotation (first -> second):\n", np.array2string(rotation, precision=4))


if __name__ == "__main__":
    main(Path(sys.argv[1] if len(sys.argv) > 1 else "face-scan-pair"))
