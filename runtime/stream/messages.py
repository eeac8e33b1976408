"""What sources, buffers and sinks share (see :mod:`mocapdb.runtime.stream.transport`): the message type,
the counters, the spec error and the ``scheme://HOST:PORT`` parsing of network specs."""
from __future__ import annotations

import socket
import threading
from dataclasses import dataclass
from typing import Any
from urllib.parse import urlsplit

from mocapdb.core.errors import MocapdbError

__all__ = ["RawMessage", "StreamSpecError", "StreamStats", "parse_host_port", "resolve_address"]

_STATS_LOCK = threading.Lock()


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
    not_regular: int = 0        # folder source: *.json entries not regular files (dangling links, FIFOs...), skipped

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


def parse_host_port(spec: str, default_port: int | None = None) -> tuple[str, int]:
    """HOST and PORT of ``scheme://HOST:PORT`` (``scheme://HOST`` too with a ``default_port``);
    StreamSpecError if either is missing or the port is not one."""
    parts = urlsplit(spec)
    form = f"{parts.scheme}://HOST" + ("[:PORT]" if default_port is not None else ":PORT")
    try:
        port = parts.port
    except ValueError:
        raise StreamSpecError(f"{spec}: expected {form}, PORT from 0 to 65535") from None
    port = default_port if port is None else port
    if not parts.hostname or port is None:
        raise StreamSpecError(f"{spec}: expected {form}")
    return parts.hostname, port


def resolve_address(host: str, port: int, kind: socket.SocketKind) -> tuple[socket.AddressFamily, Any]:
    """The first address family and socket address of HOST:PORT."""
    family, _, _, _, address = socket.getaddrinfo(host, port, type=kind)[0]
    return family, address
