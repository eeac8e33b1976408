"""The one loop behind `mocapdb reconstruct` and `mocapdb live`: messages → frames → engine → outputs.

``reconstruct`` reads every message of a folder or file in order; ``live`` reads through
:class:`~runtime.streams.LiveInput`, which drops stale messages when the engine falls behind.
Malformed messages are counted by reason and skipped; the summary reports them with frame,
people and track counts, per-frame latency (p50/p99, from a message's arrival to its output line)
and throughput.
"""
from __future__ import annotations

import sys
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
    static_tracks: list[int] = field(default_factory=list)  # left out of the BVH output
    gaps: int = 0
    degenerate: int = 0

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
        if self.static_tracks:
            lines.append(f"static tracks (keypoints never moved; no BVH, --keep-static keeps them): "
                         f"{', '.join(map(str, self.static_tracks))}")
        if self.degenerate:
            lines.append(f"people skipped with all keypoints within 4 px (no size, no depth): {self.degenerate}")
        if self.gaps:
            lines.append(f"jumps in time longer than the gap limit (every track ended): {self.gaps}")
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


class InputError(ValueError):
    """Input that contradicts the command's parameters (e.g. keypoints outside --image-size)."""


IMAGE_MARGIN = 0.1  # keypoints may lie this fraction of the image size outside it (detectors extrapolate)


@dataclass
class SessionOptions:
    """What a session does beyond the engine: ``strict`` stops at input that contradicts the
    parameters (reconstruct) instead of skipping and counting it (live); ``fps_given`` says
    whether ``--fps`` was given (else frames without time warn once). With ``bvh_dir`` each
    track's BVH is written (atomically) when the track ends, and every ``checkpoint_s`` seconds
    the open tracks' BVH so far, so a killed process loses at most that much of them."""

    strict: bool = True
    fps_given: bool = True
    keep_static: bool = False
    bvh_dir: Path | None = None
    bvh_unit: str = "m"
    checkpoint_s: float = 30.0


class Session:
    """Runs an engine over a message source and writes its outputs."""

    def __init__(self, engine: Engine, sink: Sink, parser: FrameParser, summary: SessionSummary,
                 options: SessionOptions | None = None):
        self.engine, self.sink, self.parser, self.summary = engine, sink, parser, summary
        self.options = options or SessionOptions()
        self._fps_warned = self.options.fps_given
        self._written = 0  # engine.finished recordings whose BVH is written
        self.started = self._checkpointed = time.perf_counter()
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
        problem = self._contradiction(frame)
        if problem:
            if self.options.strict:
                raise InputError(problem)
            self.summary.malformed["keypoints outside --image-size"] += 1
            return
        poses = self.engine.step(frame)
        t_s = frame.time_s if frame.time_s is not None else frame.index / self.engine.config.fps
        self.sink.write(frame_line(frame.index, t_s, poses))
        self.summary.frames += 1
        self.summary.person_frames += len(poses)
        self.summary.latencies_s.append(time.monotonic() - arrival_s)
        if self.options.bvh_dir is not None:
            self._write_bvhs()

    def _write_bvhs(self) -> None:
        """BVH files of the tracks that ended; every ``checkpoint_s``, of the open ones so far."""
        ended = self.engine.finished[self._written:]
        self._written = len(self.engine.finished)
        self._write(ended)
        if time.perf_counter() - self._checkpointed >= self.options.checkpoint_s:
            self._checkpointed = time.perf_counter()
            self._write([r for r in self.engine.open_recordings() if not r.static])

    def _write(self, recordings: list) -> None:
        keep = [r for r in recordings if self.options.keep_static or not r.static]
        self.summary.bvh_files += write_track_bvhs(keep, self.options.bvh_dir, self.engine.config.fps,
                                                   self.options.bvh_unit)

    def _contradiction(self, frame: KeypointFrame) -> str | None:
        """Why ``frame`` contradicts the parameters, or None; warns once about an assumed rate."""
        if frame.time_s is None and not self._fps_warned:
            self._fps_warned = True
            print(f"warning: the input carries no timestamps and no --fps was given: assuming "
                  f"{self.engine.config.fps:g} fps (BVH frame time 1/{self.engine.config.fps:g} s)", file=sys.stderr)
        width, height = self.engine.config.image_size
        for person in frame.people:
            seen = person.points_px[person.confidence >= self.engine.config.confidence_threshold]
            if len(seen) == 0:
                continue
            lo, hi = seen.min(axis=0), seen.max(axis=0)
            if lo.min() >= -IMAGE_MARGIN * min(width, height) and hi[0] <= (1 + IMAGE_MARGIN) * width \
                    and hi[1] <= (1 + IMAGE_MARGIN) * height:
                continue
            hint = ""
            if hi[0] <= (1 + IMAGE_MARGIN) * height and hi[1] <= (1 + IMAGE_MARGIN) * width:
                hint = f"; is the image {height}x{width} (width x height)?"
            return (f"frame {frame.index}: keypoints reach x = {hi[0]:.0f} px, y = {hi[1]:.0f} px in an image "
                    f"said to be {width}x{height} by --image-size{hint}")
        return None

    def finish(self, bvh_dir: Path | None = None, bvh_unit: str | None = None) -> SessionSummary:
        """End all tracks, write the BVH files not yet written (into ``bvh_dir`` if given, else the
        options'; static tracks only with ``keep_static``), close the sink (even if writing fails)."""
        self.summary.wall_s = time.perf_counter() - self.started
        if bvh_dir is not None and Path(bvh_dir) != self.options.bvh_dir:
            self.options.bvh_dir, self._written = Path(bvh_dir), 0
        if bvh_unit is not None:
            self.options.bvh_unit = bvh_unit
        try:
            recordings = self.engine.finish()
            self.summary.tracks = len(recordings)
            self.summary.gaps = self.engine.stats.gaps
            self.summary.degenerate = self.engine.stats.degenerate_people
            self.summary.static_tracks = [r.track for r in recordings if r.static]
            if self.options.bvh_dir is not None:
                self._write_bvhs()
                self._drop_static_checkpoints()
                self.summary.bvh_files = list(dict.fromkeys(self.summary.bvh_files))
        finally:
            self.sink.close()
        return self.summary

    def _drop_static_checkpoints(self) -> None:
        """A track found static at its end loses the BVH a checkpoint wrote while it was open."""
        if self.options.keep_static:
            return
        static = {f"track_{t}.bvh" for t in self.summary.static_tracks}
        for path in [p for p in self.summary.bvh_files if p.name in static]:
            path.unlink(missing_ok=True)
            self.summary.bvh_files.remove(path)


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

