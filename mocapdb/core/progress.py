"""Progress bars on stderr (tqdm) for long work, one switch for all of them, and the notice shown
while numba compiles the kernels on a first run.

Bars show only on a terminal (tqdm's ``disable=None``) and never with ``mocapdb -q``
(:func:`set_quiet`).
"""
from __future__ import annotations

import os
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from types import ModuleType
from typing import Any

from tqdm import tqdm

_quiet = False


def set_quiet(quiet: bool) -> None:
    """Hide (True) or show (False, the default) every progress bar of this process."""
    global _quiet
    _quiet = quiet


def progress(iterable: Any = None, **options: Any) -> tqdm:
    """A tqdm bar on stderr (same arguments as tqdm), hidden when quiet or not on a terminal."""
    return tqdm(iterable, disable=True if _quiet else None, file=sys.stderr, **options)


def kernels_cached(module: ModuleType) -> bool:
    """Whether numba's on-disk cache holds compiled kernels of ``module`` (``cache=True``): its
    index files beside the source (``__pycache__``) or under ``NUMBA_CACHE_DIR``."""
    if module.__file__ is None:  # no source file (a namespace package): nothing of it numba could cache
        return False
    source = Path(module.__file__)
    folders = [source.parent / "__pycache__"]
    if os.environ.get("NUMBA_CACHE_DIR"):
        folders.append(Path(os.environ["NUMBA_CACHE_DIR"]))
    pattern = f"{source.stem}.*.nbi"
    return any(next(folder.rglob(pattern), None) is not None for folder in folders if folder.is_dir())


@contextmanager
def compile_notice(cold: bool, what: str = "compiling kernels, once (about 20 s on 2 cores)") -> Iterator[None]:
    """While the block runs, an elapsed-time bar saying ``what`` if ``cold`` (numba compiles on
    first use, so a first run's first frame is slow); nothing otherwise."""
    if not cold or _quiet:
        yield
        return
    bar = progress(desc=what, bar_format="{desc}: {elapsed}")
    stop = threading.Event()

    def tick() -> None:
        while not stop.wait(0.5):
            bar.refresh()

    ticker = threading.Thread(target=tick, name="mocapdb-compile-notice", daemon=True)
    ticker.start()
    try:
        yield
    finally:
        stop.set()
        ticker.join()
        bar.close()
