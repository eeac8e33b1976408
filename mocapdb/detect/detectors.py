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
                  input_size: int, fast, hands: bool = False) -> FrameDetector:
    """BlazePose ``variant`` (lite, full, heavy) when ``model`` is None, with ``hands`` also each person's
    hands (:class:`~mocapdb.detect.hands.WithHands`), else the ONNX export ``model`` with the paths ``fast``
    allows (:class:`~mocapdb.detect.tracked.FastPath`); DetectError when the model cannot be used, when
    hands are asked of an export, or when BlazePose (or the hand model) is not prepared on this machine."""
    if model is None:
        from mocapdb.detect.blazepose import BlazePose
        from mocapdb.detect.model_store import blazepose_paths, hand_landmark_path

        detector_path, landmark_path = blazepose_paths(variant)
        hand_path = hand_landmark_path() if hands else None
        pose = BlazePose(detector_path, landmark_path, max_people=max_people, name=f"BlazePose {variant}")
        if hand_path is None:
            return pose
        from mocapdb.detect.hands import WithHands

        return WithHands(pose, hand_path)
    if hands:
        from mocapdb.detect.errors import DetectError

        raise DetectError("--hands needs BlazePose (its hand points give the hands' crops), not --model")
    from mocapdb.detect.model import PoseModel
    from mocapdb.detect.tracked import TrackedDetector

    return TrackedDetector(PoseModel(model, conf=conf, iou=iou, max_people=max_people, input_size=input_size), fast)
