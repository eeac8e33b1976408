"""The one loop behind `mocapdb reconstruct` and `mocapdb live`: messages → frames → engine → outputs.

``reconstruct`` reads every message of a folder or file in order; ``live`` reads through
:class:`~mocapdb.runtime.streams.LiveInput`, which drops stale messages when the engine falls behind.
Malformed messages are counted by reason and skipped; the summary reports them with frame,
people and track counts, per-frame latency (p50/p99, from a message's arrival to its output line),
throughput and what the limits held back. Whatever arrives, memory stays bounded: tracks by
:class:`~mocapdb.runtime.engine_config.TrackLimits`, recordings by BVH parts, the summary's lists by caps.
A sink that fails stops the session (:class:`SinkError`); :meth:`Session.finish` still writes
every BVH file.
"""
from __future__ import annotations

import json
import logging
import queue
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from mocapdb.core import domains as D
from mocapdb.core.errors import MocapdbError
from mocapdb.core.exports import TrackExport, write_track_files
from mocapdb.core.files import write_atomic
from mocapdb.core.formats.keypoints import LAYOUTS, KeypointError, KeypointFrame
from mocapdb.core.formats.openpose import parse_stream_line
from mocapdb.core.outputs import TrackRecording, frame_line, header_line
from mocapdb.core.progress import compile_notice, kernels_cached
from mocapdb.runtime import refine
from mocapdb.runtime.engine import Engine
from mocapdb.runtime.lag import FixedLag
from mocapdb.runtime.streams import LiveInput, RawMessage, Sink, Source, StreamStats
from mocapdb.runtime.subject import chosen, join_fragments, main_track
from mocapdb.runtime.take import fit_take
from mocapdb.runtime.take_params import TakeParams
from mocapdb.runtime.world import fit_world
from mocapdb.runtime.world_summary import track_facts, world_line, world_record

LOG = logging.getLogger(__name__)

MAX_LATENCIES = 100_000  # latency percentiles cover at most the last 2 × this many frames
MAX_REASONS = 50         # distinct malformed-message reasons counted; further ones as "other"
MAX_LISTED = 100         # static track ids listed in the summary


@dataclass
class LimitReport:
    """The limits in force and what they held back (data_specs/stream_output.md, "Limits")."""

    max_tracks: int = 0
    max_new_per_min: int = 0
    max_bvh_files: int = 0
    min_track_s: float = 0.0
    over_max_tracks: int = 0   # detections not tracked
    over_max_new: int = 0      # detections not tracked
    over_max_files: int = 0    # tracks (or parts) without a BVH file
    short_tracks: int = 0      # tracks without a BVH file

    def lines(self) -> list[str]:
        held = [(self.over_max_tracks, f"detections not tracked (--max-tracks {self.max_tracks} alive)"),
                (self.over_max_new, f"detections not tracked (--max-new-tracks-per-min {self.max_new_per_min})"),
                (self.over_max_files, f"tracks or parts without BVH (--max-bvh-files {self.max_bvh_files})"),
                (self.short_tracks, f"tracks without BVH (shorter than --min-track-s {self.min_track_s:g} s)")]
        return [f"limits: {what}: {n}" for n, what in held if n]


@dataclass
class SessionSummary:
    """What a session did; :meth:`report` renders it for the terminal."""

    frames: int = 0
    person_frames: int = 0
    tracks: int = 0
    malformed: Counter = field(default_factory=Counter)
    malformed_first: dict = field(default_factory=dict)  # reason → where it was first seen
    stream: StreamStats = field(default_factory=StreamStats)
    latencies_s: list[float] = field(default_factory=list)
    wall_s: float = 0.0
    bvh_files: list[Path] = field(default_factory=list)
    static_tracks: list[int] = field(default_factory=list)  # left out of the BVH output (first MAX_LISTED)
    n_static: int = 0
    gaps: int = 0
    degenerate: int = 0
    limits: LimitReport = field(default_factory=LimitReport)
    sink_error: str | None = None  # why the sink failed, which stopped the session
    world_lines: list[str] = field(default_factory=list)  # the take's world and each track's size (world_summary)

    def add_latency(self, latency_s: float) -> None:
        self.latencies_s.append(latency_s)
        if len(self.latencies_s) >= 2 * MAX_LATENCIES:
            del self.latencies_s[:MAX_LATENCIES]

    def add_malformed(self, reason: str, origin: str | None = None) -> None:
        if reason not in self.malformed and len(self.malformed) >= MAX_REASONS:
            reason = "other reasons"
        self.malformed[reason] += 1
        if origin and reason not in self.malformed_first:
            self.malformed_first[reason] = origin

    def add_static(self, track: int) -> None:
        self.n_static += 1
        if len(self.static_tracks) < MAX_LISTED:
            self.static_tracks.append(track)

    def _files_by_format(self) -> str:
        """``6 (2 BVH, 2 TRC, 2 CSV)``: the track files written, per format."""
        kinds = Counter(path.suffix.lstrip(".").upper() for path in self.bvh_files)
        per_format = ", ".join(f"{n} {kind}" for kind, n in kinds.items())
        return f"{len(self.bvh_files)}" + (f" ({per_format})" if per_format else "")

    def report(self) -> str:
        lat = np.array(self.latencies_s) * 1000.0
        p50, p99 = (np.percentile(lat, 50), np.percentile(lat, 99)) if len(lat) else (float("nan"),) * 2
        lines = [f"frames {self.frames}, people {self.person_frames} person-frames, tracks {self.tracks}, "
                 f"track files {self._files_by_format()}",
                 f"latency p50 {p50:.2f} ms, p99 {p99:.2f} ms; throughput "
                 f"{self.frames / max(self.wall_s, 1e-9):.1f} frames/s over {self.wall_s:.2f} s",
                 f"skipped: stale {self.stream.dropped_stale}, oversized {self.stream.oversized}, "
                 f"not UTF-8 {self.stream.decode_errors}, undelivered output lines {self.stream.sink_dropped}"
                 + (f", folder entries not regular files {self.stream.not_regular}" if self.stream.not_regular else "")]
        lines += [f"skipped malformed ({n}): {why}" + (f" (first in {self.malformed_first[why]})"
                                                         if why in self.malformed_first else "")
                  for why, n in self.malformed.most_common()]
        if self.static_tracks:
            unlisted = self.n_static - len(self.static_tracks)
            more = f" and {unlisted} more" if unlisted else ""
            lines.append(f"static tracks (keypoints never moved; no BVH, --keep-static keeps them): "
                         f"{', '.join(map(str, self.static_tracks))}{more}")
        if self.degenerate:
            lines.append(f"people skipped with all keypoints within 4 px (no size, no depth): {self.degenerate}")
        if self.gaps:
            lines.append(f"jumps in time longer than the gap limit (every track ended): {self.gaps}")
        lines += self.limits.lines()
        lines += self.world_lines
        if self.sink_error:
            lines.append(f"output stopped: the sink failed ({self.sink_error})")
        return "\n".join(lines)


class FrameParser:
    """Messages → frames: numbers frames without an index. ``layout`` (``--keypoints``) holds for
    every person; without it a person's layout is its own or its line's, else the first one seen
    for its keypoint count (so BODY_25 or BODY_25B is decided once), else detected from that count:
    a stream whose layout changes keeps every frame, and the first change is logged."""

    def __init__(self, layout: str | None = None):
        self.layout = layout
        self.next_index = 0
        self.known: dict[int, str] = {}    # keypoint count → the layout first seen with it
        self.current: str | None = None    # the layout of the last frame with people that shared one
        self.layout_changes = 0

    def __call__(self, message: RawMessage) -> KeypointFrame:
        frame = parse_stream_line(message.payload, self.layout, self.known)
        if frame.index < 0:
            frame.index = self.next_index
        self.next_index = frame.index + 1
        if frame.people and frame.layout is not None:
            self._seen(frame)
        return frame

    def _seen(self, frame: KeypointFrame) -> None:
        self.known.setdefault(len(LAYOUTS[frame.layout]), frame.layout)
        if self.current not in (None, frame.layout):
            if not self.layout_changes:
                LOG.warning("the keypoint layout changed from %s to %s (in frame %d); each frame's layout is "
                            "taken from its own keypoint count (further changes are not logged)",
                            self.current, frame.layout, frame.index)
            self.layout_changes += 1
        self.current = frame.layout


class InputError(MocapdbError, ValueError):
    """Input that contradicts the command's parameters (e.g. keypoints outside --image-size)."""


class SinkError(OSError):
    """The sink could not take a line (disk full, closed pipe): the session stops there."""


IMAGE_MARGIN = 0.1  # keypoints may lie this fraction of the image size outside it (detectors extrapolate)


@dataclass
class SessionOptions:
    """What a session does beyond the engine: ``strict`` stops at input that contradicts the
    parameters (reconstruct) instead of skipping and counting it (live); ``fps_given`` says
    whether ``--fps`` was given (else frames without time warn once). With ``bvh_dir`` each
    track's files (``export``: BVH, TRC, CSV; :mod:`mocapdb.core.exports`) are written
    (atomically) when the track ends, and every ``checkpoint_s`` seconds the open tracks' files so
    far, so a killed process loses at most that much of them.

    Limits (0: none): at most ``max_bvh_files`` files; a track shorter than ``min_track_s`` gets
    none; a track longer than ``bvh_part_min`` minutes is written in parts of that length.
    ``rate_by_arrival``: the engine's new-track limit counts by arrival time (live: the sender
    chooses the frames' times), not by the frames' time (reconstruct: the same result every run).
    """

    strict: bool = True
    fps_given: bool = True
    keep_static: bool = False
    bvh_dir: Path | None = None
    export: TrackExport = field(default_factory=TrackExport)
    checkpoint_s: float = 30.0
    max_bvh_files: int = D.MAX_BVH_FILES.default
    min_track_s: float = D.MIN_TRACK_S.default
    bvh_part_min: float = D.BVH_PART_MIN.default
    rate_by_arrival: bool = False
    take: TakeParams | None = None  # track files from the whole-take fit (runtime.take); None: per frame
    shared_floor: bool = False      # files written at the end, every track on one floor (runtime.world)
    lag_frames: int = 0             # stream lines written this many frames late, smoothed (runtime.lag)
    camera_sources: dict[str, str] = field(default_factory=dict)  # where fps, image size, focal came from
    camera_height_m: float | None = None  # the shared floor's distance below the camera, when known
    subject_heights_m: dict[int | None, float] = field(default_factory=dict)  # track (None: all) → stature
    people: str | tuple[int, ...] = "all"  # the tracks given files at the end: "all", "main" or ids (runtime.subject)
    write_in_background: bool = False  # track files fitted and written by a thread of their own (live)

    def __post_init__(self) -> None:
        D.MAX_BVH_FILES.check(self.max_bvh_files, "max_bvh_files")
        D.MIN_TRACK_S.check(self.min_track_s, "min_track_s")
        D.BVH_PART_MIN.check(self.bvh_part_min, "bvh_part_min")
        D.LAG_FRAMES.check(self.lag_frames, "lag_frames")
        D.CAMERA_HEIGHT_M.check_optional(self.camera_height_m, "camera_height_m")


def track_stem(track: int, part: int | None) -> str:
    """``track_<id>``, or ``track_<id>_part<k>`` for part k (from 1) of a split track: the name of
    its files without the format's suffix."""
    return f"track_{track}" if part is None else f"track_{track}_part{part}"


class TrackFiles:
    """The session's BVH files within its limits (:class:`SessionOptions`). Without a folder yet,
    recordings wait for :meth:`flush` (at most ``max_bvh_files`` of them).

    With ``write_in_background`` (live), every file operation (a whole-take fit and its files, a
    removal) runs in order on one writer thread, so a long track's fit (~2 s for a 10-minute part)
    does not hold up the stream; the first error it meets is raised by the next operation or by
    :meth:`drain`."""

    def __init__(self, options: SessionOptions, fps: float, summary: SessionSummary):
        self.options, self.fps, self.summary = options, fps, summary
        self.part_frames = max(round(options.bvh_part_min * 60.0 * fps), 1)
        self._names: set[str] = set()  # written or waiting
        self._paths: set[Path] = set()  # written
        self._waiting: list[tuple[TrackRecording, str]] = []
        self._held: list[tuple[TrackRecording, str]] = []  # final files held for the shared floor
        self._jobs: queue.Queue | None = None
        self._writer: threading.Thread | None = None
        self._error: BaseException | None = None

    def ended(self, rec: TrackRecording) -> None:
        """A track ended: its file (or last part), unless static or too short."""
        name = track_stem(rec.track, rec.part + 1 if rec.part else None)
        if rec.static:
            self.summary.add_static(rec.track)
        if rec.static and not self.options.keep_static:
            self._remove(name)  # a checkpoint written while it was open
        elif not rec.part and self._short(rec):
            self.summary.limits.short_tracks += 1
        else:
            self._write(rec, name, final=True)

    def cut(self, rec: TrackRecording) -> None:
        """A full part of an open track (``Engine.cut_recordings``); part 1 replaces its checkpoint."""
        if not rec.part:
            self._remove(track_stem(rec.track, None))
        if self.options.keep_static or not rec.static:
            self._write(rec, track_stem(rec.track, rec.part + 1), final=True)

    def checkpoint(self, recordings: list[TrackRecording]) -> None:
        """The open tracks' files so far (long enough, not static, within the file limit)."""
        for rec in recordings:
            if (rec.part or not self._short(rec)) and not rec.static:
                self._write(rec, track_stem(rec.track, rec.part + 1 if rec.part else None), final=False)

    def _short(self, rec: TrackRecording) -> bool:
        return rec.duration_s(self.fps) < self.options.min_track_s - 1e-9

    def flush(self) -> None:
        """Write the recordings that waited for a folder, then those held for the shared floor (all
        on one floor)."""
        self.drain()
        waiting, self._waiting = self._waiting, []
        for rec, name in waiting:
            self._save(rec, name)
        held, self._held = self._held, []
        if held:
            self._write_world(held)

    def _write_world(self, held: list[tuple[TrackRecording, str]]) -> None:
        """The held recordings as one take: fragments of one person joined, one world, its subject;
        the files of the tracks ``--people`` asks for, the summary's lines and ``world.json``."""
        names = {rec.track: name for rec, name in held}
        recordings, joined = join_fragments([rec for rec, _ in held], self.fps)  # with their input keypoints
        fitted, world = fit_world(recordings, self.fps, self.options.take, self.options.camera_height_m,
                                  self.options.subject_heights_m)
        main = main_track(recordings, 2.0 * recordings[0].camera_px[1] if recordings[0].camera_px else 1.0)
        written = {rec.track for rec in chosen(fitted, self.options.people, main)}
        facts = [track_facts(rec, world) for rec in fitted]
        self.summary.world_lines = [world_line(world)] + [f.line(f.track == main, f.track in written) for f in facts]
        self.summary.world_lines += [f"track {track} joined into track {into} (one person lost and found again)"
                                     for track, into in joined.items()]
        for rec in fitted:
            if rec.track in written:
                self._write_files(rec, names.pop(rec.track))
        for name in names.values():
            self._names.discard(name)
        if self.options.bvh_dir is not None:
            record = world_record(world, facts, main, written, joined, self.options.export.floor)
            write_atomic(Path(self.options.bvh_dir) / "world.json", json.dumps(record, indent=1) + "\n")

    def _write(self, rec: TrackRecording, name: str, final: bool) -> None:
        limit = self.options.max_bvh_files
        if name not in self._names and limit and len(self._names) >= limit:
            if final:
                self._refuse()
        elif final and self._sharing_floor(rec):
            self._names.add(name)
            self._held.append((rec, name))
        elif self.options.bvh_dir is None:
            self._names.add(name)
            self._waiting.append((rec, name))
        else:
            self._names.add(name)
            queued = self.options.write_in_background and not final  # an open track records on meanwhile
            self._run(self._save, rec.snapshot() if queued else rec, name, final)

    def _sharing_floor(self, rec: TrackRecording) -> bool:
        return self.options.shared_floor and self.options.take is not None and bool(rec.keypoints)

    def _save(self, rec: TrackRecording, name: str, final: bool = True) -> None:
        """``rec``'s files: the whole take when kept. A checkpoint (not ``final``: the live loop waits
        for it) leaves out the whole take's re-fit to the image, its costliest step."""
        if self.options.take is not None and rec.keypoints:
            params = self.options.take if final else replace(self.options.take, refit_prior=0.0)
            rec, _ = fit_take(rec, self.fps, params)
        self._write_files(rec, name)

    def _write_files(self, rec: TrackRecording, name: str) -> None:
        paths = write_track_files(rec, self.options.bvh_dir, name, self.fps, self.options.export)
        self._names.add(name)
        for path in paths:
            if path not in self._paths:
                self._paths.add(path)
                self.summary.bvh_files.append(path)

    def _run(self, operation: Callable, *args) -> None:
        """``operation(*args)`` now, or queued for the writer thread (``write_in_background``)."""
        if not self.options.write_in_background:
            operation(*args)
            return
        self._raise_error()
        if self._writer is None:
            self._jobs = queue.Queue()
            self._writer = threading.Thread(target=self._write_jobs, name="mocapdb-track-files", daemon=True)
            self._writer.start()
        self._jobs.put((operation, args))

    def _write_jobs(self) -> None:
        """The writer thread: queued operations in order until ``None``; after an error, the rest are
        skipped (the error is raised in the session's thread)."""
        while (job := self._jobs.get()) is not None:
            if self._error is None:
                try:
                    job[0](*job[1])
                except BaseException as exc:  # raised again by the session's thread
                    self._error = exc

    def drain(self) -> None:
        """Wait for the writer thread's queued operations; raise the first error it met."""
        if self._writer is not None:
            self._jobs.put(None)
            self._writer.join()
            self._writer = None
        self._raise_error()

    def _raise_error(self) -> None:
        if self._error is not None:
            error, self._error = self._error, None
            raise error

    def _remove(self, name: str) -> None:
        self._run(self._remove_now, name)

    def _remove_now(self, name: str) -> None:
        if self.options.bvh_dir is None:
            return
        for suffix in self.options.export.formats:
            path = self.options.bvh_dir / f"{name}.{suffix}"
            if path in self._paths:
                path.unlink(missing_ok=True)
                self._paths.discard(path)
                self.summary.bvh_files.remove(path)
        self._names.discard(name)

    def _refuse(self) -> None:
        self.summary.limits.over_max_files += 1
        if self.summary.limits.over_max_files == 1:
            LOG.warning("--max-bvh-files %d reached: further tracks get no file (their frames stay in the stream)",
                        self.options.max_bvh_files)


class Session:
    """Runs an engine over a message source and writes its outputs."""

    def __init__(self, engine: Engine, sink: Sink, parser: FrameParser, summary: SessionSummary,
                 options: SessionOptions | None = None):
        self.engine, self.sink, self.parser, self.summary = engine, sink, parser, summary
        self.options = options or SessionOptions()
        self.files = TrackFiles(self.options, engine.config.fps, summary)
        limits = engine.config.limits
        summary.limits = LimitReport(limits.max_tracks, limits.max_new_per_min, self.options.max_bvh_files,
                                     self.options.min_track_s)
        self._fps_warned = self.options.fps_given
        self._first_frame = True
        self.lag = None
        if self.options.lag_frames:
            take = self.options.take
            self.lag = FixedLag(self.options.lag_frames, engine.config.fps, take.smoothing_hz if take else 4.0)
        # (the stream with a lag smooths as the track files do: their --smoothing-hz, 4 Hz without them)
        self.started = self._checkpointed = time.perf_counter()
        try:
            config = engine.config
            self._emit(header_line(config.fps, config.image_size, config.focal_px, self.options.camera_sources))
        except SinkError:
            self._close_sink()
            raise

    def handle(self, message: RawMessage) -> None:
        """Parse, process and write one message; a malformed one is counted and skipped."""
        try:
            frame = self.parser(message)
        except KeypointError as exc:
            self.summary.add_malformed(str(exc)[:160], message.origin)
            return
        self.handle_frame(frame, message.arrival_s)

    def handle_frame(self, frame: KeypointFrame, arrival_s: float) -> None:
        """Process and write one parsed frame that arrived at ``arrival_s`` (time.monotonic);
        raises :class:`SinkError` if the sink fails."""
        problem = self._contradiction(frame)
        if problem:
            if self.options.strict:
                raise InputError(problem)
            self.summary.add_malformed("keypoints outside --image-size")
            return
        with compile_notice(self._first_frame and not kernels_cached(refine)):
            poses = self.engine.step(frame, arrival_s if self.options.rate_by_arrival else None)
        self._first_frame = False
        t_s = frame.time_s if frame.time_s is not None else frame.index / self.engine.config.fps
        self._write_frame(frame.index, t_s, poses)
        self.summary.frames += 1
        self.summary.person_frames += len(poses)
        self.summary.add_latency(time.monotonic() - arrival_s)
        self._bvhs()

    def _write_frame(self, index: int, time_s: float, poses: list) -> None:
        """The frame's line, or, with a lag, the lines now due (:class:`~mocapdb.runtime.lag.FixedLag`)."""
        due = [(index, time_s, poses)] if self.lag is None else self.lag.push(index, time_s, poses)
        for frame_index, frame_s, people in due:
            self._emit(frame_line(frame_index, frame_s, people))

    def _emit(self, line: str) -> None:
        try:
            self.sink.write(line)
        except OSError as exc:
            self.summary.sink_error = self.summary.sink_error or str(exc) or type(exc).__name__
            raise SinkError(f"the sink failed: {self.summary.sink_error}") from exc

    def _bvhs(self) -> None:
        """Ended tracks' files, full parts of long ones; every ``checkpoint_s``, the open ones so far."""
        for rec in self.engine.pop_finished():
            self.files.ended(rec)
        for rec in self.engine.cut_recordings(self.files.part_frames):
            self.files.cut(rec)
        if self.options.bvh_dir is not None and time.perf_counter() - self._checkpointed >= self.options.checkpoint_s:
            self._checkpointed = time.perf_counter()
            self.files.checkpoint(self.engine.open_recordings())

    def _contradiction(self, frame: KeypointFrame) -> str | None:
        """Why ``frame`` contradicts the parameters, or None; warns once about an assumed rate."""
        if frame.time_s is None and not self._fps_warned:
            self._fps_warned = True
            LOG.warning("the input carries no timestamps and no --fps was given: assuming %g fps "
                        "(BVH frame time 1/%g s)", self.engine.config.fps, self.engine.config.fps)
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

    def finish(self, bvh_dir: Path | None = None) -> SessionSummary:
        """End all tracks, write the track files not yet written (into ``bvh_dir`` if given, else the
        options'), close the sink (even if writing fails). A sink that failed earlier is only
        recorded (``summary.sink_error``); one first failing at close raises SinkError, files written."""
        self.summary.wall_s = time.perf_counter() - self.started
        if bvh_dir is not None:
            self.options.bvh_dir = Path(bvh_dir)
        try:
            if self.lag is not None and self.summary.sink_error is None:
                for frame_index, frame_s, people in self.lag.flush():
                    self._emit(frame_line(frame_index, frame_s, people))
            self.engine.finish()
            for rec in sorted(self.engine.pop_finished(), key=lambda r: r.track):
                self.files.ended(rec)
            if self.options.bvh_dir is not None:
                self.files.flush()
            self.files.drain()
        finally:
            self._count()
            self._close_sink()
        return self.summary

    def _count(self) -> None:
        stats = self.engine.stats
        self.summary.tracks, self.summary.gaps = stats.tracks_started, stats.gaps
        self.summary.degenerate = stats.degenerate_people
        self.summary.limits.over_max_tracks = stats.over_max_tracks
        self.summary.limits.over_max_new = stats.over_max_new

    def _close_sink(self) -> None:
        try:
            self.sink.close()
        except OSError as exc:
            if self.summary.sink_error is None:
                self.summary.sink_error = str(exc) or type(exc).__name__
                raise SinkError(f"the sink failed: {self.summary.sink_error}") from exc


def run_offline(session: Session, source: Source,
                wrap: Callable[[Iterable[RawMessage]], Iterable[RawMessage]] | None = None) -> None:
    """Every message of a finite source, in order (through ``wrap``, e.g. a progress bar)."""
    with source:
        for message in (wrap(source) if wrap else source):
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

