"""Hands on the people BlazePose finds: MediaPipe's hand landmark model on crops its hand points give.

As MediaPipe Holistic does, each hand's crop comes from the pose (:func:`hand_region`): the wrist and
the index and pinky knuckles give the middle knuckle (two thirds of the way from the pinky to the
index), the crop is a square centred there, :data:`HAND_SCALE` × twice the wrist-to-knuckle
distance on a side, shifted :data:`HAND_SHIFT` of its side towards the fingers and turned so the
fingers point up. The landmark model (224 × 224, converted at set-up by ``mocapdb models fetch
hands``) gives 21 points (x, y, and z: depth relative to the wrist, in the same units as x), a hand
flag (0–1) and a handedness score, mapped back to frame pixels.

A hand is **absent** (confidence 0, positions NaN) with a reason (:data:`ABSENT_REASONS`): its pose
points hidden (visibility below :data:`MIN_POSE_VISIBILITY`: the model is not run), too small (its
crop's base size, about the hand's length, below :data:`MIN_HAND_PX` pixels: not run) or unsure (the
hand flag below :data:`MIN_PRESENCE`). Decisions and figures: ``data_specs/pose_models.md``, "Hands".
"""
from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import numpy as np

from mocapdb.core.formats.keypoint_layouts import LAYOUTS
from mocapdb.detect.blazepose import Region, region_from_points
from mocapdb.detect.landmark_schedule import LastRun
from mocapdb.detect.with_landmarks import BatchedModel

HAND_PX = 224                # hand landmark model input side, pixels
N_HAND_POINTS = 21           # MediaPipe's (and OpenPose's) hand points: wrist, thumb 1-4, index 1-4, ... pinky 1-4
HAND_SCALE = 1.65             # a crop's side: this × the pose's hand size (twice the wrist-to-middle-knuckle distance)
LANDMARK_ROI_SCALE = 2.0     # a crop around a hand's own points: this × their box's longer side (MediaPipe's)
HAND_SHIFT = 0.1             # the crop's centre moves this share of its base size towards the fingers
MIN_HAND_PX = 24.0           # a hand whose size (twice wrist to middle knuckle, px; about its length) is below: small
MIN_POSE_VISIBILITY = 0.5    # the pose's wrist, index and pinky visibility at least this, else the hand is hidden
MIN_PRESENCE = 0.5           # the landmark model's hand flag at least this, else the hand is unsure
SIDES = ("right", "left")    # hand rows: the subject's right hand, then their left (the universal order)
ABSENT_REASONS = ("hidden", "small", "unsure")   # why a hand is absent ("" when it is found)
HAND_OUTPUTS = ("Identity", "Identity_1", "Identity_2")   # the 21 points, the hand flag, the handedness;
                                                          # the world points (Identity_3) are not computed


def _pose_hand_indices() -> dict[str, tuple[int, int, int]]:
    """Per side, the mediapipe33 indices of the wrist, the index knuckle and the pinky knuckle."""
    names = LAYOUTS["mediapipe33"]
    return {side: tuple(names.index(f"{side}_{part}") for part in ("wrist", "index", "pinky"))  # type: ignore[misc]
            for side in SIDES}


POSE_HAND = _pose_hand_indices()


class Hands(NamedTuple):
    """Both hands of each of ``P`` people (rows: :data:`SIDES`)."""

    points: np.ndarray       # [P, 2, 21, 4] x, y frame px, z (depth from the wrist, px; smaller: nearer), confidence
    presence: np.ndarray     # [P, 2] the model's hand flag (0 when not run)
    handedness: np.ndarray   # [P, 2] the model's probability that the hand is the side of its row (NaN: not run)
    absent: list[tuple[str, str]]   # per person and side: "" (found) or one of ABSENT_REASONS

    @staticmethod
    def empty(people: int) -> Hands:
        points = np.full((people, 2, N_HAND_POINTS, 4), np.nan)
        points[..., 3] = 0.0
        return Hands(points, np.zeros((people, 2)), np.full((people, 2), np.nan), [("", "")] * people)


def hand_region(wrist_xy: np.ndarray, index_xy: np.ndarray, pinky_xy: np.ndarray,
                scale: float = HAND_SCALE) -> tuple[Region, float]:
    """The crop of a hand from the pose's wrist, index and pinky knuckles (frame px) and the hand's size
    (px: twice the wrist-to-middle-knuckle distance): module docstring."""
    wrist_xy = np.asarray(wrist_xy, dtype=np.float64)
    middle_xy = (2.0 * np.asarray(index_xy, dtype=np.float64) + np.asarray(pinky_xy, dtype=np.float64)) / 3.0
    reach = middle_xy - wrist_xy
    size_px = 2.0 * float(np.hypot(*reach))
    turned = region_from_points(wrist_xy, middle_xy)
    towards_fingers = reach / max(size_px / 2.0, 1e-9)
    return Region(middle_xy + HAND_SHIFT * size_px * towards_fingers, scale * size_px, turned.rotation), size_px


def region_from_hand(points_xy: np.ndarray, scale: float = LANDMARK_ROI_SCALE) -> Region:
    """The crop around a hand's own 21 points ``[21, ≥2]`` (frame px), as MediaPipe follows a hand from
    frame to frame: turned so the wrist → middle knuckle points up, the box around the points in that
    turned frame, ``scale`` × its longer side, shifted :data:`HAND_SHIFT` of that side towards the fingers."""
    points_xy = np.asarray(points_xy, dtype=np.float64)[:, :2]
    rotation = region_from_points(points_xy[0], points_xy[9]).rotation
    cos, sin = np.cos(rotation), np.sin(rotation)
    turned = points_xy @ np.array([[cos, -sin], [sin, cos]])     # the crop's axes: fingers up (y smaller)
    low, high = turned.min(axis=0), turned.max(axis=0)
    side = float((high - low).max())
    centre_turned = (low + high) / 2.0 - [0.0, HAND_SHIFT * side]
    return Region(centre_turned @ np.array([[cos, sin], [-sin, cos]]), scale * side, rotation)


def pose_crop(pose: np.ndarray, side: int) -> Region | str:
    """The crop of the hand on ``side`` (row of :data:`SIDES`) of a pose ``[33, 3]`` (mediapipe33: x, y px,
    visibility), or why the model is not run on it: "hidden" (checked first) or "small"."""
    wrist, index, pinky = pose[list(POSE_HAND[SIDES[side]])]
    if min(wrist[2], index[2], pinky[2]) < MIN_POSE_VISIBILITY or not np.isfinite(pose[:, :2]).all():
        return "hidden"
    region, size_px = hand_region(wrist[:2], index[:2], pinky[:2])
    return "small" if size_px < MIN_HAND_PX else region


class HandLandmarker(BatchedModel):
    """The hand landmark model at ``path`` (converted ONNX) run on each person's hands: all the hands of
    a frame in one batched run."""

    def __init__(self, path: Path, every: int = 1, threads: int | None = None) -> None:
        super().__init__(path, HAND_OUTPUTS, HAND_PX, "hand", every, threads)

    def landmarks(self, image: np.ndarray, region: Region) -> tuple[np.ndarray, float, float]:
        """The model in ``region`` of ``image`` (uint8 BGR): points ``[21, 3]`` (x, y frame px, z px),
        the hand flag and the model's handedness score: the probability of the subject's right hand on
        a camera's own (unmirrored) image (measured: ``data_specs/pose_models.md``, "Hands")."""
        points, flags, rights = self.landmarks_batch(image, [region])
        return points[0], float(flags[0]), float(rights[0])

    def landmarks_batch(self, image: np.ndarray, regions: list[Region]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`landmarks` of each of ``regions`` in one model run: points ``[R, 21, 3]``, flags and
        handedness scores ``[R]``."""
        points, flags, rights = self.run_crops(image, regions)
        return points, np.ravel(flags).astype(np.float64), np.ravel(rights).astype(np.float64)

    def __call__(self, image: np.ndarray, keypoints: np.ndarray) -> Hands:
        """Both hands of each person ``keypoints [P, 33, 3]`` (mediapipe33: x, y px, visibility) in ``image``:
        the ones :attr:`schedule` says are due run, the others carried (:mod:`~mocapdb.detect.landmark_schedule`)."""
        hands = Hands.empty(len(keypoints))
        sides = range(len(SIDES))
        crops = {(person, side): pose_crop(pose, side) for person, pose in enumerate(keypoints) for side in sides}
        reasons = {key: crop for key, crop in crops.items() if isinstance(crop, str)}
        regions = {key: crop for key, crop in crops.items() if isinstance(crop, Region)}
        at = {key: keypoints[key[0], list(POSE_HAND[SIDES[key[1]]]), :2] for key in regions}

        def run(due: list) -> list[LastRun]:
            found = self.landmarks_batch(image, [regions[key] for key in due])
            return [LastRun(points, flag, right, bool(flag < MIN_PRESENCE)) for points, flag, right in zip(*found)]

        runs = self.schedule.frame_runs(at, {key: region.side for key, region in regions.items()}, run)
        for key, last in runs.items():
            reasons[key] = _fill(hands, key, last.points, last.presence, last.score)
        hands.absent[:] = [(reasons[person, 0], reasons[person, 1]) for person in range(len(keypoints))]
        return hands


def _fill(hands: Hands, key: tuple[int, int], points: np.ndarray, flag: float, model_right: float) -> str:
    """Fills ``hands`` at ``key`` (person, side) with the model's ``points [21, 3]``, hand flag and
    right-hand score; returns why the hand is absent ("unsure") or "" when it is found."""
    person, side = key
    hands.presence[person, side] = flag
    hands.handedness[person, side] = model_right if SIDES[side] == "right" else 1.0 - model_right
    if flag < MIN_PRESENCE:
        return "unsure"
    hands.points[person, side, :, :3] = points
    hands.points[person, side, :, 3] = flag
    return ""
