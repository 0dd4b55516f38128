"""Every Python example in the README and in docs/ runs as written (in a fresh folder, on data the project makes)."""

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]


def _blocks(page: Path) -> list[str]:
    return re.findall(r"^```python\n(.*?)^```", page.read_text(), flags=re.S | re.M)


def test_readme_has_a_python_example():
    assert _blocks(ROOT / "README.md")


@pytest.mark.slow
@pytest.mark.parametrize("page", [p for p in PAGES if _blocks(p)], ids=lambda p: p.name)
def test_python_examples_run_as_written(page, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    code = "\n\n".join(_blocks(page))
    if "meshreg-demo/" in code:  # examples that read what `meshreg demo` writes
        demo = subprocess.run([sys.executable, "-m", "meshreg.cli", "demo", "-q"], capture_output=True, text=True)
        assert demo.returncode == 0, demo.stderr
    env = {**os.environ, "MPLBACKEND": "Agg"}
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=600)
    assert proc.returncode == 0, f"{page.name}:\n{proc.stderr[-3000:]}"


def test_readme_synopsis_names_every_register_flag():
    """The README's command-line synopsis shows every flag of `meshreg register` (a flag added without it fails)."""
    from meshreg.cli import build_parser

    register = next(
        action.choices["register"] for action in build_parser()._actions if getattr(action, "choices", None)
    )
    readme = (ROOT / "README.md").read_text()
    synopsis = readme[readme.index("meshreg register FIRST SECOND") : readme.index("meshreg view OUT")]
    shown = set(re.findall(r"(?<![\w-])(--?[a-z][\w-]*)", synopsis))
    missing = [a.option_strings for a in register._actions if a.option_strings and not set(a.option_strings) & shown]
    assert missing == [["-h", "--help"]], missing
