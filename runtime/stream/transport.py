"""Transport for ``mocapdb live`` and ``mocapdb reconstruct``: raw messages in, output lines out.

This is the one import path for users of the streams: :func:`open_source` and :func:`open_sink`
turn a ``--source``/``--sink`` value into a source or a sink, and every public name of the modules
below is re-exported here.

- Sources yield :class:`RawMessage` texts and never parse them; the caller's parser does. The base
  class and line splitting: :mod:`~mocapdb.runtime.stream.source_base`; folder, ``.jsonl`` file and stdin:
  :mod:`~mocapdb.runtime.stream.sources`; TCP and UDP, with what keeps them up whatever one sender does
  (concurrent clients, timeouts, rate limits): :mod:`~mocapdb.runtime.stream.net_sources`.
- Sinks (:mod:`~mocapdb.runtime.stream.sinks`) write one line per call; the avatar sinks
  (:mod:`~mocapdb.runtime.stream.osc_sinks`) send one person per frame as OSC (VMC protocol, VRChat).
- :class:`LiveInput` (:mod:`~mocapdb.runtime.stream.buffering`) runs a source in a background thread
  behind a small drop-oldest buffer, so a slow engine skips stale frames instead of falling further
  and further behind; ``reconstruct`` iterates the source itself and processes every frame.
- Bad input never raises: oversized messages, non-UTF-8 payloads, messages over a sender's rate,
  folder entries that are not regular files and undelivered output lines are counted in
  :class:`StreamStats` (:mod:`~mocapdb.runtime.stream.messages`) and skipped. Blank messages are
  skipped silently.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

from mocapdb.runtime.stream.buffering import BufferedThread, LiveInput
from mocapdb.runtime.stream.messages import RawMessage, StreamSpecError, StreamStats, parse_host_port
from mocapdb.runtime.stream.net_sources import (
    CLIENT_TIMEOUT_S,
    MAX_CLIENTS,
    MAX_RATE,
    NetworkLimits,
    TcpSource,
    UdpSource,
)
from mocapdb.runtime.stream.osc_sinks import VMC_PORT, VRCHAT_PORT, VmcSink, VrchatSink
from mocapdb.runtime.stream.sinks import MAX_DATAGRAM_BYTES, FileSink, Sink, StdoutSink, TcpSink, TeeSink, UdpSink
from mocapdb.runtime.stream.source_base import MAX_MESSAGE_BYTES, POLL_S, Source
from mocapdb.runtime.stream.sources import SETTLE_S, FolderSource, JsonLinesFileSource, StdinSource

__all__ = ["CLIENT_TIMEOUT_S", "MAX_CLIENTS", "MAX_DATAGRAM_BYTES", "MAX_MESSAGE_BYTES", "MAX_RATE", "POLL_S",
           "SETTLE_S", "BufferedThread", "FileSink", "FolderSource", "JsonLinesFileSource", "LiveInput",
           "NetworkLimits", "RawMessage", "Sink", "Source", "StdinSource", "StdoutSink", "StreamSpecError",
           "StreamStats", "TcpSink", "TcpSource", "TeeSink", "UdpSink", "UdpSource", "VmcSink", "VrchatSink",
           "check_sink", "open_sink", "open_source"]


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


def check_sink(spec: str, vmc_track: int | None = None) -> None:
    """StreamSpecError when the options of :func:`open_sink` do not go together (before any work)."""
    if vmc_track is not None and not spec.startswith("vmc://"):
        raise StreamSpecError(f"--vmc-track {vmc_track} needs a vmc://HOST[:PORT] sink, not {spec}")


def open_sink(spec: str, stats: StreamStats | None = None, vmc_track: int | None = None) -> Sink:
    """The sink named by ``spec``: ``-`` (stdout), ``tcp://HOST:PORT`` (connect to a listening
    consumer), ``udp://HOST:PORT``, ``vmc://HOST[:PORT]`` (an avatar in the VMC protocol, port 39539 by
    default; ``vmc_track``: the track it follows, default the main one), ``vrchat://HOST[:PORT]``
    (VRChat's OSC trackers, port 9000 by default) or a file path."""
    check_sink(spec, vmc_track)
    if spec.startswith("vmc://"):
        return VmcSink(*parse_host_port(spec, VMC_PORT), stats, vmc_track)
    if spec.startswith("vrchat://"):
        return VrchatSink(*parse_host_port(spec, VRCHAT_PORT), stats)
    if spec == "-":
        return StdoutSink(stats)
    if spec.startswith("tcp://"):
        return TcpSink(*parse_host_port(spec), stats)
    if spec.startswith("udp://"):
        return UdpSink(*parse_host_port(spec), stats)
    return FileSink(Path(spec), stats)
