"""BlazePose: the converter against the TFLite originals (LiteRT) on real frames, the pipeline's
geometry against hand-computed cases, and several people found and followed on real footage.

The models are the ones `mocapdb models fetch` prepared (tools/setup.sh runs it); without them the
model tests are skipped with the command that prepares them.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from mocapdb.core.formats.keypoint_layouts import LAYOUTS
from mocapdb.detect.blazepose import (
    ANCHORS,
    DETECTOR_PX,
    BlazePose,
    Region,
    decode_people,
    region_from_points,
    scan_tiles,
)
from mocapdb.detect.errors import DetectError
from mocapdb.detect.model_store import DETECTOR, LANDMARKS, blazepose_paths, onnx_path, tflite_path
from mocapdb.detect.openpose_out import openpose_json

from .conftest import SHARED_DATA, skip_missing

SHARED = SHARED_DATA / "videos"
BALANCING = SHARED / "pose2sim_balancing" / "cam01.mp4"
SPORTS2D = SHARED / "sports2d_demo" / "demo.mp4"
REL_TOLERANCE = 1e-3   # the target: converted outputs within 1e-3 of the TFLite reference's range
SEGMENTATION = "Identity_2"   # the landmark model's person mask (logits), unused by mocapdb
MASK_TOLERANCE = 2e-3  # its logits reach ±2000 in the background, where float sums differ by ~1e-3 of
                       # that; compared as the mask's probability (sigmoid) instead


def _prepared(variant: str) -> tuple[Path, Path]:
    try:
        return blazepose_paths(variant)
    except DetectError as exc:
        skip_missing(str(exc))


def _frames(path: Path, indices: tuple[int, ...]) -> list[np.ndarray]:
    if not path.exists():
        skip_missing(f"{path} (../shared)")
    capture, frames = cv2.VideoCapture(str(path)), []
    for i in range(max(indices) + 1):
        ok, image = capture.read()
        assert ok, f"{path}: frame {i}"
        if i in indices:
            frames.append(image)
    capture.release()
    return frames


# --- the converter --------------------------------------------------------------------------------

@pytest.mark.parametrize("model", [DETECTOR, *LANDMARKS.values()], ids=lambda m: m.stem)
def test_converted_models_match_the_tflite_originals_on_real_frames(model):
    litert = pytest.importorskip("ai_edge_litert.interpreter")
    import onnxruntime as ort

    _prepared("full")
    if not onnx_path(model).is_file():
        skip_missing(f"{model.stem} not prepared: `mocapdb models fetch lite heavy`")
    reference = litert.Interpreter(model_path=str(tflite_path(model)))
    reference.allocate_tensors()
    (entry,) = reference.get_input_details()
    session = ort.InferenceSession(str(onnx_path(model)), providers=["CPUExecutionProvider"])
    height, width = entry["shape"][1:3]
    for image in _frames(BALANCING, (0, 50)) + _frames(SPORTS2D, (60,)):
        blob = (cv2.resize(image, (width, height))[None, ..., ::-1] / 255.0).astype(np.float32)
        reference.set_tensor(entry["index"], blob)
        reference.invoke()
        got = dict(zip([o.name for o in session.get_outputs()], session.run(None, {entry["name"]: blob})))
        for detail in reference.get_output_details():
            expected, converted = reference.get_tensor(detail["index"]), got[detail["name"]]
            assert converted.shape == expected.shape
            if detail["name"] == SEGMENTATION and model in LANDMARKS.values():
                np.testing.assert_allclose(_probability(converted), _probability(expected), atol=MASK_TOLERANCE)
                continue
            scale = float(np.abs(expected).max()) or 1.0
            assert np.abs(converted - expected).max() <= REL_TOLERANCE * scale, detail["name"]


def _probability(logits: np.ndarray) -> np.ndarray:
    return 1.0 / (1.0 + np.exp(-np.clip(logits.astype(np.float64), -50.0, 50.0)))


# --- geometry, by hand -----------------------------------------------------------------------------

def test_anchors_are_the_ssd_grids_in_output_order():
    assert ANCHORS.shape == (28 * 28 * 2 + 14 * 14 * 2 + 7 * 7 * 6, 2) == (2254, 2)
    np.testing.assert_allclose(ANCHORS[:3], [[0.5 / 28, 0.5 / 28]] * 2 + [[1.5 / 28, 0.5 / 28]])
    first_16 = 28 * 28 * 2
    np.testing.assert_allclose(ANCHORS[first_16], [0.5 / 14, 0.5 / 14])
    np.testing.assert_allclose(ANCHORS[-1], [6.5 / 7, 6.5 / 7])
    assert (ANCHORS[-6:] == ANCHORS[-1]).all()   # the three 32-px layers share each cell: 6 anchors


def test_decode_offsets_from_anchors_and_merges_overlapping_detections():
    raw = np.zeros((len(ANCHORS), 12))
    logits = np.full((len(ANCHORS), 1), -10.0)
    cell = 28 * 2 * 10 + 2 * 10   # row 10, column 10 of the 8-px grid
    raw[cell, :4] = [4.0, -2.0, 40.0, 80.0]
    raw[cell, 4:6] = [1.0, 30.0]                # the hips' point, offset from the anchor (px)
    raw[cell + 1] = raw[cell] + 2.0             # its twin anchor, a little off, a lower score
    logits[cell], logits[cell + 1] = 3.0, 1.0
    boxes, scores, points = decode_people(raw, logits)
    w_hi, w_lo = 1 / (1 + math.exp(-3.0)), 1 / (1 + math.exp(-1.0))
    shift = 2.0 * w_lo / (w_hi + w_lo)          # the score-weighted mean of the two
    centre = (10.5 / 28 * DETECTOR_PX + 4.0 + shift, 10.5 / 28 * DETECTOR_PX - 2.0 + shift)
    half = ((40.0 + shift) / 2, (80.0 + shift) / 2)
    assert len(scores) == 1 and scores[0] == pytest.approx(w_hi)
    np.testing.assert_allclose(boxes[0], [centre[0] - half[0], centre[1] - half[1],
                                          centre[0] + half[0], centre[1] + half[1]])
    np.testing.assert_allclose(points[0, 0], [10.5 / 28 * DETECTOR_PX + 1.0 + shift,
                                              10.5 / 28 * DETECTOR_PX + 30.0 + shift])


def test_region_of_an_upright_and_of_a_leaning_body():
    upright = region_from_points([100.0, 200.0], [100.0, 100.0])
    assert upright.rotation == pytest.approx(0.0) and upright.side == pytest.approx(250.0)
    leaning = region_from_points([0.0, 0.0], [10.0, -10.0])       # head up and to the right: 45°
    assert leaning.rotation == pytest.approx(math.pi / 4)
    to_input = leaning.to_input(256)
    head_in_input = to_input[:, :2] @ [10.0, -10.0] + to_input[:, 2]
    assert head_in_input[0] == pytest.approx(128.0) and head_in_input[1] < 128.0   # straight up in the input
    np.testing.assert_allclose(leaning.to_frame(head_in_input, 256), [10.0, -10.0], atol=1e-9)


def test_region_maps_to_the_input_and_back():
    region = Region(np.array([640.0, 360.0]), 300.0, 0.7)
    points = np.array([[600.0, 300.0], [700.0, 500.0], [640.0, 360.0]])
    forward = region.to_input(256)
    np.testing.assert_allclose(region.to_frame(points @ forward[:, :2].T + forward[:, 2], 256), points, atol=1e-9)
    np.testing.assert_allclose(points[2] @ forward[:, :2].T + forward[:, 2], [128.0, 128.0])


def test_scan_tiles_cover_the_frame_at_three_sizes():
    tiles, coarse = scan_tiles(1920, 1080)
    np.testing.assert_allclose(tiles[0], [0.0, -420.0, 1920.0])   # the whole frame, centred
    assert coarse == 1 + 3 and (tiles[1:coarse, 2] == 1080).all() and (tiles[coarse:, 2] == 540).all()
    for side in (1080.0, 540.0):
        mine = tiles[tiles[:, 2] == side]
        assert mine[:, 0].min() == 0 and mine[:, 0].max() + side == 1920
        assert mine[:, 1].min() == 0 and mine[:, 1].max() + side == 1080
        xs = np.unique(mine[:, 0])
        assert (np.diff(xs) <= 0.75 * side + 1e-9).all()   # neighbours overlap by a quarter at least


def test_mediapipe33_files_keep_all_points():
    people = np.random.default_rng(0).uniform(0, 500, (2, 33, 3))
    people[1, 5] = np.nan
    body = json.loads(openpose_json(people, "mediapipe33"))
    rows = np.array([p["pose_keypoints_2d"] for p in body["people"]]).reshape(2, 33, 3)
    np.testing.assert_allclose(rows[0, :, :2], np.round(people[0, :, :2], 2))
    assert (rows[1, 5] == 0).all() and len(LAYOUTS["mediapipe33"]) == 33


# --- real footage -----------------------------------------------------------------------------------

def test_several_people_found_and_followed_on_real_video():
    """The balancing take: the subject at once, the bystander at the back within the scan; the
    parkour clip: the jumper on the box and the walker who comes in."""
    detector = BlazePose(*_prepared("full"))
    counts = [len(detector(image).scores) for image in _frames(BALANCING, tuple(range(60)))]
    assert counts[0] >= 1 and max(counts[40:]) == min(counts[40:]) == 2
    assert detector.landmark_runs >= sum(counts)
    sports = BlazePose(*_prepared("full"))
    found = [sports(image) for image in _frames(SPORTS2D, tuple(range(140)))]
    assert len(found[0].scores) == 1 and all(len(f.scores) == 2 for f in found[100:140])
    ankles = [LAYOUTS["mediapipe33"].index(n) for n in ("left_ankle", "right_ankle", "left_heel", "left_foot_index")]
    last = found[-1]
    assert (last.keypoints[:, ankles, 2] > 0.5).all(axis=1).any()   # the walker's feet seen: heels and toes too


def _box_iou(a: np.ndarray, b: np.ndarray) -> float:
    """Intersection over union of two boxes (x1, y1, x2, y2)."""
    inter = np.prod(np.clip(np.minimum(a[2:], b[2:]) - np.maximum(a[:2], b[:2]), 0.0, None))
    return float(inter / (np.prod(a[2:] - a[:2]) + np.prod(b[2:] - b[:2]) - inter))


def test_max_people_one_follows_the_balancing_man_not_the_bystander():
    """The whole balancing take (100 frames): with ``max_people=1`` one person every frame, the one whose
    box is the largest of those the unlimited detector finds (the man; the bystander at the left edge is
    found from frame ~40 on), and one landmark run per frame."""
    frames = _frames(BALANCING, tuple(range(100)))
    everyone = BlazePose(*_prepared("full"))
    one = BlazePose(*_prepared("full"), max_people=1)
    found_all = [everyone(image) for image in frames]
    found_one = [one(image) for image in frames]
    assert max(len(f.scores) for f in found_all) == 2   # the bystander is there to be left out
    assert all(len(f.scores) == 1 for f in found_one)
    assert one.landmark_runs == len(frames)
    for all_people, chosen in zip(found_all, found_one):
        areas = np.prod(all_people.boxes[:, 2:] - all_people.boxes[:, :2], axis=1)
        assert _box_iou(chosen.boxes[0], all_people.boxes[np.argmax(areas)]) > 0.9
        assert (chosen.boxes[0, 0] + chosen.boxes[0, 2]) / 2.0 > 250.0   # not at the left edge


def test_max_people_follows_the_most_prominent_detection_and_keeps_it():
    """With ``max_people=1`` the detection of the largest region × score is followed (not the first
    found), a second one is not added while it is followed, and the scan stops running the detector."""
    detector = BlazePose(*_prepared("full"), max_people=1)
    small = Region(np.array([100.0, 100.0]), 100.0, 0.0)
    large = Region(np.array([600.0, 600.0]), 200.0, 0.0)
    faint = Region(np.array([900.0, 900.0]), 210.0, 0.0)   # 210² × 0.5 < 200² × 0.9
    detector._add_people([(small, 1.0), (faint, 0.5), (large, 0.9)])
    assert [p.region for p in detector.people] == [large]
    detector._add_people([(Region(np.array([1000.0, 600.0]), 400.0, 0.0), 1.0)])
    assert [p.region for p in detector.people] == [large]
    frames = _frames(BALANCING, tuple(range(10)))
    followed = BlazePose(*_prepared("full"), max_people=1, scan_every=1)
    followed(frames[0])
    runs = followed.detector_runs
    assert all(len(followed(image).scores) == 1 for image in frames[1:]) and followed.detector_runs == runs


def test_landmarks_follow_a_person_between_frames_without_the_detector():
    detector = BlazePose(*_prepared("full"), scan_every=1000)
    frames = _frames(BALANCING, tuple(range(10)))
    detector(frames[0])
    runs = detector.detector_runs
    steps = [detector(image).keypoints[0, :, :2] for image in frames[1:]]
    assert detector.detector_runs == runs   # followed by its own landmarks
    moves = [np.median(np.linalg.norm(b - a, axis=1)) for a, b in zip(steps, steps[1:])]
    assert max(moves) < 40.0   # pixels per frame at 60 fps: a smooth follow, not a jump to someone else


# --- the model store ----------------------------------------------------------------------------------

def test_fetch_refuses_a_package_whose_sha256_is_not_the_pinned_one(tmp_path, monkeypatch):
    from mocapdb.detect import model_store

    def tampered(package, into):
        path = into / package.file_name
        path.write_bytes(b"not the wheel")
        return path

    monkeypatch.setitem(model_store._DOWNLOADERS, "pypi", tampered)
    with pytest.raises(DetectError, match="is not the pinned"):
        model_store.fetch_models(("full",), tmp_path / "models", say=lambda _: None)
    assert not list((tmp_path / "models").glob("*.onnx"))
    with pytest.raises(DetectError, match="run `mocapdb models fetch` once"):
        blazepose_paths("full", tmp_path / "models")


def test_sides_swapped_by_the_model_are_swapped_back():
    from mocapdb.detect.blazepose import MIRROR, keep_sides

    names = LAYOUTS["mediapipe33"]
    previous = np.zeros((33, 3))
    previous[:, 0] = [(-100.0 if n.startswith("left") or n.endswith("_left") else
                       100.0 if n.startswith("right") or n.endswith("_right") else 0.0) for n in names]
    previous[:, 1] = np.arange(33) * 10.0
    moved = previous + [3.0, 2.0, 0.0]
    assert keep_sides(moved, previous) is moved                   # moved a little: kept
    swapped = moved[MIRROR]
    np.testing.assert_array_equal(keep_sides(swapped, previous), moved)   # swapped by the model: back
    assert names[MIRROR[names.index("left_heel")]] == "right_heel" and MIRROR[0] == 0


def test_live_one_thread_models_find_the_same_people_and_points():
    """`live`'s detector (each model in one intra-op thread: PIPELINE_MODEL_THREADS) gives the default
    sessions' (one thread per core) boxes, points and world points on real frames, the subject and the
    bystander, to the float: the thread count splits the work, not the sums."""
    from mocapdb.detect.detectors import PIPELINE_MODEL_THREADS, open_detector

    def detector(threads):
        return open_detector(None, "full", conf=0.5, iou=0.5, max_people=None, input_size=256, fast=None,
                             model_threads=threads)

    live, default = detector(PIPELINE_MODEL_THREADS), detector(None)
    assert live._landmarks.get_session_options().intra_op_num_threads == PIPELINE_MODEL_THREADS == 1
    for image in _frames(BALANCING, tuple(range(45))):
        a, b = live(image), default(image)
        for x, y in ((a.boxes, b.boxes), (a.keypoints, b.keypoints), (a.world, b.world)):
            np.testing.assert_allclose(x, y, rtol=0, atol=1e-5)
    assert len(a.scores) == 2


def test_live_video_frames_carry_blazepose_feet_and_hands():
    from mocapdb.core.formats.keypoint_layouts import EXTREMITIES
    from mocapdb.detect.model import Detections
    from mocapdb.detect.video import VideoFrame
    from mocapdb.runtime.stream.video_input import keypoint_frame

    points = np.random.default_rng(1).uniform(10, 500, (2, 33, 3))
    points[..., 2] = 0.9
    frame = keypoint_frame(VideoFrame(4, 0.1, 0.0, np.zeros((2, 2, 3), np.uint8)),
                           Detections(np.zeros((2, 4)), np.ones(2), points), "mediapipe33")
    heel = LAYOUTS["mediapipe33"].index("left_heel")
    assert frame.layout == "mediapipe33" and len(frame.people) == 2
    slot = EXTREMITIES.index("l_heel")
    np.testing.assert_allclose(frame.people[1].extremities[slot], points[1, heel])


def test_world_landmarks_metric_hip_centred_and_along_the_image_axes():
    """The landmark model's world head (``Identity_4``, [1, 117]) on the balancing take: 33 points per
    person in metres, origin at the hips' centre, x and y turned with the region onto the image's axes
    (the subject leans in camera 1's image: the crop is turned ~35°); the 2D are those of a run without it."""
    frames = _frames(BALANCING, tuple(range(12)))
    with_world, without = BlazePose(*_prepared("full")), BlazePose(*_prepared("full"), world_landmarks=False)
    for image in frames:
        found, plain = with_world(image), without(image)
    assert plain.world is None and found.world.shape == (len(found.scores), 33, 3)
    np.testing.assert_array_equal(found.keypoints, plain.keypoints)
    names = LAYOUTS["mediapipe33"]
    hips = [names.index("left_hip"), names.index("right_hip")]
    main = int(np.argmax(np.ptp(found.keypoints[:, :, 1], axis=1)))   # the subject: the tallest in the image
    world, points = found.world[main], found.keypoints[main, :, :2]
    assert np.linalg.norm(world[hips].mean(axis=0)) < 0.02
    reach = world[names.index("nose")] - world[[names.index("left_ankle"), names.index("right_ankle")]].mean(axis=0)
    assert 1.2 < np.linalg.norm(reach) < 1.9 and reach[1] < -0.8   # metres; the nose above the ankles: y down
    offsets = points - points[hips].mean(axis=0)
    far = np.linalg.norm(offsets, axis=1) > 100
    norms = np.linalg.norm(offsets, axis=1) * np.linalg.norm(world[:, :2], axis=1)
    cosine = np.sum(offsets * world[:, :2], axis=1) / norms
    assert np.median(cosine[far]) > 0.95   # the image's directions, not the upright crop's


def test_world_landmarks_change_sides_with_the_landmarks_and_reach_live_frames():
    from mocapdb.detect.blazepose import IDENTITY, MIRROR, side_order
    from mocapdb.detect.model import Detections
    from mocapdb.detect.video import VideoFrame
    from mocapdb.runtime.stream.video_input import keypoint_frame

    previous = np.random.default_rng(2).uniform(0, 500, (33, 3))
    assert side_order(previous[MIRROR], previous) is MIRROR and side_order(previous + 1.0, previous) is IDENTITY
    points = np.random.default_rng(1).uniform(10, 500, (2, 33, 3))
    world = np.random.default_rng(4).uniform(-0.5, 0.5, (2, 33, 3))
    frame = keypoint_frame(VideoFrame(4, 0.1, 0.0, np.zeros((2, 2, 3), np.uint8)),
                           Detections(np.zeros((2, 4)), np.ones(2), points, world), "mediapipe33")
    np.testing.assert_allclose(frame.people[1].world_m[10], world[1, LAYOUTS["mediapipe33"].index("right_ankle")])
    with pytest.raises(ValueError, match="COCO-17"):
        openpose_json(np.zeros((1, 17, 3)), "coco17", np.zeros((1, 17, 3)))
