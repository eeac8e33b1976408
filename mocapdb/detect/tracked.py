"""Detection that follows the people: person crops, the whole frame now and then, optical flow between.

:class:`TrackedDetector` turns the consecutive frames of one video into
:class:`~mocapdb.detect.model.Detections`, as :class:`~mocapdb.detect.model.PoseModel` does, each by
the cheapest path its :class:`FastPath` allows:

- **full**: the model on the whole frame (letterboxed to its input size): the first frame, a frame
  after nobody was seen, and at least every ``full_every`` frames, so people coming in are found;
- **crop**: one model run on a square crop around the people of the frame before (the union of
  their boxes, enlarged by :data:`CROP_MARGIN` of its larger side each way), warped straight from
  the frame into an input of at most ``crop_px`` pixels (fewer for a smaller crop: no enlargement;
  a multiple of :data:`STRIDE_PX`). A crop that finds fewer people than the frame before had (a
  track lost) is followed by a full-frame run on the same frame (path ``crop+full``);
- **flow**: with ``model_every`` N > 1, the model runs on every N-th frame only and the frames
  between get the keypoints of the frame before carried by pyramidal Lucas–Kanade optical flow
  (:func:`carry_keypoints`); each box moves with its keypoints.

A model with a fixed input size runs crops at that size (a dynamic export, ``dynamic=True``, runs
them smaller and so faster). Geometry and costs: ``data_specs/pose_models.md``.
"""
from __future__ import annotations

import math
import time
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from mocapdb.core import domains as D
from mocapdb.detect.model import PAD_VALUE, Detections, Letterbox, PoseModel
from mocapdb.detect.options import DEFAULT_CROP_PX, DEFAULT_FULL_EVERY

CROP_MARGIN = 0.25     # a crop reaches this share of the people's larger side beyond their boxes, each way
STRIDE_PX = 32         # model inputs are whole multiples of YOLO-pose's and RTMO's largest stride
FLOW_WINDOW_PX = 21    # Lucas–Kanade search window side, pixels at each pyramid level
FLOW_LEVELS = 3        # pyramid levels above the frame: motions up to ~2^3 × 10 px per frame are followed


@dataclass(frozen=True)
class FastPath:
    """The paths :class:`TrackedDetector` may take (module docstring), checked by their domains.

    ``crops``: follow the people in crops (else the whole frame every time); ``crop_px``: largest
    model input side for a crop, pixels; ``full_every``: the whole frame at least every this many
    frames; ``model_every``: the model on every this-many-th frame, optical flow between (1: never).
    """

    crops: bool = True
    crop_px: int = DEFAULT_CROP_PX
    full_every: int = DEFAULT_FULL_EVERY
    model_every: int = 1

    def __post_init__(self) -> None:
        D.MODEL_INPUT_PX.check(self.crop_px, "crop_px")
        D.DETECT_EVERY.check(self.full_every, "full_every")
        D.MODEL_EVERY.check(self.model_every, "model_every")

    def describe(self) -> str:
        """``person crops ≤ 256 px, full frame every 30 frames, model every 2nd frame (flow between)``."""
        parts = [f"person crops ≤ {self.crop_px} px, full frame every {self.full_every} frames"
                 if self.crops else "full frame"]
        if self.model_every > 1:
            parts.append(f"model every {self.model_every} frames (optical flow between)")
        return ", ".join(parts)


FULL_FRAME = FastPath(crops=False)   # the model on the whole of every frame


# --- crop geometry -----------------------------------------------------------------------------

def crop_square(boxes: np.ndarray, margin: float = CROP_MARGIN) -> tuple[np.ndarray, float]:
    """The square around people ``boxes [P, 4]`` (x1, y1, x2, y2 px): its centre (x, y) and side, pixels.

    The side is the union's larger side plus ``margin`` of it on each side, at least :data:`STRIDE_PX`.
    """
    low, high = boxes[:, :2].min(axis=0), boxes[:, 2:].max(axis=0)
    return (low + high) / 2.0, max(float((high - low).max()) * (1.0 + 2.0 * margin), STRIDE_PX)


def crop_input_px(side_px: float, largest_px: int) -> int:
    """The model input side for a crop of ``side_px``: at most ``largest_px``, at most the crop itself
    (no enlargement), rounded up to a multiple of :data:`STRIDE_PX`; pixels."""
    return max(STRIDE_PX, math.ceil(min(side_px, largest_px) / STRIDE_PX) * STRIDE_PX)


def crop_letterbox(centre_xy: np.ndarray, side_px: float, input_wh: tuple[int, int]) -> Letterbox:
    """Where the square of ``side_px`` around ``centre_xy`` (frame pixels) sits in a model input
    ``input_wh``: scaled to the input's shorter side, its centre at the input's centre."""
    scale = min(input_wh) / side_px
    offset = np.asarray(input_wh, dtype=np.float64) / 2.0 - scale * np.asarray(centre_xy, dtype=np.float64)
    return Letterbox(np.array([scale, scale]), offset)


def warp(image: np.ndarray, box: Letterbox, input_wh: tuple[int, int], pad_value: int = PAD_VALUE) -> np.ndarray:
    """The model input ``[h, w, 3]`` holding ``image`` where ``box`` puts it (input px = frame px ×
    scale + offset, continuous pixels), ``pad_value`` grey beyond the frame's edges."""
    (sx, sy), (ox, oy) = box.scale, box.offset
    # OpenCV maps pixel indices, whose centres lie half a pixel in: the offset shifts by (scale - 1) / 2
    matrix = np.array([[sx, 0.0, ox + (sx - 1.0) / 2.0], [0.0, sy, oy + (sy - 1.0) / 2.0]])
    return cv2.warpAffine(image, matrix, input_wh, flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                          borderValue=(pad_value,) * 3)


# --- optical flow --------------------------------------------------------------------------------

def carry_keypoints(previous_gray: np.ndarray, gray: np.ndarray, keypoints: np.ndarray) -> np.ndarray:
    """Keypoints ``[P, 17, 3]`` (x px, y px, confidence) of the frame ``previous_gray`` moved to the
    frame ``gray`` by pyramidal Lucas–Kanade optical flow; a point the flow loses keeps its place
    with confidence 0."""
    points = np.ascontiguousarray(keypoints[..., :2].reshape(-1, 1, 2), dtype=np.float32)
    # nextPts is an output here (no OPTFLOW_USE_INITIAL_FLOW): an array rather than None, which
    # OpenCV 4's type stubs refuse and OpenCV 5's accept
    moved, status, _ = cv2.calcOpticalFlowPyrLK(previous_gray, gray, points, np.empty_like(points),
                                                winSize=(FLOW_WINDOW_PX, FLOW_WINDOW_PX), maxLevel=FLOW_LEVELS)
    moved = moved.reshape(keypoints.shape[:2] + (2,))
    found = status.reshape(keypoints.shape[:2]).astype(bool) & np.isfinite(moved).all(axis=-1)
    carried = keypoints.copy()
    carried[..., :2] = np.where(found[..., None], moved, keypoints[..., :2])
    carried[..., 2] = np.where(found, keypoints[..., 2], 0.0)
    return carried


def _carry(previous: Detections, carried: np.ndarray) -> Detections:
    """``previous`` with its keypoints replaced by ``carried``; each box moved by the median shift of
    its person's points the flow followed."""
    shift = carried[..., :2] - previous.keypoints[..., :2]
    followed = carried[..., 2] > 0
    moves = np.array([np.median(s[f], axis=0) if f.any() else np.zeros(2) for s, f in zip(shift, followed)])
    return Detections(previous.boxes + np.tile(moves.reshape(-1, 2), 2), previous.scores, carried)


# --- the detector --------------------------------------------------------------------------------

class TrackedDetector:
    """The frames of one video, in order → :class:`~mocapdb.detect.model.Detections` (frame pixels),
    each by the cheapest path ``fast`` allows (module docstring).

    ``last_path`` names the path of the last frame (``full``, ``crop``, ``crop+full``, ``flow``),
    ``paths`` counts them; ``fps`` is the rate sustained (frames per second of detection time).
    """

    keypoint_layout = "coco17"

    def __init__(self, model: PoseModel, fast: FastPath = FULL_FRAME) -> None:
        self.model, self.fast = model, fast
        self.paths: Counter[str] = Counter()
        self.last_path = ""
        self.frames, self.seconds = 0, 0.0
        self._previous: Detections | None = None
        self._gray: np.ndarray | None = None
        self._last_model = self._last_full = -1   # frame numbers (from 0) of the last model and full-frame runs

    @property
    def path(self) -> Path:
        """The model file."""
        return self.model.path

    @property
    def fps(self) -> float:
        """Frames per second of detection time so far (0 before the first frame)."""
        return self.frames / self.seconds if self.seconds > 0 else 0.0

    def describe(self) -> str:
        """The model, the paths allowed and, once frames were detected, how many took each."""
        text = f"{self.model.describe()}; {self.fast.describe()}"
        if self.fast.crops and not self.model.dynamic:
            text += "; crops at the model's fixed input size (a dynamic export runs them smaller)"
        if self.paths:
            text += "; frames by path: " + ", ".join(f"{path} {n}" for path, n in sorted(self.paths.items()))
        return text

    def __call__(self, image: np.ndarray) -> Detections:
        """The people in ``image [H, W, 3]`` (uint8 BGR), the frame after the one of the last call."""
        started = time.perf_counter()
        found, self.last_path = self._detect(image)
        self._previous = found
        self.paths[self.last_path] += 1
        self.frames += 1
        self.seconds += time.perf_counter() - started
        return found

    def _detect(self, image: np.ndarray) -> tuple[Detections, str]:
        frame, previous, previous_gray = self.frames, self._previous, self._gray
        if self.fast.model_every > 1:
            self._gray = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
        gray = self._gray
        seen = previous if previous is not None and len(previous.scores) > 0 else None  # the last frame's people
        if (seen is not None and previous_gray is not None and gray is not None
                and frame - self._last_model < self.fast.model_every):
            return _carry(seen, carry_keypoints(previous_gray, gray, seen.keypoints)), "flow"
        self._last_model = frame
        path = "full"
        if self.fast.crops and seen is not None and frame - self._last_full < self.fast.full_every:
            found = self._crop(image, seen.boxes)
            if len(found.scores) >= len(seen.scores):
                return found, "crop"
            path = "crop+full"
        self._last_full = frame
        return self.model(image), path

    def _crop(self, image: np.ndarray, boxes: np.ndarray) -> Detections:
        """The model on one crop around ``boxes`` (frame pixels)."""
        centre, side_px = crop_square(boxes)
        input_wh = self.model.input_wh
        if self.model.dynamic:
            side = crop_input_px(side_px, self.fast.crop_px)
            input_wh = (side, side)
        box = crop_letterbox(centre, side_px, input_wh)
        return self.model.run(warp(image, box, input_wh), box)
