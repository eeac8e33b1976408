"""Transport for ``mocapdb live`` and ``mocapdb reconstruct``: raw messages in, output lines out.

Sources (:func:`open_source`, in :mod:`mocapdb.runtime.sources`) yield :class:`RawMessage` texts and never
parse them; the caller's parser does. Sinks (:func:`open_sink`, in :mod:`mocapdb.runtime.sinks`) write one
line per call. :class:`LiveInput` runs a source in a background thread behind a small drop-oldest
buffer, so a slow engine skips stale frames instead of falling further and further behind;
``reconstruct`` iterates the source itself and processes every frame. Bad input never raises:
oversized messages, non-UTF-8 payloads, messages over a sender's rate and undelivered output lines
are counted in :class:`StreamStats` and skipped. Blank messages are skipped silently. How a live
source stays up whatever one sender does (concurrent TCP clients, timeouts, rate limits, a cheap
folder watch): :mod:`mocapdb.runtime.sources`.

Choices:

- Folder source, live (``follow=True``): a ``*.json`` file is taken as soon as it parses as JSON, so
  a half-written file is never passed on and a complete one costs no extra poll of latency (a
  size-stability rule would add a poll per frame and still pass on the file of a writer that paused).
  A file that still does not parse once it has not changed for ``settle_s`` is passed on anyway,
  for the parser to report rather than have it vanish. Files go out in frame order: a file not yet
  taken holds back the later ones. Offline (``follow=False``) the folder is complete and every file
  is read at once.
- File sink: truncated at open, then written through line by line. A live user can watch it
  (``tail -f``, another program) and a crash keeps every frame written so far, with at most a final
  partial line; a temporary file renamed at close would show nothing until the end and lose the
  whole session on a crash.
- TCP sink: a sender thread owns the connection, so ``write`` only appends to a bounded queue. Lines
  written while the consumer is unreachable (after a failed connection attempt, until the next
  attempt) are dropped and counted; the sender retries with exponential backoff.
"""
from __future__ import annotations

import threading
from collections import deque
from collections.abc import Iterator
from typing import Generic, Self, TypeVar

from mocapdb.runtime.sinks import MAX_DATAGRAM_BYTES, Sink, open_sink
from mocapdb.runtime.sources import (
    MAX_MESSAGE_BYTES,
    NetworkLimits,
    RawMessage,
    Source,
    StreamSpecError,
    StreamStats,
    open_source,
)

__all__ = ["MAX_DATAGRAM_BYTES", "MAX_MESSAGE_BYTES", "BufferedThread", "LiveInput", "NetworkLimits", "RawMessage",
           "Sink", "Source", "StreamSpecError", "StreamStats", "open_sink", "open_source"]

T = TypeVar("T")


class BufferedThread(Generic[T]):
    """Items of :meth:`_items` produced in a background thread behind a buffer of ``capacity``;
    when it is full the oldest item is dropped and counted (``dropped``, ``stats.dropped_stale``),
    so the consumer always gets the newest and latency stays bounded. Subclasses set their own
    fields, then call :meth:`_start`."""

    def __init__(self, capacity: int, stats: StreamStats, thread_name: str) -> None:
        self.stats, self._capacity, self.dropped = stats, capacity, 0
        self._buffer: deque[T] = deque()
        self._cond = threading.Condition()
        self._ended = False
        self._error: Exception | None = None
        self._thread = threading.Thread(target=self._run, name=thread_name, daemon=True)

    def _items(self) -> Iterator[T]:
        raise NotImplementedError

    def _start(self) -> None:
        self._thread.start()

    def _run(self) -> None:
        try:
            for item in self._items():
                self._put(item)
        except Exception as exc:   # handed to the consumer by get()
            self._error = exc
        finally:
            with self._cond:
                self._ended = True
                self._cond.notify_all()

    def _put(self, item: T) -> None:
        with self._cond:
            if len(self._buffer) >= self._capacity:
                self._buffer.popleft()
                self.dropped += 1
                self.stats.add(dropped_stale=1)
            self._buffer.append(item)
            self._cond.notify()

    def get(self, timeout: float | None = None) -> T | None:
        """The oldest buffered item, waiting up to ``timeout`` s; None on timeout or when
        :attr:`finished`. An error that ended the thread is raised once the buffer is empty."""
        with self._cond:
            self._cond.wait_for(lambda: self._buffer or self._ended, timeout)
            if self._buffer:
                return self._buffer.popleft()
            error, self._error = self._error, None
        if error is not None:
            raise error
        return None

    @property
    def finished(self) -> bool:
        """True once the thread has ended and every buffered item has been taken."""
        with self._cond:
            return self._ended and not self._buffer

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        raise NotImplementedError


class LiveInput(BufferedThread[RawMessage]):
    """Runs a source in a background thread behind a buffer of ``capacity`` messages (see
    :class:`BufferedThread`)."""

    def __init__(self, source: Source, capacity: int = 2) -> None:
        if capacity < 1:
            raise ValueError("capacity must be at least 1")
        super().__init__(capacity, source.stats, "mocapdb-live-input")
        self.source = source
        self._start()

    def _items(self) -> Iterator[RawMessage]:
        return iter(self.source)

    def close(self) -> None:
        """Stops the reader thread, waits for it and closes the source; idempotent."""
        self.source.stop()
        self._thread.join()
        self.source.close()


