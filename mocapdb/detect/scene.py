"""The room's straight lines in a few video frames, for the camera's tilt and focal (issue 51).

:class:`SceneSampler` is handed every frame ``detect`` writes with the people found in it
(:meth:`SceneSampler.see`); one frame every 2 s (:data:`SAMPLE_PERIOD_S`, at most
:data:`MAX_FRAMES`, thinned evenly when a take is longer) it finds the frame's line segments
(:func:`line_segments`: OpenCV's LSD on the grey image scaled to :data:`WORK_SIDE_PX`, else Canny and
the probabilistic Hough transform where an OpenCV build lacks LSD), drops those that cross a
person's box, keeps the :data:`MAX_SEGMENTS` longest and gives them as
:class:`~mocapdb.core.formats.scene.SceneLines`, written as ``scene.json`` (:meth:`SceneSampler.finish`).
Cost (1080 × 1920, 2 shared cores): 35-85 ms a sampled frame, 0.3-0.7 ms a frame of a 60 fps
video, 2-4 % of BlazePose's detection (``tools/scene_lines.py`` prints it).
"""
from __future__ import annotations

from functools import cache
from pathlib import Path

import cv2
import numpy as np

from mocapdb.core.formats.scene import SCENE_FILE, SceneLines, write_scene

SAMPLE_PERIOD_S = 2.0     # one frame every 2 s: a still camera's lines do not change
MAX_FRAMES = 60           # frames kept; a longer take keeps every other one, the period doubled
WORK_SIDE_PX = 640        # the image's long side for the line detector (pixels)
MIN_LENGTH = 0.025        # shortest segment kept, a share of the image's long side
MAX_SEGMENTS = 256        # longest segments kept a frame
UNKNOWN_RATE_HZ = 30.0    # a camera's frames, numbered as they come
BOX_MARGIN = 0.15         # a person's box grown by this share of its height on every side (hair, feet, shadow)


def line_segments(image: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """The straight segments ``[N, 4]`` (x1, y1, x2, y2; pixels of ``image``) of a BGR or grey
    ``image`` that stay out of every box ``boxes [P, 4]`` (x0, y0, x1, y1 px), at least
    :data:`MIN_LENGTH` of the long side, the :data:`MAX_SEGMENTS` longest."""
    grey = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    scale = min(1.0, WORK_SIDE_PX / max(grey.shape))
    small = cv2.resize(grey, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA) if scale < 1 else grey
    segments = _detect(small) / scale
    length = np.hypot(segments[:, 2] - segments[:, 0], segments[:, 3] - segments[:, 1])
    keep = (length >= MIN_LENGTH * max(grey.shape)) & ~_crosses_boxes(segments, boxes)
    segments, length = segments[keep], length[keep]
    return segments[np.argsort(-length)[:MAX_SEGMENTS]]


def _detect(grey: np.ndarray) -> np.ndarray:
    """Segments ``[N, 4]`` of a grey image: LSD where OpenCV has it (:func:`detector_name`), else
    Canny + HoughLinesP."""
    found: np.ndarray | None
    if detector_name() == "lsd":
        found = cv2.createLineSegmentDetector().detect(grey)[0]
    else:
        edges = cv2.Canny(grey, 50, 150)
        side = max(grey.shape)
        found = cv2.HoughLinesP(edges, 1, np.pi / 360, 40, minLineLength=MIN_LENGTH * side, maxLineGap=3)
    return np.zeros((0, 4)) if found is None else found.reshape(-1, 4).astype(np.float64)


@cache
def detector_name() -> str:
    """"lsd" where this OpenCV's line segment detector runs (OpenCV 3.x and >= 4.5.1; 4.0-4.5.0 have
    the function but raise: its code was withdrawn over its licence, then restored), else "hough"."""
    try:
        cv2.createLineSegmentDetector().detect(np.zeros((16, 16), np.uint8))
    except (AttributeError, cv2.error):
        return "hough"
    return "lsd"


def _crosses_boxes(segments: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """Per segment, whether any of 9 points along it lies in a box grown by :data:`BOX_MARGIN`."""
    if not len(boxes) or not len(segments):
        return np.zeros(len(segments), dtype=bool)
    t = np.linspace(0.0, 1.0, 9)[None, :, None]
    points = segments[:, None, :2] * (1 - t) + segments[:, None, 2:] * t              # [N, 9, 2]
    margin = BOX_MARGIN * (boxes[:, 3] - boxes[:, 1])[:, None]
    low, high = boxes[:, :2] - margin, boxes[:, 2:] + margin                           # [P, 2]
    inside = ((points[:, :, None] >= low) & (points[:, :, None] <= high)).all(axis=-1)  # [N, 9, P]
    return inside.any(axis=(1, 2))


def people_boxes(keypoints: np.ndarray) -> np.ndarray:
    """Each person's box ``[P, 4]`` (x0, y0, x1, y1 px) about its keypoints ``[P, K, 3]`` seen
    (confidence > 0); a person with none seen gets no box."""
    boxes = []
    for person in np.asarray(keypoints, dtype=np.float64):
        seen = person[(person[:, 2] > 0) & np.isfinite(person[:, :2]).all(axis=1), :2]
        if len(seen):
            boxes.append([*seen.min(axis=0), *seen.max(axis=0)])
    return np.array(boxes, dtype=np.float64).reshape(-1, 4)


class SceneSampler:
    """Collects the line segments of one frame every :data:`SAMPLE_PERIOD_S` of a take at
    ``rate_hz`` frames a second (the keypoints' rate; None: :data:`UNKNOWN_RATE_HZ`), and writes them
    as ``scene.json``: a frame watcher of ``detect``
    (:class:`~mocapdb.detect.openpose_out.FrameWatcher`)."""

    def __init__(self, rate_hz: float | None) -> None:
        self.every = max(round((rate_hz or UNKNOWN_RATE_HZ) * SAMPLE_PERIOD_S), 1)
        self.frames: list[int] = []
        self.segments: list[np.ndarray] = []
        self.image_size: tuple[int, int] | None = None
        self._next = 0

    def see(self, number: int, image: np.ndarray, keypoints: np.ndarray) -> None:
        """Frame ``number`` (BGR ``image``; ``keypoints [P, K, 3]`` the people found in it): its
        segments when its turn has come."""
        if number < self._next:
            return
        self.image_size = self.image_size or (int(image.shape[1]), int(image.shape[0]))
        self.frames.append(number)
        self.segments.append(line_segments(image, people_boxes(keypoints)))
        self._next = number + self.every
        if len(self.frames) > MAX_FRAMES:   # keep every other frame, sample half as often
            self.frames, self.segments, self.every = self.frames[::2], self.segments[::2], 2 * self.every

    def scene(self) -> SceneLines | None:
        """What was sampled (None: no frame)."""
        if self.image_size is None:
            return None
        return SceneLines(self.image_size, tuple(self.frames), tuple(self.segments), detector_name())

    def finish(self, out_dir: Path) -> list[str]:
        """Writes ``out_dir/scene.json`` (none when no frame was seen); the line ``detect`` reports."""
        lines = self.scene()
        if lines is None:
            return []
        write_scene(out_dir, lines)
        count = sum(len(s) for s in lines.segments)
        return [f"scene: {count} line segments in {len(lines.frames)} frame(s) ({SCENE_FILE})"]
