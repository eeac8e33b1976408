"""The docs: the README stays short, the site and its API reference build without a warning, and
every file the README and the guides point at exists."""
from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
README_MAX_LINES = 200


def test_readme_is_short_and_starts_with_the_two_commands():
    text = (ROOT / "README.md").read_text()
    assert len(text.splitlines()) <= README_MAX_LINES
    first_blocks = re.findall(r"```\n(.*?)```", text, re.S)[:2]
    assert first_blocks == ["bash tools/quickstart.sh\n", ".venv/bin/python -m pytest -q\n"]


def test_every_path_the_docs_name_exists():
    pages = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
    named = {m for page in pages for m in re.findall(r"`((?:docs|data_specs|tools|tests)/[\w./-]+\.(?:md|py|png))`",
                                                     page.read_text())}
    missing = sorted(p for p in named if not (ROOT / p).exists())
    assert named and not missing, missing


def test_docs_site_builds_without_warnings(tmp_path):
    run = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(tmp_path / "site")],
                         cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-3000:]
    reference = (tmp_path / "site" / "reference" / "index.html").read_text()
    assert "BlazePose" in reference and "Engine" in reference   # the API reference was generated
