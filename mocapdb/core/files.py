"""Files: atomic writes of files and of whole folders (crash-safe replacement, recovery after a
write that died), inputs read within bounds (regular files of a bounded size) and OS errors that
name their file."""
from __future__ import annotations

import ctypes
import errno
import functools
import json
import os
import re
import shutil
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


def read_sidecar(folder: str | os.PathLike, name: str, max_bytes: int, error: type[Exception], what: str,
                 form: str, version: int) -> tuple[Path, dict] | None:
    """The JSON object of file ``name`` beside a take's files in ``folder`` and its path, checked to be
    of ``form`` at ``version`` (None when there is no such file); ``error`` naming the file when it is
    not (``what`` names the kind: "scene file", "camera path")."""
    path = Path(folder) / name
    if not Path(folder).is_dir() or not path.exists():
        return None
    try:
        body = json.loads(read_input_text(path, max_bytes, error, what))
    except (ValueError, RecursionError) as exc:
        raise error(f"{path}: not a {what} ({exc})") from None
    if not isinstance(body, dict) or body.get("format") != form:
        raise error(f"{path}: not a {what} (format {form!r} expected)")
    if body.get("version") != version:
        raise error(f"{path}: version {body.get('version')!r}; this mocapdb reads version {version}")
    return path, body


# --- folders written whole: a temporary sibling, then swapped in --------------------------------

def output_target(path: str | os.PathLike) -> Path:
    """The absolute path a folder write replaces for ``path``: symlinks (also a dangling one at
    ``path`` itself) are followed, so a linked folder is replaced at its target."""
    return Path(os.path.realpath(os.path.abspath(path)))


def write_synced(file: Path, data: bytes) -> None:
    """``data`` written to ``file`` and flushed to the disk."""
    with open(file, "wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())


def fsync_dir(directory: Path) -> None:
    """The folder's entries (renames, new files) flushed to the disk."""
    fd = os.open(directory, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def sibling(path: Path, kind: str, pid: int) -> Path:
    """``.<name>.<kind>-<pid>`` next to ``path``: a folder write's temporary (``tmp``) or set-aside (``old``) folder."""
    return path.with_name(f".{path.name}.{kind}-{pid}")


def replace_folder(tmp: Path, path: Path) -> None:
    """Move the finished folder ``tmp`` to ``path``, deleting what it replaces; ``path`` is never
    missing (an atomic swap where the OS has one, else renames :func:`recover_interrupted` undoes)."""
    if not os.path.lexists(path):
        os.rename(tmp, path)
        fsync_dir(path.parent)
    elif _exchange(tmp, path):  # atomic swap: ``tmp`` now holds the old database
        fsync_dir(path.parent)
        shutil.rmtree(tmp, ignore_errors=True)
    else:
        _replace_by_renames(tmp, path)


def _replace_by_renames(tmp: Path, path: Path) -> None:
    """Where no atomic swap exists: old aside, new in, old deleted; the old comes back on any failure
    between the renames (and after a crash there, :func:`recover_interrupted` brings it back)."""
    old = sibling(path, "old", os.getpid())
    shutil.rmtree(old, ignore_errors=True)
    os.rename(path, old)
    try:
        os.rename(tmp, path)
    except BaseException:
        os.rename(old, path)
        raise
    fsync_dir(path.parent)
    shutil.rmtree(old, ignore_errors=True)


_RENAME_EXCHANGE = 2  # linux/fs.h
_AT_FDCWD = -100
_NO_EXCHANGE = {errno.ENOSYS, errno.EINVAL, errno.ENOTSUP, errno.EOPNOTSUPP}


@functools.cache
def _renameat2():
    """libc's ``renameat2`` (Linux, glibc ≥ 2.28), or None."""
    try:
        return getattr(ctypes.CDLL(None, use_errno=True), "renameat2", None)
    except OSError:
        return None


def _exchange(a: Path, b: Path) -> bool:
    """Atomically swap the existing paths ``a`` and ``b``; False where the OS or file system cannot."""
    renameat2 = _renameat2()
    if renameat2 is None:
        return False
    if renameat2(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE) == 0:
        return True
    err = ctypes.get_errno()
    if err in _NO_EXCHANGE:
        return False
    raise OSError(err, os.strerror(err), str(b))


def _pid_alive(pid: int) -> bool:
    """Whether process ``pid`` runs on this machine (unknown counts as running)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (OSError, OverflowError):
        return True
    return True


def _stale_siblings(path: Path) -> list[tuple[str, str]]:
    """``(folder name, "tmp" | "old")`` of the write folders of ``path`` whose process has ended (or is
    this one), ``old`` first."""
    pattern = re.compile(rf"\.{re.escape(path.name)}\.(tmp|old)-(\d+)")
    try:
        entries = sorted(os.scandir(path.parent), key=lambda e: e.name)
    except OSError:
        return []
    found = [(e.name, m.group(1), int(m.group(2))) for e in entries
             if (m := pattern.fullmatch(e.name)) and e.is_dir(follow_symlinks=False)]
    stale = [(name, kind) for name, kind, pid in found if pid == os.getpid() or not _pid_alive(pid)]
    return sorted(stale, key=lambda s: s[1] != "old")


def recover_interrupted(path: str | os.PathLike) -> list[str]:
    """Clean up after folder writes to ``path`` that died (killed, power loss): put a set-aside old folder
    (``.<name>.old-<pid>``) back at ``path`` if ``path`` is missing, and delete the other such
    folders and the temporary ones (``.<name>.tmp-<pid>``). Only folders of processes no longer
    running (or of this process) are touched. Returns what was done, one line each."""
    path = output_target(path)
    done = []
    for name, kind in _stale_siblings(path):
        folder = path.with_name(name)
        if kind == "old" and not os.path.lexists(path):
            os.rename(folder, path)
            done.append(f"restored {path} from {name}, left by an interrupted write")
        else:
            shutil.rmtree(folder, ignore_errors=True)
            done.append(f"removed {name}, left by an interrupted write")
    return done
