"""The base of every message source (see :mod:`mocapdb.runtime.stream.transport`): :class:`Source` and the
size-bounded :class:`LineSplitter` that cuts byte streams into messages.

No wait is unbounded: every source looks at its stop flag and its idle timeout at least every
``poll_s``, so SIGINT/SIGTERM and ``--idle-timeout`` are honoured whatever the input does.
``idle_timeout_s`` counts from the last message passed on (or the start), for every source.
Blank messages are skipped silently; oversized, non-UTF-8 and rate-limited ones are counted in
:class:`~mocapdb.runtime.stream.messages.StreamStats` and skipped.
"""
from __future__ import annotations

import threading
import time
from abc import ABC, abstractmethod
from collections.abc import Iterator
from typing import Protocol, Self

from mocapdb.runtime.stream.messages import RawMessage, StreamStats

__all__ = ["MAX_MESSAGE_BYTES", "POLL_S", "READ_BYTES", "LineSplitter", "Source"]

MAX_MESSAGE_BYTES = 1 << 20   # longest accepted input message (line, datagram line or file)
POLL_S = 0.02                 # how often waits check for stop, idle timeout and new files
READ_BYTES = 1 << 16          # bytes asked for per read of a stream or socket


class _Limiter(Protocol):
    def allow(self, sender: str) -> bool: ...


class LineSplitter:
    """Cuts a byte stream into numbered lines; a line over ``limit`` bytes is dropped and counted
    as soon as it exceeds the limit, never buffered whole."""

    def __init__(self, limit: int, stats: StreamStats) -> None:
        self._limit, self._stats = limit, stats
        self._buf = bytearray()
        self._skipping = False   # inside an oversized line, until its newline
        self._line_no = 0

    def feed(self, data: bytes) -> list[tuple[int, bytes]]:
        """The lines that ``data`` completes, with their 1-based line numbers."""
        *complete, rest = data.split(b"\n")
        lines = [line for piece in complete if (line := self._end_line(piece)) is not None]
        self._extend(rest)
        return lines

    def flush(self) -> list[tuple[int, bytes]]:
        """The last line of a stream that ended without a newline."""
        line = self._end_line(b"") if self._buf else None
        self._skipping = False
        return [line] if line is not None else []

    def _end_line(self, piece: bytes) -> tuple[int, bytes] | None:
        self._line_no += 1
        self._extend(piece)
        line = None if self._skipping else (self._line_no, bytes(self._buf))
        self._buf.clear()
        self._skipping = False
        return line

    def _extend(self, piece: bytes) -> None:
        if self._skipping:
            return
        if len(self._buf) + len(piece) > self._limit:
            self._stats.add(oversized=1)
            self._skipping = True
            self._buf.clear()
        else:
            self._buf += piece


class Source(ABC):
    """An iterable of :class:`RawMessage`. :meth:`stop` (from any thread) ends the iteration within
    about ``poll_s``, as does ``idle_timeout_s`` without a message passed on; :meth:`close` then
    releases files and sockets (idempotent). ``lossless``: its messages are files already written
    (a folder of frames, a JSON-lines file), read at the engine's pace and never dropped as stale."""

    lossless = False

    def __init__(self, *, stats: StreamStats | None = None, poll_s: float = POLL_S,
                 max_message_bytes: int = MAX_MESSAGE_BYTES, idle_timeout_s: float | None = None) -> None:
        self.stats = stats if stats is not None else StreamStats()
        self.poll_s, self.max_message_bytes, self.idle_timeout_s = poll_s, max_message_bytes, idle_timeout_s
        self._stop = threading.Event()
        self._limiter: _Limiter | None = None   # network sources: messages per sender
        self._last_message_s = time.monotonic()

    def __iter__(self) -> Iterator[RawMessage]:
        """Messages in arrival order until the input ends, :meth:`stop` is called or the idle timeout passes."""
        self._last_message_s = time.monotonic()
        for item in self._poll():
            if item is not None:
                self._last_message_s = item.arrival_s
                yield item
            elif self._stop.is_set() or self._idle():
                return

    @abstractmethod
    def _poll(self) -> Iterator[RawMessage | None]:
        """Messages, and None at least every ``poll_s`` (where stop and idle timeout are checked)."""

    def _idle(self) -> bool:
        return self.idle_timeout_s is not None and time.monotonic() - self._last_message_s > self.idle_timeout_s

    def stop(self) -> None:
        """Makes a running iteration end soon; thread-safe."""
        self._stop.set()

    def close(self) -> None:
        """Stops and releases the source; call once no thread iterates it any more."""
        self.stop()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _message(self, raw: bytes, origin: str, sender: str | None = None) -> RawMessage | None:
        """A message from raw bytes, or None for a blank one, one over ``sender``'s rate or an
        undecodable one (the last two counted)."""
        raw = raw.strip()
        if not raw:
            return None
        if self._limiter is not None and sender is not None and not self._limiter.allow(sender):
            self.stats.add(rate_limited=1)
            return None
        try:
            payload = raw.decode("utf-8")
        except UnicodeDecodeError:
            self.stats.add(decode_errors=1)
            return None
        self.stats.add(messages_in=1)
        return RawMessage(payload, origin, time.monotonic())

    def _lines(self, lines: list[tuple[int, bytes]], name: str, sender: str | None = None) -> Iterator[RawMessage]:
        for line_no, raw in lines:
            if (msg := self._message(raw, f"{name}:line {line_no}", sender)) is not None:
                yield msg
