"""The package type-checks: mypy (settings in pyproject.toml) finds nothing in ``mypy -p mocapdb``, every
module of the package, ``mocapdb.runtime`` (the ``runtime/`` folder, through the ``mocapdb/runtime``
link) included: the source files it reports checked are all of them. Modules imported from outside the
package are analysed for their types, their own errors not reported (``follow_imports = "silent"``;
docs/install.md)."""
import os
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def package_sources() -> list[Path]:
    """Every module of the package, those reached through the ``mocapdb/runtime`` link included."""
    return sorted(Path(folder, name) for folder, _, names in os.walk(ROOT / "mocapdb", followlinks=True)
                  if "__pycache__" not in Path(folder).parts for name in names if name.endswith(".py"))


def test_package_type_checks(tmp_path):
    # a fresh cache: a few minutes on two cores, never stale; the generous timeout only stops a hung run
    run = subprocess.run([sys.executable, "-m", "mypy", "--config-file", str(ROOT / "pyproject.toml"),
                          "--cache-dir", str(tmp_path / "mypy_cache"), "-p", "mocapdb"],
                         cwd=ROOT, capture_output=True, text=True, timeout=1800)
    assert run.returncode == 0, f"mypy -p mocapdb\n{run.stdout}{run.stderr}"
    checked = re.search(r"no issues found in (\d+) source files", run.stdout)
    assert checked and int(checked.group(1)) == len(package_sources()), run.stdout
