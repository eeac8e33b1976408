"""Where numba keeps the compiled kernels (``@njit(cache=True)``), chosen before any kernel is defined.

numba caches a kernel in ``NUMBA_CACHE_DIR``, else in ``__pycache__`` beside its source, else in the user's cache
folder, and raises "cannot cache function …: no locator available" when it can write to none of them (a service
account, a read-only container). :func:`choose_kernel_cache` runs at ``import mocapdb``, before numba chooses.
:func:`load_cached_kernels` loads the cached code before a stream's first frame (`live`).
"""
from __future__ import annotations

import importlib.util
import os
import stat
import sys
import tempfile
from pathlib import Path
from typing import Any

# the packages whose modules define cache=True kernels (numba caches each beside its source by default)
_KERNEL_PACKAGES = ("mocapdb.core", "mocapdb.builder", "mocapdb.evaluation", "mocapdb.runtime",
                    "mocapdb.runtime.world")


def choose_kernel_cache() -> str | None:
    """Let numba cache mocapdb's kernels wherever this process can write; call it before any kernel module is
    imported (``mocapdb/__init__.py`` does).

    Keeps a writable ``NUMBA_CACHE_DIR``, else numba's default (``__pycache__`` beside the sources) when writable,
    else sets ``NUMBA_CACHE_DIR`` to ``$XDG_CACHE_HOME/mocapdb/numba`` (``~/.cache/mocapdb/numba``) or to a private
    ``mocapdb-numba-<uid>`` in the temporary folder; with none writable, kernels compile on every run. One warning
    notes a fallback folder when it is made, and compiling on every run each time. Returns the cache folder set in
    ``NUMBA_CACHE_DIR``, None for numba's default or none.
    """
    user = os.environ.get("NUMBA_CACHE_DIR")
    if user and _writable(Path(user)):
        return user
    if all(_writable(folder / "__pycache__") for folder in _kernel_folders()):
        return None
    folder, existed = _fallback()
    if folder is None:
        _compile_uncached()
        _note("kernels are compiled on every run (no writable cache folder; set NUMBA_CACHE_DIR to keep them)")
        return None
    os.environ["NUMBA_CACHE_DIR"] = str(folder)
    if "numba.core.config" in sys.modules:  # read at numba's import: already done
        # numba.core.config sets its settings from the environment at run time: mypy sees no CACHE_DIR
        sys.modules["numba.core.config"].CACHE_DIR = str(folder)  # type: ignore[attr-defined]
    if not existed:  # noted when the folder is made, not on every run of a system-wide install
        why = f"NUMBA_CACHE_DIR {user} and mocapdb's folder are" if user else "mocapdb's folder is"
        _note(f"compiled kernels are cached in {folder} ({why} not writable)")
    return str(folder)


def load_cached_kernels(prefix: str = "mocapdb.") -> int:
    """Load the cached compiled code of every kernel (``cache=True``) of the modules named ``prefix``… imported so
    far, without running any: their first calls then run at once. Otherwise each first call loads its code from the
    cache (2–5 ms, holding the GIL), and `live`'s first frames paid about 60 ms for the dozens their first engine
    steps call, which held up the detector's thread and were most of the latency's p99 on a short take
    (docs/benchmarks.md, "Live latency and speed: one thread a model, kernels loaded before the first frame"). Only
    this machine's entries for the kernels' present source are loaded (numba's cache index); a kernel cached for
    none compiles at its first call as before. Returns the overloads loaded."""
    from numba.core.dispatcher import Dispatcher

    modules = [m for name, m in list(sys.modules.items()) if name.startswith(prefix) and m is not None]
    kernels = {id(k): k for m in modules for k in list(vars(m).values()) if isinstance(k, Dispatcher)}
    return sum(_load_cached(kernel) for kernel in kernels.values())


def _load_cached(kernel: Any) -> int:
    """Load ``kernel``'s overloads cached for this machine and its present source (:func:`load_cached_kernels`);
    how many."""
    cache = kernel._cache
    if not hasattr(cache, "_cache_file"):  # numba's null cache: a kernel without cache=True
        return 0
    codegen = kernel.targetctx.codegen()
    signatures = [key[0] for key in cache._cache_file._load_index() if key == cache._index_key(key[0], codegen)]
    for signature in signatures:
        kernel.compile(signature)   # found in the cache: loaded, not compiled
    return len(signatures)


def _kernel_folders() -> list[Path]:
    """The folders of the kernel modules."""
    folders = []
    for name in _KERNEL_PACKAGES:
        spec = importlib.util.find_spec(name)
        if spec is None or spec.origin is None:
            raise ImportError(f"{name}, a package of mocapdb's kernels, is not installed as a folder of modules")
        folders.append(Path(spec.origin).parent)
    return folders


def _writable(folder: Path, mode: int = 0o777) -> bool:
    """Whether numba can cache in ``folder``, tested as numba does: create it, then a temporary file in it."""
    try:
        os.makedirs(folder, mode=mode, exist_ok=True)
        tempfile.TemporaryFile(dir=folder).close()
    except OSError:
        return False
    return True


def _fallback() -> tuple[Path | None, bool]:
    """The user's cache folder if writable, else this user's own folder in the temporary folder, else None; and
    whether that folder existed before."""
    user_cache = Path(os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache")) / "mocapdb" / "numba"
    existed = user_cache.is_dir()
    if user_cache.is_absolute() and _writable(user_cache):
        return user_cache, existed
    try:
        temp = Path(tempfile.gettempdir()) / f"mocapdb-numba-{os.getuid()}"
    except OSError:  # no usable temporary folder
        return None, False
    existed = temp.is_dir()
    return (temp, existed) if _writable(temp, 0o700) and _private(temp) else (None, False)


def _private(folder: Path) -> bool:
    """Whether ``folder`` is a directory (not a link) of this user that nobody else can write: the temporary folder
    is shared, and numba's cache files are pickles, loaded as code."""
    info = folder.lstat()
    return stat.S_ISDIR(info.st_mode) and info.st_uid == os.getuid() and not info.st_mode & 0o022


def _compile_uncached() -> None:
    """Leave mocapdb's kernels on the null cache numba gives every function without ``cache=True``.

    numba 0.68 has no switch to turn ``cache=True`` off, and a cache locator (``NUMBA_CACHE_LOCATOR_CLASSES``) cannot
    do it: every locator needs a folder to write, and a failed write is an error (ignored on Windows only). So the one
    place ``cache=True`` acts, ``Dispatcher.enable_caching``, skips functions of mocapdb's modules; others keep numba's
    behaviour.
    """
    from numba.core.dispatcher import Dispatcher

    enable_caching = Dispatcher.enable_caching

    def enable_caching_but_mocapdb(self) -> None:
        if not self.py_func.__module__.startswith("mocapdb."):
            enable_caching(self)

    Dispatcher.enable_caching = enable_caching_but_mocapdb  # type: ignore[method-assign]  # the patch described


def _note(text: str) -> None:
    """A warning through the ``mocapdb`` logger, or on stderr as the CLI prints one while logging is not set up (at
    ``import mocapdb`` the CLI has not configured it yet)."""
    import logging

    logger = logging.getLogger("mocapdb")
    if logger.hasHandlers():
        logger.warning(text)
    else:
        print(f"mocapdb: warning: {text}", file=sys.stderr)
