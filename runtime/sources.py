"""Message sources for ``mocapdb live`` and ``mocapdb reconstruct`` (see :mod:`mocapdb.runtime.streams`).

Every source yields :class:`RawMessage` texts and never parses them. A live source is built so that
one sender cannot take it down:

- No wait is unbounded: every source looks at its stop flag and its idle timeout at least every
  ``poll_s``, so SIGINT/SIGTERM and ``--idle-timeout`` are honoured whatever the input does.
  ``idle_timeout_s`` counts from the last message passed on (or the start), for every source.
- TCP: one thread serves up to ``max_clients`` clients at once through :mod:`selectors` on
  non-blocking sockets, each with its own line splitter; a client that completes no line for
  ``client_timeout_s`` is closed, connections beyond ``max_clients`` are closed at once. Both are
  logged to stderr (at most one line per kind per second) and counted in :class:`StreamStats`.
- TCP and UDP: at most ``max_rate`` messages per second per sender address (its IP, so that more
  connections or ports buy no more), bursts up to one second's worth; the excess is dropped and
  counted (``rate_limited``). With the message size limit and the client limit, the memory a
  source holds is bounded whatever arrives.
- Listening on an address other than loopback prints a warning: there is no authentication.
- Folder, live: the folder is listed again only when its modification time changed (plus once
  after that time stops being recent, for file systems with coarse time stamps, and every
  ``rescan_s`` as a safety net), and only names not seen before are looked at: an idle folder
  costs one ``stat`` per poll however many files it holds.
"""
from __future__ import annotations

import ipaddress
import json
import os
import re
import select
import selectors
import socket
import stat
import sys
import threading
import time
from abc import ABC, abstractmethod
from collections import OrderedDict
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Self
from urllib.parse import urlsplit

from mocapdb.core.errors import MocapdbError

__all__ = ["CLIENT_TIMEOUT_S", "MAX_CLIENTS", "MAX_MESSAGE_BYTES", "MAX_RATE", "FolderSource",
           "JsonLinesFileSource", "RawMessage", "Source", "StdinSource", "StreamSpecError", "StreamStats",
           "TcpSource", "UdpSource", "open_source"]

MAX_MESSAGE_BYTES = 1 << 20   # longest accepted input message (line, datagram line or file)
POLL_S = 0.02                 # how often waits check for stop, idle timeout and new files
SETTLE_S = 0.5                # folder source: unparsable file passed on after this long unchanged
RESCAN_S = 5.0                # folder source: full listing at least this often, changed or not
RECENT_NS = 2_000_000_000     # folder source: a folder time stamp this recent may hide more entries
MAX_CLIENTS = 16              # TCP source: simultaneous clients; more are refused
CLIENT_TIMEOUT_S = 30.0       # TCP source: a client without a complete line for this long is closed
MAX_RATE = 1000.0             # TCP/UDP sources: messages per second per sender address
MAX_SENDERS = 4096            # rate limiter: addresses remembered (least recently seen forgotten)
LOG_EVERY_S = 1.0             # at most one stderr line per kind of event per second
_READ_BYTES = 1 << 16
_STATS_LOCK = threading.Lock()
_FRAME_RE = re.compile(r"_([0-9]+)_keypoints\.json$")   # OpenPose: <name>_<frame>_keypoints.json
_DIGITS_RE = re.compile(r"([0-9]+)")


class StreamSpecError(MocapdbError, ValueError):
    """A --source or --sink value that names no supported stream."""


@dataclass
class StreamStats:
    """Counters shared by a source, its LiveInput and a sink; update them with :meth:`add`."""

    messages_in: int = 0        # messages passed on to the caller
    dropped_stale: int = 0      # LiveInput: oldest buffered message dropped for a newer one
    oversized: int = 0          # input messages over the size limit, skipped
    decode_errors: int = 0      # input messages that are not UTF-8, skipped
    sink_dropped: int = 0       # output lines not delivered
    reconnects: int = 0         # TCP connections after the first (source: clients; sink: to the consumer)
    rate_limited: int = 0       # input messages over a sender's rate limit, skipped
    clients_refused: int = 0    # TCP source: connections closed because max_clients were connected
    clients_timed_out: int = 0  # TCP source: clients closed after client_timeout_s without a line

    def add(self, **counts: int) -> None:
        """Adds to the named counters; safe from any thread."""
        with _STATS_LOCK:
            for name, n in counts.items():
                setattr(self, name, getattr(self, name) + n)

    def source_report(self) -> str:
        """What the source-side protections dropped, one line; empty if nothing."""
        parts = [f"{label} {n}" for label, n in (("rate-limited messages", self.rate_limited),
                                                  ("TCP clients refused", self.clients_refused),
                                                  ("idle TCP clients closed", self.clients_timed_out)) if n]
        return "source: " + ", ".join(parts) if parts else ""


@dataclass(frozen=True)
class RawMessage:
    """One unparsed message: its text, where it came from (for error messages) and when it arrived."""

    payload: str
    origin: str
    arrival_s: float   # time.monotonic() when read


def log(text: str) -> None:
    """One line on stderr (the live loop's own output goes to the sink, often stdout)."""
    print(text, file=sys.stderr, flush=True)


class _ThrottledLog:
    """Stderr lines by kind, at most one per kind every ``every_s``; the suppressed ones are
    counted in the next line, so a flood of refused connections cannot flood the terminal."""

    def __init__(self, every_s: float = LOG_EVERY_S) -> None:
        self.every_s = every_s
        self._last: dict[str, tuple[float, int]] = {}   # kind -> (last printed, suppressed since)

    def __call__(self, kind: str, text: str) -> None:
        now = time.monotonic()
        last, suppressed = self._last.get(kind, (-self.every_s, 0))
        if now - last < self.every_s:
            self._last[kind] = (last, suppressed + 1)
            return
        self._last[kind] = (now, 0)
        log(text + (f" (and {suppressed} more like it)" if suppressed else ""))


class _RateLimiter:
    """Token bucket per sender: ``rate`` messages per second, bursts up to ``max(rate, 1)``. At
    most ``max_senders`` buckets are kept (least recently used forgotten). ``rate`` None or 0:
    no limit."""

    def __init__(self, rate: float | None, max_senders: int = MAX_SENDERS) -> None:
        self.rate, self.burst, self.max_senders = rate, max(rate or 0.0, 1.0), max_senders
        self._buckets: OrderedDict[str, tuple[float, float]] = OrderedDict()   # sender -> (tokens, when)

    def allow(self, sender: str) -> bool:
        """Takes a token from ``sender``'s bucket; False if it is empty."""
        if not self.rate:
            return True
        now = time.monotonic()
        tokens, then = self._buckets.pop(sender, (self.burst, now))
        tokens = min(self.burst, tokens + (now - then) * self.rate)
        allowed = tokens >= 1.0
        self._buckets[sender] = (tokens - 1.0 if allowed else tokens, now)
        if len(self._buckets) > self.max_senders:
            self._buckets.popitem(last=False)
        return allowed


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
    about ``poll_s``, as does ``idle_timeout_s`` without a message passed on; :meth:`close` then
    releases files and sockets (idempotent)."""

    def __init__(self, *, stats: StreamStats | None = None, poll_s: float = POLL_S,
                 max_message_bytes: int = MAX_MESSAGE_BYTES, idle_timeout_s: float | None = None) -> None:
        self.stats = stats if stats is not None else StreamStats()
        self.poll_s, self.max_message_bytes, self.idle_timeout_s = poll_s, max_message_bytes, idle_timeout_s
        self._stop = threading.Event()
        self._limiter: _RateLimiter | None = None   # network sources: messages per sender
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
    """The ``*.json`` files of a folder, one message each, in frame order (see the module notes of
    :mod:`mocapdb.runtime.streams` and of this module)."""

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
            with os.scandir(self.folder) as entries:
                new = [e.name for e in entries
                       if e.name.endswith(".json") and e.name not in self._known and e.is_file()]
        except OSError:
            return
        if new:
            self._known.update(new)
            self._pending = sorted(self._pending + new, key=_frame_order_key)

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
        (size, mtime); None for a file that vanished or is not a regular file (never blocks on a FIFO)."""
        try:
            fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
        except OSError:
            return None, (0, 0)
        with os.fdopen(fd, "rb") as f:
            st = os.fstat(fd)
            if not stat.S_ISREG(st.st_mode):
                return None, (0, 0)
            return f.read(self.max_message_bytes + 1), (st.st_size, st.st_mtime_ns)

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
        splitter = _LineSplitter(self.max_message_bytes, self.stats)
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
    ``tail -f`` until stopped or the idle timeout passes."""

    def __init__(self, path: Path, *, follow: bool = False, **common: Any) -> None:
        super().__init__(**common)
        self.name, self.follow = str(path), follow
        self._file = open(path, "rb")

    def _read_chunk(self) -> bytes | None:
        if (data := self._file.read(_READ_BYTES)) or not self.follow:
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
            data = self._stream.read(_READ_BYTES)
            return data.encode("utf-8") if isinstance(data, str) else data
        ready, _, _ = select.select([self._fd], [], [], self.poll_s)
        return os.read(self._fd, _READ_BYTES) if ready else None


def resolve_address(host: str, port: int, kind: socket.SocketKind) -> tuple[socket.AddressFamily, Any]:
    """The first address family and socket address of HOST:PORT."""
    family, _, _, _, address = socket.getaddrinfo(host, port, type=kind)[0]
    return family, address


def parse_host_port(spec: str) -> tuple[str, int]:
    """HOST and PORT of ``scheme://HOST:PORT``; StreamSpecError if either is missing."""
    parts = urlsplit(spec)
    try:
        port = parts.port
    except ValueError:
        port = None
    if not parts.hostname or port is None:
        raise StreamSpecError(f"{spec}: expected {parts.scheme}://HOST:PORT")
    return parts.hostname, port


def _warn_if_public(host: str, address: tuple[Any, ...]) -> None:
    """Warns on stderr when the bound address is reachable from other machines."""
    try:
        loopback = ipaddress.ip_address(address[0].split("%")[0]).is_loopback
    except ValueError:
        loopback = False
    if not loopback:
        log(f"warning: listening on {host}: anyone on the network can send poses (there is no authentication)")


@dataclass
class _Client:
    """One TCP connection: its socket, its own line splitter and when it last completed a line."""

    sock: socket.socket
    name: str           # tcp:HOST:PORT, for origins and log lines
    host: str           # rate-limit key: every connection from one address shares a budget
    splitter: _LineSplitter
    last_line_s: float


class TcpSource(Source):
    """Listens on HOST:PORT and reads newline-delimited messages from up to ``max_clients``
    clients at once, in one thread (see the module notes). ``address`` is the bound (host, port)."""

    def __init__(self, host: str, port: int, *, max_clients: int = MAX_CLIENTS,
                 client_timeout_s: float = CLIENT_TIMEOUT_S, max_rate: float | None = MAX_RATE,
                 **common: Any) -> None:
        super().__init__(**common)
        self.max_clients, self.client_timeout_s = max_clients, client_timeout_s
        self._limiter, self._log = _RateLimiter(max_rate), _ThrottledLog()
        family, address = resolve_address(host, port, socket.SOCK_STREAM)
        self._server = socket.create_server(address, family=family, backlog=max_clients)
        self._server.setblocking(False)
        self.address: tuple[str, int] = self._server.getsockname()[:2]
        self._selector = selectors.DefaultSelector()
        self._selector.register(self._server, selectors.EVENT_READ, None)
        self._clients: dict[socket.socket, _Client] = {}
        self._accepted = 0
        _warn_if_public(host, self.address)

    @property
    def client_count(self) -> int:
        """Clients connected now."""
        return len(self._clients)

    def _poll(self) -> Iterator[RawMessage | None]:
        while True:
            for key, _ in self._selector.select(self.poll_s):
                if key.data is None:
                    self._accept()
                else:
                    yield from self._receive(key.data)
            self._close_idle_clients()
            yield None

    def _accept(self) -> None:
        try:
            conn, peer = self._server.accept()
        except OSError:   # gone before we got to it, or out of file descriptors: try again later
            return
        name = f"tcp:{peer[0]}:{peer[1]}"
        if len(self._clients) >= self.max_clients:
            conn.close()
            self.stats.add(clients_refused=1)
            self._log("refused", f"tcp source: refused {name}: {self.max_clients} clients already connected")
            return
        if self._accepted:
            self.stats.add(reconnects=1)
        self._accepted += 1
        conn.setblocking(False)
        client = _Client(conn, name, peer[0], _LineSplitter(self.max_message_bytes, self.stats), time.monotonic())
        self._clients[conn] = client
        self._selector.register(conn, selectors.EVENT_READ, client)

    def _receive(self, client: _Client) -> Iterator[RawMessage]:
        try:
            data = client.sock.recv(_READ_BYTES)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:   # reset by the client: treat as a disconnect
            data = b""
        lines = client.splitter.feed(data) if data else client.splitter.flush()
        if lines:
            client.last_line_s = time.monotonic()
        if not data:
            self._drop(client)
        yield from self._lines(lines, client.name, client.host)

    def _close_idle_clients(self) -> None:
        now = time.monotonic()
        for client in [c for c in self._clients.values() if now - c.last_line_s > self.client_timeout_s]:
            self._drop(client)
            self.stats.add(clients_timed_out=1)
            self._log("idle", f"tcp source: closed {client.name}: no complete line for "
                              f"{self.client_timeout_s:g} s")

    def _drop(self, client: _Client) -> None:
        self._selector.unregister(client.sock)
        del self._clients[client.sock]
        client.sock.close()

    def close(self) -> None:
        super().close()
        for client in list(self._clients.values()):
            self._drop(client)
        self._selector.close()
        self._server.close()


class UdpSource(Source):
    """Binds HOST:PORT; each datagram holds one message or several newline-separated ones, at
    most ``max_rate`` messages per second per sender address. ``address`` is the bound (host, port)."""

    def __init__(self, host: str, port: int, *, max_rate: float | None = MAX_RATE, **common: Any) -> None:
        super().__init__(**common)
        self._limiter = _RateLimiter(max_rate)
        family, address = resolve_address(host, port, socket.SOCK_DGRAM)
        self._sock = socket.socket(family, socket.SOCK_DGRAM)
        self._sock.bind(address)
        self._sock.settimeout(self.poll_s)
        self.address: tuple[str, int] = self._sock.getsockname()[:2]
        _warn_if_public(host, self.address)

    def _poll(self) -> Iterator[RawMessage | None]:
        while True:
            try:
                data, peer = self._sock.recvfrom(65535)
            except (TimeoutError, ConnectionResetError):   # the latter: ICMP noise on some systems
                yield None
                continue
            splitter = _LineSplitter(self.max_message_bytes, self.stats)
            yield from self._lines(splitter.feed(data) + splitter.flush(), f"udp:{peer[0]}:{peer[1]}", peer[0])
            yield None

    def close(self) -> None:
        super().close()
        self._sock.close()


@dataclass(frozen=True)
class NetworkLimits:
    """What one sender may cost a TCP/UDP source (``max_rate`` None or 0: no rate limit)."""

    max_clients: int = MAX_CLIENTS
    client_timeout_s: float = CLIENT_TIMEOUT_S
    max_rate: float | None = MAX_RATE

    def __post_init__(self) -> None:
        if self.max_clients < 1 or self.client_timeout_s <= 0 or (self.max_rate or 0) < 0:
            raise StreamSpecError("max clients must be at least 1, the client timeout positive and the "
                                  "maximum rate not negative")


def open_source(spec: str, *, stats: StreamStats | None = None, follow: bool = False,
                idle_timeout_s: float | None = None, settle_s: float = SETTLE_S, poll_s: float = POLL_S,
                max_message_bytes: int = MAX_MESSAGE_BYTES, limits: NetworkLimits | None = None) -> Source:
    """The source named by ``spec``: a folder of ``*.json`` files, a ``.jsonl``/``.ndjson`` file,
    ``-`` (stdin), ``tcp://HOST:PORT`` (listen) or ``udp://HOST:PORT`` (bind). ``follow`` applies
    to folders and files (live: wait for more; offline: stop at the end); ``idle_timeout_s`` to
    every source; ``limits`` to TCP and UDP."""
    if idle_timeout_s is not None and idle_timeout_s <= 0:
        raise StreamSpecError("the idle timeout must be positive")
    common: dict[str, Any] = {"stats": stats, "poll_s": poll_s, "max_message_bytes": max_message_bytes,
                              "idle_timeout_s": idle_timeout_s}
    limits = limits or NetworkLimits()
    if spec.startswith("tcp://"):
        return TcpSource(*parse_host_port(spec), max_clients=limits.max_clients,
                         client_timeout_s=limits.client_timeout_s, max_rate=limits.max_rate, **common)
    if spec.startswith("udp://"):
        return UdpSource(*parse_host_port(spec), max_rate=limits.max_rate, **common)
    if spec == "-":
        return StdinSource(**common)
    path = Path(spec)
    if path.is_dir():
        return FolderSource(path, follow=follow, settle_s=settle_s, **common)
    if path.suffix.lower() in (".jsonl", ".ndjson"):
        return JsonLinesFileSource(path, follow=follow, **common)
    raise StreamSpecError(
        f"{spec}: not a folder, a .jsonl/.ndjson file, '-', tcp://HOST:PORT or udp://HOST:PORT")
