"""The interactive page (view.html): self-contained, loads in a real headless browser, hovering marks the match."""

import re
import subprocess
import sys
import time

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from meshreg.mesh.samples import random_disk_mesh
from meshreg.samples import bump

CHROMIUM, CHROMEDRIVER = "/usr/bin/chromium", "/usr/bin/chromedriver"  # Debian's, installed by .ci/run


@pytest.fixture(scope="module")
def registered(tmp_path_factory):
    d = tmp_path_factory.mktemp("view")
    v1, f1, _ = random_disk_mesh(bump(), 400, seed=6)
    v2, f2, _ = random_disk_mesh(bump(), 600, seed=7, rotation=Rotation.random(random_state=1).as_matrix(), scale=2.0)
    trimesh.Trimesh(v1, f1, process=False).export(d / "a.ply")
    trimesh.Trimesh(v2, f2, process=False).export(d / "b.ply")
    out = d / "out"
    cmd = [sys.executable, "-m", "meshreg.cli", "register", str(d / "a.ply"), str(d / "b.ply"), "-o", str(out)]
    proc = subprocess.run([*cmd, "--html", "--resolution", "31", "-q"], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    assert "view.html" in proc.stdout
    return out


def test_page_is_self_contained(registered):
    html = (registered / "view.html").read_text()
    assert not re.search(r"<script[^>]+src=[\"']https?:", html)  # nothing fetched: plotly.js is embedded
    assert "plotly" in html and len(html) > 1_000_000


def test_view_command_rewrites_the_page(registered):
    (registered / "view.html").unlink()
    proc = subprocess.run(
        [sys.executable, "-m", "meshreg.cli", "view", str(registered)], capture_output=True, text=True
    )
    assert proc.returncode == 0, proc.stderr
    assert (registered / "view.html").stat().st_size > 1_000_000
    for where, words in ((registered / "nothing", "no such directory"), (registered.parent, "no mesh registration")):
        proc = subprocess.run([sys.executable, "-m", "meshreg.cli", "view", str(where)], capture_output=True, text=True)
        assert proc.returncode == 2 and words in proc.stderr and "Traceback" not in proc.stderr
    page = (registered / "view.html").read_bytes()
    (registered / "view.html").write_text("my page")  # not meshreg's any more: kept
    view = [sys.executable, "-m", "meshreg.cli", "view", str(registered)]
    proc = subprocess.run(view, capture_output=True, text=True)
    assert proc.returncode == 2 and "is not on meshreg's list" in proc.stderr
    assert (registered / "view.html").read_text() == "my page"
    (registered / "view.html").write_bytes(page)


def test_view_of_damaged_outputs_says_what_is_wrong(registered, tmp_path):
    """Held out 2026-12-02 (a fuzz of the command line): a cut result.npz or an unreadable first.ply gave tracebacks,
    and a first.ply of another mesh a page of wrong matches."""
    import shutil

    damages = {
        "cut": ("result.npz", lambda p: p.write_bytes(p.read_bytes()[:3000]), "not a meshreg result file"),
        "junk": ("first.ply", lambda p: p.write_text("junk"), "cannot read this mesh"),
        "other": ("first.ply", lambda p: trimesh.creation.box().export(p), "not of one run"),
    }
    for name, (victim, damage, words) in damages.items():
        out = tmp_path / name
        shutil.copytree(registered, out)
        (out / "view.html").unlink()
        damage(out / victim)
        proc = subprocess.run([sys.executable, "-m", "meshreg.cli", "view", str(out)], capture_output=True, text=True)
        assert proc.returncode == 2 and words in proc.stderr and "Traceback" not in proc.stderr, (name, proc.stderr)
        assert not (out / "view.html").exists()


@pytest.mark.slow
def test_page_draws_both_meshes_and_marks_the_match_in_a_real_browser(registered):
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    opts = webdriver.ChromeOptions()
    opts.binary_location = CHROMIUM
    for arg in (
        "--headless=new",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-dev-shm-usage",
        "--use-angle=swiftshader",
        "--enable-unsafe-swiftshader",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--no-first-run",
        "--window-size=1200,700",
    ):
        opts.add_argument(arg)
    opts.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    driver = webdriver.Chrome(service=Service(CHROMEDRIVER), options=opts)
    try:
        driver.get((registered / "view.html").as_uri())
        plot = "document.querySelector('.js-plotly-plot')"
        for _ in range(150):
            if driver.execute_script(f"var g = {plot}; return g && g._fullData ? g._fullData.length : 0") == 4:
                break
            time.sleep(0.2)
        drawn = driver.execute_script(
            f"var g = {plot}; return [g._fullLayout.scene._scene.glplot != null, "
            "g._fullLayout.scene2._scene.glplot != null, g._fullData[0].x.length, g._fullData[1].x.length]"
        )
        assert drawn[:2] == [True, True]  # both WebGL scenes exist
        n1, n2 = len(trimesh.load(registered / "first.ply", process=False).vertices), drawn[3]
        assert drawn[2] == n1 and n2 > 0
        k = 37
        marked = driver.execute_script(
            f"var g = {plot}; g.emit('plotly_hover', {{points: [{{curveNumber: 0, pointNumber: {k}, "
            "x: g._fullData[0].x[37], y: g._fullData[0].y[37], z: g._fullData[0].z[37]}]}); "
            "return [g.data[3].visible, g.data[3].x[0], g.data[3].y[0], g.data[3].z[0]]"
        )
        errors = [e for e in driver.get_log("browser") if e["level"] == "SEVERE"]
    finally:
        driver.quit()
    assert not errors, errors
    with np.load(registered / "result.npz") as data:
        match, transform = data["matched_first"][k], data["transform"]
    back = np.linalg.inv(transform)
    expected = back[:3, :3] @ match + back[:3, 3]  # the match on the second mesh, shown in the first's pose
    assert marked[0] is True
    assert np.allclose(marked[1:], expected, rtol=1e-4, atol=1e-4 * np.abs(expected).max())
