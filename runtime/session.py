"""The one loop behind `mocapdb reconstruct` and `mocapdb live`: messages → frames → engine → outputs.

``reconstruct`` reads every message of a folder or file in order; ``live`` reads through
:class:`~runtime.streams.LiveInput`, which drops stale messages when the engine falls behind.
Malformed messages are counted by reason and skipped; the summary reports them with frame,
people and track counts, per-frame latency (p50/p99, from a message's arrival to its output line)
and throughput.
"""
from __future__ import annotations

import threading
import time
from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mocapdb.keypoints import KeypointError, KeypointFrame, parse_stream_line

from .engine import Engine
from .output import frame_line, header_line, write_track_bvhs
from .streams import LiveInput, RawMessage, Sink, Source, StreamStats


@dataclass
class SessionSummary:
    """What a session did; :meth:`report` renders it for the terminal."""

    frames: int = 0
    person_frames: int = 0
    tracks: int = 0
    malformed: Counter = field(default_factory=Counter)
    stream: StreamStats = field(default_factory=StreamStats)
    latencies_s: list[float] = field(default_factory=list)
    wall_s: float = 0.0
    bvh_files: list[Path] = field(default_factory=list)

    def report(self) -> str:
        lat = np.array(self.latencies_s) * 1000.0
        p50, p99 = (np.percentile(lat, 50), np.percentile(lat, 99)) if len(lat) else (float("nan"),) * 2
        lines = [f"frames {self.frames}, people {self.person_frames} person-frames, tracks {self.tracks}, "
                 f"BVH files {len(self.bvh_files)}",
                 f"latency p50 {p50:.2f} ms, p99 {p99:.2f} ms; throughput "
                 f"{self.frames / max(self.wall_s, 1e-9):.1f} frames/s over {self.wall_s:.2f} s",
                 f"skipped: stale {self.stream.dropped_stale}, oversized {self.stream.oversized}, "
                 f"not UTF-8 {self.stream.decode_errors}, undelivered output lines {self.stream.sink_dropped}"]
        lines += [f"skipped malformed ({n}): {why}" for why, n in self.malformed.most_common()]
        return "\n".join(lines)


class FrameParser:
    """Messages → frames: numbers frames without an index, keeps the first detected layout."""

    def __init__(self, layout: str | None = None):
        self.layout = layout
        self.next_index = 0

    def __call__(self, message: RawMessage) -> KeypointFrame:
        frame = parse_stream_line(message.payload, self.layout)
        if self.layout is None and frame.people and frame.layout is not None:
            self.layout = frame.layout
        if frame.index < 0:
            frame.index = self.next_index
        self.next_index = frame.index + 1
        return frame


def _short_reason(exc: KeypointError) -> str:
    return str(exc).split(": ", 1)[-1][:120]


class Session:
    """Runs an engine over a message source and writes its outputs."""

    def __init__(self, engine: Engine, sink: Sink, parser: FrameParser, summary: SessionSummary):
        self.engine, self.sink, self.parser, self.summary = engine, sink, parser, summary
        self.started = time.perf_counter()
        self.sink.write(header_line(engine.config.fps))

    def handle(self, message: RawMessage) -> None:
        """Parse, process and write one message; a malformed one is counted and skipped."""
        try:
            frame = self.parser(message)
        except KeypointError as exc:
            self.summary.malformed[_short_reason(exc)] += 1
            return
        self.handle_frame(frame, message.arrival_s)

    def handle_frame(self, frame: KeypointFrame, arrival_s: float) -> None:
        """Process and write one parsed frame that arrived at ``arrival_s`` (time.monotonic)."""
        poses = self.engine.step(frame)
        t_s = frame.time_s if frame.time_s is not None else frame.index / self.engine.config.fps
        self.sink.write(frame_line(frame.index, t_s, poses))
        self.summary.frames += 1
        self.summary.person_frames += len(poses)
        self.summary.latencies_s.append(time.monotonic() - arrival_s)

    def finish(self, bvh_dir: Path | None, bvh_unit: str = "m") -> SessionSummary:
        """End all tracks, write their BVH files (if ``bvh_dir``), close the sink."""
        self.summary.wall_s = time.perf_counter() - self.started
        recordings = self.engine.finish()
        self.summary.tracks = len(recordings)
        if bvh_dir is not None:
            self.summary.bvh_files = write_track_bvhs(recordings, bvh_dir, self.engine.config.fps, bvh_unit)
        self.sink.close()
        return self.summary


def run_offline(session: Session, source: Source) -> None:
    """Every message of a finite source, in order."""
    with source:
        for message in source:
            session.handle(message)


def run_arrays(session: Session, frames: Iterable[KeypointFrame]) -> None:
    """Every frame of a detector's keypoint array (already parsed), in order."""
    for frame in frames:
        session.handle_frame(frame, time.monotonic())


def run_live(session: Session, source: Source, stop: threading.Event, capacity: int = 2) -> None:
    """Messages as they come until the source ends or ``stop`` is set; stale ones are dropped."""
    with LiveInput(source, capacity) as live:
        while not stop.is_set():
            message = live.get(timeout=0.05)
            if message is not None:
                session.handle(message)
            elif live.finished:
                break

