"""The ONNX pose model of `mocapdb detect`: a YOLO-pose or RTMO export run by onnxruntime (CPU).

:class:`PoseModel` tells the export layouts apart by their tensor shapes (:func:`identify_layout`),
letterboxes each frame (:func:`letterbox`), thresholds and suppresses overlapping people
(:func:`nms`) and maps keypoints back to the frame's pixels. Layouts and pre-processing:
``data_specs/pose_models.md``. Nothing is downloaded: the user points ``--model`` at an export of
their own. Frames come from :mod:`mocapdb.detect.video`; the files written, from
:mod:`mocapdb.detect.openpose_out`.
"""
from __future__ import annotations

import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any, NamedTuple

import cv2
import numpy as np

from mocapdb.core.formats.keypoints import LAYOUTS
from mocapdb.detect.errors import DetectError, check_readable
from mocapdb.detect.options import DEFAULT_CONF, DEFAULT_INPUT_SIZE, DEFAULT_IOU

PAD_VALUE = 114            # letterbox padding grey level (both layouts were trained with it)
MAX_CANDIDATES = 1000      # best-scoring people passed to NMS, bounding its cost

N_COCO = len(LAYOUTS["coco17"])
YOLO_CHANNELS = 4 + 1 + 3 * N_COCO
KNOWN_LAYOUTS = (f"YOLO-pose (input [1, 3, H, W]; output [1, {YOLO_CHANNELS}, anchors] or "
                 f"[1, anchors, {YOLO_CHANNELS}]) and RTMO (input [1, 3, H, W]; outputs [1, N, 5] "
                 f"and [1, N, {N_COCO}, 3])")
_INPUT_TYPES = {"tensor(float)": np.float32, "tensor(float16)": np.float16}


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

def box_area(boxes: np.ndarray) -> np.ndarray:
    """Areas ``[N]`` of boxes ``[N, 4]`` (x1, y1, x2, y2); 0 for an empty or inverted box."""
    return np.prod(np.clip(boxes[:, 2:] - boxes[:, :2], 0.0, None), axis=-1)


def box_intersection(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Overlap areas ``[N, M]`` of boxes ``a [N, 4]`` and ``b [M, 4]`` (x1, y1, x2, y2)."""
    top_left = np.maximum(a[:, None, :2], b[None, :, :2])
    bottom_right = np.minimum(a[:, None, 2:], b[None, :, 2:])
    return np.prod(np.clip(bottom_right - top_left, 0.0, None), axis=-1)


def box_iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Intersection over union ``[N, M]`` of boxes ``a [N, 4]`` and ``b [M, 4]`` (x1, y1, x2, y2)."""
    inter = box_intersection(a, b)
    union = box_area(a)[:, None] + box_area(b)[None, :] - inter
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
    keypoints: np.ndarray  # [P, K, 3] x, y, confidence in the detector's layout (COCO-17, BlazePose's 33)
    # [P, K, 3] the model's own 3D of the keypoints (BlazePose's world landmarks: metres, x right and y down
    # along the image's axes, z away from the camera, origin at the hips' centre); None when it gives none
    world: np.ndarray | None = None
    # both hands of each person (mocapdb.detect.hands.Hands: 21 points each, presence, why absent); None
    # unless hands were asked for
    hands: Any = None
    # the face of each person (mocapdb.detect.face.Faces: 468 mesh points, presence, why absent); None unless
    # faces were asked for
    faces: Any = None


def _first_line(exc: Exception) -> str:
    """The first line of an exception's message, or its type name when it has none."""
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


def cpu_cores() -> int:
    """The CPU cores this process may run on (its affinity where the platform tells it)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def load_session(path: Path, outputs: tuple[str, ...] | None = None, *, any_batch: bool = False,
                 threads: int | None = None) -> Any:
    """An onnxruntime CPU session for ``path`` set for this machine (intra-op threads: ``threads``, by
    default its cores, not spinning when idle; sequential execution; all graph optimisations); DetectError
    when missing or not loadable. ``outputs``: only the part of the graph these outputs need is loaded
    (the rest is never computed); ``any_batch``: the inputs' and outputs' first dimension (a converted
    model's fixed batch of 1) left free, for a model whose layers treat each batch item alone. ``threads``
    = 1 runs the model in the calling thread alone: what a pipeline whose own threads (decoder, detector,
    engine) fill the cores wants (:data:`~mocapdb.detect.detectors.PIPELINE_MODEL_THREADS`)."""
    if not path.exists():
        raise DetectError(f"pose model not found: {path}")
    check_readable(path, "pose model")
    import onnxruntime as ort

    options = ort.SessionOptions()
    options.log_severity_level = 3   # errors only
    options.intra_op_num_threads = threads or cpu_cores()   # one per core: ORT's default may count differently
    options.inter_op_num_threads = 1
    options.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL   # one model, one branch at a time
    options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    # idle threads sleep: spinning would take the cores the decoder and the live engine need
    options.add_session_config_entry("session.intra_op.allow_spinning", "0")
    try:
        model = str(path) if outputs is None and not any_batch else _subgraph(path, outputs, any_batch)
        return ort.InferenceSession(model, options, providers=["CPUExecutionProvider"])
    except Exception as exc:  # noqa: BLE001 - onnxruntime's and onnx's exception types share no narrower base
        raise DetectError(f"{path}: not a usable ONNX model ({_first_line(exc)})") from None


def _subgraph(path: Path, outputs: tuple[str, ...] | None, any_batch: bool) -> bytes:
    """The serialised part of the model at ``path`` that computes ``outputs`` (None: all) from its inputs,
    with ``any_batch`` its first dimension free (:func:`load_session`)."""
    import onnx
    from onnx.utils import Extractor

    model = onnx.load(str(path))
    inputs = [i.name for i in model.graph.input]
    wanted = [o.name for o in model.graph.output] if outputs is None else list(outputs)
    part = Extractor(model).extract_model(inputs, wanted)
    if any_batch:
        for value in [*part.graph.input, *part.graph.output]:
            value.type.tensor_type.shape.dim[0].dim_param = "batch"
        del part.graph.value_info[:]   # inner shapes were inferred for a batch of 1
    return part.SerializeToString()


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
    (None: all); ``input_size``: side in pixels for a dynamic input (``dynamic``: the export takes
    any input size, which :meth:`run` may be given); ``threads``: onnxruntime's intra-op threads
    (:func:`load_session`). ``fps`` is the rate detection sustains (frames per second of
    pre-processing, inference and post-processing time).
    """

    keypoint_layout = "coco17"

    def __init__(self, path: str | Path, *, conf: float = DEFAULT_CONF, iou: float = DEFAULT_IOU,
                 max_people: int | None = None, input_size: int = DEFAULT_INPUT_SIZE,
                 threads: int | None = None) -> None:
        _check_options(conf, iou, max_people, input_size)
        self.path = Path(path)
        self._session = load_session(self.path, threads=threads)
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
        self.dynamic = not all(isinstance(d, int) and d > 0 for d in inputs[0].shape[2:])   # any input size runs
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
        found = self.run(*letterbox(image, self.input_wh, self.layout.centred))
        self.frames += 1
        self.seconds += time.perf_counter() - started
        return found

    def run(self, canvas: np.ndarray, box: Letterbox) -> Detections:
        """The people in a prepared model input ``canvas [h, w, 3]`` (uint8 BGR; ``input_wh`` unless the
        input is :attr:`dynamic`), mapped back to the frame's pixels by ``box``."""
        boxes, scores, keypoints = self._decode(self._infer(canvas))
        keep = self._select(boxes, scores)
        corners = box.to_original(boxes[keep].reshape(-1, 2, 2)).reshape(-1, 4)
        points = np.concatenate([box.to_original(keypoints[keep, :, :2]), keypoints[keep, :, 2:]], axis=-1)
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
