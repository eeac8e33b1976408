"""Runs anywhere (issue 20, item 5): with mocapdb's folder and the home folder read-only, numba's kernel cache falls
back to a writable folder, or kernels compile on every run; one note says which.

The chooser alone on folders in tmp_path, then real runs of ``python -m mocapdb inspect`` in a private mount namespace
(``unshare --mount``) with read-only bind mounts.
"""
import logging
import os
import re
import shlex
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

from mocapdb.core import kernel_cache
from mocapdb.core.kernel_cache import choose_kernel_cache

ROOT = Path(__file__).resolve().parents[1]
BVH = ROOT / "data" / "sample_bvh" / "002_01.bvh"
UNCACHED = "kernels are compiled on every run"


@pytest.fixture
def folders(tmp_path, monkeypatch, caplog):
    """The chooser's folders in tmp_path, all writable: the kernels' folder (``package``), HOME and the temporary
    folder; numba's settings are restored after the test."""
    from numba.core import config
    from numba.core.dispatcher import Dispatcher

    for name in ("NUMBA_CACHE_DIR", "XDG_CACHE_HOME"):  # set first, so that monkeypatch removes what the chooser sets
        monkeypatch.setenv(name, "")
        monkeypatch.delenv(name)
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    (tmp_path / "tmp").mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "tmp"))
    monkeypatch.setattr(kernel_cache, "_kernel_folders", lambda: [tmp_path / "package"])
    monkeypatch.setattr(config, "CACHE_DIR", config.CACHE_DIR)
    monkeypatch.setattr(Dispatcher, "enable_caching", Dispatcher.enable_caching)
    caplog.set_level(logging.WARNING, logger="mocapdb")
    return tmp_path


def _blocked(tmp_path: Path) -> Path:
    """A folder nobody can create, not even root: its parent is a file."""
    (tmp_path / "file").touch()
    return tmp_path / "file" / "folder"


def _notes(caplog) -> list[str]:
    return [record.getMessage() for record in caplog.records if record.name == "mocapdb"]


def test_keeps_a_writable_numba_cache_dir(folders, monkeypatch, caplog):
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(folders / "mine"))
    monkeypatch.setattr(kernel_cache, "_kernel_folders", lambda: [_blocked(folders)])
    assert choose_kernel_cache() == str(folders / "mine")
    assert os.environ["NUMBA_CACHE_DIR"] == str(folders / "mine")
    assert _notes(caplog) == []


def test_keeps_numbas_default_when_the_kernels_folder_is_writable(folders, caplog):
    assert choose_kernel_cache() is None
    assert "NUMBA_CACHE_DIR" not in os.environ
    assert (folders / "package" / "__pycache__").is_dir()
    assert _notes(caplog) == []


@pytest.mark.parametrize("xdg", [True, False])
def test_falls_back_to_the_user_cache_folder(folders, monkeypatch, caplog, xdg):
    from numba.core import config

    monkeypatch.setattr(kernel_cache, "_kernel_folders", lambda: [_blocked(folders)])
    if xdg:
        monkeypatch.setenv("XDG_CACHE_HOME", str(folders / "xdg"))
    expected = (folders / "xdg" if xdg else folders / "home" / ".cache") / "mocapdb" / "numba"
    assert choose_kernel_cache() == str(expected)
    assert os.environ["NUMBA_CACHE_DIR"] == config.CACHE_DIR == str(expected)
    assert _notes(caplog) == [f"compiled kernels are cached in {expected} (mocapdb's folder is not writable)"]


def test_falls_back_to_a_private_temporary_folder(folders, monkeypatch, caplog):
    blocked = _blocked(folders)
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(blocked))
    monkeypatch.setattr(kernel_cache, "_kernel_folders", lambda: [blocked])
    monkeypatch.setenv("HOME", str(blocked))
    expected = folders / "tmp" / f"mocapdb-numba-{os.getuid()}"
    assert choose_kernel_cache() == str(expected)
    assert os.environ["NUMBA_CACHE_DIR"] == str(expected)
    assert expected.stat().st_mode & 0o777 == 0o700
    [note] = _notes(caplog)
    assert note.startswith(f"compiled kernels are cached in {expected} (NUMBA_CACHE_DIR {blocked} and")


def test_refuses_a_temporary_folder_others_can_write(folders, monkeypatch, caplog):
    monkeypatch.setattr(kernel_cache, "_kernel_folders", lambda: [_blocked(folders)])
    monkeypatch.setenv("HOME", str(_blocked(folders)))
    planted = folders / "tmp" / f"mocapdb-numba-{os.getuid()}"
    planted.mkdir()
    planted.chmod(0o777)
    assert choose_kernel_cache() is None
    assert [note.split(" (")[0] for note in _notes(caplog)] == [UNCACHED]


def test_compiles_mocapdbs_kernels_uncached_when_nothing_is_writable(folders, monkeypatch, caplog):
    from numba import njit

    blocked = _blocked(folders)
    monkeypatch.setattr(kernel_cache, "_kernel_folders", lambda: [blocked])
    monkeypatch.setenv("HOME", str(blocked))
    monkeypatch.setattr(tempfile, "tempdir", str(blocked))
    assert choose_kernel_cache() is None
    assert "NUMBA_CACHE_DIR" not in os.environ
    assert [note.split(" (")[0] for note in _notes(caplog)] == [UNCACHED]

    def ours(x):
        return x + 1

    def theirs(x):
        return x + 1

    ours.__module__ = "mocapdb.core.example"
    assert njit(cache=True)(ours).stats.cache_path is None  # numba's null cache: defined, compiled, never stored
    assert njit(cache=True)(ours)(1) == 2
    assert njit(cache=True)(theirs).stats.cache_path is not None  # other modules keep numba's behaviour


def test_the_probed_folders_hold_every_cached_kernel():
    kernels = {path.parent for folder in (ROOT / "mocapdb", ROOT / "runtime") for path in folder.rglob("*.py")
               if re.search(r"@njit\([^)]*cache=True", path.read_text())}
    # runtime/ is mocapdb/runtime through a link: the same folder, so the same cache
    assert kernels and kernels <= {folder.resolve() for folder in kernel_cache._kernel_folders()}


@pytest.fixture(scope="module")
def unshare():
    """Skips unless this process may make a private mount namespace with a read-only bind mount."""
    if shutil.which("unshare") is None:
        pytest.skip("unshare is not installed")
    probe = f"mount --bind -o ro {shlex.quote(str(ROOT))} {shlex.quote(str(ROOT))}"
    out = subprocess.run(["unshare", "--mount", "sh", "-c", probe], capture_output=True, text=True)
    if out.returncode:
        pytest.skip(f"unshare --mount is not permitted here: {out.stderr.strip()}")


def _inspect(read_only: list[Path], cwd: Path, **env: str) -> subprocess.CompletedProcess:
    """``python -m mocapdb inspect`` (from ``cwd``) with ``read_only`` folders bind-mounted read-only and NUMBA/XDG/temp
    variables only from ``env``."""
    names = ("NUMBA_CACHE_DIR", "NUMBA_CACHE_LOCATOR_CLASSES", "XDG_CACHE_HOME", "TMPDIR", "TEMP", "TMP")
    environ = {name: value for name, value in os.environ.items() if name not in names} | env
    quoted = [shlex.quote(str(folder)) for folder in read_only]
    mounts = [f"mount --bind {q} {q} && mount -o remount,bind,ro {q} {q}" for q in quoted]
    run = f"cd {shlex.quote(str(cwd))} && exec {shlex.quote(sys.executable)} -m mocapdb inspect {shlex.quote(str(BVH))}"
    return subprocess.run(["unshare", "--mount", "sh", "-c", " && ".join([*mounts, run])], env=environ,
                          capture_output=True, text=True, timeout=300)


def _warnings(stderr: str) -> list[str]:
    return [line for line in stderr.splitlines() if line.startswith("mocapdb: warning:")]


def test_read_only_package_and_home_cache_in_the_temporary_folder(unshare, tmp_path):
    home, temp = tmp_path / "home", tmp_path / "tmp"
    home.mkdir()
    temp.mkdir()
    out = _inspect([ROOT / "mocapdb", ROOT / "runtime", home], home, HOME=str(home), TMPDIR=str(temp))
    assert out.returncode == 0, out.stderr
    assert "convention:  character_creator" in out.stdout and "CC_Base_Head" in out.stdout
    cache = temp / f"mocapdb-numba-{os.getuid()}"
    assert _warnings(out.stderr) == [f"mocapdb: warning: compiled kernels are cached in {cache} "
                                     "(mocapdb's folder is not writable)"], out.stderr
    assert list(cache.rglob("*.nbi")) and list(cache.rglob("*.nbc"))


def test_nothing_writable_compiles_on_every_run(unshare, tmp_path):
    home = tmp_path / "home"
    (home / "cache").mkdir(parents=True)
    system_temp = [Path(folder) for folder in ("/tmp", "/var/tmp", "/usr/tmp") if Path(folder).is_dir()]
    out = _inspect([ROOT / "mocapdb", ROOT / "runtime", home, *system_temp], home,
                   HOME=str(home), TMPDIR=str(home), XDG_CACHE_HOME=str(home / "cache"))
    assert out.returncode == 0, out.stderr
    assert "convention:  character_creator" in out.stdout and "CC_Base_Head" in out.stdout
    assert [line.split(" (")[0] for line in _warnings(out.stderr)] == [f"mocapdb: warning: {UNCACHED}"], out.stderr
    assert not list(home.rglob("*.nb?"))


def test_cached_kernels_load_before_their_first_call():
    """load_cached_kernels gives an imported module's kernels their cached code without running them: the
    first call then neither loads nor compiles (numba's own count of cache hits and misses)."""
    first_run = "import numpy as np; from mocapdb.core import geometry; geometry.matrix_to_quat(np.eye(3))"
    subprocess.run([sys.executable, "-c", first_run], check=True, cwd=ROOT)   # cached here if not before
    probe = (
        "import numpy as np; from mocapdb.core import geometry; from mocapdb.core.kernel_cache import "
        "load_cached_kernels\n"
        "kernel = geometry._matrices_to_quats\n"
        "before = len(kernel.signatures); loaded = load_cached_kernels()\n"
        "hits, misses = sum(kernel.stats.cache_hits.values()), sum(kernel.stats.cache_misses.values())\n"
        "signatures = len(kernel.signatures); geometry.matrix_to_quat(np.eye(3))\n"
        "print(before, loaded, hits, misses, signatures, len(kernel.signatures), "
        "sum(kernel.stats.cache_misses.values()))")
    out = subprocess.run([sys.executable, "-c", probe], check=True, cwd=ROOT, capture_output=True, text=True).stdout
    before, loaded, hits, misses, signatures, after_call, misses_after = map(int, out.split())
    assert before == 0 and loaded >= 1 and hits >= 1 and misses == 0
    assert signatures >= 1 and after_call == signatures and misses_after == 0   # the call found it loaded
