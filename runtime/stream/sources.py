"""Local message sources (see :mod:`mocapdb.runtime.stream.transport`): a folder of ``*.json`` files, a
``.jsonl``/``.ndjson`` file and standard input. Network sources: :mod:`mocapdb.runtime.stream.net_sources`.

Choices:

- Folder source, live (``follow=True``): a ``*.json`` file is taken as soon as it parses as JSON, so
  a half-written file is never passed on and a complete one costs no extra poll of latency (a
  size-stability rule would add a poll per frame and still pass on the file of a writer that paused).
  A file that still does not parse once it has not changed for ``settle_s`` is passed on anyway,
  for the parser to report rather than have it vanish. Files go out in frame order
  (:func:`~mocapdb.core.formats.openpose.frame_order_key`, the order the offline folder reader
  uses): a file not yet taken holds back the later ones. Offline (``follow=False``) the folder is
  complete and every file is read at once.
- Folder, live: the folder is listed again only when its modification time changed (plus once
  after that time stops being recent, for file systems with coarse time stamps, and every
  ``rescan_s`` as a safety net), and only names not seen before are looked at: an idle folder
  costs one ``stat`` per poll however many files it holds.
- Folder: an entry named like a frame that is not a regular file when listed (a dangling or looping
  symlink, a FIFO, a device, a folder) is never opened nor waited on: it is skipped for good, counted
  (``StreamStats.not_regular``) and named in one warning (:func:`~mocapdb.core.formats.openpose.frame_entries`).
"""
from __future__ import annotations

import json
import os
import select
import stat
import sys
import time
from abc import abstractmethod
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from mocapdb.core.formats.openpose import frame_entries, frame_order_key
from mocapdb.runtime.stream.messages import RawMessage
from mocapdb.runtime.stream.source_base import READ_BYTES, LineSplitter, Source

__all__ = ["RESCAN_S", "SETTLE_S", "FolderSource", "JsonLinesFileSource", "StdinSource"]

SETTLE_S = 0.5                # folder source: unparsable file passed on after this long unchanged
RESCAN_S = 5.0                # folder source: full listing at least this often, changed or not
RECENT_NS = 2_000_000_000     # folder source: a folder time stamp this recent may hide more entries


def _is_json(data: bytes) -> bool:
    try:
        json.loads(data.decode("utf-8"))
    except (ValueError, RecursionError):
        return False
    return True


class FolderSource(Source):
    """The ``*.json`` files of a folder, one message each, in frame order (see the module notes);
    lossless: files on disk are read at the engine's pace, none dropped."""

    lossless = True

    def __init__(self, folder: Path, *, follow: bool = False, settle_s: float = SETTLE_S,
                 rescan_s: float = RESCAN_S, **common: Any) -> None:
        super().__init__(**common)
        self.folder, self.follow, self.settle_s, self.rescan_s = folder, follow, settle_s, rescan_s
        self.scans = 0                                  # folder listings so far
        self._known: set[str] = set()                   # every *.json name listed so far
        self._pending: list[str] = []                   # listed, not taken yet, in frame order
        self._unsettled: dict[str, tuple[tuple[int, int], float]] = {}   # name -> (size, mtime), since
        self._listed: tuple[int | None, int, float] = (None, 0, -float("inf"))   # folder mtime, wall ns, monotonic

    def _poll(self) -> Iterator[RawMessage | None]:
        if not self.follow:
            self._scan()
            for name in self._pending:
                if (data := self._read(self.folder / name)[0]) and (msg := self._emit(name, data)):
                    yield msg
            return
        while True:
            if self._changed():
                self._scan()
            yield from self._take_ready()
            yield None
            self._stop.wait(self.poll_s)

    def _changed(self) -> bool:
        """Whether the folder may hold names not listed yet: its time stamp moved, it was recent
        at the last listing (an entry may have come in the same tick), or ``rescan_s`` passed."""
        mtime = self._folder_mtime()
        listed_mtime, listed_wall_ns, listed_s = self._listed
        if mtime != listed_mtime or time.monotonic() - listed_s >= self.rescan_s:
            return True
        return mtime is not None and listed_wall_ns < mtime + RECENT_NS <= time.time_ns()

    def _folder_mtime(self) -> int | None:
        try:
            return os.stat(self.folder).st_mtime_ns
        except OSError:
            return None

    def _scan(self) -> None:
        """Lists the folder; names not seen before join the pending ones, in frame order."""
        self._listed = (self._folder_mtime(), time.time_ns(), time.monotonic())
        self.scans += 1
        try:
            new, skipped = frame_entries(self.folder, self._known)
        except OSError:
            return
        self._known.update(new + skipped)   # a name not a regular file when listed is skipped for good
        self.stats.add(not_regular=len(skipped))
        if new:
            self._pending = sorted(self._pending + new, key=frame_order_key)

    def _take_ready(self) -> Iterator[RawMessage]:
        """The pending files that are ready, in order; a file not ready holds back the later ones."""
        taken = 0
        try:
            for name in self._pending:
                data = self._ready(name)
                if data is None:
                    break
                taken += 1
                if (msg := self._emit(name, data)) is not None:
                    yield msg
        finally:
            del self._pending[:taken]

    def _read(self, path: Path) -> tuple[bytes | None, tuple[int, int]]:
        """At most one byte over the limit (enough to tell it is oversized) and the file's
        (size, mtime); None for a file that vanished, is not a regular file or cannot be read (never
        blocks: a FIFO, or a file that would block, such as ``/proc/kmsg`` behind a symlink)."""
        try:
            fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
        except OSError:
            return None, (0, 0)
        with os.fdopen(fd, "rb") as f:
            st = os.fstat(fd)
            if not stat.S_ISREG(st.st_mode):
                return None, (0, 0)
            try:
                data = f.read(self.max_message_bytes + 1)
            except OSError:
                return None, (0, 0)
            return data, (st.st_size, st.st_mtime_ns)

    def _ready(self, name: str) -> bytes | None:
        """The file's bytes once it parses as JSON or has not changed for ``settle_s`` (b"" if it
        vanished: skipped), else None (an empty file, just created, waits like a half-written one)."""
        data, signature = self._read(self.folder / name)
        if data is None:
            return b""
        if _is_json(data):
            return data
        now, seen = time.monotonic(), self._unsettled.get(name)
        if seen is None or seen[0] != signature:
            self._unsettled[name] = (signature, now)
            return None
        return data if now - seen[1] >= self.settle_s else None

    def _emit(self, name: str, data: bytes) -> RawMessage | None:
        self._unsettled.pop(name, None)
        if len(data) > self.max_message_bytes:
            self.stats.add(oversized=1)
            return None
        return self._message(data, str(self.folder / name))


class _ByteStreamSource(Source):
    """Newline-delimited messages from a byte stream that the subclass reads in chunks."""

    name: str

    def _poll(self) -> Iterator[RawMessage | None]:
        splitter = LineSplitter(self.max_message_bytes, self.stats)
        while True:
            data = self._read_chunk()
            if data == b"":
                yield from self._lines(splitter.flush(), self.name)
                return
            if data is not None:
                yield from self._lines(splitter.feed(data), self.name)
            yield None

    @abstractmethod
    def _read_chunk(self) -> bytes | None:
        """Next bytes; b"" at the end of the stream, None if nothing arrived within about a poll."""


class JsonLinesFileSource(_ByteStreamSource):
    """A ``.jsonl``/``.ndjson`` file, one message per line; with ``follow`` it is tailed like
    ``tail -f`` until stopped or the idle timeout passes. Lossless, as :class:`FolderSource`."""

    lossless = True

    def __init__(self, path: Path, *, follow: bool = False, **common: Any) -> None:
        super().__init__(**common)
        self.name, self.follow = str(path), follow
        self._file = open(path, "rb")

    def _read_chunk(self) -> bytes | None:
        if (data := self._file.read(READ_BYTES)) or not self.follow:
            return data
        self._stop.wait(self.poll_s)
        return None

    def close(self) -> None:
        super().close()
        self._file.close()


class StdinSource(_ByteStreamSource):
    """Standard input, one message per line; ends at end of input. Reads the file descriptor with
    ``select`` so :meth:`stop` and the idle timeout work while no input comes; a stream without one
    (``io.StringIO``) is read directly."""

    name = "stdin"

    def __init__(self, **common: Any) -> None:
        super().__init__(**common)
        self._stream = sys.stdin
        try:
            self._fd: int | None = self._stream.fileno()
        except (OSError, ValueError):
            self._fd = None

    def _read_chunk(self) -> bytes | None:
        if self._fd is None:
            data = self._stream.read(READ_BYTES)
            return data.encode("utf-8") if isinstance(data, str) else data
        ready, _, _ = select.select([self._fd], [], [], self.poll_s)
        return os.read(self._fd, READ_BYTES) if ready else None

