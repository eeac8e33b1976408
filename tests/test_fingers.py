"""Fingers: the hand landmark models (full, lite) converted against their TFLite originals, the hand crop from the pose,
finger flexion against hand-built hands, the absent hands' flags, the hands in keypoint JSON and back,
and the four gestures recognised on MediaPipe's own real photos (data/sample_hands).

The model tests need `mocapdb models fetch hands`; without it they skip with that command.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from mocapdb.core.fingers import FINGERS, curl_deg, finger_chain, flexion_deg
from mocapdb.core.formats.keypoint_layouts import LAYOUTS
from mocapdb.core.formats.openpose import parse_openpose_json
from mocapdb.detect.errors import DetectError
from mocapdb.detect.hands import HAND_SCALE, MIN_HAND_PX, HandLandmarker, Hands, hand_region, region_from_hand
from mocapdb.detect.model_store import HAND_VARIANTS, blazepose_paths, hand_landmark_path, tflite_path
from mocapdb.detect.openpose_out import openpose_json
from mocapdb.evaluation.gestures import classify

from .conftest import ROOT, assert_matches_tflite, skip_missing

SAMPLE_HANDS = ROOT / "data" / "sample_hands"
REL_TOLERANCE = 1e-3   # converted outputs within 1e-3 of the TFLite reference's range (as the pose models)


def _hand_model(variant: str = "full") -> Path:
    try:
        return hand_landmark_path(variant)
    except DetectError as exc:
        skip_missing(str(exc))


def _pose_models() -> tuple[Path, Path]:
    try:
        return blazepose_paths("full")
    except DetectError as exc:
        skip_missing(str(exc))


# --- the converter ----------------------------------------------------------------------------------

@pytest.mark.parametrize("variant", sorted(HAND_VARIANTS))
def test_hand_model_converted_matches_the_tflite_original_on_real_photos(variant):
    """MEAN and FULLY_CONNECTED (new for these models) and the rest, on real hand photos and a blank input."""
    images = [cv2.imread(str(SAMPLE_HANDS / name)) for name in ("thumb_up_1.jpg", "thumb_up_2.jpg", "pointing_1.jpg")]
    blobs = [(cv2.resize(image, (224, 224))[None, ..., ::-1] / 255.0).astype(np.float32)
             for image in images + [np.zeros((224, 224, 3), np.uint8)]]
    assert_matches_tflite(_hand_model(variant), tflite_path(HAND_VARIANTS[variant]), blobs, REL_TOLERANCE)


def test_models_fetch_hands_prepares_both_hand_models(tmp_path, monkeypatch):
    """`models fetch hands` wants the lite model too: with only the full one prepared it downloads (here refused),
    with both it downloads nothing and names both."""
    from mocapdb.detect import model_store

    def offline(package, into):
        raise DetectError(f"offline: {package.name} asked for")

    prepared = _hand_model("full").parent
    folder = tmp_path / "models"
    folder.mkdir()
    wanted = (model_store.DETECTOR, model_store.LANDMARKS["full"], HAND_VARIANTS["full"])
    for model in wanted + (HAND_VARIANTS["lite"],):
        for name in (f"{model.stem}.onnx", f"{model.stem}.json", Path(model.member).name):
            if model is not HAND_VARIANTS["lite"] or not name.endswith(".onnx"):
                (folder / name).symlink_to(prepared / name)
    monkeypatch.setitem(model_store._DOWNLOADERS, "pypi", offline)
    with pytest.raises(DetectError, match="offline: mediapipe"):
        model_store.fetch_models(("full",), folder, say=lambda _: None, extras=("hands",))
    (folder / "hand_landmark_lite.onnx").symlink_to(_hand_model("lite"))
    paths = model_store.fetch_models(("full",), folder, say=lambda _: None, extras=("hands",))
    assert paths[-2:] == [folder / "hand_landmark_full.onnx", folder / "hand_landmark_lite.onnx"]
    assert hand_landmark_path("lite", folder) == folder / "hand_landmark_lite.onnx"
    with pytest.raises(DetectError, match="unknown hand landmark model 'heavy': one of full, lite"):
        hand_landmark_path("heavy", folder)


def test_hand_model_option_reaches_detect_and_live(tmp_path):
    """`--hand-model lite` on `detect` and `live` runs the lite model; without it, full."""
    from mocapdb.cli.main import parser
    from mocapdb.detect.detectors import open_detector

    _hand_model("lite")
    video, db = str(SAMPLE_HANDS / "open_palm_1.jpg"), str(ROOT / "demo" / "sample.db")   # files the parser finds
    detect = parser().parse_args(["detect", video, "--hands", "--out", str(tmp_path / "kp")])
    live = parser().parse_args(["live", "--source", video, "--db", db, "--hands", "--hand-model", "lite"])
    assert (detect.hand_model, live.hand_model) == ("full", "lite")
    for args in (detect, live):
        detector = open_detector(None, "full", conf=0.5, iou=0.5, max_people=1, input_size=256, fast=None,
                                 hands=True, hand_model=args.hand_model)
        assert detector.landmarkers["hands"].path == _hand_model(args.hand_model)


# --- geometry and angles, by hand -------------------------------------------------------------------

def test_hand_crop_from_the_pose_points_up_along_the_fingers():
    # a hand pointing right: wrist at (100, 200), index knuckle (130, 190), pinky knuckle (130, 220)
    region, size_px = hand_region([100.0, 200.0], [130.0, 190.0], [130.0, 220.0])
    middle = np.array([130.0, (2 * 190.0 + 220.0) / 3.0])             # two thirds from the pinky to the index
    assert size_px == pytest.approx(2.0 * math.hypot(30.0, 0.0))
    assert region.side == pytest.approx(HAND_SCALE * size_px)
    assert region.rotation == pytest.approx(math.pi / 2)                 # fingers to the right: turned 90°
    np.testing.assert_allclose(region.centre, middle + [0.1 * size_px, 0.0])   # shifted towards the fingers
    forward = region.to_input(224)
    tip_in_input = forward[:, :2] @ [200.0, middle[1]] + forward[:, 2]
    assert tip_in_input[1] < 112 and tip_in_input[0] == pytest.approx(112.0)   # the fingers point up in the crop


def test_crop_around_a_hands_own_points_is_twice_their_extent():
    points = np.zeros((21, 2))
    points[:, 0] = 50.0
    points[:, 1] = np.linspace(300.0, 200.0, 21)        # an upright hand 100 px tall, wrist (point 0) below
    points[9] = [50.0, 250.0]
    points[4] = [90.0, 260.0]                           # the thumb out to the right: 40 px wide
    region = region_from_hand(points)
    assert region.rotation == pytest.approx(0.0) and region.side == pytest.approx(200.0)
    np.testing.assert_allclose(region.centre, [70.0, 250.0 - 10.0])


def _hand_with_bends(bends_deg: dict[str, tuple[float, float, float]]) -> np.ndarray:
    """A hand of 21 points in the x-y plane: each finger a chain of unit bones from the wrist, each
    bone turned from the one before by the finger's bends (degrees)."""
    points = np.zeros((21, 3))
    for k, finger in enumerate(FINGERS):
        heading = math.radians(-90.0 + 15.0 * (k - 2))
        chain = finger_chain(finger)
        position = np.zeros(3)
        position[:2] = [3.0 * math.cos(heading), 3.0 * math.sin(heading)]
        points[chain[1]] = position
        for bone, bend in enumerate(bends_deg.get(finger, (0.0, 0.0, 0.0))):
            heading += math.radians(bend)
            position = position + [math.cos(heading), math.sin(heading), 0.0]
            points[chain[bone + 2]] = position
    return points


def test_flexion_is_the_turn_between_bones():
    bends = {"index": (90.0, 45.0, 10.0), "thumb": (20.0, 30.0, 40.0)}
    flexion = flexion_deg(_hand_with_bends(bends))
    np.testing.assert_allclose(flexion[1], [90.0, 45.0, 10.0], atol=1e-9)
    np.testing.assert_allclose(flexion[0], [20.0, 30.0, 40.0], atol=1e-9)
    np.testing.assert_allclose(flexion[2:], 0.0, atol=1e-6)             # the other fingers straight
    assert curl_deg(flexion)[1] == pytest.approx(145.0)
    with pytest.raises(ValueError, match="21, 3"):
        flexion_deg(np.zeros((21, 2)))


def test_gestures_from_hand_built_angles():
    curled = (70.0, 80.0, 40.0)
    fist = {f: curled for f in FINGERS[1:]} | {"thumb": (40.0, 50.0, 40.0)}
    assert classify(_hand_with_bends(fist)) == "fist"
    pointing = {f: curled for f in FINGERS[2:]}
    assert classify(_hand_with_bends(pointing)) == "pointing"
    assert classify(_hand_with_bends({})) == "open_palm"
    thumb_up = {f: curled for f in FINGERS[1:]}                          # fingers curled, thumb straight, up
    assert classify(_hand_with_bends(thumb_up)) == "thumb_up"
    flipped = _hand_with_bends(thumb_up) * [1.0, -1.0, 1.0]              # the same hand upside down
    assert classify(flipped) == "thumb_down"


def test_gestures_on_mediapipes_own_results_for_its_test_photos():
    """MediaPipe's expected world landmarks for its test photos fist.jpg, pointing_up.jpg, thumb_up.jpg,
    victory.jpg (the fist's photo is not in MediaPipe's repository: data/sample_hands/README.md)."""
    hands = json.loads((SAMPLE_HANDS / "mediapipe_world_landmarks.json").read_text())["hands"]
    found = {name: classify(np.array(points)) for name, points in hands.items()}
    assert found == {"fist": "fist", "pointing_up": "pointing", "thumb_up": "thumb_up", "victory": "other"}


def test_hands_batched_in_one_run_match_one_run_each():
    """All of a frame's hands go through the model in one run: each hand's outputs as the converted model's
    own batch-of-1 run on that crop alone gives them (within 1e-5)."""
    from mocapdb.detect.blazepose import Region
    from mocapdb.detect.hands import HAND_OUTPUTS, HAND_PX
    from mocapdb.detect.model import load_session
    from mocapdb.detect.with_landmarks import crop_input

    path = _hand_model()
    image = cv2.imread(str(SAMPLE_HANDS / "open_palm_1.jpg"))
    height, width = image.shape[:2]
    regions = [Region(np.array([width * x, height * y]), side * width, turn)
               for x, y, side, turn in ((0.5, 0.5, 0.6, 0.0), (0.3, 0.4, 0.3, 0.5), (0.7, 0.6, 0.4, -1.0))]
    points, flags, rights = HandLandmarker(path).landmarks_batch(image, regions)
    single = load_session(path, HAND_OUTPUTS)   # the converted model as it is: a batch of 1
    for hand, region in enumerate(regions):
        raw, flag, right = single.run(list(HAND_OUTPUTS), {"input_1": crop_input(image, region, HAND_PX)[None]})
        values = raw.reshape(21, 3)
        px_per_input = region.side / 224
        expected = np.concatenate([region.to_frame(values[:, :2], 224), values[:, 2:] * px_per_input], axis=1)
        np.testing.assert_allclose(points[hand], expected, atol=1e-5 * px_per_input)
        assert flags[hand] == pytest.approx(float(flag.ravel()[0]), abs=1e-5)
        assert rights[hand] == pytest.approx(float(right.ravel()[0]), abs=1e-5)


# --- absent hands -------------------------------------------------------------------------------------

def _pose_with_hand(scale_px: float, visibility: float = 0.9) -> np.ndarray:
    pose = np.zeros((1, 33, 3))
    pose[..., 2] = visibility
    names = LAYOUTS["mediapipe33"]
    for side, x in (("right", 100.0), ("left", 300.0)):
        pose[0, names.index(f"{side}_wrist")] = [x, 200.0, visibility]
        pose[0, names.index(f"{side}_index")] = [x - 0.2 * scale_px, 200.0 - scale_px, visibility]
        pose[0, names.index(f"{side}_pinky")] = [x + 0.2 * scale_px, 200.0 - scale_px, visibility]
    return pose


def test_hidden_small_and_unsure_hands_are_absent_and_flagged():
    model = HandLandmarker(_hand_model())
    blank = np.full((480, 640, 3), 128, np.uint8)                       # no hand anywhere: unsure
    hidden = model(blank, _pose_with_hand(60.0, visibility=0.2))
    small = model(blank, _pose_with_hand(MIN_HAND_PX / 2.0 * 0.9))
    unsure = model(blank, _pose_with_hand(60.0))
    assert hidden.absent == [("hidden", "hidden")] and model.runs == 2
    assert small.absent == [("small", "small")] and model.runs == 2   # neither was run through the model
    assert unsure.absent == [("unsure", "unsure")] and (unsure.presence < 0.5).all()
    for hands in (hidden, small, unsure):
        assert (hands.points[..., 3] == 0).all() and np.isnan(hands.points[..., :3]).all()


# --- the keypoint files --------------------------------------------------------------------------------

def test_hands_written_in_openpose_fields_and_read_back():
    rng = np.random.default_rng(3)
    hands = Hands.empty(2)
    hands.points[0, 0] = np.concatenate([rng.uniform(10, 500, (21, 2)), rng.uniform(-20, 20, (21, 1)),
                                         np.full((21, 1), 0.93)], axis=1)
    hands.presence[0] = [0.93, 0.2]
    hands.handedness[0] = [0.88, 0.4]
    hands.absent[0] = ("", "unsure")
    hands.absent[1] = ("hidden", "small")
    pose = rng.uniform(10, 500, (2, 33, 3))
    text = openpose_json(pose, "mediapipe33", hands=hands)
    person = json.loads(text)["people"][0]
    assert len(person["hand_right_keypoints_2d"]) == 63 and person["hand_left_keypoints_2d"] == [0.0] * 63
    assert person["hands"]["left"] == {"state": "unsure", "presence": 0.2, "handedness": 0.4, "depth_px": []}
    frame = parse_openpose_json(text, 0)
    read = frame.people[0].hands
    np.testing.assert_allclose(read[0, :, :2], np.round(hands.points[0, 0, :, :2], 2))
    np.testing.assert_allclose(read[0, :, 2], np.round(hands.points[0, 0, :, 2], 2))
    assert (read[0, :, 3] == pytest.approx(0.93)) and (read[1, :, 3] == 0).all() and np.isnan(read[1, :, :3]).all()
    assert (frame.people[1].hands[..., 3] == 0).all()
    body_only = openpose_json(pose, "mediapipe33")
    assert parse_openpose_json(body_only, 0).people[0].hands is None   # OpenPose's empty hand lists: no hands


def test_a_hand_field_of_the_wrong_size_is_refused_by_name():
    from mocapdb.core.formats.keypoints import KeypointError

    person = {"pose_keypoints_2d": [1.0, 2.0, 0.9] * 33, "hand_left_keypoints_2d": [1.0] * 60}
    with pytest.raises(KeypointError, match="hand_left_keypoints_2d holds 60 values"):
        parse_openpose_json(json.dumps({"people": [person]}), 0, source="f.json")


# --- real photos -----------------------------------------------------------------------------------------

@pytest.mark.parametrize("photo", sorted(p.name for p in SAMPLE_HANDS.glob("*.jpg")))
def test_gestures_recognised_on_real_photos(photo):
    """MediaPipe's photos of people pointing, showing a flat hand or a thumb down (the hands cropped from
    BlazePose's hand points) and close-ups of a thumb up: a hand in each shows the gesture its name says."""
    from mocapdb.evaluation.gestures import photo_hands

    hands = photo_hands(cv2.imread(str(SAMPLE_HANDS / photo)), _pose_models(), _hand_model())
    expected = photo.rsplit("_", 1)[0]
    assert expected in [classify(points) for _, points, _ in hands]


def test_live_frames_carry_the_detectors_hands():
    """`live --source VIDEO --hands`: each person's hands reach the engine's frame (Person.hands)."""
    from mocapdb.detect.model import Detections
    from mocapdb.detect.video import VideoFrame
    from mocapdb.runtime.stream.video_input import keypoint_frame

    keypoints = np.random.default_rng(0).uniform(10, 500, size=(2, 33, 3))
    hands = Hands.empty(2)
    hands.points[1, 0, :, :2] = np.arange(42.0).reshape(21, 2)
    hands.points[1, 0, :, 3] = 0.9
    image = np.zeros((4, 4, 3), np.uint8)
    found = Detections(np.zeros((2, 4)), np.ones(2), keypoints, None, hands)
    frame = keypoint_frame(VideoFrame(7, 0.25, 0.0, image), found, "mediapipe33")
    assert np.array_equal(frame.people[1].hands, hands.points[1], equal_nan=True)
    assert frame.people[0].hands.shape == (2, 21, 4) and (frame.people[0].hands[..., 3] == 0).all()
    without = keypoint_frame(VideoFrame(7, 0.25, 0.0, image), found._replace(hands=None), "mediapipe33")
    assert all(person.hands is None for person in without.people)
