"""The code stays lint-clean: ruff's pycodestyle errors, pyflakes findings and import order (E, F, I;
settings in pyproject.toml) over the package, the tools and the tests."""
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_ruff_finds_nothing():
    result = subprocess.run([sys.executable, "-m", "ruff", "check", "--select", "E,F,I", "--output-format", "concise",
                             "mocapdb", "runtime", "tools", "tests"], cwd=ROOT, capture_output=True, text=True)
    assert result.returncode == 0, result.stdout + result.stderr
