"""From video to 2D keypoints: an ONNX pose model (YOLO-pose or RTMO export) on decoded frames.

`mocapdb detect` decodes a video file or a camera with OpenCV, runs the model with onnxruntime
(CPU) on each frame and writes one OpenPose ``--write_json`` file per frame in the COCO-18 layout.
:class:`PoseModel` tells the export layouts apart by their tensor shapes, letterboxes each frame,
thresholds and suppresses overlapping people (NMS) and maps keypoints back to the frame's pixels.
Layouts, pre-processing and the files written: ``data_specs/pose_models.md``. Nothing is downloaded:
the user points ``--model`` at an export of their own.
"""
from __future__ import annotations

import json
import math
import sys
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any, NamedTuple

import cv2
import numpy as np
from tqdm import tqdm

from mocapdb.core.errors import MocapdbError
from mocapdb.core.files import os_error_message, write_atomic
from mocapdb.core.formats.keypoints import LAYOUTS
from mocapdb.detect.options import DEFAULT_CONF, DEFAULT_INPUT_SIZE, DEFAULT_IOU

PAD_VALUE = 114            # letterbox padding grey level (both layouts were trained with it)
MAX_CANDIDATES = 1000      # best-scoring people passed to NMS, bounding its cost

N_COCO = len(LAYOUTS["coco17"])
YOLO_CHANNELS = 4 + 1 + 3 * N_COCO
KNOWN_LAYOUTS = (f"YOLO-pose (input [1, 3, H, W]; output [1, {YOLO_CHANNELS}, anchors] or "
                 f"[1, anchors, {YOLO_CHANNELS}]) and RTMO (input [1, 3, H, W]; outputs [1, N, 5] "
                 f"and [1, N, {N_COCO}, 3])")
_INPUT_TYPES = {"tensor(float)": np.float32, "tensor(float16)": np.float16}


class DetectError(MocapdbError, RuntimeError):
    """A model, video or option that cannot be used; the message says which and why."""


def _check_readable(path: Path, what: str) -> None:
    """DetectError naming ``path`` when it is a folder or cannot be opened for reading."""
    if path.is_dir():
        raise DetectError(f"{path}: is a folder, not a {what} file")
    try:
        with open(path, "rb"):
            pass
    except OSError as exc:
        raise DetectError(os_error_message(exc, path, f"read the {what}")) from None


# --- letterbox -------------------------------------------------------------------------------

@dataclass(frozen=True)
class Letterbox:
    """Where a frame sits in the model input: input px = frame px × ``scale`` + ``offset`` (x, y)."""

    scale: np.ndarray   # [2] input pixels per frame pixel
    offset: np.ndarray  # [2] pixels of padding before the frame

    def to_original(self, xy: np.ndarray) -> np.ndarray:
        """Model-input coordinates ``[..., 2]`` (pixels) → frame coordinates (pixels)."""
        return (xy - self.offset) / self.scale


def letterbox(image: np.ndarray, size_wh: tuple[int, int], centred: bool,
              pad_value: int = PAD_VALUE) -> tuple[np.ndarray, Letterbox]:
    """``image [H, W, 3]`` scaled to fit ``size_wh`` (aspect kept) on a ``pad_value`` canvas.

    ``centred``: the padding is split evenly on both sides; otherwise the image sits top-left.
    """
    height, width = image.shape[:2]
    out_w, out_h = size_wh
    ratio = min(out_w / width, out_h / height)
    new_w, new_h = max(1, round(width * ratio)), max(1, round(height * ratio))
    x0, y0 = ((out_w - new_w) // 2, (out_h - new_h) // 2) if centred else (0, 0)
    canvas = np.full((out_h, out_w, 3), pad_value, dtype=np.uint8)
    canvas[y0:y0 + new_h, x0:x0 + new_w] = cv2.resize(image, (new_w, new_h), interpolation=cv2.INTER_LINEAR)
    return canvas, Letterbox(np.array([new_w / width, new_h / height]), np.array([x0, y0], dtype=np.float64))


# --- boxes -----------------------------------------------------------------------------------

def box_iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Intersection over union ``[N, M]`` of boxes ``a [N, 4]`` and ``b [M, 4]`` (x1, y1, x2, y2)."""
    top_left = np.maximum(a[:, None, :2], b[None, :, :2])
    bottom_right = np.minimum(a[:, None, 2:], b[None, :, 2:])
    inter = np.prod(np.clip(bottom_right - top_left, 0.0, None), axis=-1)
    area_a = np.prod(np.clip(a[:, 2:] - a[:, :2], 0.0, None), axis=-1)
    area_b = np.prod(np.clip(b[:, 2:] - b[:, :2], 0.0, None), axis=-1)
    union = area_a[:, None] + area_b[None, :] - inter
    return np.divide(inter, union, out=np.zeros_like(inter), where=union > 0)


def nms(boxes: np.ndarray, scores: np.ndarray, iou_threshold: float = DEFAULT_IOU) -> np.ndarray:
    """Greedy class-agnostic non-maximum suppression: the indices kept, best score first.

    A box is dropped when its IoU with a kept, better-scoring box exceeds ``iou_threshold``. The
    IoU matrix is computed at once; the greedy pass walks the candidates in score order.
    """
    order = np.argsort(-scores, kind="stable")
    overlaps = box_iou(boxes[order], boxes[order]) > iou_threshold
    keep = np.ones(len(order), dtype=bool)
    for i in range(len(order)):
        if keep[i]:
            keep[i + 1:] &= ~overlaps[i, i + 1:]
    return order[keep]


# --- model layouts ---------------------------------------------------------------------------

Decoded = tuple[np.ndarray, np.ndarray, np.ndarray]   # boxes [N, 4], scores [N], keypoints [N, 17, 3]


def _decode_yolo(outputs: list[np.ndarray], anchors_last: bool) -> Decoded:
    """YOLO-pose rows (cx, cy, w, h, score, 17 × (x, y, conf)), in input pixels."""
    rows = outputs[0][0].T if anchors_last else outputs[0][0]
    centre, half = rows[:, 0:2], rows[:, 2:4] / 2
    return np.concatenate([centre - half, centre + half], axis=1), rows[:, 4], rows[:, 5:].reshape(-1, N_COCO, 3)


def _decode_rtmo(outputs: list[np.ndarray], dets_at: int, keypoints_at: int) -> Decoded:
    """RTMO ``dets`` (x1, y1, x2, y2, score) and ``keypoints`` (x, y, score), in input pixels."""
    dets = outputs[dets_at][0]
    return dets[:, :4], dets[:, 4], outputs[keypoints_at][0]


@dataclass(frozen=True)
class ModelLayout:
    """How a known export is fed and read."""

    name: str
    centred: bool      # letterbox: padding split evenly (else the frame sits top-left)
    rgb: bool          # channel order RGB (else BGR, as decoded)
    unit_range: bool   # pixel values divided by 255 (else raw 0–255)
    decode: Callable[[list[np.ndarray]], Decoded]


_ANY, _BATCH = "any", "batch"   # shape patterns: any size; 1 or a symbolic (dynamic) size


def _matches(shape: list[Any] | None, pattern: tuple[Any, ...]) -> bool:
    """Whether a tensor shape (ints; strings or None when dynamic; None when unknown) fits ``pattern``."""
    return shape is not None and len(shape) == len(pattern) and all(
        p == _ANY or (p == _BATCH and (d == 1 or not isinstance(d, int))) or d == p
        for d, p in zip(shape, pattern))


def identify_layout(input_shapes: list[list[Any]], output_shapes: list[list[Any]]) -> ModelLayout | None:
    """The layout whose input and output shapes these are, or None."""
    if len(input_shapes) != 1 or not _matches(input_shapes[0], (_BATCH, 3, _ANY, _ANY)):
        return None
    if len(output_shapes) == 1:
        for anchors_last, pattern in ((True, (_BATCH, YOLO_CHANNELS, _ANY)), (False, (_BATCH, _ANY, YOLO_CHANNELS))):
            if _matches(output_shapes[0], pattern):
                return ModelLayout("yolo-pose", True, True, True, partial(_decode_yolo, anchors_last=anchors_last))
    if len(output_shapes) == 2:
        dets = [i for i, s in enumerate(output_shapes) if _matches(s, (_BATCH, _ANY, 5))]
        keypoints = [i for i, s in enumerate(output_shapes) if _matches(s, (_BATCH, _ANY, N_COCO, 3))]
        if len(dets) == 1 and len(keypoints) == 1:
            return ModelLayout("rtmo", False, False, False,
                               partial(_decode_rtmo, dets_at=dets[0], keypoints_at=keypoints[0]))
    return None


def _shape_text(shape: list[Any] | None) -> str:
    return "[?]" if shape is None else "[" + ", ".join("?" if d is None else str(d) for d in shape) + "]"


# --- the model -------------------------------------------------------------------------------

class Detections(NamedTuple):
    """The people found in one frame, best score first, in frame pixels."""

    boxes: np.ndarray      # [P, 4] x1, y1, x2, y2
    scores: np.ndarray     # [P]
    keypoints: np.ndarray  # [P, 17, 3] x, y, confidence in the COCO-17 order


def _first_line(exc: Exception) -> str:
    """The first line of an exception's message, or its type name when it has none."""
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


def _load_session(path: Path) -> Any:
    """An onnxruntime CPU session for ``path``; DetectError when missing or not loadable."""
    if not path.exists():
        raise DetectError(f"pose model not found: {path}")
    _check_readable(path, "pose model")
    import onnxruntime as ort

    options = ort.SessionOptions()
    options.log_severity_level = 3   # errors only
    try:
        return ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
    except Exception as exc:  # noqa: BLE001 - onnxruntime's exception types share no narrower base
        raise DetectError(f"{path}: not a usable ONNX model ({_first_line(exc)})") from None


def _check_options(conf: float, iou: float, max_people: int | None, input_size: int) -> None:
    if not 0.0 <= conf <= 1.0:
        raise DetectError(f"confidence threshold (--conf) {conf} is not in [0, 1]")
    if not 0.0 < iou <= 1.0:
        raise DetectError(f"NMS IoU threshold (--iou) {iou} is not in (0, 1]")
    if max_people is not None and max_people < 1:
        raise DetectError("the maximum number of people (--max-people) must be at least 1")
    if input_size < 32:
        raise DetectError(f"input size (--input-size) {input_size} px is too small (at least 32)")


class PoseModel:
    """A YOLO-pose or RTMO ONNX export run by onnxruntime on the CPU: frame (BGR) → :class:`Detections`.

    ``conf``: least person score kept; ``iou``: NMS threshold; ``max_people``: the best ones kept
    (None: all); ``input_size``: side in pixels for a dynamic input. ``fps`` is the rate detection
    sustains (frames per second of pre-processing, inference and post-processing time).
    """

    def __init__(self, path: str | Path, *, conf: float = DEFAULT_CONF, iou: float = DEFAULT_IOU,
                 max_people: int | None = None, input_size: int = DEFAULT_INPUT_SIZE) -> None:
        _check_options(conf, iou, max_people, input_size)
        self.path = Path(path)
        self._session = _load_session(self.path)
        inputs, outputs = self._session.get_inputs(), self._session.get_outputs()
        layout = identify_layout([i.shape for i in inputs], [o.shape for o in outputs])
        if layout is None or inputs[0].type not in _INPUT_TYPES:
            raise DetectError(
                f"{self.path}: unknown pose model layout: inputs "
                f"{', '.join(f'{i.name} {_shape_text(i.shape)} {i.type}' for i in inputs)}; outputs "
                f"{', '.join(f'{o.name} {_shape_text(o.shape)}' for o in outputs)}. Known layouts: {KNOWN_LAYOUTS} "
                f"(float32 or float16 input)")
        self.layout = layout
        self._input_name, self._dtype = inputs[0].name, _INPUT_TYPES[inputs[0].type]
        height, width = (d if isinstance(d, int) and d > 0 else input_size for d in inputs[0].shape[2:])
        self.input_wh = (width, height)
        self.conf, self.iou, self.max_people = conf, iou, max_people
        self.frames, self.seconds = 0, 0.0

    @property
    def fps(self) -> float:
        """Frames per second of detection time so far (0 before the first frame)."""
        return self.frames / self.seconds if self.seconds > 0 else 0.0

    def describe(self) -> str:
        """Layout and input size, e.g. ``yolo-pose 640x640``."""
        return f"{self.layout.name} {self.input_wh[0]}x{self.input_wh[1]}"

    def __call__(self, image: np.ndarray) -> Detections:
        """The people in ``image [H, W, 3]`` (uint8 BGR, as OpenCV decodes), in its pixels."""
        started = time.perf_counter()
        canvas, box = letterbox(image, self.input_wh, self.layout.centred)
        boxes, scores, keypoints = self._decode(self._infer(canvas))
        keep = self._select(boxes, scores)
        corners = box.to_original(boxes[keep].reshape(-1, 2, 2)).reshape(-1, 4)
        points = np.concatenate([box.to_original(keypoints[keep, :, :2]), keypoints[keep, :, 2:]], axis=-1)
        self.frames += 1
        self.seconds += time.perf_counter() - started
        return Detections(corners, scores[keep], points)

    def _infer(self, canvas: np.ndarray) -> list[np.ndarray]:
        pixels = canvas[..., ::-1] if self.layout.rgb else canvas
        blob = np.ascontiguousarray(pixels.transpose(2, 0, 1)[None], dtype=self._dtype)
        if self.layout.unit_range:
            blob *= self._dtype(1.0 / 255.0)
        try:
            return self._session.run(None, {self._input_name: blob})
        except Exception as exc:  # noqa: BLE001 - onnxruntime's exception types share no narrower base
            raise DetectError(f"{self.path}: inference failed ({_first_line(exc)})") from None

    def _decode(self, outputs: list[np.ndarray]) -> Decoded:
        """Boxes, scores and keypoints in input pixels; DetectError when the outputs do not fit the layout."""
        try:
            boxes, scores, keypoints = self.layout.decode([np.asarray(o, dtype=np.float64) for o in outputs])
            fits = boxes.shape[1:] == (4,) and len(boxes) == len(scores) == len(keypoints)
        except (ValueError, IndexError):
            fits = False
        if not fits:
            shapes = ", ".join(_shape_text(list(np.shape(o))) for o in outputs)
            raise DetectError(f"{self.path}: outputs of shapes {shapes} do not fit the {self.layout.name} layout")
        return boxes, scores, keypoints

    def _select(self, boxes: np.ndarray, scores: np.ndarray) -> np.ndarray:
        """Indices of the people kept: score threshold, the best candidates, NMS, ``max_people``."""
        ok = np.flatnonzero(np.isfinite(scores) & (scores >= self.conf) & np.isfinite(boxes).all(axis=1))
        ok = ok[np.argsort(-scores[ok], kind="stable")][:MAX_CANDIDATES]
        return ok[nms(boxes[ok], scores[ok], self.iou)][:self.max_people]


# --- video -----------------------------------------------------------------------------------

class VideoFrame(NamedTuple):
    """One decoded frame."""

    index: int             # frame number in the video (camera: since opening), from 0
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
        self.name = f"camera{source}" if self.is_camera else Path(source).stem
        self.label = f"camera {source}" if self.is_camera else str(source)
        self.ended = False
        if not self.is_camera:
            if not Path(source).exists():
                raise DetectError(f"video not found: {source}")
            _check_readable(Path(source), "video")
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


# --- OpenPose JSON ---------------------------------------------------------------------------

def _coco17_name(openpose_name: str) -> str:
    """An OpenPose COCO-18 name in the COCO-17 spelling: ``RShoulder`` → ``right_shoulder``."""
    sides = {"R": "right_", "L": "left_"}
    if openpose_name[0] in sides and openpose_name[1:2].isupper():
        return sides[openpose_name[0]] + openpose_name[1:].lower()
    return openpose_name.lower()


_COCO18_SOURCE = np.array([LAYOUTS["coco17"].index(n) if n in LAYOUTS["coco17"] else -1
                           for n in map(_coco17_name, LAYOUTS["coco18"])])
_NECK = LAYOUTS["coco18"].index("Neck")
_SHOULDERS = [LAYOUTS["coco17"].index("left_shoulder"), LAYOUTS["coco17"].index("right_shoulder")]


def coco17_to_coco18(keypoints: np.ndarray) -> np.ndarray:
    """``[P, 17, 3]`` (x px, y px, confidence) → ``[P, 18, 3]`` in the OpenPose COCO-18 order.

    The neck is the mid-shoulder point with the smaller shoulder confidence; (0, 0, 0), OpenPose's
    "not found", when either shoulder has confidence 0. Non-finite entries become (0, 0, 0) too.
    """
    out = keypoints[:, np.maximum(_COCO18_SOURCE, 0)].copy()
    shoulders = keypoints[:, _SHOULDERS]
    neck_conf = shoulders[..., 2].min(axis=1)
    neck = np.concatenate([shoulders[..., :2].mean(axis=1), neck_conf[:, None]], axis=-1)
    out[:, _NECK] = np.where(neck_conf[:, None] > 0, neck, 0.0)
    return np.where(np.isfinite(out).all(axis=-1, keepdims=True), out, 0.0)


def openpose_json(keypoints: np.ndarray) -> str:
    """One OpenPose ``--write_json`` frame (version 1.3, COCO-18) for people ``[P, 17, 3]`` in COCO-17."""
    rows = coco17_to_coco18(np.asarray(keypoints, dtype=np.float64).reshape(-1, N_COCO, 3))
    rows = np.concatenate([np.round(rows[..., :2], 2), np.round(rows[..., 2:], 4)], axis=-1)
    people = [{"person_id": [-1], "pose_keypoints_2d": person.ravel().tolist(), "face_keypoints_2d": [],
               "hand_left_keypoints_2d": [], "hand_right_keypoints_2d": []} for person in rows]
    return json.dumps({"version": 1.3, "people": people})


def frame_file_name(stem: str, index: int) -> str:
    """OpenPose's per-frame file name: ``<stem>_<frame:012d>_keypoints.json``."""
    return f"{stem}_{index:012d}_keypoints.json"


# --- the detect command ----------------------------------------------------------------------

@dataclass
class DetectSummary:
    """What a detect run did; :meth:`report` renders it."""

    frames_read: int = 0
    people: list[int] = field(default_factory=list)   # people in each frame written
    detection_fps: float = 0.0
    interrupted: bool = False
    truncated: str | None = None   # why the video looks truncated (VideoReader.truncation), else None

    def report(self) -> str:
        counts = np.array(self.people, dtype=np.int64)
        mean, most = (counts.mean(), counts.max()) if counts.size else (0.0, 0)
        return "\n".join([
            f"frames read {self.frames_read}, frames written {counts.size}"
            + (" (interrupted)" if self.interrupted else "")
            + (" (the video ended early: truncated?)" if self.truncated else ""),
            f"people per frame: mean {mean:.2f}, max {most}, frames with nobody {int(np.sum(counts == 0))}",
            f"detection {self.detection_fps:.1f} frames/s"])


def detect_video(reader: VideoReader, model: PoseModel, out_dir: Path, every: int = 1,
                 stop: threading.Event | None = None) -> DetectSummary:
    """Detect people in every ``every``-th frame and write one OpenPose JSON file per frame
    (atomically) into ``out_dir``; ends with the video or once ``stop`` is set. ``truncated`` of
    the summary says when the video file ended before its declared frame count (the files written
    are complete); DetectError naming the path when the folder or a file cannot be written."""
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise DetectError(os_error_message(exc, out_dir, "create the output folder")) from None
    summary = DetectSummary()
    total = -(-reader.frame_count // every) if reader.frame_count else None
    with tqdm(total=total, desc=f"detect {reader.name}", unit="frame", disable=None, file=sys.stderr) as bar:
        for frame in reader.frames(every):
            found = model(frame.image)
            path = out_dir / frame_file_name(reader.name, frame.index)
            try:
                write_atomic(path, openpose_json(found.keypoints))
            except OSError as exc:
                raise DetectError(os_error_message(exc, path, "write the keypoints")) from None
            summary.people.append(len(found.scores))
            bar.update()
            if stop is not None and stop.is_set():
                summary.interrupted = True
                break
    summary.frames_read, summary.detection_fps = reader.frames_read, model.fps
    summary.truncated = None if summary.interrupted else reader.truncation()
    return summary


