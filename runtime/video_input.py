"""Video as a live source: decoding and 2D pose detection in their own thread, feeding the live loop.

:class:`VideoDetections` decodes a video file or a camera and runs a :class:`~mocapdb.detect.PoseModel`
on each frame in a background thread, so detection of the next frame overlaps the engine's
retrieval of this one. Frames (universal 14 keypoints) wait in a small buffer; when the consumer
falls behind, the oldest is dropped and counted (``StreamStats.dropped_stale``), as
:class:`~runtime.streams.LiveInput` does for messages. Every frame carries the moment it was
decoded, so the session's latency is end to end: capture → output line. A file is read as fast as
detection goes (not paced to its frame rate); a camera paces itself.
"""
from __future__ import annotations

import threading
from collections import deque
from typing import TYPE_CHECKING, NamedTuple, Self

from mocapdb.detect import (DEFAULT_CONF, DEFAULT_INPUT_SIZE, DEFAULT_IOU, DetectError, PoseModel, VideoFrame,
                            VideoReader)
from mocapdb.keypoints import KeypointFrame, Person, to_universal

from .streams import StreamStats

if TYPE_CHECKING:
    from .session import Session

POLL_S = 0.05   # how often the live loop checks ``stop`` while no frame is ready


class CapturedFrame(NamedTuple):
    """A detected frame and when its image was decoded (``time.monotonic()`` seconds)."""

    frame: KeypointFrame
    capture_s: float


class VideoDetections:
    """Frames of ``source`` (a video file path, or a camera index) with the people ``model`` finds.

    ``every``: detect every N-th frame only; ``capacity``: frames buffered before the oldest is
    dropped. Opening the video happens here (DetectError if it fails); the thread starts at once.
    """

    def __init__(self, source: str | int, model: PoseModel, *, every: int = 1, capacity: int = 2,
                 stats: StreamStats | None = None) -> None:
        if every < 1 or capacity < 1:
            raise DetectError("every and capacity must be at least 1")
        self.model, self.every, self._capacity = model, every, capacity
        self.stats = stats if stats is not None else StreamStats()
        self.reader = VideoReader(source)
        self.frames_detected = 0
        self.dropped = 0
        self._buffer: deque[CapturedFrame] = deque()
        self._cond = threading.Condition()
        self._ended = False
        self._error: Exception | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="mocapdb-video-detect", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        try:
            for video_frame in self.reader.frames(self.every):
                if self._stop.is_set():
                    break
                self._put(CapturedFrame(self._detect(video_frame), video_frame.capture_s))
        except Exception as exc:  # noqa: BLE001 - handed to the consumer by get()
            self._error = exc
        finally:
            with self._cond:
                self._ended = True
                self._cond.notify_all()

    def _detect(self, video_frame: VideoFrame) -> KeypointFrame:
        found = self.model(video_frame.image)
        points, confidence = to_universal(found.keypoints, "coco17")
        people = [Person(p, c) for p, c in zip(points, confidence)]
        return KeypointFrame(video_frame.index, video_frame.time_s, people, "coco17")

    def _put(self, item: CapturedFrame) -> None:
        with self._cond:
            self.frames_detected += 1
            if len(self._buffer) >= self._capacity:
                self._buffer.popleft()
                self.dropped += 1
                self.stats.add(dropped_stale=1)
            self._buffer.append(item)
            self.stats.add(messages_in=1)
            self._cond.notify()

    def get(self, timeout: float | None = None) -> CapturedFrame | None:
        """The oldest buffered frame, waiting up to ``timeout`` s; None on timeout or when
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
        """True once the video has ended (or the thread stopped) and every buffered frame was taken."""
        with self._cond:
            return self._ended and not self._buffer

    @property
    def detection_fps(self) -> float:
        """Frames per second of detection time (what the detector sustains)."""
        return self.model.fps

    def report(self) -> str:
        """One summary line: frames read, detected, dropped, detection rate."""
        return (f"video {self.reader.label}: frames read {self.reader.frames_read}, detected {self.frames_detected}, "
                f"dropped {self.dropped}; detection {self.detection_fps:.1f} frames/s ({self.model.describe()})")

    def close(self) -> None:
        """Stops the thread (after the frame in hand), waits for it and releases the video; idempotent."""
        self._stop.set()
        self._thread.join()
        self.reader.close()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def open_video_source(spec: str, model_path: str, *, conf: float = DEFAULT_CONF, iou: float = DEFAULT_IOU,
                      max_people: int | None = None, input_size: int = DEFAULT_INPUT_SIZE, every: int = 1,
                      capacity: int = 2, stats: StreamStats | None = None) -> VideoDetections:
    """``mocapdb live --source SPEC --model POSE.onnx``: SPEC of digits is a camera index, anything
    else a video file. The model options are :class:`~mocapdb.detect.PoseModel`'s; DetectError on failure."""
    model = PoseModel(model_path, conf=conf, iou=iou, max_people=max_people, input_size=input_size)
    source: str | int = int(spec) if spec.isdigit() else spec
    return VideoDetections(source, model, every=every, capacity=capacity, stats=stats)


def run_video(session: Session, video: VideoDetections, stop: threading.Event) -> None:
    """Detected frames as they come until the video ends or ``stop`` is set; closes ``video``.
    Latency runs from each frame's capture to its output line."""
    with video:
        while not stop.is_set():
            item = video.get(timeout=POLL_S)
            if item is not None:
                session.handle_frame(item.frame, item.capture_s)
            elif video.finished:
                break
