"""The public API type-checks: mypy (settings in pyproject.toml) finds nothing in ``mocapdb``, the modules
behind its names (``mocapdb._API``, so a new public name is checked with it) and the stream transport and
session. The modules they import are analysed for their types, their own errors not reported
(``follow_imports = "silent"``); ``mypy -p mocapdb`` checks everything (docs/install.md)."""
import subprocess
import sys
from pathlib import Path

import mocapdb

ROOT = Path(__file__).resolve().parents[1]
STREAM_MODULES = ["mocapdb.runtime.stream.transport", "mocapdb.runtime.stream.session"]


def public_modules() -> list[str]:
    return sorted({"mocapdb", *mocapdb._API.values(), *STREAM_MODULES})


def test_public_api_type_checks(tmp_path):
    modules = [arg for module in public_modules() for arg in ("-m", module)]
    # a fresh cache: about a minute on two cores, never stale; the generous timeout only stops a hung run
    run = subprocess.run([sys.executable, "-m", "mypy", "--config-file", str(ROOT / "pyproject.toml"),
                          "--cache-dir", str(tmp_path / "mypy_cache"), *modules],
                         cwd=ROOT, capture_output=True, text=True, timeout=1800)
    assert run.returncode == 0, f"mypy {' '.join(modules)}\n{run.stdout}{run.stderr}"
