"""The drop-oldest buffer between a producer thread and the live loop (see :mod:`mocapdb.runtime.stream.transport`).

:class:`BufferedThread` runs a producer in a background thread behind a small buffer; when the
consumer falls behind, the oldest item is dropped and counted, so a slow engine skips stale frames
instead of falling further and further behind. A lossless buffer makes the producer wait instead:
files already on disk (a folder of frames, a JSON-lines file) are read at the engine's pace and
none is dropped (:attr:`~mocapdb.runtime.stream.source_base.Source.lossless`). :class:`LiveInput` does
this for a message source; :class:`~mocapdb.runtime.stream.video_input.VideoDetections` for detected video
frames. ``reconstruct``
iterates its source itself and processes every frame.
"""
from __future__ import annotations

import threading
from collections import deque
from collections.abc import Iterator
from typing import Generic, Self, TypeVar

from mocapdb.runtime.stream.messages import RawMessage, StreamStats
from mocapdb.runtime.stream.source_base import Source

__all__ = ["BufferedThread", "LiveInput"]

T = TypeVar("T")


class BufferedThread(Generic[T]):
    """Items of :meth:`_items` produced in a background thread behind a buffer of ``capacity``;
    when it is full the oldest item is dropped and counted (``dropped``, ``stats.dropped_stale``),
    so the consumer always gets the newest and latency stays bounded; or, ``lossless``, the
    producer waits for room. Subclasses set their own fields, then call :meth:`_start`, and call
    :meth:`_release` before joining the thread."""

    def __init__(self, capacity: int, stats: StreamStats, thread_name: str, lossless: bool = False) -> None:
        self.stats, self._capacity, self.dropped, self.lossless = stats, capacity, 0, lossless
        self._buffer: deque[T] = deque()
        self._cond = threading.Condition()
        self._ended = self._released = False
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
            if self.lossless:
                self._cond.wait_for(lambda: len(self._buffer) < self._capacity or self._released)
                if self._released:
                    return
            elif len(self._buffer) >= self._capacity:
                self._buffer.popleft()
                self.dropped += 1
                self.stats.add(dropped_stale=1)
            self._buffer.append(item)
            self._cond.notify_all()

    def _release(self) -> None:
        """Let a producer waiting for room go (the consumer stops taking items)."""
        with self._cond:
            self._released = True
            self._cond.notify_all()

    def get(self, timeout: float | None = None) -> T | None:
        """The oldest buffered item, waiting up to ``timeout`` s; None on timeout or when
        :attr:`finished`. An error that ended the thread is raised once the buffer is empty."""
        with self._cond:
            self._cond.wait_for(lambda: self._buffer or self._ended, timeout)
            if self._buffer:
                item = self._buffer.popleft()
                self._cond.notify_all()  # room for a lossless producer
                return item
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
    :class:`BufferedThread`): lossless for a source of files already written (``source.lossless``)."""

    def __init__(self, source: Source, capacity: int = 2) -> None:
        if capacity < 1:
            raise ValueError("capacity must be at least 1")
        super().__init__(capacity, source.stats, "mocapdb-live-input", lossless=source.lossless)
        self.source = source
        self._start()

    def _items(self) -> Iterator[RawMessage]:
        return iter(self.source)

    def close(self) -> None:
        """Stops the reader thread, waits for it and closes the source; idempotent."""
        self.source.stop()
        self._release()
        self._thread.join()
        self.source.close()
