"""Decoded video frames for the detector: a video file or a camera read with OpenCV.

:class:`VideoReader` decodes its first frame when opening (so a missing, corrupt or unsupported
video fails at once with :class:`~mocapdb.detect.errors.DetectError`), gives every frame its
timestamp and the moment it was decoded, skips frames undecoded for ``--every`` and tells a video
file that ended before its declared frame count (:meth:`VideoReader.truncation`).
"""
from __future__ import annotations

import math
import time
from collections.abc import Iterator
from pathlib import Path
from typing import NamedTuple

import cv2
import numpy as np

from mocapdb.detect.errors import DetectError, check_readable


class VideoFrame(NamedTuple):
    """One decoded frame."""

    # frame number in the video (camera: since opening), from 0; a field named like tuple.index, which mypy
    # refuses in a NamedTuple (attribute access gives the field)
    index: int  # type: ignore[assignment]
    time_s: float | None   # seconds since the first frame (video timestamps, else index / fps)
    capture_s: float       # time.monotonic() when it was decoded
    image: np.ndarray      # [H, W, 3] uint8 BGR


# A video file that ends more than max(TRUNCATION_SLACK_FRAMES, TRUNCATION_SLACK_SHARE × count)
# frames before the frame count its container declares looks truncated. The slack: containers
# that give no count of their own have one estimated from the duration, which can be a frame or
# two off (and a few per cent for a variable frame rate).
TRUNCATION_SLACK_FRAMES = 2
TRUNCATION_SLACK_SHARE = 0.01


class VideoReader:
    """The frames of a video file (``str``) or a camera (``int`` index), decoded by OpenCV.

    The first frame is decoded when opening, so a missing, corrupt or unsupported video fails here
    with DetectError. ``frames_read`` counts frames decoded or skipped; ``ended`` is set once
    :meth:`frames` has run to the end of the video (see :meth:`truncation`).
    """

    def __init__(self, source: str | int) -> None:
        self.is_camera = isinstance(source, int)
        self.name = f"camera{source}" if isinstance(source, int) else Path(source).stem
        self.label = f"camera {source}" if self.is_camera else str(source)
        self.ended = False
        if not isinstance(source, int):
            if not Path(source).exists():
                raise DetectError(f"video not found: {source}")
            check_readable(Path(source), "video")
        self._cap = cv2.VideoCapture(source)
        if self.is_camera:
            self._cap.set(cv2.CAP_PROP_BUFFERSIZE, 1)   # the newest frame, not a stale queue
        fps, count = self._cap.get(cv2.CAP_PROP_FPS), self._cap.get(cv2.CAP_PROP_FRAME_COUNT)
        self.fps = fps if math.isfinite(fps) and fps > 0 else None
        self.frame_count = int(count) if not self.is_camera and math.isfinite(count) and count > 0 else None
        self.frames_read, self._last_ms = 0, -math.inf
        self._first_capture_s: float | None = None
        self._pending = self._decode() if self._cap.isOpened() else None
        if self._pending is None:
            self.close()
            what = "cannot be opened" if self.is_camera else "has no frame OpenCV can decode (corrupt or unsupported)"
            raise DetectError(f"{self.label}: {what}")

    def frames(self, every: int = 1) -> Iterator[VideoFrame]:
        """Frames 0, ``every``, 2 × ``every``, ... until the video ends (the others are skipped undecoded)."""
        frame, self._pending = self._pending, None
        while frame is not None:
            yield frame
            frame = self._decode() if self._skip(every - 1) else None
        self.ended = True

    def truncation(self) -> str | None:
        """Why the video file looks truncated, once :meth:`frames` has reached its end: it ended
        more than the slack (:data:`TRUNCATION_SLACK_FRAMES`) before the frame count its container
        declares. None otherwise, and for a camera or a container without a frame count."""
        if self.is_camera or not self.ended or self.frame_count is None:
            return None
        slack = max(TRUNCATION_SLACK_FRAMES, math.ceil(TRUNCATION_SLACK_SHARE * self.frame_count))
        if self.frames_read >= self.frame_count - slack:
            return None
        return (f"{self.label}: video ended after {self.frames_read} of {self.frame_count} frames: "
                "the file looks truncated (an interrupted copy or download, or a recording that was not closed)")

    def _skip(self, count: int) -> bool:
        for _ in range(count):
            if not self._cap.grab():
                return False
            self.frames_read += 1
        return True

    def _decode(self) -> VideoFrame | None:
        ok, image = self._cap.read()
        if not ok or image is None:
            return None
        capture_s = time.monotonic()
        frame = VideoFrame(self.frames_read, self._time_s(self.frames_read, capture_s), capture_s, image)
        self.frames_read += 1
        return frame

    def _time_s(self, index: int, capture_s: float) -> float | None:
        """Camera: seconds since its first frame. File: the frame's timestamp when the backend gives
        increasing ones, else ``index / fps`` (None without a frame rate)."""
        if self.is_camera:
            if self._first_capture_s is None:
                self._first_capture_s = capture_s
            return capture_s - self._first_capture_s
        position_ms = self._cap.get(cv2.CAP_PROP_POS_MSEC)
        if math.isfinite(position_ms) and position_ms > self._last_ms:
            self._last_ms = position_ms
            return position_ms / 1000.0
        return index / self.fps if self.fps else None

    def close(self) -> None:
        """Releases the video or camera; idempotent."""
        self._cap.release()
