"""The Open3D and MeshLab adapters on real open3d / pymeshlab objects."""

import importlib
import sys

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from meshreg.mesh.samples import random_disk_mesh
from meshreg.options import Options
from meshreg.rotation import angle_between
from meshreg.samples import bump

ROT = Rotation.from_euler("zxz", [40, 25, -60], degrees=True).as_matrix()


def test_open3d_register_and_parametrize():
    import open3d as o3d  # installed by the dev extra: a missing library fails the test, it is not skipped
    from meshreg.plugins import open3d as mo3d

    v1, f1, _ = random_disk_mesh(bump(), 1200, seed=11)
    v2, f2, _ = random_disk_mesh(bump(), 1800, seed=12, rotation=ROT, scale=2.0)
    source = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(v1), o3d.utility.Vector3iVector(f1.astype(np.int32)))
    target = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(v2), o3d.utility.Vector3iVector(f2.astype(np.int32)))
    res = mo3d.register(source, target, Options(resolution=41))
    assert res.energy == res.registration.energy and res.distance == pytest.approx(np.sqrt(res.energy))
    assert res.energy < 0.02 and angle_between(res.registration.rotation, ROT) < 2.0
    t = res.transformation
    scale = np.cbrt(np.linalg.det(t[:3, :3]))
    assert scale == pytest.approx(2.0, rel=0.05)
    assert np.allclose(t[:3, :3] / scale, res.registration.rotation) and np.allclose(t[3], [0, 0, 0, 1])
    # matched vertices land near each other once the source is moved by the transformation
    pairs = res.correspondence_set
    assert (
        pairs.shape[1] == 2 and pairs.shape[0] >= 0.99 * len(v1) and pairs[:, 1].max() < len(v2)
    )  # cleanup drops ears
    moved = v1 @ t[:3, :3].T + t[:3, 3]
    gap = np.median(np.linalg.norm(moved[pairs[:, 0]] - v2[pairs[:, 1]], axis=1))
    assert gap < 0.03 * np.ptp(v2, axis=0).max()
    for mesh, n in ((res.source_colored, len(v1)), (res.target_colored, len(v2))):
        colors = np.asarray(mesh.vertex_colors)
        assert colors.shape == (n, 3) and np.all((colors >= 0) & (colors <= 1))
    assert len(np.asarray(source.vertex_colors)) == 0  # the input is untouched
    assert len(np.asarray(res.registered.vertices)) == 41 * 41
    uv = np.asarray(mo3d.parametrize(source).triangle_uvs)
    assert uv.shape == (3 * len(f1), 2) and np.nanmin(uv) >= 0 and np.nanmax(uv) <= 1 and np.isnan(uv).mean() < 0.01


def test_meshlab_apply_prepares_a_raw_scan_crop():
    import pymeshlab
    from meshreg.plugins import meshlab

    from meshreg.mesh.samples import face_scan_pair

    (v1, f1), (v2, f2, _), _ = face_scan_pair(n_points=12000, seed=2, rotation=ROT)
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=v1, face_matrix=f1), mesh_name="scan")
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=v2, face_matrix=f2), mesh_name="copy")
    info = meshlab.apply(ms, 0, 1, prepare=True, options=Options(resolution=41))
    # one surface: E near 0 (the default mesh path minimizes E_w, not E: measured 0.024, 0.013 with bend_window=0)
    assert info["energy"] <= 0.03 and info["distance"] == pytest.approx(np.sqrt(info["energy"]))
    assert angle_between(info["registration"].rotation, ROT) < 2.0
    # the MeshLab script closed the scan's holes and split its pinched vertices: meshreg had none left to fill
    assert not any("filled" in line or "touches" in line for line in info["cleanup"]["first"])
    assert ms.mesh(0).vertex_number() == len(v1) and ms.mesh(1).vertex_number() == len(v2)  # inputs untouched
    for key, _name in meshlab.LAYER_NAMES.items():
        mesh = ms.mesh(info["layers"][key])
        colors = mesh.vertex_color_matrix()
        assert colors.shape == (mesh.vertex_number(), 4) and np.ptp(colors[:, :3]) > 0.3
    assert info["transformation"].shape == (4, 4)


@pytest.mark.parametrize("module, extra", [("open3d", "open3d"), ("pymeshlab", "meshlab")])
def test_missing_extra_names_it(monkeypatch, module, extra):
    monkeypatch.setitem(sys.modules, module, None)  # import of it now fails
    name = "meshreg.plugins.open3d" if extra == "open3d" else "meshreg.plugins.meshlab"
    monkeypatch.delitem(sys.modules, name, raising=False)
    with pytest.raises(ImportError, match=rf"meshreg\[{extra}\]"):
        importlib.import_module(name)


def test_meshlab_prepare_prints_nothing(tmp_path):
    """pymeshlab's C++ code prints a line per filter of a script; the adapter keeps a user's terminal clean."""
    v1, f1, _ = random_disk_mesh(bump(), 300, seed=1)
    v2, f2, _ = random_disk_mesh(bump(), 400, seed=2)
    for name, (v, f) in (("a.ply", (v1, f1)), ("b.ply", (v2, f2))):
        import trimesh

        trimesh.Trimesh(v, f, process=False).export(tmp_path / name)
    code = (
        "import pymeshlab, meshreg; from meshreg.plugins import meshlab; ms = pymeshlab.MeshSet(); "
        f"ms.load_new_mesh({str(tmp_path / 'a.ply')!r}); ms.load_new_mesh({str(tmp_path / 'b.ply')!r}); "
        "meshlab.apply(ms, 0, 1, prepare=True, options=meshreg.Options(resolution=21)); print('done')"
    )
    import subprocess
    import sys

    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "done" and "Reading filter" not in proc.stderr
