"""Which detector runs on a video: BlazePose (the default, converted at set-up) or a YOLO-pose/RTMO export.

:func:`open_detector` gives what `mocapdb detect` and `live` call once per frame: a
:class:`~mocapdb.detect.blazepose.BlazePose` when no ``--model`` is given, else the export in a
:class:`~mocapdb.detect.tracked.TrackedDetector`. Both give
:class:`~mocapdb.detect.model.Detections` and say their ``keypoint_layout`` (``mediapipe33`` or
``coco17``), ``fps``, ``path`` and :meth:`describe`.
"""
from __future__ import annotations

from pathlib import Path
from typing import Protocol

import numpy as np

from mocapdb.detect.model import Detections
from mocapdb.detect.options import DEFAULT_HAND_MODEL

# intra-op threads of each model in `live`'s pipeline, whose decoder, pose, landmark and engine threads share the cores:
# there a second intra-op thread cost CPU and gained no speed (docs/benchmarks.md, "Live latency and speed: one
# thread a model, kernels loaded before the first frame")
PIPELINE_MODEL_THREADS = 1


class FrameDetector(Protocol):
    """A detector run on the consecutive frames of one video."""

    keypoint_layout: str

    @property
    def path(self) -> Path: ...

    @property
    def fps(self) -> float: ...

    def describe(self) -> str: ...

    def __call__(self, image: np.ndarray) -> Detections: ...


def open_detector(model: str | Path | None, variant: str, *, conf: float, iou: float, max_people: int | None,
                  input_size: int, fast, hands: bool = False, faces: bool = False,
                  hands_every: int = 1, face_every: int = 1, model_threads: int | None = None,
                  hand_model: str = DEFAULT_HAND_MODEL) -> FrameDetector:
    """BlazePose ``variant`` (lite, full, heavy) when ``model`` is None, with ``hands`` also each person's
    hands (the ``hand_model`` landmark model, full or lite, run every ``hands_every`` frames, carried between:
    :mod:`~mocapdb.detect.landmark_schedule`) and
    with ``faces`` their face mesh (every ``face_every`` frames alike;
    :class:`~mocapdb.detect.with_landmarks.WithLandmarks`), else the ONNX
    export ``model`` with the paths ``fast`` allows (:class:`~mocapdb.detect.tracked.FastPath`);
    ``model_threads``: each model's intra-op threads (default the cores: :func:`~mocapdb.detect.model.load_session`;
    `live` runs one, :data:`PIPELINE_MODEL_THREADS`); DetectError
    when the model cannot be used, when hands or faces are asked of an export, or when BlazePose (or the
    hand or face model) is not prepared on this machine."""
    if model is None:
        return _blazepose(variant, max_people, hands_every if hands else 0, face_every if faces else 0, model_threads,
                          hand_model)
    if hands or faces:
        from mocapdb.detect.errors import DetectError

        raise DetectError("--hands and --face need BlazePose (its points give the crops), not --model")
    from mocapdb.detect.model import PoseModel
    from mocapdb.detect.tracked import TrackedDetector

    return TrackedDetector(PoseModel(model, conf=conf, iou=iou, max_people=max_people, input_size=input_size,
                                     threads=model_threads), fast)


def _blazepose(variant: str, max_people: int | None, hands_every: int, face_every: int,
               threads: int | None, hand_model: str = DEFAULT_HAND_MODEL) -> FrameDetector:
    """BlazePose ``variant``, with the hand (``hand_model``, when ``hands_every`` > 0) and face (``face_every``
    > 0) landmark models asked for, each model with ``threads`` intra-op threads (:func:`open_detector`)."""
    from mocapdb.detect.blazepose import BlazePose
    from mocapdb.detect.model_store import blazepose_paths, extra_model_path, hand_landmark_path
    from mocapdb.detect.with_landmarks import Landmarker, WithLandmarks

    detector_path, landmark_path = blazepose_paths(variant)
    landmarkers: dict[str, Landmarker] = {}
    if hands_every:
        from mocapdb.detect.hands import HandLandmarker
        landmarkers["hands"] = HandLandmarker(hand_landmark_path(hand_model), hands_every, threads)
    if face_every:
        from mocapdb.detect.face import FaceLandmarker
        landmarkers["faces"] = FaceLandmarker(extra_model_path("face"), face_every, threads)
    pose = BlazePose(detector_path, landmark_path, max_people=max_people, name=f"BlazePose {variant}", threads=threads)
    return WithLandmarks(pose, **landmarkers) if landmarkers else pose
