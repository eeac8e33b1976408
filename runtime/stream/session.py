"""The one loop behind `mocapdb reconstruct` and `mocapdb live`: messages → frames → engine → outputs.

``reconstruct`` reads every message of a folder or file in order; ``live`` reads through
:class:`~mocapdb.runtime.stream.transport.LiveInput`, which drops stale messages when the engine falls behind.
Malformed messages are counted by reason and skipped; the summary reports them with frame,
people and track counts, the end-to-end latency (p50/p99, from a frame's capture or a message's
arrival to the moment the sink sent its output: :mod:`mocapdb.runtime.stream.latency`) with the lag,
throughput and what the limits held back. Whatever arrives, memory stays bounded: tracks by
:class:`~mocapdb.runtime.engine_config.TrackLimits`, recordings by BVH parts, the summary's lists by caps.
A sink that fails stops the session (:class:`SinkError`); :meth:`Session.finish` still writes
every BVH file. Its options: :mod:`mocapdb.runtime.stream.session_options`; its summary:
:mod:`mocapdb.runtime.stream.session_summary`; its track files: :mod:`mocapdb.runtime.stream.track_files`.
"""
from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import replace
from pathlib import Path

import numpy as np

from mocapdb.core.errors import MocapdbError
from mocapdb.core.formats.keypoints import LAYOUTS, KeypointError, KeypointFrame, Person
from mocapdb.core.formats.openpose import parse_stream_line
from mocapdb.core.formats.take import beyond_image, holds_keypoints
from mocapdb.core.outputs import header_line
from mocapdb.core.progress import compile_notice, kernels_cached
from mocapdb.runtime import refine
from mocapdb.runtime.engine import Engine
from mocapdb.runtime.online_take import OnlineParams, OnlineTake
from mocapdb.runtime.stream.session_options import SessionOptions
from mocapdb.runtime.stream.session_summary import LimitReport, SessionSummary
from mocapdb.runtime.stream.track_files import TrackFiles
from mocapdb.runtime.stream.transport import LiveInput, RawMessage, Sink, Source

LOG = logging.getLogger(__name__)


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
            self._seen(frame, frame.layout)
        return frame

    def _seen(self, frame: KeypointFrame, layout: str) -> None:
        """Note the ``layout`` the people of ``frame`` shared."""
        self.known.setdefault(len(LAYOUTS[layout]), layout)
        if self.current not in (None, layout):
            if not self.layout_changes:
                LOG.warning("the keypoint layout changed from %s to %s (in frame %d); each frame's layout is "
                            "taken from its own keypoint count (further changes are not logged)",
                            self.current, layout, frame.index)
            self.layout_changes += 1
        self.current = layout


class InputError(MocapdbError, ValueError):
    """Input that contradicts the command's parameters (e.g. keypoints outside --image-size)."""


# where the image size came from (camera_sources["image_size"]) → how a frame outside it names the size
SIZE_ORIGINS = {"given": " by --image-size", "read": " by the take description",
                "default": ", a size assumed (none given, no take description)",
                "keypoints": ", a size taken from the first frames' keypoints (none given, no take description)"}
ASSUMED_SIZES = ("default", "keypoints")  # a frame outside these stops the run (live too)


def _unseen_beyond(person: Person, size: tuple[int, int]) -> tuple[Person, int]:
    """``person`` with their keypoints and extremities (heels, toes, knuckles, face points) beyond an image of
    ``size`` (width, height px; :func:`~mocapdb.core.formats.take.beyond_image`) made unseen (confidence 0, NaN
    place), and how many were."""
    beyond = beyond_image(size, person.points_px) & (person.confidence > 0)
    changes: dict = {"points_px": np.where(beyond[:, None], np.nan, person.points_px),
                     "confidence": np.where(beyond, 0.0, person.confidence)}
    count = int(beyond.sum())
    if person.extremities is not None:
        far = beyond_image(size, person.extremities[:, :2]) & (person.extremities[:, 2] > 0)
        changes["extremities"] = np.where(far[:, None], [np.nan, np.nan, 0.0], person.extremities)
        count += int(far.sum())
    return (replace(person, **changes) if count else person), count


class SinkError(OSError):
    """The sink could not take a line (disk full, closed pipe): the session stops there."""


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
        self._first_done_s: float | None = None
        self.online = None
        if self.options.online_take:
            take = self.options.take  # the stream smooths as the track files do: their --smoothing-hz
            smoothing_hz = take.smoothing_hz if take and take.smoothing_hz > 0 else OnlineParams.smoothing_hz
            config = engine.config
            self.online = OnlineTake(config.fps, OnlineParams(self.options.lag_frames, smoothing_hz),
                                     (config.focal_px, *config.center_px))
        summary.latency.fps = engine.config.fps
        sink.notify_sent(summary.latency.sent)
        self.started = self._checkpointed = time.perf_counter()
        try:
            config = engine.config
            self._emit(header_line(config.fps, config.image_size, config.focal_px, self.options.camera_sources,
                                   self.options.lag_frames if self.online else None))
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
        """Process and write one parsed frame captured or arrived at ``arrival_s`` (time.monotonic);
        raises :class:`SinkError` if the sink fails. A frame outside the image size is refused
        (:class:`InputError`) when the size was assumed or ``strict``, else counted and skipped; where the size
        is the video's own (read from it or its take description), points beyond it are unseen instead."""
        if self.options.camera_sources.get("image_size") == "read":
            frame = self._out_of_frame_unseen(frame)
        problem = self._contradiction(frame)
        if problem:
            if self.options.camera_sources.get("image_size") in ASSUMED_SIZES:
                raise InputError(f"{problem}; give --image-size WIDTHxHEIGHT, or write the take description "
                                 "(take.json, data_specs/take_description.md) beside the keypoints")
            if self.options.strict:
                raise InputError(problem)
            self.summary.add_malformed("keypoints outside --image-size")
            return
        self.summary.latency.captured(frame.index, arrival_s)
        with compile_notice(self._first_frame and not kernels_cached(refine)):
            poses = self.engine.step(self._from_reference(frame), arrival_s if self.options.rate_by_arrival else None)
        self._first_frame = False
        t_s = frame.time_s if frame.time_s is not None else frame.index / self.engine.config.fps
        self._write_frame(frame.index, t_s, poses)
        self.summary.frames += 1
        self.summary.person_frames += len(poses)
        self._frame_done()
        self._bvhs()

    def _frame_done(self) -> None:
        """The steady-state clock: seconds from the first frame processed to this one."""
        now = time.perf_counter()
        if self._first_done_s is None:
            self._first_done_s = now
        self.summary.steady_s = now - self._first_done_s

    def _write_frame(self, index: int, time_s: float, poses: list) -> None:
        """The frame's people, or, through the online take, those now due
        (:class:`~mocapdb.runtime.online_take.OnlineTake`)."""
        due = [(index, time_s, poses)] if self.online is None else self.online.push(index, time_s, poses)
        for frame_index, frame_s, people in due:
            self._emit_frame(frame_index, frame_s, people)

    def _emit(self, line: str) -> None:
        try:
            self.sink.write(line)
        except OSError as exc:
            self._sink_failed(exc)

    def _emit_frame(self, frame_index: int, time_s: float, people: list) -> None:
        try:
            self.sink.write_frame(frame_index, time_s, people)
        except OSError as exc:
            self._sink_failed(exc)

    def _sink_failed(self, exc: OSError) -> None:
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

    def _out_of_frame_unseen(self, frame: KeypointFrame) -> KeypointFrame:
        """``frame`` with the keypoints and extremities a detector placed beyond its own video's image (by more
        than :data:`~mocapdb.core.formats.take.IMAGE_MARGIN`: a body part out of the frame, its place guessed)
        unseen, counted in ``summary.points_out_of_frame``."""
        people = []
        for person in frame.people:
            kept, beyond = _unseen_beyond(person, self.engine.config.image_size)
            people.append(kept)
            self.summary.points_out_of_frame += beyond
        return replace(frame, people=people)

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
            if holds_keypoints((width, height), lo, hi):
                continue
            swapped = holds_keypoints((height, width), lo, hi)
            hint = f"; is the image {height}x{width} (width x height)?" if swapped else ""
            said = SIZE_ORIGINS[self.options.camera_sources.get("image_size", "given")]
            return (f"frame {frame.index}: keypoints reach x = {hi[0]:.0f} px, y = {hi[1]:.0f} px in an image "
                    f"said to be {width}x{height}{said}{hint}")
        return None

    def _from_reference(self, frame: KeypointFrame) -> KeypointFrame:
        """``frame`` as the reference camera of a turning camera's path sees it
        (:meth:`~mocapdb.core.formats.camera_path.CameraPath.derotate`); as it is without a path."""
        path = self.options.camera_path
        return frame if path is None else path.derotate(frame)

    def finish(self, bvh_dir: Path | None = None) -> SessionSummary:
        """End all tracks, write the track files not yet written (into ``bvh_dir`` if given, else the
        options'), close the sink (even if writing fails). A sink that failed earlier is only
        recorded (``summary.sink_error``); one first failing at close raises SinkError, files written."""
        self.summary.wall_s = time.perf_counter() - self.started
        if bvh_dir is not None:
            self.options.bvh_dir = Path(bvh_dir)
        try:
            if self.online is not None and self.summary.sink_error is None:
                for frame_index, frame_s, people in self.online.flush():
                    self._emit_frame(frame_index, frame_s, people)
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
