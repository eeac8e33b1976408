"""The face landmark model (Face Mesh): converted against its TFLite original, its crop from the pose, one
batched run against single runs, the absent faces' reasons, and the mesh on real photos against
BlazePose's own eye and mouth points (an independent model) (data/sample_hands: MediaPipe's photos).

The model tests need `mocapdb models fetch face`; without it they skip with that command.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from mocapdb.core.formats.keypoint_layouts import LAYOUTS
from mocapdb.core.formats.keypoints import KeypointError
from mocapdb.core.formats.openpose import parse_openpose_json
from mocapdb.detect.blazepose import BlazePose
from mocapdb.detect.errors import DetectError
from mocapdb.detect.face import (
    FACE_INPUT_PX,
    FACE_SCALE,
    MIN_FACE_PX,
    FaceLandmarker,
    Faces,
    face_region,
    pose_crop,
)
from mocapdb.detect.model_store import FACE_LANDMARKS, blazepose_paths, extra_model_path, tflite_path
from mocapdb.detect.openpose_out import openpose_json
from mocapdb.detect.with_landmarks import crop_input

from .conftest import ROOT, assert_matches_tflite, skip_missing

SAMPLE = ROOT / "data" / "sample_hands"
PHOTOS = ("open_palm_1.jpg", "open_palm_3.jpg", "pointing_1.jpg", "pointing_4.jpg", "thumb_down_1.jpg")
REL_TOLERANCE = 1e-3   # converted outputs within 1e-3 of the TFLite reference's range (as the other models)
NAMES = LAYOUTS["mediapipe33"]
# Face Mesh vertices (MediaPipe's canonical face model numbering): outer eye corners, mouth corners
MESH_EYES_OUTER, MESH_MOUTH = (33, 263), (61, 291)


def _face_model() -> Path:
    try:
        return extra_model_path("face")
    except DetectError as exc:
        skip_missing(str(exc))


def _poses(names: tuple[str, ...]) -> list[tuple[np.ndarray, np.ndarray]]:
    """Each photo of ``names`` and the BlazePose (full) keypoints ``[33, 3]`` of its one person."""
    try:
        paths = blazepose_paths("full")
    except DetectError as exc:
        skip_missing(str(exc))
    found = []
    for name in names:   # a fresh detector per photo: BlazePose follows a video's people from frame to frame
        image = cv2.imread(str(SAMPLE / name))
        found.append((image, BlazePose(*paths)(image).keypoints[0]))
    return found


def test_face_model_converted_matches_the_tflite_original_on_real_faces():
    """PRELU (new for this model) and the rest, on face crops of real photos and a blank input."""
    blobs = [crop_input(image, pose_crop(pose), FACE_INPUT_PX)[None] for image, pose in _poses(PHOTOS[:2])]
    blobs.append(np.zeros((1, FACE_INPUT_PX, FACE_INPUT_PX, 3), np.float32))
    assert_matches_tflite(_face_model(), tflite_path(FACE_LANDMARKS), blobs, REL_TOLERANCE)


def test_face_crop_levels_the_eyes_and_covers_the_face_points():
    # a face turned 30° clockwise in the image: the eyes' line from the right eye to the left at +30°
    angle = math.radians(30.0)
    axis, down = np.array([math.cos(angle), math.sin(angle)]), np.array([-math.sin(angle), math.cos(angle)])
    centre = np.array([300.0, 200.0])
    face = np.array([centre + 40 * a * axis + 30 * b * down for a, b in ((-1, 0), (1, 0), (0, 1), (0, -1))])
    region, side = face_region(face, face[0], face[1])
    assert region.rotation == pytest.approx(angle)
    assert side == pytest.approx(80.0)                                   # the turned box's longer side
    assert region.side == pytest.approx(FACE_SCALE * 80.0)
    np.testing.assert_allclose(region.centre, centre, atol=1e-9)
    crop = region.to_input(FACE_INPUT_PX) @ np.append(face[1] - face[0] + centre, 1.0)
    assert crop[1] == pytest.approx(FACE_INPUT_PX / 2)                  # the eyes' line is level in the crop


def test_hidden_and_small_faces_are_not_run():
    pose = np.zeros((33, 3))
    pose[:11, :2] = np.array([[100 + 3 * k, 100 + (k % 3)] for k in range(11)], float)
    pose[:, 2] = 1.0
    pose[NAMES.index("right_eye"), 2] = 0.2                              # a camera behind the head
    assert pose_crop(pose) == "hidden"
    pose[:, 2] = 1.0
    pose[:11, :2] = 100 + (pose[:11, :2] - 100) * (0.9 * MIN_FACE_PX / 30.0)
    assert pose_crop(pose) == "small"


def test_faces_of_a_frame_in_one_batch_match_single_runs_and_land_on_the_pose_face():
    landmarker = FaceLandmarker(_face_model())
    for image, pose in _poses(PHOTOS):
        region = pose_crop(pose)
        batch, flags = landmarker.landmarks_batch(image, [region, region, region])
        single, flag = landmarker.landmarks_batch(image, [region])
        assert flags.min() >= 0.5 and flag[0] >= 0.5                     # a face in each photo
        np.testing.assert_allclose(batch, np.repeat(single, 3, axis=0), atol=1e-3)
        mesh = single[0]
        # the mesh's outer eye corners and mouth corners against BlazePose's (another model, coarser): within
        # 0.4 of the eyes' distance (measured 0.12-0.29 on these photos), and nearer than mirrored left to right
        eyes = np.linalg.norm(mesh[MESH_EYES_OUTER[0], :2] - mesh[MESH_EYES_OUTER[1], :2])
        pose_points = pose[[NAMES.index(n) for n in ("right_eye_outer", "left_eye_outer", "mouth_right",
                                                     "mouth_left")], :2]
        mesh_points = mesh[list(MESH_EYES_OUTER + MESH_MOUTH), :2]
        error = np.linalg.norm(mesh_points - pose_points, axis=1).max()
        assert error < 0.4 * eyes
        assert error < np.linalg.norm(mesh_points[[1, 0, 3, 2]] - pose_points, axis=1).max()
    assert landmarker.runs == 4 * len(PHOTOS) and landmarker.batches == 2 * len(PHOTOS)


def test_the_mesh_in_keypoint_json_and_back():
    """`detect --face` writes each person's mesh in mocapdb's face_mesh field (OpenPose's 70-point
    face_keypoints_2d stays empty); reading gives Person.face, to 0.01 px; an absent face reads NaN, a body
    without the field None; a malformed field is refused naming it."""
    pose = np.zeros((2, 33, 3))
    pose[..., :2] = np.arange(66, dtype=float).reshape(2, 33, 1) + 100.0
    pose[..., 2] = 0.9
    faces = Faces.empty(2)
    mesh = np.random.default_rng(2).uniform(50.0, 900.0, (468, 3))
    faces.points[0, :, :3], faces.points[0, :, 3], faces.presence[0] = mesh, 0.97, 0.97
    faces.absent[1] = "small"
    text = openpose_json(pose, "mediapipe33", faces=faces)
    assert json.loads(text)["people"][0]["face_keypoints_2d"] == []
    first, second = parse_openpose_json(text, 0).people
    np.testing.assert_allclose(first.face[:, :3], mesh, atol=0.005 + 1e-9)
    assert (first.face[:, 3] == 0.97).all()
    assert np.isnan(second.face[:, :3]).all() and (second.face[:, 3] == 0).all()
    assert parse_openpose_json(openpose_json(pose, "mediapipe33"), 0).people[0].face is None
    broken = json.loads(text)
    broken["people"][0]["face_mesh"]["points"] = broken["people"][0]["face_mesh"]["points"][:400]
    with pytest.raises(KeypointError, match="person 0 face_mesh points must be 468"):
        parse_openpose_json(json.dumps(broken), 0)
