"""The locked install (tools/lock.py, docs/install.md): every lock satisfies pyproject.toml with a hash on
every pin, the checker catches what a stale lock looks like, and this environment holds exactly its lock
(requirements.lock, or $MOCAPDB_LOCK where CI runs the tests on another: .ci/opencv4.lock)."""
import os
import sys
from importlib import metadata

import pytest
from packaging.markers import Marker

from .conftest import ROOT

sys.path.insert(0, str(ROOT / "tools"))
import lock  # noqa: E402

HASH = "    --hash=sha256:" + "0" * 64


def test_every_lock_satisfies_pyproject_with_hashes():
    assert [problem for each in lock.LOCKS for problem in lock.lock_problems(each)] == []


@pytest.mark.parametrize("text, problem", [
    ("numpy==1.20.0 \\\n" + HASH, "numpy==1.20.0 is outside numpy>=1.26"),   # pyproject says >=1.26
    ("numpy==2.4.6\n", "numpy==2.4.6 has no hash"),
    ("", "numpy is not locked"),
])
def test_a_stale_lock_is_named(tmp_path, monkeypatch, text, problem):
    monkeypatch.setattr(lock, "ROOT", tmp_path)
    (tmp_path / "stale.lock").write_text(text)
    problems = lock.lock_problems(lock.Lock("stale.lock", True, (), universal=True))
    assert f"stale.lock: {problem}" in problems


def test_pins_read_markers_and_extras():
    text = ("numpy==2.4.6 ; python_full_version < '3.12' \\\n" + HASH + "\n"
            "dask[distributed]==2026.8.0 \\\n" + HASH + "\n    # via mocapdb\n")
    assert lock.pins(text) == [("numpy", "2.4.6", "python_full_version < '3.12'"), ("dask", "2026.8.0", "")]


def test_moved_versions_and_figures_name_what_changed():
    before = "a==1.0 \\\n" + HASH + "\nb==2.0 \\\n" + HASH + "\n"
    after = "a==1.1 \\\n" + HASH + "\nb==2.0 \\\n" + HASH + "\nc==3.0 \\\n" + HASH + "\n"
    assert lock.moved_versions(before, after) == ["a: 1.0 -> 1.1", "c: - -> 3.0"]
    assert lock.moved_figures({"x": 1.0, "y": 2.0}, {"x": 1.0, "y": 2.5}) == ["y: 2.0 -> 2.5"]


def test_this_environment_holds_exactly_its_lock():
    """Every pin for this interpreter is the installed version: the install came from the lock."""
    path = ROOT / os.environ.get("MOCAPDB_LOCK", "requirements.lock")
    wrong = []
    for name, version, marker in lock.pins(path.read_text()):
        if marker and not Marker(marker).evaluate():
            continue
        try:
            installed = metadata.version(name)
        except metadata.PackageNotFoundError:
            installed = None
        if installed != version:
            wrong.append(f"{name}: locked {version}, installed {installed}")
    assert wrong == [], f"reinstall from {path.name}: bash tools/setup.sh"
