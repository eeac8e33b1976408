"""Hands and faces at a lower rate (issue 49's cost in live): the schedule by hand, the similarity that
carries a hand or face, and on real photos moved rigidly, the carried hand against the model's own run on
the moved image, the carried face against the known similarity and the model's own run.

The photo tests need `mocapdb models fetch full hands face`; without them they skip with that command."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from mocapdb.detect.blazepose import BlazePose
from mocapdb.detect.errors import DetectError
from mocapdb.detect.face import FaceLandmarker
from mocapdb.detect.hands import POSE_HAND, HandLandmarker
from mocapdb.detect.landmark_schedule import MOVED, LandmarkSchedule, LastRun, carry, similarity
from mocapdb.detect.model_store import blazepose_paths, extra_model_path

from .conftest import ROOT, skip_missing
from .test_fingers import SAMPLE_HANDS, _hand_model, _pose_models

KEY = (0, 1)


def test_similarity_recovers_a_turn_scale_and_shift_and_carries_depth():
    rng = np.random.default_rng(3)
    source = rng.uniform(0, 100, size=(3, 2))
    a, b = 1.5 * np.exp(1j * np.radians(30.0)), 12.0 - 7.0j
    moved = a * (source[:, 0] + 1j * source[:, 1]) + b
    got_a, got_b = similarity(source, np.column_stack([moved.real, moved.imag]))
    assert got_a == pytest.approx(a) and got_b == pytest.approx(b)
    points = np.column_stack([source, [4.0, -2.0, 0.0]])
    carried = carry(points, a, b)
    np.testing.assert_allclose(carried[:, :2], np.column_stack([moved.real, moved.imag]))
    np.testing.assert_allclose(carried[:, 2], [6.0, -3.0, 0.0])


def _found(empty: bool = False) -> LastRun:
    return LastRun(np.zeros((21, 3)), 0.1 if empty else 0.9, 0.8, empty)


def test_a_found_hand_runs_every_nth_frame_an_empty_one_less_often_a_moved_or_new_one_at_once():
    schedule = LandmarkSchedule(every=2, empty_every=6)
    still = np.array([[100.0, 100.0], [110.0, 80.0], [90.0, 80.0]])
    ran = []
    for frame in range(7):
        if schedule.due(KEY, still, 80.0):
            schedule.ran(KEY, still, 80.0, _found())
            ran.append(frame)
        else:
            schedule.carried(KEY, still)
        schedule.end_frame({KEY})
    assert ran == [0, 2, 4, 6] and schedule.carries == 3
    schedule = LandmarkSchedule(every=2, empty_every=6)
    ran = []
    for frame in range(13):
        if schedule.due(KEY, still, 80.0):
            schedule.ran(KEY, still, 80.0, _found(empty=True))
            ran.append(frame)
        schedule.end_frame({KEY})
    assert ran == [0, 6, 12]
    moved = still + [MOVED * 80.0 + 1.0, 0.0]
    assert not schedule.due(KEY, still + [MOVED * 80.0 - 1.0, 0.0], 80.0) and schedule.due(KEY, moved, 80.0)
    schedule.end_frame(set())            # the hand not shown (hidden): forgotten, run when it comes back
    assert schedule.due(KEY, still, 80.0)
    assert all(LandmarkSchedule(every=1).due(KEY, still, 80.0) for _ in range(3))


def _moved(image: np.ndarray, pose: np.ndarray, turn_deg: float, shift: tuple[float, float]):
    """The image and pose turned by ``turn_deg`` about the first person's right wrist, then shifted (px)."""
    height, width = image.shape[:2]
    matrix = cv2.getRotationMatrix2D(tuple(pose[0, POSE_HAND["right"][0], :2]), turn_deg, 1.0)
    matrix[:, 2] += shift
    moved = cv2.warpAffine(image, matrix, (width, height), flags=cv2.INTER_LINEAR)
    moved_pose = pose.copy()
    moved_pose[..., :2] = pose[..., :2] @ matrix[:, :2].T + matrix[:, 2]
    return moved, moved_pose


@pytest.mark.parametrize("turn_deg, shift, carried_sides, tolerance",
                         [(0.0, (12.0, -8.0), (0, 1), 1e-3), (12.0, (3.0, 2.0), (0,), 0.06)])
def test_a_carried_hand_is_where_the_model_finds_it_after_a_rigid_move(turn_deg, shift, carried_sides, tolerance):
    """A real photo (MediaPipe's pointing_2.jpg, both hands found), its pose by BlazePose; the photo and pose
    moved rigidly. Hands every 2nd frame: frame 0 is run, frame 1 (moved) carried, frame 2 (the same moved
    image) run. The carried hand is the run's within ``tolerance`` of the hand's length (wrist to middle
    knuckle): shifted by whole pixels the crop is the same pixels (1e-3); turned 12° about the right wrist,
    resampled (6 %). Turned, the left hand moves further than its crop's :data:`MOVED`: run again at once."""
    image = cv2.imread(str(SAMPLE_HANDS / "pointing_2.jpg"))
    pose = BlazePose(*_pose_models())(image).keypoints
    model = HandLandmarker(_hand_model(), every=2)
    first = model(image, pose)
    assert first.absent == [("", "")] and model.runs == 2
    moved_image, moved_pose = _moved(image, pose, turn_deg, shift)
    carried = model(moved_image, moved_pose)
    assert model.runs == 4 - len(carried_sides) and model.schedule.carries == len(carried_sides)
    run = model(moved_image, moved_pose)
    assert model.runs == 6 - len(carried_sides) and carried.absent == run.absent == [("", "")]
    for side in carried_sides:
        length = np.linalg.norm(run.points[0, side, 9, :2] - run.points[0, side, 0, :2])
        error = np.linalg.norm(carried.points[0, side, :, :2] - run.points[0, side, :, :2], axis=1).max()
        assert error <= tolerance * length
        assert carried.presence[0, side] == first.presence[0, side]


@pytest.mark.parametrize("turn_deg, scale, shift", [(0.0, 1.0, (9.0, -6.0)), (8.0, 1.05, (4.0, 3.0))])
def test_a_carried_face_is_the_first_mesh_moved_by_the_known_similarity(turn_deg, scale, shift):
    """A real photo (sergey.jpg, 600 px), its pose by BlazePose; the photo and pose moved by a known
    similarity (turned ``turn_deg`` and scaled about the nose, shifted, px). Faces every 2nd frame: frame 0
    run, frame 1 carried, frame 2 (the same moved image) run. The carried mesh is the first mesh moved by
    that similarity (depth times the scale) to 1e-6 px, and within 3 % of the eyes' distance of the
    model's own run on the moved photo."""
    try:
        detector, model = BlazePose(*blazepose_paths("full")), FaceLandmarker(extra_model_path("face"), every=2)
    except DetectError as exc:
        skip_missing(str(exc))
    image = cv2.imread(str(ROOT / "data" / "sample_faces" / "sergey.jpg"))
    pose = detector(image).keypoints[:1]
    first = model(image, pose)
    assert first.absent == [""] and model.runs == 1
    matrix = cv2.getRotationMatrix2D(tuple(pose[0, 0, :2]), turn_deg, scale)
    matrix[:, 2] += shift
    moved_image = cv2.warpAffine(image, matrix, image.shape[1::-1], flags=cv2.INTER_LINEAR)
    moved_pose = pose.copy()
    moved_pose[..., :2] = pose[..., :2] @ matrix[:, :2].T + matrix[:, 2]
    carried = model(moved_image, moved_pose)
    assert model.runs == 1 and model.schedule.carries == 1 and carried.absent == [""]
    expected = first.points[0, :, :2] @ matrix[:, :2].T + matrix[:, 2]
    np.testing.assert_allclose(carried.points[0, :, :2], expected, atol=1e-6)
    np.testing.assert_allclose(carried.points[0, :, 2], first.points[0, :, 2] * scale, atol=1e-6)
    run = model(moved_image, moved_pose)
    assert model.runs == 2
    eyes = np.linalg.norm(run.points[0, 33, :2] - run.points[0, 263, :2])
    assert np.linalg.norm(carried.points[0, :, :2] - run.points[0, :, :2], axis=1).mean() <= 0.03 * eyes
