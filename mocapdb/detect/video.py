"""Decoded video frames for the detector: a video file or a camera read with OpenCV.

:class:`VideoReader` decodes its first frame when opening (so a missing, corrupt or unsupported
video fails at once with :class:`~mocapdb.detect.errors.DetectError`), gives every frame its
timestamp and the moment it was decoded, skips frames undecoded for ``--every`` and tells a video
file that ended before its declared frame count (:meth:`VideoReader.truncation`: a warning, the
frames decoded are all used). A file's frame times are its container's timestamps, checked
(:meth:`VideoReader.time_warnings`); :class:`FrameClock` numbers the frames on the video's nominal
timeline, so a gap in the timestamps keeps its length (``data_specs/take_description.md``, "Frame
times").
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
    time_s: float | None   # seconds since the first frame (the container's timestamps, else from the frame rate)
    capture_s: float       # time.monotonic() when it was decoded
    image: np.ndarray      # [H, W, 3] uint8 BGR


# A video file that ends more than max(TRUNCATION_SLACK_FRAMES, TRUNCATION_SLACK_SHARE × count)
# frames before the frame count its container declares looks truncated. The slack: containers
# that give no count of their own have one estimated from the duration, which can be a frame or
# two off (and a few per cent for a variable frame rate).
TRUNCATION_SLACK_FRAMES = 2
TRUNCATION_SLACK_SHARE = 0.01
# A container timestamp further than this after the frame before is nonsense (a corrupt value), not a
# gap: phones pause a recording into a new file, and a gap this long would end every track anyway.
MAX_TIMESTAMP_JUMP_S = 60.0
# A file's frame rate is checked against the median interval of its first PROBE_FRAMES timestamps: a
# container's rate more than RATE_TOLERANCE off it (FFmpeg's average rate counts a gap's missing time,
# 25 fps for 30 frames over 1.2 s) gives way to the timestamps' rate.
PROBE_FRAMES = 24
RATE_TOLERANCE = 0.01


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
        self.rate_note: str | None = None   # why the frame rate is not the container's, if it is not
        if not self.is_camera and self._cap.isOpened():
            self._check_rate(str(source))
        self.frame_count = int(count) if not self.is_camera and math.isfinite(count) and count > 0 else None
        self.frames_read = 0
        self.times_guessed = 0   # frames whose container timestamp was missing or nonsense (see _file_time_s)
        self.times_decoded = 0   # frames given a time, from the container or guessed
        self._origin_ms: float | None = None            # the first frame's container timestamp (ms)
        self._anchor: tuple[int, float] = (0, 0.0)      # (index, seconds) of the last frame given a time
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
        return (f"{self.label}: the container promised {self.frame_count} frames, {self.frames_read} could be read: "
                "the file looks cut short (an interrupted copy or download, or a recording that was not closed); "
                "every frame read is used")

    def time_warnings(self) -> list[str]:
        """Warnings on a video file's timing: the frame rate taken from its timestamps rather than
        from the container (:meth:`_check_rate`), and frames without a usable container timestamp
        (missing, not increasing, or more than :data:`MAX_TIMESTAMP_JUMP_S` after the frame before)
        whose times were counted from the frame rate instead."""
        warnings = [self.rate_note] if self.rate_note else []
        if self.times_guessed:
            warnings.append(f"{self.label}: {self.times_guessed} of {self.times_decoded} frames had no usable "
                            "timestamp in the container (missing, not increasing, or jumping more than "
                            f"{MAX_TIMESTAMP_JUMP_S:g} s): their times are counted from the frame rate")
        return warnings

    def _check_rate(self, path: str) -> None:
        """``fps`` becomes the rate the first :data:`PROBE_FRAMES` timestamps keep (1 / their median
        interval) when the container gives none or one more than :data:`RATE_TOLERANCE` off it
        (``rate_note`` says so); unchanged when the timestamps do not tell (fewer than 3 increasing)."""
        probe = cv2.VideoCapture(path)
        try:
            times_ms = [probe.get(cv2.CAP_PROP_POS_MSEC) for _ in range(PROBE_FRAMES) if probe.grab()]
        finally:
            probe.release()
        steps_ms = np.diff(np.array(times_ms, dtype=np.float64))
        steps_ms = steps_ms[np.isfinite(steps_ms) & (steps_ms > 0)]
        if len(steps_ms) < 2:
            return
        measured = float(f"{1000.0 / float(np.median(steps_ms)):.6g}")   # 1 µs/s: no drift a take would show
        if self.fps is not None and abs(measured / self.fps - 1.0) <= RATE_TOLERANCE:
            return
        said = f"says {self.fps:g} fps" if self.fps else "gives no frame rate"
        self.rate_note = (f"{self.label}: the container {said}, its timestamps keep {measured:g} fps "
                          f"(median interval of the first {len(times_ms)} frames): using {measured:g} fps")
        self.fps = measured

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
        """Camera: seconds since its first frame. File: :meth:`_file_time_s`."""
        if not self.is_camera:
            return self._file_time_s(index)
        if self._first_capture_s is None:
            self._first_capture_s = capture_s
        return capture_s - self._first_capture_s

    def _file_time_s(self, index: int) -> float | None:
        """Seconds since the first frame: the container's timestamp of the frame just decoded
        (``CAP_PROP_POS_MSEC``) when it is finite, later than the frame before and at most
        :data:`MAX_TIMESTAMP_JUMP_S` after it; else counted (``times_guessed``) at the frame rate from
        the last frame given a time (``index / fps`` when the container gives none); None without
        either."""
        self.times_decoded += 1
        position_ms = self._cap.get(cv2.CAP_PROP_POS_MSEC)
        if self._origin_ms is None:   # the first frame: times count from it
            self._origin_ms = position_ms if math.isfinite(position_ms) else 0.0
        anchor_index, anchor_s = self._anchor
        read_s = (position_ms - self._origin_ms) / 1000.0
        if index == 0 and read_s == 0.0 or anchor_s < read_s <= anchor_s + MAX_TIMESTAMP_JUMP_S:
            self._anchor = (index, read_s)
            return read_s
        self.times_guessed += 1
        if self.fps is None:
            return None
        self._anchor = (index, anchor_s + (index - anchor_index) / self.fps)
        return self._anchor[1]

    def close(self) -> None:
        """Releases the video or camera; idempotent."""
        self._cap.release()


class FrameClock:
    """Frame numbers on a video's nominal timeline at ``rate_hz`` (the keypoints' rate: the video's
    frame rate over ``--every``): the frame at ``time_s`` seconds is number ``round(time_s × rate_hz)``,
    at least one more than the frame before (numbers keep increasing where frames come faster). The
    numbers a gap in the timestamps passes over have no frame: ``missing`` counts them, ``gaps`` the
    jumps, ``longest_gap_s`` the longest time between two frames across one. Without a rate or a
    time, the next number."""

    def __init__(self, rate_hz: float | None) -> None:
        self.rate_hz = rate_hz
        self.missing = self.gaps = 0
        self.longest_gap_s = 0.0
        self._last: tuple[int, float | None] = (-1, None)   # the last frame's number and time (s)

    def number(self, time_s: float | None) -> int:
        """The number of the next frame, at ``time_s`` seconds (None: unknown)."""
        last, last_s = self._last
        due = round(time_s * self.rate_hz) if time_s is not None and self.rate_hz else last + 1
        number = max(due, last + 1)
        if number > last + 1 and last >= 0:
            self.missing += number - last - 1
            self.gaps += 1
            if time_s is not None and last_s is not None:
                self.longest_gap_s = max(self.longest_gap_s, time_s - last_s)
        self._last = (number, time_s)
        return number

    def report(self) -> str | None:
        """One line on the gaps in the timestamps, None without any."""
        if not self.gaps:
            return None
        return (f"the timestamps jump {self.gaps} time(s) (longest {self.longest_gap_s * 1000:.0f} ms between two "
                f"frames): {self.missing} frame time(s) at {self.rate_hz:g} Hz hold no frame; frames keep their "
                "times (frame numbers skip the gap)")
