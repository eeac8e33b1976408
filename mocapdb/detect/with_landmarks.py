"""A BlazePose detector followed by landmark models on each person it finds (hands, face), their crops
given by its points, as MediaPipe Holistic does: :class:`WithLandmarks`."""
from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, Protocol

import cv2
import numpy as np

from mocapdb.detect.blazepose import BlazePose, Region, model_input
from mocapdb.detect.landmark_schedule import LandmarkSchedule
from mocapdb.detect.model import Detections, load_session


def crop_input(image: np.ndarray, region: Region, size_px: int) -> np.ndarray:
    """A landmark model's input ``[size_px, size_px, 3]`` (RGB in [0, 1]): ``region`` of ``image`` (uint8
    BGR), black beyond the image."""
    crop = cv2.warpAffine(image, region.to_input(size_px), (size_px, size_px), flags=cv2.INTER_LINEAR,
                          borderMode=cv2.BORDER_CONSTANT, borderValue=(0, 0, 0))
    return model_input(crop, 1.0 / 255.0)


class BatchedModel:
    """A landmark model at ``path`` (converted ONNX; square input of ``input_px``) run on all the crops of
    a frame in one batch (its layers treat each crop alone: the same outputs as one run each);
    ``outputs``: the ones computed, the first the points (x, y, z input px); ``what``: what a crop holds;
    ``every``: each crop run every this many frames, carried between (:attr:`schedule`,
    :mod:`~mocapdb.detect.landmark_schedule`); ``threads``: the model's intra-op threads
    (:func:`~mocapdb.detect.model.load_session`)."""

    def __init__(self, path: Path, outputs: tuple[str, ...], input_px: int, what: str, every: int = 1,
                 threads: int | None = None) -> None:
        self.path, self.outputs, self.input_px, self.what = Path(path), outputs, input_px, what
        self.schedule = LandmarkSchedule(every)
        self._session = load_session(self.path, outputs, any_batch=True, threads=threads)
        self._input = self._session.get_inputs()[0].name
        self.runs = 0      # crops run through the model
        self.batches = 0   # model runs (each on one frame's crops)

    def describe(self) -> str:
        every = self.schedule.every
        carried = f", {self.schedule.carries} carried (every {every} frames)" if every > 1 else ""
        return f"{self.what} landmarks {self.input_px} px per {self.what}, {self.runs} in {self.batches} runs{carried}"

    def run_crops(self, image: np.ndarray, regions: list[Region]) -> list[np.ndarray]:
        """The :attr:`outputs` of ``regions`` of ``image`` (uint8 BGR), one run; the points ``[R, N, 3]``
        mapped to x, y frame px and z px (scaled like x), the others as the model gives them."""
        blob = np.stack([crop_input(image, region, self.input_px) for region in regions])
        raw, *others = self._session.run(list(self.outputs), {self._input: blob})
        self.runs += len(regions)
        self.batches += 1
        values = raw.reshape(len(regions), -1, 3).astype(np.float64)
        points = np.stack([np.concatenate([region.to_frame(crop[:, :2], self.input_px),
                                           crop[:, 2:] * region.side / self.input_px], axis=1)
                           for crop, region in zip(values, regions)])
        return [points, *others]


class Landmarker(Protocol):
    """A landmark model run on every person of a frame (:class:`~mocapdb.detect.hands.HandLandmarker`,
    :class:`~mocapdb.detect.face.FaceLandmarker`)."""

    def __call__(self, image: np.ndarray, keypoints: np.ndarray) -> Any: ...

    def describe(self) -> str: ...


class WithLandmarks:
    """A BlazePose detector whose :class:`~mocapdb.detect.model.Detections` also carry, per field named
    (``hands``, ``faces``), what its landmarker finds on each person ``keypoints [P, 33, 3]``; its ``fps``
    counts the landmarkers' time too."""

    def __init__(self, detector: BlazePose, **landmarkers: Landmarker) -> None:
        self.detector, self.landmarkers = detector, landmarkers
        self.keypoint_layout = detector.keypoint_layout
        self.landmark_seconds = 0.0

    @property
    def path(self):
        return self.detector.path

    @property
    def fps(self) -> float:
        frames = self.detector.frames
        seconds = self.detector.seconds + self.landmark_seconds
        return frames / seconds if seconds > 0 else 0.0

    def describe(self) -> str:
        return "; ".join([self.detector.describe(), *(lm.describe() for lm in self.landmarkers.values())])

    def __call__(self, image: np.ndarray) -> Detections:
        return self.landmarks(image, self.detector(image))

    def landmarks(self, image: np.ndarray, found: Detections) -> Detections:
        """``found`` (this detector's people in ``image``) with what each landmarker finds on them; `live`
        runs this in a thread of its own while the detector takes the next frame (:func:`detection_stages`)."""
        started = time.perf_counter()
        extra = {name: landmarker(image, found.keypoints) for name, landmarker in self.landmarkers.items()}
        self.landmark_seconds += time.perf_counter() - started
        return found._replace(**extra)


def no_landmarks(image: np.ndarray, found: Detections) -> Detections:
    """A detector's people as found: the second stage of one without landmark models."""
    return found


def detection_stages(model: Any) -> tuple[Callable[[np.ndarray], Detections],
                                          Callable[[np.ndarray, Detections], Detections]]:
    """A frame detector (:func:`~mocapdb.detect.detectors.open_detector`) as two stages that can run in two
    threads, one frame apart: the people (BlazePose, an export), then their landmarks (hands, face:
    :meth:`WithLandmarks.landmarks`; :func:`no_landmarks` without). A stage keeps its own state across frames
    (the pose's tracking, the landmarks' schedule); neither reads the other's."""
    if isinstance(model, WithLandmarks):
        return model.detector, model.landmarks
    return model, no_landmarks
