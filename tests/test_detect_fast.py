"""Detection that follows the people (mocapdb.detect.tracked): crop geometry, the scheduler, optical flow,
the options' domains.

The ONNX models are built here as in tests/test_detect.py: fixed people at known model-input pixels;
``bright_model`` scores its person by the input's mean brightness, so a dark frame shows nobody.
"""
import argparse

import cv2
import numpy as np
import onnx
import pytest
from onnx import TensorProto, helper, numpy_helper

from mocapdb.cli.main import main, parser
from mocapdb.core.domains import DomainError
from mocapdb.detect.model import PoseModel
from mocapdb.detect.tracked import (
    FULL_FRAME,
    FastPath,
    TrackedDetector,
    carry_keypoints,
    crop_input_px,
    crop_letterbox,
    crop_square,
    warp,
)

from .test_detect import PEOPLE, VIDEO_H, VIDEO_W, make_model, yolo_rows

SIDE = 320                         # the full-frame input: the 640×360 frame scaled by 0.5, 70 px of padding above
ONE = {"A": PEOPLE["A"]}           # input box (70, 100, 130, 220), keypoints at (80 + 3k, 105 + 6k)
SCORE_ROW = 4                      # YOLO-pose row of the person score


@pytest.fixture
def dynamic_model(tmp_path):
    """Person A at fixed input pixels whatever the input size (a dynamic export)."""
    return make_model(tmp_path / "dyn.onnx", [1, 3, "height", "width"], {"output0": yolo_rows(ONE).T[None]},
                      {"output0": [1, 56, "anchors"]})


@pytest.fixture
def bright_model(tmp_path):
    """Person A, scored by the input's mean value (0–1): seen in a white frame, not in a black one."""
    rows = yolo_rows(ONE).T[None].astype(np.float32)
    mask = np.zeros_like(rows)
    mask[0, SCORE_ROW, 0] = 1.0
    rows[0, SCORE_ROW, 0] = 0.0
    nodes = [helper.make_node("ReduceMean", ["images"], ["mean"], keepdims=0),
             helper.make_node("Constant", [], ["mask"], value=numpy_helper.from_array(mask)),
             helper.make_node("Constant", [], ["rows"], value=numpy_helper.from_array(rows)),
             helper.make_node("Mul", ["mean", "mask"], ["score"]),
             helper.make_node("Add", ["rows", "score"], ["output0"])]
    graph = helper.make_graph(nodes, "bright_pose",
                              [helper.make_tensor_value_info("images", TensorProto.FLOAT, [1, 3, "h", "w"])],
                              [helper.make_tensor_value_info("output0", TensorProto.FLOAT, [1, 56, "anchors"])])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    onnx.save(model, str(tmp_path / "bright.onnx"))
    return tmp_path / "bright.onnx"


def white() -> np.ndarray:
    return np.full((VIDEO_H, VIDEO_W, 3), 255, dtype=np.uint8)


def texture(shift_xy: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
    """A blurred-noise BGR image of the video's size, moved by ``shift_xy`` pixels."""
    rng = np.random.default_rng(0)
    grey = cv2.GaussianBlur(rng.random((VIDEO_H, VIDEO_W)).astype(np.float32), (0, 0), 2.0)
    grey = cv2.normalize(grey, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
    moved = cv2.warpAffine(grey, np.float32([[1, 0, shift_xy[0]], [0, 1, shift_xy[1]]]), (VIDEO_W, VIDEO_H),
                           borderMode=cv2.BORDER_REFLECT)
    return cv2.cvtColor(moved, cv2.COLOR_GRAY2BGR)


def a_in_frame() -> np.ndarray:
    """Person A's keypoints in frame pixels after the full-frame letterbox: (input − (0, 70)) × 2."""
    return (PEOPLE["A"][2][:, :2] - [0, 70]) * 2


# --- crop geometry -----------------------------------------------------------------------------

def test_crop_geometry_by_hand():
    # A in the frame: box (140, 60, 260, 300), 120 × 240 px → square side 240 × 1.5 = 360, centre (200, 180)
    centre, side = crop_square(np.array([[140.0, 60.0, 260.0, 300.0]]))
    np.testing.assert_allclose(centre, [200, 180])
    assert side == pytest.approx(360.0)
    assert crop_input_px(side, 256) == 256 and crop_input_px(side, 300) == 320 and crop_input_px(100.0, 256) == 128
    box = crop_letterbox(centre, side, (256, 256))   # scale 256 / 360; the centre lands on (128, 128)
    np.testing.assert_allclose(box.scale, [256 / 360] * 2)
    np.testing.assert_allclose(box.to_original(np.array([[128.0, 128.0], [0.0, 0.0], [256.0, 256.0]])),
                               [[200, 180], [20, 0], [380, 360]])
    two = crop_square(np.array([[0.0, 0.0, 10.0, 40.0], [30.0, 20.0, 50.0, 60.0]]), margin=0.0)
    np.testing.assert_allclose(two[0], [25, 30])     # the union (0, 0, 50, 60), its larger side
    assert two[1] == pytest.approx(60.0)
    assert crop_square(np.array([[5.0, 5.0, 5.0, 5.0]]))[1] == 32.0   # a box of no size: the smallest crop


def test_warp_puts_continuous_pixels_where_the_letterbox_says():
    """A ramp image (value = column index, whose centre is at x + 0.5): each input pixel's value is
    the frame x its centre maps back to, minus 0.5; beyond the frame, the padding grey."""
    ramp = np.repeat(np.arange(400, dtype=np.float32)[None, :, None], 300, axis=0).repeat(3, axis=2)
    box = crop_letterbox(np.array([50.0, 100.0]), 200.0, (64, 64))   # scale 0.32, offset (16, 0)
    canvas = warp(ramp, box, (64, 64))
    x_frame = box.to_original(np.stack([np.arange(64) + 0.5, np.full(64, 32.5)], axis=1))[:, 0]
    inside = x_frame - 0.5 >= 0
    np.testing.assert_allclose(canvas[32, inside, 0], x_frame[inside] - 0.5, atol=0.05)
    assert (canvas[32, x_frame < -1, 0] == 114).all() and (~inside).any()


def test_crop_keypoints_map_back_to_frame_pixels_exactly(dynamic_model, tmp_path):
    detector = TrackedDetector(PoseModel(dynamic_model, input_size=SIDE), FastPath(crop_px=256))
    first = detector(white())
    assert detector.last_path == "full"
    np.testing.assert_allclose(first.keypoints[0, :, :2], a_in_frame(), atol=1e-3)
    second = detector(white())
    assert detector.last_path == "crop"
    # by hand: crop side 360 around (200, 180) into 256 px: frame = (input + (14.22, 0)) × 360 / 256
    k = np.arange(17)
    expected = np.stack([1.40625 * (80 + 3 * k) + 20, 1.40625 * (105 + 6 * k)], axis=1)
    np.testing.assert_allclose(second.keypoints[0, :, :2], expected, atol=1e-3)
    np.testing.assert_allclose(second.boxes[0], [1.40625 * 70 + 20, 1.40625 * 100, 1.40625 * 130 + 20, 1.40625 * 220],
                               atol=1e-3)
    fixed = make_model(tmp_path / "fixed.onnx", [1, 3, SIDE, SIDE], {"output0": yolo_rows(ONE).T[None]})
    detector = TrackedDetector(PoseModel(fixed), FastPath(crop_px=256))
    detector(white())
    crop = detector(white())   # a fixed 320 px input: frame = (input + (17.78, 0)) × 360 / 320
    np.testing.assert_allclose(crop.keypoints[0, :, :2], np.stack([1.125 * (80 + 3 * k) + 20, 1.125 * (105 + 6 * k)],
                                                                  axis=1), atol=1e-3)
    assert "fixed input size" in detector.describe()


# --- the scheduler -----------------------------------------------------------------------------

def test_the_whole_frame_every_k_frames(bright_model):
    detector = TrackedDetector(PoseModel(bright_model, input_size=SIDE), FastPath(full_every=3))
    paths = []
    for _ in range(7):
        assert len(detector(white()).scores) == 1
        paths.append(detector.last_path)
    assert paths == ["full", "crop", "crop", "full", "crop", "crop", "full"]
    assert detector.paths == {"full": 3, "crop": 4} and detector.fps > 0
    assert detector.describe().endswith("frames by path: crop 4, full 3")


def test_a_lost_person_brings_the_whole_frame_back(bright_model):
    detector = TrackedDetector(PoseModel(bright_model, input_size=SIDE), FastPath())
    black = np.zeros_like(white())
    seen = []
    for image in (white(), white(), black, black, white(), white()):
        found = detector(image)
        seen.append((len(found.scores), detector.last_path))
    assert seen == [(1, "full"), (1, "crop"), (0, "crop+full"), (0, "full"), (1, "full"), (1, "crop")]


def test_the_full_frame_path_never_crops(bright_model):
    detector = TrackedDetector(PoseModel(bright_model, input_size=SIDE), FULL_FRAME)
    for _ in range(4):
        detector(white())
    assert detector.paths == {"full": 4}


# --- optical flow ------------------------------------------------------------------------------

def test_flow_carries_keypoints_by_the_known_shift():
    shift = np.array([3.0, -2.0])
    before, after = (cv2.cvtColor(texture(s), cv2.COLOR_BGR2GRAY) for s in ((0.0, 0.0), shift))
    keypoints = np.array([[[200.0, 150.0, 0.9], [320.0, 180.0, 0.8], [420.0, 250.0, 0.7], [-500.0, -500.0, 0.9]]])
    carried = carry_keypoints(before, after, keypoints)
    np.testing.assert_allclose(carried[0, :3, :2], keypoints[0, :3, :2] + shift, atol=0.05)
    np.testing.assert_allclose(carried[0, :3, 2], [0.9, 0.8, 0.7])
    np.testing.assert_allclose(carried[0, 3], [-500, -500, 0])   # lost by the flow: kept, confidence 0


def test_flow_frames_between_model_runs_move_the_people(dynamic_model):
    detector = TrackedDetector(PoseModel(dynamic_model, input_size=SIDE), FastPath(model_every=2))
    shift = np.array([2.5, 1.5])
    first = detector(texture())
    carried = detector(texture(shift))
    assert detector.last_path == "flow"
    np.testing.assert_allclose(carried.keypoints[0, :, :2], first.keypoints[0, :, :2] + shift, atol=0.1)
    np.testing.assert_allclose(carried.boxes[0], first.boxes[0] + np.tile(shift, 2), atol=0.1)
    detector(texture(2 * shift))
    assert detector.last_path == "crop" and detector.paths == {"full": 1, "flow": 1, "crop": 1}


# --- options -----------------------------------------------------------------------------------

def test_options_outside_their_domains_are_refused(tmp_path, capsys):
    for bad in ({"crop_px": 16}, {"crop_px": 5000}, {"full_every": 0}, {"model_every": 0}, {"model_every": 101},
                {"model_every": 1.5}):
        with pytest.raises(DomainError, match="must be"):
            FastPath(**bad)
    (tmp_path / "v.mp4").write_bytes(b"\0")
    base = ["detect", str(tmp_path / "v.mp4"), "--out", str(tmp_path / "o")]
    for option, value in (("--crop-size", "16"), ("--full-every", "0"), ("--model-every", "0"),
                          ("--model-every", "101"), ("--detector", "fast")):
        assert main([*base, option, value]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and f"argument {option}:" in err, err


def test_crops_are_live_s_default_and_full_frames_detect_s(tmp_path):
    video, model = tmp_path / "v.mp4", tmp_path / "m.onnx"
    video.write_bytes(b"\0")
    model.write_bytes(b"\0")
    live = parser().parse_args(["live", "--source", str(video), "--model", str(model), "--db", str(tmp_path)])
    detect = parser().parse_args(["detect", str(video), "--model", str(model), "--out", str(tmp_path / "o")])
    assert (live.detector, detect.detector) == ("crops", "full")
    from mocapdb.cli.detect import fast_path

    assert fast_path(live) == FastPath() and fast_path(detect) == FULL_FRAME
    assert fast_path(argparse.Namespace(detector="crops", crop_size=320, full_every=5, model_every=2)) == FastPath(
        crop_px=320, full_every=5, model_every=2)
