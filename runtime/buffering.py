"""The drop-oldest buffer between a producer thread and the live loop (see :mod:`mocapdb.runtime.streams`).

:class:`BufferedThread` runs a producer in a background thread behind a small buffer; when the
consumer falls behind, the oldest item is dropped and counted, so a slow engine skips stale frames
instead of falling further and further behind. :class:`LiveInput` does this for a message source;
:class:`~mocapdb.runtime.video_input.VideoDetections` for detected video frames. ``reconstruct``
iterates its source itself and processes every frame.
"""
from __future__ import annotations

import threading
from collections import deque
from collections.abc import Iterator
from typing import Generic, Self, TypeVar

from mocapdb.runtime.source_base import Source
from mocapdb.runtime.stream_types import RawMessage, StreamStats

__all__ = ["BufferedThread", "LiveInput"]

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
