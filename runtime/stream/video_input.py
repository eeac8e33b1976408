"""Video as a live source: decoding, 2D pose detection and the landmark models in threads of their own,
feeding the live loop.

:class:`VideoDetections` decodes a video file or a camera (:class:`DecodedFrames`, one thread) and runs a
detector (:func:`~mocapdb.detect.detectors.open_detector`: BlazePose, or a YOLO-pose/RTMO export) on each
frame in another, and, for a file read as fast as it goes, the landmark models (hands, face) and the camera's
path in a third behind the pose's (:class:`PoseFrames`), so the decoding of the next frame, the detection of
this one and the engine's step on the one before overlap (OpenCV's decoder and onnxruntime release the GIL).
Frames (universal 14 keypoints) wait in a small buffer; when the consumer falls behind a camera or a paced file,
the oldest is dropped and counted (``StreamStats.dropped_stale``), as
:class:`~mocapdb.runtime.stream.buffering.LiveInput` does for messages; a file read as fast as it goes waits
for the consumer instead (lossless: nothing is gained by dropping where no clock runs).
Every frame carries the moment it was decoded (a camera: grabbed), so the session's latency is end to
end: capture → the sink's send. A file is read as fast as detection goes (not paced to its frame rate:
its decoder waits for the detector, no frame dropped there), unless ``paced``: then each frame is
delivered at its time since the first, as a camera would, and a late detector drops the oldest frames
as behind a camera; a camera paces itself. A file's frames carry their container timestamps and their
numbers on the video's nominal timeline (:class:`~mocapdb.detect.video.FrameClock`): a gap in the video is
a jump in frame numbers, which the engine bridges as frames nobody was seen in, so the BVH keeps the
gap's length.
"""
from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING, NamedTuple, TypeVar

import numpy as np

from mocapdb.core.formats.camera_path import derotate_frame
from mocapdb.core.formats.keypoints import KeypointFrame, Person, to_extremities, to_universal, to_universal_world
from mocapdb.detect.camera_motion import LIVE_EVERY, BackgroundMotion
from mocapdb.detect.detectors import FrameDetector
from mocapdb.detect.errors import DetectError
from mocapdb.detect.model import Detections
from mocapdb.detect.video import FrameClock, VideoFrame, VideoReader
from mocapdb.detect.with_landmarks import detection_stages
from mocapdb.runtime.stream.buffering import BufferedThread
from mocapdb.runtime.stream.messages import StreamStats

if TYPE_CHECKING:
    from mocapdb.runtime.stream.session import Session

POLL_S = 0.05   # how often the live loop checks ``stop`` while no frame is ready
KEYPOINT_FILE_SUFFIXES = (".jsonl", ".json", ".ndjson", ".txt")   # a --source file with these is keypoints
T = TypeVar("T")


class CapturedFrame(NamedTuple):
    """A detected frame and when its image was decoded (``time.monotonic()`` seconds)."""

    frame: KeypointFrame
    capture_s: float


def keypoint_frame(video_frame: VideoFrame, found: Detections, layout: str = "coco17",
                   number: int | None = None) -> KeypointFrame:
    """The people ``found`` (keypoints in ``layout``) in ``video_frame`` as the engine takes them
    (universal keypoints, frame pixels; the detector's world landmarks and hands when it gives them), numbered
    ``number`` (default: the frame's index in the video)."""
    points, confidence = to_universal(found.keypoints, layout)
    extremities = to_extremities(found.keypoints, layout)   # heels, toes, knuckles (BlazePose), else None
    world = None if found.world is None else to_universal_world(found.world, layout)
    hands = None if found.hands is None else found.hands.points   # [P, 2, 21, 4] with --hands
    faces = None if found.faces is None else found.faces.points   # [P, 468, 4] with --face
    people = [Person(p, c, None, None if extremities is None else extremities[i], None if world is None else world[i],
                     None if hands is None else hands[i], face=None if faces is None else faces[i])
              for i, (p, c) in enumerate(zip(points, confidence))]
    return KeypointFrame(video_frame.index if number is None else number, video_frame.time_s, people, layout)


class DecodedFrames(BufferedThread[tuple[VideoFrame, int]]):
    """The frames of ``reader`` decoded in a thread of their own (every ``every``-th), each with its number
    on the video's nominal timeline (:attr:`clock`, counted as decoded: a frame dropped here is not a gap
    in the video), one frame ahead of the detector: a file not ``paced`` waits for it to be taken
    (lossless), a camera or a paced file replaces it by the newer one (the detector always gets the
    newest: no frame waits behind another). A paced file's frame is delivered (and its ``capture_s``
    set) at its time since the first frame."""

    def __init__(self, reader: VideoReader, every: int, stats: StreamStats, paced: bool = False) -> None:
        super().__init__(1, stats, "mocapdb-video-decode", lossless=not (reader.is_camera or paced))
        self.reader, self.every, self.paced = reader, every, paced and not reader.is_camera
        self.clock = FrameClock(None if reader.is_camera or not reader.fps else reader.fps / every)
        self._stop = threading.Event()
        self._start()

    def _items(self) -> Iterator[tuple[VideoFrame, int]]:
        started_s = time.monotonic()
        for video_frame in self.reader.frames(self.every):
            if self._stop.is_set():
                break
            number = self.clock.number(video_frame.time_s)
            if self.paced and video_frame.time_s is not None:
                if self._stop.wait(max(0.0, started_s + video_frame.time_s - time.monotonic())):
                    break
                video_frame = video_frame._replace(capture_s=time.monotonic())
            yield video_frame, number

    def close(self) -> None:
        """Stops the thread (after the frame in hand) and waits for it; idempotent."""
        self._stop.set()
        self._release()
        self._thread.join()


def _taken(buffer: BufferedThread[T], stop: threading.Event) -> Iterator[T]:
    """The items of ``buffer`` as its thread gives them, until it is finished or ``stop`` is set."""
    while not stop.is_set():
        item = buffer.get(timeout=POLL_S)
        if item is not None:
            yield item
        elif buffer.finished:
            break


class PoseFrames(BufferedThread[tuple[VideoFrame, int, Detections]]):
    """The people ``detect`` finds in each frame of ``decoded``, in a thread of its own, one frame ahead of
    the landmark models (:func:`~mocapdb.detect.with_landmarks.detection_stages`): it waits for them to take
    its frame (lossless), so a late stage behind it drops frames only where the decoder does."""

    def __init__(self, decoded: DecodedFrames, detect: Callable[[np.ndarray], Detections], stats: StreamStats) -> None:
        super().__init__(1, stats, "mocapdb-video-pose", lossless=True)
        self.decoded, self.detect = decoded, detect
        self._stop = threading.Event()
        self._start()

    def _items(self) -> Iterator[tuple[VideoFrame, int, Detections]]:
        for video_frame, number in _taken(self.decoded, self._stop):
            yield video_frame, number, self.detect(video_frame.image)

    def close(self) -> None:
        """Stops the thread (after the frame in hand) and waits for it; idempotent."""
        self._stop.set()
        self._release()
        self._thread.join()


class VideoDetections(BufferedThread[CapturedFrame]):
    """Frames of ``source`` (a video file path, or a camera index) with the people ``model`` finds
    (BlazePose or a :class:`~mocapdb.detect.tracked.TrackedDetector`: both follow them across frames).

    A file read as fast as it goes: three threads, decoding (:class:`DecodedFrames`), the people
    (:class:`PoseFrames`), then their hands and faces (the landmark models of ``--hands``, ``--face``) and the
    camera's path (``motion``) in this one's, so the landmark models of a frame run while the pose model takes
    the next (throughput: with hands 0.63 → 0.75 × the frames/s without them). A camera or a paced file: the
    people and their landmarks in this one thread after decoding (latency: a frame's landmark models do not
    share the cores with the next frame's pose; with the three threads the p99 latency at 60 fps was 1.96
    frame times without hands, 5.7 with, against 0.90 and 1.88: docs/benchmarks.md, "Hands' cost: the
    landmark models in a thread of their own").
    ``every``: detect every N-th frame only; ``capacity``: frames buffered before the oldest is
    dropped (a camera, a paced file) or the detector waits (a file not paced; see
    :class:`~mocapdb.runtime.stream.buffering.BufferedThread`), after detection (after decoding and after
    the people: one); ``paced``: a file delivered at its frame rate (module notes).
    Opening the video happens here (DetectError if it fails); the threads start at once.
    """

    def __init__(self, source: str | int, model: FrameDetector, *, every: int = 1, capacity: int = 2,
                 stats: StreamStats | None = None, paced: bool = False, motion: BackgroundMotion | None = None) -> None:
        if every < 1 or capacity < 1:
            raise DetectError("every and capacity must be at least 1")
        reader = VideoReader(source)
        super().__init__(capacity, stats if stats is not None else StreamStats(), "mocapdb-video-detect",
                         lossless=not (reader.is_camera or paced))
        self.model, self.every, self.motion = model, every, motion
        self.reader = reader
        self.frames_detected = 0
        self._stop = threading.Event()
        self._pose, self._landmarks = detection_stages(model)
        self.decoded = DecodedFrames(self.reader, every, self.stats, paced)
        self.poses = PoseFrames(self.decoded, self._pose, self.stats) if self.lossless else None
        self.clock = self.decoded.clock
        self._start()

    def _found(self) -> Iterator[tuple[VideoFrame, int, Detections]]:
        """Each decoded frame, its number and the people in it: from :attr:`poses` when the pose model has a
        thread of its own, else found here."""
        if self.poses is not None:
            return _taken(self.poses, self._stop)
        return ((video_frame, number, self._pose(video_frame.image))
                for video_frame, number in _taken(self.decoded, self._stop))

    def _items(self) -> Iterator[CapturedFrame]:
        for video_frame, number, found in self._found():
            captured = CapturedFrame(self._detect(video_frame, found, number), video_frame.capture_s)
            self.frames_detected += 1
            self.stats.add(messages_in=1)
            yield captured

    def _detect(self, video_frame: VideoFrame, found: Detections, number: int) -> KeypointFrame:
        """The frame's people ``found`` with their landmarks; with ``motion``, seen from the first frame's
        camera by the path known so far (data_specs/world.md, "A camera that turns")."""
        found = self._landmarks(video_frame.image, found)
        frame = keypoint_frame(video_frame, found, self.model.keypoint_layout, number)
        if self.motion is None:
            return frame
        self.motion.see(number, video_frame.image, found.keypoints)
        turn = self.motion.online()
        return frame if turn is None else derotate_frame(frame, turn, self.motion.full_intrinsics)

    @property
    def detection_fps(self) -> float:
        """Frames per second of detection time (what the detector sustains)."""
        return self.model.fps

    def report(self) -> str:
        """One summary line: frames read, detected, dropped, detection rate; a line on the gaps in the
        video's timestamps (:class:`~mocapdb.detect.video.FrameClock`); a warning line when the video
        file ended before its declared frame count or some frames had no usable timestamp
        (:meth:`~mocapdb.detect.video.VideoReader.truncation`, ``time_warnings``)."""
        notes = [f"frame times: {gaps}" for gaps in [self.clock.report()] if gaps]
        notes += [f"warning: {w}" for w in (self.reader.truncation(), *self.reader.time_warnings()) if w]
        return "\n".join([f"video {self.reader.label}: frames read {self.reader.frames_read}, detected "
                          f"{self.frames_detected}, dropped {self.dropped + self.decoded.dropped}; detection "
                          f"{self.detection_fps:.1f} frames/s ({self.model.describe()})", *notes])

    def close(self) -> None:
        """Stops the threads (after the frames in hand), waits for them and releases the video; idempotent."""
        self._stop.set()
        self.decoded.close()
        if self.poses is not None:
            self.poses.close()
        self._thread.join()
        self.reader.close()


def is_video_source(spec: str) -> bool:
    """Whether ``live --source SPEC`` is a camera (an index: digits) or a video file (a file that is
    not JSON lines), rather than a keypoint stream."""
    from pathlib import Path

    return spec.isdigit() or (Path(spec).is_file() and Path(spec).suffix.lower() not in KEYPOINT_FILE_SUFFIXES)


def open_video_source(spec: str, model: FrameDetector, *, every: int = 1, capacity: int = 2,
                      stats: StreamStats | None = None, paced: bool = False, turning: bool = True
                      ) -> VideoDetections:
    """``mocapdb live --source SPEC`` on a video: SPEC of digits is a camera index, anything else a
    video file (``paced``: delivered at its frame rate), ``model`` the detector
    (:func:`~mocapdb.detect.detectors.open_detector`); on a file that may have ``turning``, the
    camera's path measured from the background as the frames come
    (:class:`~mocapdb.detect.camera_motion.BackgroundMotion`, measured every
    :data:`~mocapdb.detect.camera_motion.LIVE_EVERY` frames, extrapolated between); a camera device
    stands still (a webcam on a desk or a tripod: data_specs/world.md, "A camera that turns").
    DetectError on failure."""
    source: str | int = int(spec) if spec.isdigit() else spec
    motion = BackgroundMotion(history=False, every=LIVE_EVERY) if turning and isinstance(source, str) else None
    return VideoDetections(source, model, every=every, capacity=capacity, stats=stats, paced=paced, motion=motion)


def run_video(session: Session, video: VideoDetections, stop: threading.Event) -> None:
    """Detected frames as they come until the video ends or ``stop`` is set; closes ``video``.
    Latency runs from each frame's capture to the sink's send of its output."""
    with video:
        for item in _taken(video, stop):
            session.handle_frame(item.frame, item.capture_s)
