"""Network message sources: a TCP server and a UDP socket (see :mod:`mocapdb.runtime.stream.transport`),
built so that one sender cannot take them down:

- TCP: one thread serves up to ``max_clients`` clients at once through :mod:`selectors` on
  non-blocking sockets, each with its own line splitter; a client that completes no line for
  ``client_timeout_s`` is closed, connections beyond ``max_clients`` are closed at once. Both are
  logged to stderr (at most one line per kind per second) and counted in :class:`StreamStats`.
- TCP and UDP: at most ``max_rate`` messages per second per sender address (its IP, so that more
  connections or ports buy no more), bursts up to one second's worth; the excess is dropped and
  counted (``rate_limited``). With the message size limit and the client limit, the memory a
  source holds is bounded whatever arrives.
- Listening on an address other than loopback prints a warning: there is no authentication.
"""
from __future__ import annotations

import ipaddress
import logging
import selectors
import socket
import time
from collections import OrderedDict
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

from mocapdb.core import domains as D
from mocapdb.runtime.stream.messages import RawMessage, resolve_address
from mocapdb.runtime.stream.source_base import READ_BYTES, LineSplitter, Source

__all__ = ["CLIENT_TIMEOUT_S", "MAX_CLIENTS", "MAX_RATE", "NetworkLimits", "TcpSource", "UdpSource"]

MAX_CLIENTS = 16              # TCP source: simultaneous clients; more are refused
CLIENT_TIMEOUT_S = 30.0       # TCP source: a client without a complete line for this long is closed
MAX_RATE = 1000.0             # TCP/UDP sources: messages per second per sender address
MAX_SENDERS = 4096            # rate limiter: addresses remembered (least recently seen forgotten)
LOG_EVERY_S = 1.0             # at most one stderr line per kind of event per second


LOG = logging.getLogger(__name__)


def log(text: str) -> None:
    """One warning through logging: stderr under the CLI (the live loop's own output goes to the
    sink, often stdout)."""
    LOG.warning(text)


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


def _warn_if_public(host: str, address: tuple[Any, ...]) -> None:
    """Warns on stderr when the bound address is reachable from other machines."""
    try:
        loopback = ipaddress.ip_address(address[0].split("%")[0]).is_loopback
    except ValueError:
        loopback = False
    if not loopback:
        log(f"listening on {host}: anyone on the network can send poses (there is no authentication)")


@dataclass(frozen=True)
class NetworkLimits:
    """What one sender may cost a TCP/UDP source (``max_rate`` None or 0: no rate limit)."""

    max_clients: int = MAX_CLIENTS
    client_timeout_s: float = CLIENT_TIMEOUT_S
    max_rate: float | None = MAX_RATE

    def __post_init__(self) -> None:
        D.MAX_CLIENTS.check(self.max_clients, "max_clients")
        D.CLIENT_TIMEOUT_S.check(self.client_timeout_s, "client_timeout_s")
        D.MAX_RATE_HZ.check_optional(self.max_rate, "max_rate")


@dataclass
class _Client:
    """One TCP connection: its socket, its own line splitter and when it last completed a line."""

    sock: socket.socket
    name: str           # tcp:HOST:PORT, for origins and log lines
    host: str           # rate-limit key: every connection from one address shares a budget
    splitter: LineSplitter
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
        client = _Client(conn, name, peer[0], LineSplitter(self.max_message_bytes, self.stats), time.monotonic())
        self._clients[conn] = client
        self._selector.register(conn, selectors.EVENT_READ, client)

    def _receive(self, client: _Client) -> Iterator[RawMessage]:
        try:
            data = client.sock.recv(READ_BYTES)
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
            splitter = LineSplitter(self.max_message_bytes, self.stats)
            yield from self._lines(splitter.feed(data) + splitter.flush(), f"udp:{peer[0]}:{peer[1]}", peer[0])
            yield None

    def close(self) -> None:
        super().close()
        self._sock.close()
