"""From a fresh virtual environment: `pip install ./python[images]` and the README's snippet
produce a PNG (dependencies from PyPI, or pip's cache)."""

import re
import subprocess
import sys
from pathlib import Path


def test_a_fresh_venv_installs_the_package_and_runs_the_readme_snippet(tmp_path):
    root = Path(__file__).resolve().parents[2]
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
    python = venv / "bin" / "python"
    subprocess.run([str(python), "-m", "pip", "install", "--quiet", "--disable-pip-version-check", f"{root / 'python'}[images]"], check=True)
    section = (root / "README.md").read_text().split("## Use from Python", 1)[1]
    snippet = re.search(r"```python\n(.*?)```", section, re.S).group(1).replace('"lego.png"', repr(str(tmp_path / "lego.png")))
    subprocess.run([str(python), "-c", snippet], check=True, cwd=root)
    assert (tmp_path / "lego.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
