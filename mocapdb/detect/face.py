"""Faces on the people BlazePose finds: MediaPipe's face landmark model (Face Mesh) on crops its face points give.

As MediaPipe Holistic does, each face's crop comes from the pose (:func:`face_region`): the box around
BlazePose's 11 face points (nose, eyes, ears, mouth corners) in the frame turned so the eyes' line is
level, its centre the crop's, :data:`FACE_SCALE` × its longer side the crop's side. The landmark model
(192 × 192, converted at set-up by ``mocapdb models fetch face``) gives 468 points (x, y, and z: depth
relative to the face's centre, in the same units as x; smaller: nearer) and a face flag (a logit),
mapped back to frame pixels. All the faces of a frame go through the model in one batched run. With
``every`` N > 1 (``live --face-every``) a face is run every N-th frame and carried between by the
similarity of BlazePose's 11 face points (:mod:`~mocapdb.detect.landmark_schedule`).

A face is **absent** (confidence 0, positions NaN) with a reason (:data:`ABSENT_REASONS`): its pose
points hidden (the nose's or an eye's visibility below :data:`MIN_POSE_VISIBILITY`; the model is not run),
too small (the box's longer side below :data:`MIN_FACE_PX` pixels: not run) or unsure (the face flag below
:data:`MIN_PRESENCE`). A camera behind the head is mostly caught by the face flag, not the visibility:
BlazePose guesses the face there and calls it visible (the balancing take's cameras 3 and 4). Decisions and
figures: ``data_specs/head.md``, "Face mesh".
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import NamedTuple

import numpy as np

from mocapdb.core.formats.keypoint_layouts import LAYOUTS
from mocapdb.detect.blazepose import Region
from mocapdb.detect.landmark_schedule import LastRun
from mocapdb.detect.with_landmarks import BatchedModel

FACE_INPUT_PX = 192          # face landmark model input side, pixels
N_FACE_POINTS = 468          # MediaPipe Face Mesh's points (the canonical face model's vertices)
FACE_SCALE = 2.0             # a crop's side: this × the longer side of the pose's face box (measured: head.md)
MIN_FACE_PX = 20.0           # a face whose pose box is smaller than this (px) is small: not run (measured: head.md)
MIN_POSE_VISIBILITY = 0.5    # the pose's nose and eyes visibility at least this, else the face is hidden
MIN_PRESENCE = 0.5           # the model's face flag (a probability) at least this, else the face is unsure
ABSENT_REASONS = ("hidden", "small", "unsure")   # why a face is absent ("" when it is found)
FACE_OUTPUTS = ("conv2d_21", "conv2d_31")        # the 468 points, the face flag (logit)
POSE_FACE = tuple(range(11))  # mediapipe33's face points: nose, eyes (inner, centre, outer), ears, mouth corners
_NAMES = LAYOUTS["mediapipe33"]
POSE_EYES = (_NAMES.index("right_eye"), _NAMES.index("left_eye"))   # the subject's right, then left eye


class Faces(NamedTuple):
    """The face of each of ``P`` people."""

    points: np.ndarray       # [P, 468, 4] x, y frame px, z (depth, px; smaller: nearer), confidence (0: absent)
    presence: np.ndarray     # [P] the model's face flag (0 when not run)
    absent: list[str]        # per person: "" (found) or one of ABSENT_REASONS

    @staticmethod
    def empty(people: int) -> Faces:
        points = np.full((people, N_FACE_POINTS, 4), np.nan)
        points[..., 3] = 0.0
        return Faces(points, np.zeros(people), [""] * people)


def face_region(face_xy: np.ndarray, right_eye_xy: np.ndarray, left_eye_xy: np.ndarray,
                scale: float = FACE_SCALE) -> tuple[Region, float]:
    """The crop of a face from the pose's face points ``[K, 2]`` (frame px) and its eyes, and the face
    box's longer side (px): module docstring."""
    face_xy = np.asarray(face_xy, dtype=np.float64)
    dx, dy = np.asarray(left_eye_xy, dtype=np.float64) - np.asarray(right_eye_xy, dtype=np.float64)
    rotation = math.atan2(dy, dx)             # the eyes' line against the image's x (the crop levels it)
    cos, sin = math.cos(rotation), math.sin(rotation)
    turned = face_xy @ np.array([[cos, -sin], [sin, cos]])    # the crop's axes: eyes level
    low, high = turned.min(axis=0), turned.max(axis=0)
    side = float((high - low).max())
    centre = (low + high) / 2.0 @ np.array([[cos, sin], [-sin, cos]])
    return Region(centre, scale * side, rotation), side


def pose_crop(pose: np.ndarray) -> Region | str:
    """The crop of the face of a pose ``[33, 3]`` (mediapipe33: x, y px, visibility), or why the model is
    not run on it: "hidden" (checked first) or "small"."""
    seen = pose[[0, *POSE_EYES], 2]
    face = pose[list(POSE_FACE)]
    if seen.min() < MIN_POSE_VISIBILITY or not np.isfinite(face[:, :2]).all():
        return "hidden"
    region, side = face_region(face[:, :2], pose[POSE_EYES[0], :2], pose[POSE_EYES[1], :2])
    return "small" if side < MIN_FACE_PX else region


class FaceLandmarker(BatchedModel):
    """The face landmark model at ``path`` (converted ONNX) run on each person's face: all the faces of
    a frame in one batched run."""

    def __init__(self, path: Path, every: int = 1, threads: int | None = None) -> None:
        super().__init__(path, FACE_OUTPUTS, FACE_INPUT_PX, "face", every, threads)

    def landmarks_batch(self, image: np.ndarray, regions: list[Region]) -> tuple[np.ndarray, np.ndarray]:
        """The model in each of ``regions`` of ``image`` (uint8 BGR), one run: points ``[R, 468, 3]`` (x, y
        frame px, z px scaled like x) and face flags ``[R]`` (probabilities)."""
        points, flags = self.run_crops(image, regions)
        return points, 1.0 / (1.0 + np.exp(-np.ravel(flags).astype(np.float64)))

    def __call__(self, image: np.ndarray, keypoints: np.ndarray) -> Faces:
        """The face of each person ``keypoints [P, 33, 3]`` (mediapipe33: x, y px, visibility) in ``image``:
        the ones :attr:`schedule` says are due run, the others carried."""
        faces = Faces.empty(len(keypoints))
        crops = [pose_crop(pose) for pose in keypoints]
        regions = {person: crop for person, crop in enumerate(crops) if isinstance(crop, Region)}
        reasons = [crop if isinstance(crop, str) else "" for crop in crops]
        at = {person: keypoints[person, list(POSE_FACE), :2] for person in regions}

        def run(due: list) -> list[LastRun]:
            points, flags = self.landmarks_batch(image, [regions[person] for person in due])
            return [LastRun(face, flag, 0.0, bool(flag < MIN_PRESENCE)) for face, flag in zip(points, flags)]

        runs = self.schedule.frame_runs(at, {person: region.side for person, region in regions.items()}, run)
        for person, last in runs.items():
            faces.presence[person] = last.presence
            if last.empty:
                reasons[person] = "unsure"
                continue
            faces.points[person, :, :3] = last.points
            faces.points[person, :, 3] = last.presence
        faces.absent[:] = reasons
        return faces
