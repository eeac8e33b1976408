"""Transport for ``mocapdb live`` and ``mocapdb reconstruct``: raw messages in, output lines out.

Sources (:func:`open_source`) yield :class:`RawMessage` texts and never parse them; the caller's
parser does. Sinks (:func:`open_sink`) write one line per call. :class:`LiveInput` runs a source in a
background thread behind a small drop-oldest buffer, so a slow engine skips stale frames instead of
falling further and further behind; ``reconstruct`` iterates the source itself and processes every
frame. Bad input never raises: oversized messages, non-UTF-8 payloads and undelivered output lines
are counted in :class:`StreamStats` and skipped. Blank messages are skipped silently.

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

import json
import os
import re
import select
import signal
import socket
import sys
import threading
import time
from abc import ABC, abstractmethod
from collections import deque
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Generic, Self, TypeVar
from urllib.parse import urlsplit

__all__ = ["MAX_DATAGRAM_BYTES", "MAX_MESSAGE_BYTES", "BufferedThread", "LiveInput", "RawMessage", "Sink", "Source",
           "StreamSpecError", "StreamStats", "install_stop_handlers", "open_sink", "open_source"]

T = TypeVar("T")
MAX_MESSAGE_BYTES = 1 << 20   # longest accepted input message (line or file)
MAX_DATAGRAM_BYTES = 60_000   # longest UDP sink datagram; longer lines are dropped
POLL_S = 0.02                 # how often blocking waits check for stop / new files
SETTLE_S = 0.5                # folder source: unparsable file passed on after this long unchanged
_READ_BYTES = 1 << 16
_STATS_LOCK = threading.Lock()
_FRAME_RE = re.compile(r"_([0-9]+)_keypoints\.json$")   # OpenPose: <name>_<frame>_keypoints.json
_DIGITS_RE = re.compile(r"([0-9]+)")


class StreamSpecError(ValueError):
    """A --source or --sink value that names no supported stream."""


@dataclass
class StreamStats:
    """Counters shared by a source, its LiveInput and a sink; update them with :meth:`add`."""

    messages_in: int = 0     # messages passed on to the caller
    dropped_stale: int = 0   # LiveInput: oldest buffered message dropped for a newer one
    oversized: int = 0       # input messages over the size limit, skipped
    decode_errors: int = 0   # input messages that are not UTF-8, skipped
    sink_dropped: int = 0    # output lines not delivered
    reconnects: int = 0      # TCP connections after the first (source: clients; sink: to the consumer)

    def add(self, **counts: int) -> None:
        """Adds to the named counters; safe from any thread."""
        with _STATS_LOCK:
            for name, n in counts.items():
                setattr(self, name, getattr(self, name) + n)


@dataclass(frozen=True)
class RawMessage:
    """One unparsed message: its text, where it came from (for error messages) and when it arrived."""

    payload: str
    origin: str
    arrival_s: float   # time.monotonic() when read


class _LineSplitter:
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
    about ``poll_s``; :meth:`close` then releases files and sockets (idempotent)."""

    def __init__(self, *, stats: StreamStats | None = None, poll_s: float = POLL_S,
                 max_message_bytes: int = MAX_MESSAGE_BYTES) -> None:
        self.stats = stats if stats is not None else StreamStats()
        self.poll_s, self.max_message_bytes = poll_s, max_message_bytes
        self._stop = threading.Event()

    @abstractmethod
    def __iter__(self) -> Iterator[RawMessage]:
        """Messages in arrival order until the input ends or :meth:`stop` is called."""

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

    def _message(self, raw: bytes, origin: str) -> RawMessage | None:
        """A message from raw bytes, or None (counted if not UTF-8) for a blank or undecodable one."""
        raw = raw.strip()
        if not raw:
            return None
        try:
            payload = raw.decode("utf-8")
        except UnicodeDecodeError:
            self.stats.add(decode_errors=1)
            return None
        self.stats.add(messages_in=1)
        return RawMessage(payload, origin, time.monotonic())

    def _lines(self, lines: list[tuple[int, bytes]], name: str) -> Iterator[RawMessage]:
        for line_no, raw in lines:
            if (msg := self._message(raw, f"{name}:line {line_no}")) is not None:
                yield msg


def _frame_order_key(name: str) -> tuple[int, int, tuple[Any, ...]]:
    """OpenPose frame number when the name has one, else natural order (f2 before f10)."""
    natural = tuple(int(t) if i % 2 else t.lower() for i, t in enumerate(_DIGITS_RE.split(name)))
    match = _FRAME_RE.search(name)
    return (0, int(match.group(1)), natural) if match else (1, 0, natural)


def _is_json(data: bytes) -> bool:
    try:
        json.loads(data.decode("utf-8"))
    except (ValueError, RecursionError):
        return False
    return True


class FolderSource(Source):
    """The ``*.json`` files of a folder, one message each, in frame order (see the module notes)."""

    def __init__(self, folder: Path, *, follow: bool = False, idle_timeout_s: float | None = None,
                 settle_s: float = SETTLE_S, **common: Any) -> None:
        super().__init__(**common)
        self.folder, self.follow = folder, follow
        self.idle_timeout_s, self.settle_s = idle_timeout_s, settle_s
        self._taken: set[str] = set()
        self._unsettled: dict[str, tuple[tuple[int, int], float]] = {}   # name -> (size, mtime), since

    def __iter__(self) -> Iterator[RawMessage]:
        if not self.follow:
            for path in self._new_files():
                if (data := self._read(path)) is not None and (msg := self._emit(path, data)):
                    yield msg
            return
        last_new = time.monotonic()
        while not self._stop.is_set():
            for path in self._new_files():
                if (data := self._take(path)) is None:
                    break   # later frames wait for this one
                last_new = time.monotonic()
                if msg := self._emit(path, data):
                    yield msg
            if self.idle_timeout_s is not None and time.monotonic() - last_new > self.idle_timeout_s:
                return
            self._stop.wait(self.poll_s)

    def _new_files(self) -> list[Path]:
        with os.scandir(self.folder) as entries:
            names = [e.name for e in entries
                     if e.name.endswith(".json") and e.name not in self._taken and e.is_file()]
        return [self.folder / name for name in sorted(names, key=_frame_order_key)]

    def _read(self, path: Path) -> bytes | None:
        """At most one byte over the limit (enough to tell it is oversized); None if it vanished."""
        try:
            with open(path, "rb") as f:
                return f.read(self.max_message_bytes + 1)
        except FileNotFoundError:
            return None

    def _take(self, path: Path) -> bytes | None:
        """The file's bytes once it parses as JSON or has not changed for ``settle_s``, else None."""
        try:
            st = path.stat()
        except FileNotFoundError:
            return None
        if (data := self._read(path)) is None or _is_json(data):
            return data
        now, signature = time.monotonic(), (st.st_size, st.st_mtime_ns)
        seen = self._unsettled.get(path.name)
        if seen is None or seen[0] != signature:
            self._unsettled[path.name] = (signature, now)
            return None
        return data if now - seen[1] >= self.settle_s else None

    def _emit(self, path: Path, data: bytes) -> RawMessage | None:
        self._taken.add(path.name)
        self._unsettled.pop(path.name, None)
        if len(data) > self.max_message_bytes:
            self.stats.add(oversized=1)
            return None
        return self._message(data, str(path))


class _ByteStreamSource(Source):
    """Newline-delimited messages from a byte stream that the subclass reads in chunks."""

    name: str

    def __iter__(self) -> Iterator[RawMessage]:
        splitter = _LineSplitter(self.max_message_bytes, self.stats)
        while not self._stop.is_set():
            data = self._read_chunk()
            if data is None:
                continue
            if not data:
                yield from self._lines(splitter.flush(), self.name)
                return
            yield from self._lines(splitter.feed(data), self.name)

    @abstractmethod
    def _read_chunk(self) -> bytes | None:
        """Next bytes; b"" at the end of the stream, None if nothing arrived within about a poll."""


class JsonLinesFileSource(_ByteStreamSource):
    """A ``.jsonl``/``.ndjson`` file, one message per line; with ``follow`` it is tailed like
    ``tail -f`` until stopped or ``idle_timeout_s`` passes without new bytes."""

    def __init__(self, path: Path, *, follow: bool = False, idle_timeout_s: float | None = None,
                 **common: Any) -> None:
        super().__init__(**common)
        self.name, self.follow, self.idle_timeout_s = str(path), follow, idle_timeout_s
        self._file = open(path, "rb")
        self._last_data = time.monotonic()

    def _read_chunk(self) -> bytes | None:
        if data := self._file.read(_READ_BYTES):
            self._last_data = time.monotonic()
            return data
        idle = time.monotonic() - self._last_data
        if not self.follow or (self.idle_timeout_s is not None and idle > self.idle_timeout_s):
            return b""
        self._stop.wait(self.poll_s)
        return None

    def close(self) -> None:
        super().close()
        self._file.close()


class StdinSource(_ByteStreamSource):
    """Standard input, one message per line; ends at end of input. Reads the file descriptor with
    ``select`` so :meth:`stop` works while no input comes; a stream without one (``io.StringIO``)
    is read directly."""

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
            data = self._stream.read(_READ_BYTES)
            return data.encode("utf-8") if isinstance(data, str) else data
        ready, _, _ = select.select([self._fd], [], [], self.poll_s)
        return os.read(self._fd, _READ_BYTES) if ready else None


def _resolve(host: str, port: int, kind: socket.SocketKind) -> tuple[socket.AddressFamily, Any]:
    family, _, _, _, address = socket.getaddrinfo(host, port, type=kind)[0]
    return family, address


class TcpSource(Source):
    """Listens on HOST:PORT and reads newline-delimited messages from one client at a time; when it
    disconnects the next client is accepted. ``address`` is the bound (host, port)."""

    def __init__(self, host: str, port: int, **common: Any) -> None:
        super().__init__(**common)
        family, address = _resolve(host, port, socket.SOCK_STREAM)
        self._server = socket.create_server(address, family=family, backlog=4)
        self._server.settimeout(self.poll_s)
        self.address: tuple[str, int] = self._server.getsockname()[:2]

    def __iter__(self) -> Iterator[RawMessage]:
        clients = 0
        while not self._stop.is_set():
            try:
                conn, peer = self._server.accept()
            except TimeoutError:
                continue
            if clients:
                self.stats.add(reconnects=1)
            clients += 1
            with conn:
                yield from self._receive(conn, f"tcp:{peer[0]}:{peer[1]}")

    def _receive(self, conn: socket.socket, name: str) -> Iterator[RawMessage]:
        conn.settimeout(self.poll_s)
        splitter = _LineSplitter(self.max_message_bytes, self.stats)
        while not self._stop.is_set():
            try:
                data = conn.recv(_READ_BYTES)
            except TimeoutError:
                continue
            except OSError:   # reset by the client: treat as a disconnect
                data = b""
            yield from self._lines(splitter.feed(data) if data else splitter.flush(), name)
            if not data:
                return

    def close(self) -> None:
        super().close()
        self._server.close()


class UdpSource(Source):
    """Binds HOST:PORT; each datagram holds one message or several newline-separated ones.
    ``address`` is the bound (host, port)."""

    def __init__(self, host: str, port: int, **common: Any) -> None:
        super().__init__(**common)
        family, address = _resolve(host, port, socket.SOCK_DGRAM)
        self._sock = socket.socket(family, socket.SOCK_DGRAM)
        self._sock.bind(address)
        self._sock.settimeout(self.poll_s)
        self.address: tuple[str, int] = self._sock.getsockname()[:2]

    def __iter__(self) -> Iterator[RawMessage]:
        while not self._stop.is_set():
            try:
                data, peer = self._sock.recvfrom(65535)
            except (TimeoutError, ConnectionResetError):   # the latter: ICMP noise on some systems
                continue
            splitter = _LineSplitter(self.max_message_bytes, self.stats)
            yield from self._lines(splitter.feed(data) + splitter.flush(), f"udp:{peer[0]}:{peer[1]}")

    def close(self) -> None:
        super().close()
        self._sock.close()


def _host_port(spec: str) -> tuple[str, int]:
    parts = urlsplit(spec)
    try:
        port = parts.port
    except ValueError:
        port = None
    if not parts.hostname or port is None:
        raise StreamSpecError(f"{spec}: expected {parts.scheme}://HOST:PORT")
    return parts.hostname, port


def open_source(spec: str, *, stats: StreamStats | None = None, follow: bool = False,
                idle_timeout_s: float | None = None, settle_s: float = SETTLE_S, poll_s: float = POLL_S,
                max_message_bytes: int = MAX_MESSAGE_BYTES) -> Source:
    """The source named by ``spec``: a folder of ``*.json`` files, a ``.jsonl``/``.ndjson`` file,
    ``-`` (stdin), ``tcp://HOST:PORT`` (listen) or ``udp://HOST:PORT`` (bind). ``follow`` and
    ``idle_timeout_s`` apply to folders and files (live: wait for more; offline: stop at the end)."""
    common: dict[str, Any] = {"stats": stats, "poll_s": poll_s, "max_message_bytes": max_message_bytes}
    if spec.startswith("tcp://"):
        return TcpSource(*_host_port(spec), **common)
    if spec.startswith("udp://"):
        return UdpSource(*_host_port(spec), **common)
    if spec == "-":
        return StdinSource(**common)
    path = Path(spec)
    if path.is_dir():
        return FolderSource(path, follow=follow, idle_timeout_s=idle_timeout_s, settle_s=settle_s, **common)
    if path.suffix.lower() in (".jsonl", ".ndjson"):
        return JsonLinesFileSource(path, follow=follow, idle_timeout_s=idle_timeout_s, **common)
    raise StreamSpecError(
        f"{spec}: not a folder, a .jsonl/.ndjson file, '-', tcp://HOST:PORT or udp://HOST:PORT")


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


class Sink(ABC):
    """Writes one output line per :meth:`write`; an unreachable consumer is counted
    (``sink_dropped``), never raised and never waited for."""

    def __init__(self, stats: StreamStats | None = None) -> None:
        self.stats = stats if stats is not None else StreamStats()

    def write(self, line: str) -> None:
        """Writes ``line`` and a newline; ``line`` itself must not contain one."""
        if "\n" in line:
            raise ValueError("a sink line must not contain a newline")
        self._put(line + "\n")

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
        self._queue: deque[str] = deque(maxlen=queue_lines)
        self._cond = threading.Condition()
        self._accepting = True   # False from a failed attempt until the next one
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="mocapdb-tcp-sink", daemon=True)
        self._thread.start()

    def _put(self, text: str) -> None:
        with self._cond:
            if not self._accepting:
                self.stats.add(sink_dropped=1)
                return
            if len(self._queue) == self._queue.maxlen:
                self.stats.add(sink_dropped=1)   # append() pushes the oldest line out
            self._queue.append(text)
            self._cond.notify()

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
                sock.sendall("".join(batch).encode("utf-8"))
            except OSError:
                self.stats.add(sink_dropped=len(batch))
                return
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
        family, self._address = _resolve(host, port, socket.SOCK_DGRAM)
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


def open_sink(spec: str, stats: StreamStats | None = None) -> Sink:
    """The sink named by ``spec``: ``-`` (stdout), ``tcp://HOST:PORT`` (connect to a listening
    consumer), ``udp://HOST:PORT`` or a file path."""
    if spec == "-":
        return StdoutSink(stats)
    if spec.startswith("tcp://"):
        return TcpSink(*_host_port(spec), stats)
    if spec.startswith("udp://"):
        return UdpSink(*_host_port(spec), stats)
    return FileSink(Path(spec), stats)


@contextmanager
def install_stop_handlers(stop_event: threading.Event) -> Iterator[threading.Event]:
    """Within the block, SIGINT and SIGTERM set ``stop_event`` so the live loop can finish cleanly;
    a second SIGINT while it is set raises KeyboardInterrupt (force quit). The previous handlers
    are restored on exit. Main thread only."""
    if threading.current_thread() is not threading.main_thread():
        raise RuntimeError("signal handlers can only be installed from the main thread")

    def handler(signum: int, _frame: object) -> None:
        if signum == signal.SIGINT and stop_event.is_set():
            raise KeyboardInterrupt
        stop_event.set()

    previous: dict[int, Callable[..., Any] | int] = {}
    try:
        for sig in (signal.SIGINT, signal.SIGTERM):
            old = signal.signal(sig, handler)
            previous[sig] = signal.SIG_DFL if old is None else old
        yield stop_event
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)
