"""Output sinks for ``mocapdb live`` and ``mocapdb reconstruct`` (see :mod:`mocapdb.runtime.stream.transport`): one
line per :meth:`Sink.write`; an unreachable consumer is counted, never raised and never waited for.

Choices:

- File sink: truncated at open, then written through line by line. A live user can watch it
  (``tail -f``, another program) and a crash keeps every frame written so far, with at most a final
  partial line; a temporary file renamed at close would show nothing until the end and lose the
  whole session on a crash.
- TCP sink: a sender thread owns the connection, so ``write`` only appends to a bounded queue. Lines
  written while the consumer is unreachable (after a failed connection attempt, until the next
  attempt) are dropped and counted; the sender retries with exponential backoff.
"""
from __future__ import annotations

import socket
import sys
import threading
from abc import ABC, abstractmethod
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import Self

from mocapdb.core.outputs import PersonPose, frame_line
from mocapdb.runtime.stream.messages import StreamStats, resolve_address

__all__ = ["MAX_DATAGRAM_BYTES", "FileSink", "Sink", "StdoutSink", "TcpSink", "TeeSink", "UdpSink"]

MAX_DATAGRAM_BYTES = 60_000   # longest UDP sink datagram; longer lines are dropped


class Sink(ABC):
    """Writes one output line per :meth:`write`; an unreachable consumer is counted
    (``sink_dropped``), never raised and never waited for. ``on_sent`` (:meth:`notify_sent`) is told
    each frame's index the moment its output left the sink (the session's latency)."""

    def __init__(self, stats: StreamStats | None = None) -> None:
        self.stats = stats if stats is not None else StreamStats()
        self.on_sent: Callable[[int], None] | None = None

    def notify_sent(self, callback: Callable[[int], None]) -> None:
        """Calls ``callback(frame_index)`` as each frame's output leaves the sink (from any thread)."""
        self.on_sent = callback

    def _sent(self, frame_index: int) -> None:
        """Frame ``frame_index``'s output left the sink now."""
        if self.on_sent is not None:
            self.on_sent(frame_index)

    def write(self, line: str) -> None:
        """Writes ``line`` and a newline; ``line`` itself must not contain one."""
        if "\n" in line:
            raise ValueError("a sink line must not contain a newline")
        self._put(line + "\n")

    def write_frame(self, frame_index: int, time_s: float, people: list[PersonPose]) -> None:
        """Writes one frame's people; the line sinks write its JSON line (:func:`frame_line`), the
        avatar sinks (:mod:`mocapdb.runtime.stream.osc_sinks`) send it in their protocol."""
        self.write(frame_line(frame_index, time_s, people))
        self._sent(frame_index)

    @abstractmethod
    def _put(self, text: str) -> None:
        """Delivers one newline-terminated line."""

    @abstractmethod
    def close(self) -> None:
        """Flushes and releases the sink; idempotent."""

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class TeeSink(Sink):
    """Every line and frame to each of ``sinks`` in turn (each in its own way: a line sink its JSON
    line, an avatar sink its protocol); counts in the first one's stats, and a frame is sent when the
    first one sent it. :meth:`close` closes them all, then raises the first error any raised."""

    def __init__(self, sinks: list[Sink]) -> None:
        super().__init__(sinks[0].stats)
        self.sinks = sinks

    def notify_sent(self, callback: Callable[[int], None]) -> None:
        self.sinks[0].notify_sent(callback)

    def _put(self, text: str) -> None:
        for sink in self.sinks:
            sink.write(text[:-1])

    def write_frame(self, frame_index: int, time_s: float, people: list[PersonPose]) -> None:
        for sink in self.sinks:
            sink.write_frame(frame_index, time_s, people)

    def close(self) -> None:
        errors = []
        for sink in self.sinks:
            try:
                sink.close()
            except OSError as exc:
                errors.append(exc)
        if errors:
            raise errors[0]


class StdoutSink(Sink):
    """Standard output, flushed after every line."""

    def _put(self, text: str) -> None:
        sys.stdout.write(text)
        sys.stdout.flush()

    def close(self) -> None:
        sys.stdout.flush()


class FileSink(Sink):
    """A file truncated at open and written through line by line (see the module notes)."""

    def __init__(self, path: Path, stats: StreamStats | None = None) -> None:
        super().__init__(stats)
        self._file = open(path, "w", encoding="utf-8", newline="\n", buffering=1)

    def _put(self, text: str) -> None:
        self._file.write(text)

    def close(self) -> None:
        self._file.close()


class TcpSink(Sink):
    """Connects to a consumer listening on HOST:PORT. A sender thread owns the connection; ``write``
    only queues (at most ``queue_lines``, the oldest dropped first). Lines queued when a connection
    attempt fails or a send fails, and lines written until the next attempt, are dropped and
    counted; attempts are retried after ``backoff_s[0]`` s, doubling up to ``backoff_s[1]``.
    :meth:`close` sends what is queued (bounded by ``send_timeout_s``) before closing."""

    def __init__(self, host: str, port: int, stats: StreamStats | None = None, *, queue_lines: int = 1024,
                 connect_timeout_s: float = 1.0, send_timeout_s: float = 1.0,
                 backoff_s: tuple[float, float] = (0.05, 2.0)) -> None:
        super().__init__(stats)
        self._address = (host, port)
        self._connect_timeout_s, self._send_timeout_s = connect_timeout_s, send_timeout_s
        self._backoff_s = backoff_s
        self._queue: deque[tuple[str, int | None]] = deque(maxlen=queue_lines)   # (line, frame index)
        self._cond = threading.Condition()
        self._accepting = True   # False from a failed attempt until the next one
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="mocapdb-tcp-sink", daemon=True)
        self._thread.start()

    def _put(self, text: str, frame_index: int | None = None) -> None:
        with self._cond:
            if not self._accepting:
                self.stats.add(sink_dropped=1)
                return
            if len(self._queue) == self._queue.maxlen:
                self.stats.add(sink_dropped=1)   # append() pushes the oldest line out
            self._queue.append((text, frame_index))
            self._cond.notify()

    def write_frame(self, frame_index: int, time_s: float, people: list[PersonPose]) -> None:
        """Queues the frame's JSON line; it is sent (:meth:`_sent`) when the sender thread sends it."""
        self._put(frame_line(frame_index, time_s, people) + "\n", frame_index)

    def _set_accepting(self, accepting: bool) -> None:
        with self._cond:
            self._accepting = accepting
            if not accepting:
                self.stats.add(sink_dropped=len(self._queue))
                self._queue.clear()

    def _run(self) -> None:
        delay, connected_before = self._backoff_s[0], False
        while not self._stop.is_set():
            self._set_accepting(True)
            if (sock := self._connect()) is None:
                self._set_accepting(False)
                self._stop.wait(delay)
                delay = min(2 * delay, self._backoff_s[1])
                continue
            if connected_before:
                self.stats.add(reconnects=1)
            delay, connected_before = self._backoff_s[0], True
            with sock:
                self._pump(sock)
        self._set_accepting(False)

    def _connect(self) -> socket.socket | None:
        try:
            sock = socket.create_connection(self._address, timeout=self._connect_timeout_s)
        except OSError:
            return None
        sock.settimeout(self._send_timeout_s)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)   # one frame per line: no Nagle delay
        return sock

    def _pump(self, sock: socket.socket) -> None:
        """Sends queued lines until a send fails or the sink is closed (after a last drain)."""
        while True:
            with self._cond:
                self._cond.wait_for(lambda: self._queue or self._stop.is_set())
                batch, stopping = list(self._queue), self._stop.is_set()
                self._queue.clear()
            try:
                sock.sendall("".join(text for text, _ in batch).encode("utf-8"))
            except OSError:
                self.stats.add(sink_dropped=len(batch))
                return
            for _, frame_index in batch:
                if frame_index is not None:
                    self._sent(frame_index)
            if stopping:
                return

    def close(self) -> None:
        with self._cond:
            self._stop.set()
            self._cond.notify_all()
        self._thread.join()


class UdpSink(Sink):
    """Sends each line as one datagram to HOST:PORT; lines over ``MAX_DATAGRAM_BYTES`` and failed
    sends are dropped and counted. Never blocks."""

    def __init__(self, host: str, port: int, stats: StreamStats | None = None) -> None:
        super().__init__(stats)
        family, self._address = resolve_address(host, port, socket.SOCK_DGRAM)
        self._sock = socket.socket(family, socket.SOCK_DGRAM)
        self._sock.setblocking(False)

    def _put(self, text: str) -> None:
        data = text.encode("utf-8")
        if len(data) > MAX_DATAGRAM_BYTES:
            self.stats.add(sink_dropped=1)
            return
        try:
            self._sock.sendto(data, self._address)
        except OSError:
            self.stats.add(sink_dropped=1)

    def close(self) -> None:
        self._sock.close()
