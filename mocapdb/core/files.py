"""Files: atomic writes and OS errors that name their file."""
from __future__ import annotations

import os
from pathlib import Path


def write_atomic(path: str | os.PathLike, text: str) -> None:
    """Write ``text`` to ``path`` through a temporary file and a rename (never a half file)."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    tmp.write_text(text, encoding="utf-8")
    os.replace(tmp, path)


def os_error_message(exc: OSError, path: str | Path | None = None, doing: str | None = None) -> str:
    """An OS error that names its file: ``<file>: cannot <doing> (<reason>)`` or ``<file>: <reason>``."""
    name = exc.filename if exc.filename is not None else path
    reason = exc.strerror or str(exc) or type(exc).__name__
    what = f"cannot {doing} ({reason})" if doing else reason
    return f"{name}: {what}" if name is not None else what
