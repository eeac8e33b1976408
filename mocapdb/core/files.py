"""Files: atomic writes, inputs read within bounds (regular files of a bounded size) and OS errors
that name their file."""
from __future__ import annotations

import os
import stat
from pathlib import Path
from typing import BinaryIO


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


MIB = 1 << 20
_FILE_KINDS = ((stat.S_ISDIR, "a folder"), (stat.S_ISFIFO, "a FIFO (named pipe)"), (stat.S_ISCHR, "a device"),
               (stat.S_ISBLK, "a device"), (stat.S_ISSOCK, "a socket"))


def file_kind(mode: int) -> str:
    """What a file of ``st_mode`` ``mode`` is, in words: "a folder", "a FIFO (named pipe)", "a device",
    "a socket", "a regular file" (or "a special file")."""
    if stat.S_ISREG(mode):
        return "a regular file"
    return next((words for test, words in _FILE_KINDS if test(mode)), "a special file")


def _size_text(n_bytes: int) -> str:
    return f"{n_bytes / MIB:,.1f} MiB" if n_bytes >= MIB else f"{n_bytes:,} bytes"


def open_input(path: str | os.PathLike, max_bytes: int, error: type[Exception], what: str) -> BinaryIO:
    """``path`` opened for reading in binary, once it is known to be a regular file of at most
    ``max_bytes`` (a symlink is followed); else ``error`` naming the file: a folder, a FIFO, a
    device or a socket is refused before any byte is read (a FIFO never blocks the open), and so
    is a larger file. ``what`` names the content ("BVH file") in the messages."""
    name = os.fspath(path)
    try:
        fd = os.open(name, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0))
    except OSError as exc:
        raise error(os_error_message(exc, name, f"read the {what}")) from None
    status = os.fstat(fd)
    if not stat.S_ISREG(status.st_mode) or status.st_size > max_bytes:
        os.close(fd)
        if not stat.S_ISREG(status.st_mode):
            raise error(f"{name}: {file_kind(status.st_mode)}, not a {what}")
        raise error(f"{name}: {_size_text(status.st_size)}, more than a {what} may hold ({_size_text(max_bytes)})")
    return os.fdopen(fd, "rb")


def read_input_bytes(path: str | os.PathLike, max_bytes: int, error: type[Exception], what: str) -> bytes:
    """The bytes of a regular file of at most ``max_bytes`` (:func:`open_input`'s checks); a file
    that grows past the bound while it is read is refused too."""
    with open_input(path, max_bytes, error, what) as file:
        try:
            data = file.read(max_bytes + 1)
        except OSError as exc:
            raise error(os_error_message(exc, os.fspath(path), f"read the {what}")) from None
    if len(data) > max_bytes:
        raise error(f"{os.fspath(path)}: grew past {_size_text(max_bytes)} while it was read")
    return data


def read_input_text(path: str | os.PathLike, max_bytes: int, error: type[Exception], what: str,
                    errors: str = "strict") -> str:
    """:func:`read_input_bytes` decoded as UTF-8 (a leading BOM dropped); ``errors`` as for
    ``bytes.decode``; undecodable text is ``error`` naming the file and the line."""
    data = read_input_bytes(path, max_bytes, error, what)
    try:
        return data.decode("utf-8", errors=errors).removeprefix("\ufeff")
    except UnicodeDecodeError as exc:
        line = data[:exc.start].count(b"\n") + 1
        raise error(f"{os.fspath(path)}, line {line}: not UTF-8 text, not a {what}") from None
