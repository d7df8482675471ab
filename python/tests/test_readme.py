"""The README's Python snippet, as written there, renders a PNG."""

import re
from pathlib import Path


def test_the_readme_snippet_writes_a_png(tmp_path, monkeypatch):
    root = Path(__file__).resolve().parents[2]
    text = (root / "README.md").read_text()
    section = text[text.index("## Use from Python"):]
    snippet = re.search(r"```python\n(.*?)```", section, re.S).group(1)
    assert "nerf_bundle" in snippet
    monkeypatch.chdir(root)
    snippet = snippet.replace('"lego.png"', repr(str(tmp_path / "lego.png")))
    exec(compile(snippet, "README.md", "exec"), {})
    png = (tmp_path / "lego.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 1000
