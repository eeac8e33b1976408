"""Video → 2D keypoints: model layouts, letterbox, NMS, OpenPose files, errors, the video thread.

The ONNX models are built here: graphs whose outputs are fixed tensors (Constant nodes, plus a
term computed from the input so the input is used), holding people at known model-input pixels.
"""
import json
import os
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import onnx
import pytest
from onnx import TensorProto, helper, numpy_helper

from mocapdb.cli.main import main
from mocapdb.core.formats.keypoints import to_universal
from mocapdb.core.formats.openpose import read_openpose_folder
from mocapdb.detect.errors import DetectError
from mocapdb.detect.model import PoseModel, box_iou, letterbox, nms
from mocapdb.detect.openpose_out import coco17_to_coco18
from mocapdb.detect.video import VideoReader
from mocapdb.runtime.stream.transport import StreamStats
from mocapdb.runtime.stream.video_input import VideoDetections, open_video_source, run_video

VIDEO_W, VIDEO_H, VIDEO_FRAMES, VIDEO_FPS = 640, 360, 10, 10.0
SIDE = 320   # model input side: the 640×360 video is scaled by 0.5; YOLO pads 70 px above and below


# --- helpers ---------------------------------------------------------------------------------

def make_model(path: Path, input_shape: list, outputs: dict[str, np.ndarray],
               declared: dict[str, list] | None = None) -> Path:
    """An ONNX model whose named outputs are the given constants (shapes as declared, default
    their own). Each output adds 0 × mean(input), so the input is consumed."""
    declared = declared or {}
    nodes = [helper.make_node("ReduceMean", ["images"], ["mean"], keepdims=0),
             helper.make_node("Constant", [], ["zero"], value=numpy_helper.from_array(np.float32(0.0))),
             helper.make_node("Mul", ["mean", "zero"], ["nothing"])]
    for name, value in outputs.items():
        nodes += [helper.make_node("Constant", [], [f"{name}_value"],
                                   value=numpy_helper.from_array(value.astype(np.float32))),
                  helper.make_node("Add", [f"{name}_value", "nothing"], [name])]
    graph = helper.make_graph(
        nodes, "fixed_pose", [helper.make_tensor_value_info("images", TensorProto.FLOAT, input_shape)],
        [helper.make_tensor_value_info(n, TensorProto.FLOAT, declared.get(n, list(v.shape)))
         for n, v in outputs.items()])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    onnx.checker.check_model(model)
    onnx.save(model, str(path))
    return path


def person_keypoints(x0: float, y0: float, conf: float) -> np.ndarray:
    """17 keypoints [17, 3] at (x0 + 3k, y0 + 6k), model-input pixels."""
    k = np.arange(17)
    return np.stack([x0 + 3 * k, y0 + 6 * k, np.full(17, conf)], axis=1)


# People in model-input pixels: box (x1, y1, x2, y2), score, keypoints.
PEOPLE = {
    "A": (np.array([70, 100, 130, 220]), 0.9, person_keypoints(80, 105, 0.8)),
    "B": (np.array([74, 102, 134, 222]), 0.8, person_keypoints(84, 107, 0.7)),    # overlaps A: suppressed
    "C": (np.array([225, 110, 275, 210]), 0.7, person_keypoints(230, 115, 0.6)),  # apart from A: kept
    "D": (np.array([170, 180, 190, 220]), 0.2, person_keypoints(172, 182, 0.5)),  # under the 0.25 threshold
}


def yolo_rows(people: dict) -> np.ndarray:
    """[anchors, 56] rows (cx, cy, w, h, score, keypoints); two empty anchors at the end."""
    rows = [np.concatenate([(b[:2] + b[2:]) / 2, b[2:] - b[:2], [s], k.ravel()]) for b, s, k in people.values()]
    return np.vstack(rows + [np.zeros(56)] * 2)


@pytest.fixture
def yolo_model(tmp_path):
    """YOLO-pose layout [1, 56, anchors], input [1, 3, 320, 320], dynamic batch and anchor count."""
    out = yolo_rows(PEOPLE).T[None]
    return make_model(tmp_path / "yolo.onnx", ["batch", 3, SIDE, SIDE], {"output0": out},
                      {"output0": ["batch", 56, "anchors"]})


@pytest.fixture
def rtmo_model(tmp_path):
    """RTMO layout, keypoints output first; input [1, 3, 320, 320]."""
    dets = np.array([np.concatenate([b, [s]]) for b, s, _ in PEOPLE.values()] + [np.zeros(5)])[None]
    keypoints = np.stack([k for _, _, k in PEOPLE.values()] + [np.zeros((17, 3))])[None]
    return make_model(tmp_path / "rtmo.onnx", [1, 3, SIDE, SIDE], {"keypoints": keypoints, "dets": dets})


@pytest.fixture
def video(tmp_path):
    """A 640×360 MJPG .avi of 10 frames at 10 fps."""
    return _write_video(tmp_path / "clip.avi", VIDEO_FRAMES, step=20)


def _write_video(path, n_frames: int, step: int):
    """An MJPG .avi of ``n_frames`` grey frames, each ``step`` levels brighter."""
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), VIDEO_FPS, (VIDEO_W, VIDEO_H))
    assert writer.isOpened()
    for i in range(n_frames):
        writer.write(np.full((VIDEO_H, VIDEO_W, 3), step * i, dtype=np.uint8))
    writer.release()
    return path


def frame_image() -> np.ndarray:
    return np.zeros((VIDEO_H, VIDEO_W, 3), dtype=np.uint8)


def yolo_to_frame(xy: np.ndarray) -> np.ndarray:
    """By hand: scale 0.5, centred, 70 px of padding above → frame px = (input px − (0, 70)) × 2."""
    return (xy - [0, 70]) * 2


def detect(*argv: str) -> int:
    """``mocapdb detect ARGV`` through the command line's one error path; its exit code."""
    return main(["detect", *argv])


# --- pre- and post-processing ----------------------------------------------------------------

def test_letterbox_inverse_on_a_non_square_frame():
    image = np.full((VIDEO_H, VIDEO_W, 3), 255, dtype=np.uint8)
    canvas, box = letterbox(image, (416, 416), centred=True)
    # scale 416 / 640 = 0.65 → 416 × 234 pixels, (416 − 234) / 2 = 91 rows of padding above
    assert canvas.shape == (416, 416, 3) and (canvas[:91] == 114).all() and (canvas[91:325] == 255).all()
    np.testing.assert_allclose(box.to_original(np.array([[208.0, 208.0], [0.0, 91.0]])), [[320, 180], [0, 0]])
    canvas, box = letterbox(image, (416, 416), centred=False)
    assert (canvas[:234] == 255).all() and (canvas[234:] == 114).all()
    np.testing.assert_allclose(box.to_original(np.array([65.0, 117.0])), [100, 180])


def test_nms_keeps_the_better_of_two_overlapping_boxes_and_a_disjoint_one():
    boxes = np.array([[0, 0, 10, 10], [1, 1, 11, 11], [50, 50, 60, 60]], dtype=float)
    scores = np.array([0.6, 0.9, 0.5])
    assert box_iou(boxes[:1], boxes[1:2])[0, 0] == pytest.approx(81 / 119)
    assert nms(boxes, scores, 0.65).tolist() == [1, 2]
    assert nms(boxes, scores, 0.7).tolist() == [1, 0, 2]   # IoU 0.68 is under this threshold


def test_coco18_neck_is_the_mid_shoulder_point():
    kp = person_keypoints(10, 20, 0.9)[None]
    kp[0, 6, 2] = 0.4   # right shoulder less sure
    out = coco17_to_coco18(kp)
    np.testing.assert_allclose(out[0, 1], [(kp[0, 5, 0] + kp[0, 6, 0]) / 2, (kp[0, 5, 1] + kp[0, 6, 1]) / 2, 0.4])
    np.testing.assert_allclose(out[0, 2], kp[0, 6])   # COCO-18 RShoulder ← COCO-17 right_shoulder
    kp[0, 5, 2] = 0.0
    np.testing.assert_allclose(coco17_to_coco18(kp)[0, 1], [0, 0, 0])


# --- model layouts ---------------------------------------------------------------------------

def test_yolo_pose_model_threshold_nms_and_inverse_letterbox(yolo_model):
    model = PoseModel(yolo_model)
    assert model.layout.name == "yolo-pose" and model.input_wh == (SIDE, SIDE)
    found = model(frame_image())
    np.testing.assert_allclose(found.scores, [0.9, 0.7], rtol=1e-6)
    for got, name in zip(found.keypoints, "AC", strict=True):
        _, _, kp = PEOPLE[name]
        np.testing.assert_allclose(got[:, :2], yolo_to_frame(kp[:, :2]), atol=1e-3)
        np.testing.assert_allclose(got[:, 2], kp[:, 2], rtol=1e-6)
    np.testing.assert_allclose(found.boxes[0], yolo_to_frame(PEOPLE["A"][0].reshape(2, 2)).ravel(), atol=1e-3)
    assert len(PoseModel(yolo_model, conf=0.1)(frame_image()).scores) == 3   # D passes a lower threshold
    assert len(PoseModel(yolo_model, max_people=1)(frame_image()).scores) == 1


def test_yolo_pose_transposed_output_and_dynamic_input(tmp_path):
    path = make_model(tmp_path / "yolo_t.onnx", [1, 3, "height", "width"], {"output0": yolo_rows(PEOPLE)[None]})
    model = PoseModel(path, input_size=SIDE)
    assert model.input_wh == (SIDE, SIDE)
    found = model(frame_image())
    np.testing.assert_allclose(found.keypoints[0, :, :2], yolo_to_frame(PEOPLE["A"][2][:, :2]), atol=1e-3)


def test_rtmo_model_top_left_letterbox(rtmo_model):
    model = PoseModel(rtmo_model)
    assert model.layout.name == "rtmo"
    found = model(frame_image())
    np.testing.assert_allclose(found.scores, [0.9, 0.7], rtol=1e-6)
    # scale 0.5, frame at the top-left: frame px = input px × 2
    np.testing.assert_allclose(found.keypoints[1, :, :2], PEOPLE["C"][2][:, :2] * 2, atol=1e-3)
    np.testing.assert_allclose(found.boxes[0], PEOPLE["A"][0] * 2, atol=1e-3)


def test_unknown_layout_is_refused_naming_the_shapes(tmp_path):
    path = make_model(tmp_path / "other.onnx", [1, 3, 64, 64], {"logits": np.zeros((1, 10))})
    with pytest.raises(DetectError) as err:
        PoseModel(path)
    message = str(err.value)
    assert "unknown pose model layout" in message and "[1, 3, 64, 64]" in message and "logits [1, 10]" in message
    assert "YOLO-pose" in message and "RTMO" in message


def test_missing_and_corrupt_models(tmp_path):
    with pytest.raises(DetectError, match="pose model not found"):
        PoseModel(tmp_path / "absent.onnx")
    (tmp_path / "bad.onnx").write_bytes(np.random.default_rng(0).bytes(2000))
    with pytest.raises(DetectError, match="not a usable ONNX model"):
        PoseModel(tmp_path / "bad.onnx")


# --- video -----------------------------------------------------------------------------------

def test_video_decoding_counts_frames_and_times(video):
    reader = VideoReader(str(video))
    frames = list(reader.frames())
    reader.close()
    assert len(frames) == VIDEO_FRAMES == reader.frames_read
    assert [f.index for f in frames] == list(range(VIDEO_FRAMES))
    np.testing.assert_allclose([f.time_s for f in frames], np.arange(VIDEO_FRAMES) / VIDEO_FPS, atol=1e-6)
    reader = VideoReader(str(video))
    assert [f.index for f in reader.frames(every=4)] == [0, 4, 8]
    reader.close()


def test_missing_and_corrupt_videos(tmp_path):
    with pytest.raises(DetectError, match="video not found"):
        VideoReader(str(tmp_path / "absent.mp4"))
    (tmp_path / "bad.mp4").write_bytes(np.random.default_rng(1).bytes(5000))
    with pytest.raises(DetectError, match="no frame OpenCV can decode"):
        VideoReader(str(tmp_path / "bad.mp4"))


# --- the command -----------------------------------------------------------------------------

def test_detect_writes_coco18_openpose_files(video, yolo_model, tmp_path, capsys):
    out = tmp_path / "keypoints"
    assert detect(str(video), "--model", str(yolo_model), "--out", str(out)) == 0
    files = sorted(f for f in out.iterdir() if f.name not in ("take.json", "camera_path.json", "scene.json"))
    assert [f.name for f in files][:2] == ["clip_000000000000_keypoints.json", "clip_000000000001_keypoints.json"]
    assert len(files) == VIDEO_FRAMES
    take = json.loads((out / "take.json").read_text())   # what detect knows of the take, for reconstruct
    assert take["format"] == "mocapdb-take" and take["fps"] == pytest.approx(VIDEO_FPS)
    assert take["image_size"] == [VIDEO_W, VIDEO_H] and take["frames"] == VIDEO_FRAMES
    assert take["model"] == yolo_model.name and take["source"] == str(video) and take["focal_px"] is None
    first = json.loads(files[0].read_text())
    assert first["version"] == 1.3 and first["people"][0]["person_id"] == [-1]
    assert len(first["people"][0]["pose_keypoints_2d"]) == 18 * 3
    frames = list(read_openpose_folder(out))
    assert frames[0].layout == "coco18" and all(len(f.people) == 2 for f in frames)
    expected = np.stack([PEOPLE[n][2] for n in "AC"])
    expected[..., :2] = yolo_to_frame(expected[..., :2])
    points, conf = to_universal(expected, "coco17")
    for person, p, c in zip(frames[-1].people, points, conf, strict=True):
        np.testing.assert_allclose(person.points_px, p, atol=0.01)
        np.testing.assert_allclose(person.confidence, c, atol=1e-4)
    report = capsys.readouterr().out
    assert "frames read 10, frames written 10" in report and "mean 2.00" in report
    path = json.loads((out / "camera_path.json").read_text())   # the camera's rotation per frame, from the background
    assert path["still"] and path["frames"] == list(range(VIDEO_FRAMES)) and "camera still" in report


def test_detect_every_and_conf_options(video, rtmo_model, tmp_path):
    out = tmp_path / "sparse"
    assert detect(str(video), "--model", str(rtmo_model), "--out", str(out), "--every", "3", "--conf", "0.1") == 0
    frames = list(read_openpose_folder(out))
    assert [f.name.split("_")[1] for f in sorted(out.iterdir()) if f.name.startswith("clip")] == [
        "000000000000", "000000000003", "000000000006", "000000000009"]
    assert all(len(f.people) == 3 for f in frames)
    assert json.loads((out / "take.json").read_text())["fps"] == pytest.approx(VIDEO_FPS / 3)  # the keypoints' rate


def test_detect_user_errors_exit_2_with_clear_messages(video, yolo_model, tmp_path, capsys, monkeypatch):
    bad_video = tmp_path / "bad.mp4"
    bad_video.write_bytes(np.random.default_rng(2).bytes(5000))
    monkeypatch.setenv("MOCAPDB_MODELS", str(tmp_path / "no_models"))   # an offline machine never set up
    no_model = "BlazePose full is not prepared on this machine"
    cases = [((str(video), "--out", str(tmp_path / "o")), no_model),
             ((str(video), "--model", str(tmp_path / "absent.onnx"), "--out", str(tmp_path / "o")),
              "absent.onnx: no such file"),
             ((str(bad_video), "--model", str(yolo_model), "--out", str(tmp_path / "o")), "no frame OpenCV can decode"),
             (("--model", str(yolo_model), "--out", str(tmp_path / "o")), "give either a VIDEO file or --camera N")]
    for argv, message in cases:
        assert detect(*argv) == 2
        err = capsys.readouterr().err
        assert err.startswith("mocapdb detect: error: ") and message in err and "Traceback" not in err
    assert not (tmp_path / "o").exists()
    assert detect(str(video), "--out", str(tmp_path / "o")) == 2
    assert "run `mocapdb models fetch` once" in capsys.readouterr().err


# --- the live video source -------------------------------------------------------------------

def test_video_detections_drop_the_oldest_for_a_slow_consumer_of_a_paced_file(video, yolo_model):
    """A file delivered at its frame rate (live --realtime; a camera alike) drops the oldest detections behind
    a consumer busy elsewhere: the consumer gets the newest."""
    stats = StreamStats()
    live = open_video_source(str(video), PoseModel(yolo_model), capacity=2, stats=stats, paced=True)
    deadline = time.monotonic() + 10
    while not live.decoded.finished and time.monotonic() < deadline:
        time.sleep(0.01)   # a consumer busy elsewhere
    time.sleep(0.3)        # the last frame detected
    got = [live.get(timeout=1.0), live.get(timeout=1.0)]
    assert live.get(timeout=0.5) is None and live.finished
    # dropped behind the detector (or, on a loaded machine, already behind the decoder)
    assert [g.frame.index for g in got] == [8, 9] and live.dropped + live.decoded.dropped == stats.dropped_stale == 8
    frame = got[0].frame
    assert frame.layout == "coco17" and frame.time_s == pytest.approx(0.8) and len(frame.people) == 2
    np.testing.assert_allclose(frame.people[0].points_px[0], yolo_to_frame(PEOPLE["A"][2][0, :2]), atol=1e-3)
    assert got[0].capture_s <= got[1].capture_s <= time.monotonic() and live.detection_fps > 0
    live.close()
    live.close()
    assert not live._thread.is_alive()
    assert "dropped 8" in live.report()


def test_a_file_read_as_fast_as_it_goes_loses_no_frame_to_a_slow_consumer(video, yolo_model):
    """Not paced, a file's detections wait for the consumer (nothing is gained by dropping where no clock runs):
    every frame arrives, in order, none dropped."""
    stats = StreamStats()
    live = open_video_source(str(video), PoseModel(yolo_model), capacity=2, stats=stats)
    time.sleep(0.5)        # a consumer busy elsewhere while the detector could run through the file
    got = []
    while (item := live.get(timeout=1.0)) is not None:
        got.append(item.frame.index)
    assert got == list(range(VIDEO_FRAMES)) and live.dropped == stats.dropped_stale == 0
    live.close()


def test_run_video_hands_every_frame_to_the_session(video, yolo_model):
    class Recorder:
        def __init__(self):
            self.frames = []

        def handle_frame(self, frame, arrival_s):
            self.frames.append((frame.index, arrival_s))

    session, stop = Recorder(), threading.Event()
    live = VideoDetections(str(video), PoseModel(yolo_model), capacity=VIDEO_FRAMES)
    run_video(session, live, stop)
    assert [i for i, _ in session.frames] == list(range(VIDEO_FRAMES))
    assert not live._thread.is_alive()


def test_the_landmark_models_run_on_a_frame_while_the_pose_model_takes_the_next(video):
    """live runs the hand and face models in a thread of their own: the landmarks of frame k wait until the
    pose model has started on frame k + 1 (one thread would wait forever: 10 s, then the test fails), and
    every frame still arrives in order with its landmarks."""
    from mocapdb.detect.hands import Hands
    from mocapdb.detect.model import Detections
    from mocapdb.detect.with_landmarks import WithLandmarks

    pose_started = [threading.Event() for _ in range(VIDEO_FRAMES)]

    class Pose:
        keypoint_layout, path, seconds, frames = "mediapipe33", Path("pose.onnx"), 0.0, 0

        def __call__(self, image):
            pose_started[self.frames].set()
            self.frames += 1
            return Detections(np.zeros((1, 4)), np.ones(1), np.full((1, 33, 3), 100.0))

        def describe(self):
            return "pose"

    class Landmarks:
        def __init__(self):
            self.frames, self.overlapped, self.threads = 0, [], set()

        def __call__(self, image, keypoints):
            if self.frames + 1 < VIDEO_FRAMES and all(self.overlapped):
                self.overlapped.append(pose_started[self.frames + 1].wait(10.0))
            self.frames += 1
            self.threads.add(threading.current_thread().name)
            hands = Hands.empty(len(keypoints))
            hands.points[..., :3], hands.points[..., 3] = self.frames, 1.0
            return hands

        def describe(self):
            return "hands"

    landmarks = Landmarks()
    live = VideoDetections(str(video), WithLandmarks(Pose(), hands=landmarks), capacity=VIDEO_FRAMES)
    got = []
    while (item := live.get(timeout=15.0)) is not None:
        got.append(item.frame)
    live.close()
    assert [frame.index for frame in got] == list(range(VIDEO_FRAMES))
    assert landmarks.overlapped == [True] * (VIDEO_FRAMES - 1) and landmarks.threads == {"mocapdb-video-detect"}
    assert [frame.people[0].hands[0, 0, 0] for frame in got] == list(range(1, VIDEO_FRAMES + 1))


def test_a_paced_video_runs_the_pose_and_landmark_models_in_one_thread(video):
    """At a camera's pace (live --realtime, a camera) a frame's landmark models run right after its pose, in the
    detection thread, not beside the next frame's pose: the latency of each frame, not the throughput, counts."""
    from mocapdb.detect.hands import Hands
    from mocapdb.detect.model import Detections
    from mocapdb.detect.with_landmarks import WithLandmarks

    threads: dict[str, set[str]] = {"pose": set(), "hands": set()}

    class Pose:
        keypoint_layout, path, seconds, frames = "mediapipe33", Path("pose.onnx"), 0.0, 0

        def __call__(self, image):
            threads["pose"].add(threading.current_thread().name)
            return Detections(np.zeros((1, 4)), np.ones(1), np.full((1, 33, 3), 100.0))

        def describe(self):
            return "pose"

    class Landmarks:
        def __call__(self, image, keypoints):
            threads["hands"].add(threading.current_thread().name)
            return Hands.empty(len(keypoints))

        def describe(self):
            return "hands"

    live = VideoDetections(str(video), WithLandmarks(Pose(), hands=Landmarks()), capacity=VIDEO_FRAMES, paced=True)
    got = [item for item in iter(lambda: live.get(timeout=5.0), None)]
    live.close()
    assert live.poses is None and len(got) >= 1
    assert threads["pose"] == threads["hands"] == {"mocapdb-video-detect"}


def test_a_video_file_measures_its_camera_path_unless_filmed_still(video, yolo_model):
    """live measures a file's camera path from the background; --still-camera (turning=False) skips it."""
    for turning, measured in ((True, True), (False, False)):
        live = open_video_source(str(video), PoseModel(yolo_model), turning=turning)
        assert (live.motion is not None) is measured
        live.close()


def test_open_video_source_reads_digits_as_a_camera(yolo_model):
    with pytest.raises(DetectError, match="camera 99: cannot be opened"):
        open_video_source("99", PoseModel(yolo_model))


# --- end to end: video → keypoints → 3D → BVH ---------------------------------------------------

COCO17_OF_UNIVERSAL = {0: 0, 2: 6, 3: 8, 4: 10, 5: 5, 6: 7, 7: 9, 8: 12, 9: 14, 10: 16, 11: 11, 12: 13, 13: 15}


@pytest.fixture
def human_model(tmp_path, small_db):
    """A YOLO-pose model that always sees one person: a database pose, 150 px high in the input."""
    pose = small_db.keypoints_2d[40].astype(np.float64) * 150.0 + [160.0, 180.0]
    keypoints = np.zeros((17, 3))
    for universal, coco in COCO17_OF_UNIVERSAL.items():
        keypoints[coco] = [pose[universal, 0], pose[universal, 1], 0.9]
    keypoints[1:5] = [pose[0, 0], pose[0, 1], 0.9]  # eyes and ears at the nose
    box = np.concatenate([pose.min(axis=0) - 5, pose.max(axis=0) + 5])
    row = np.concatenate([(box[:2] + box[2:]) / 2, box[2:] - box[:2], [0.95], keypoints.ravel()])
    return make_model(tmp_path / "human.onnx", [1, 3, SIDE, SIDE], {"output0": row[:, None][None]})


def test_video_to_bvh_through_detect_and_reconstruct(video, human_model, small_db_path, tmp_path, capsys):
    from mocapdb.cli.main import main

    assert main(["detect", str(video), "--model", str(human_model), "--out", str(tmp_path / "kp")]) == 0
    assert main(["reconstruct", str(tmp_path / "kp"), "--db", str(small_db_path), "--out", str(tmp_path / "out"),
                 "--fps", str(VIDEO_FPS), "--image-size", f"{VIDEO_W}x{VIDEO_H}"]) == 0
    assert f"frames {VIDEO_FRAMES}" in capsys.readouterr().out
    assert (tmp_path / "out" / "track_0.bvh").exists()


def test_live_video_source_to_bvh(video, human_model, small_db_path, tmp_path, capsys):
    from mocapdb.cli.main import main

    assert main(["live", "--source", str(video), "--model", str(human_model), "--db", str(small_db_path),
                 "--sink", str(tmp_path / "live.jsonl"), "--bvh-dir", str(tmp_path), "--buffer", "20"]) == 0
    err = capsys.readouterr().err
    assert f"frames {VIDEO_FRAMES}" in err and "detection" in err
    lines = (tmp_path / "live.jsonl").read_text().splitlines()
    header = json.loads(lines[0])   # frame rate and size taken from the video itself
    assert header["fps"] == pytest.approx(VIDEO_FPS) and header["image_size"] == [VIDEO_W, VIDEO_H]
    assert header["camera_sources"]["fps"] == header["camera_sources"]["image_size"] == "read"
    frames = [json.loads(line) for line in lines[1:]]
    assert sum(len(f["people"]) for f in frames) == VIDEO_FRAMES - 1  # confirmed on the second frame
    assert (tmp_path / "track_0.bvh").exists()


def test_live_with_a_missing_model_is_a_clear_error(video, small_db_path, tmp_path, capsys):
    from mocapdb.cli.main import main

    assert main(["live", "--source", str(video), "--model", str(tmp_path / "none.onnx"),
                 "--db", str(small_db_path)]) == 2
    assert "none.onnx" in capsys.readouterr().err


# --- truncated videos and OS errors (issue 13) ----------------------------------------------------

TRUNCATED_FRAMES = 20


@pytest.fixture
def truncated_video(tmp_path):
    """A 20-frame MJPG .avi cut after its first frame's chunk: the header still declares 20 frames."""
    path = _write_video(tmp_path / "full.avi", TRUNCATED_FRAMES, step=10)
    data = path.read_bytes()
    first = data.index(b"movi") + 4                       # the first frame's chunk: '00dc', size, JPEG
    assert data[first:first + 4] == b"00dc"
    size = int.from_bytes(data[first + 4:first + 8], "little")
    cut = tmp_path / "cut.avi"
    cut.write_bytes(data[:first + 8 + size + (size & 1)])
    return cut


def test_a_truncated_video_is_read_to_its_last_frame_with_a_warning(truncated_video, yolo_model, tmp_path, capsys):
    """Issue 52, item 4: a file shorter than its header is what players play: every frame read is
    written, a warning says how many of how many, the command succeeds."""
    reader = VideoReader(str(truncated_video))
    assert reader.frame_count == TRUNCATED_FRAMES and reader.truncation() is None   # not at its end yet
    assert len(list(reader.frames())) == 1 and reader.ended
    assert reader.truncation().endswith("the container promised 20 frames, 1 could be read: the file looks cut "
                                        "short (an interrupted copy or download, or a recording that was not "
                                        "closed); every frame read is used")
    reader.close()
    out = tmp_path / "kp"
    assert detect(str(truncated_video), "--model", str(yolo_model), "--out", str(out)) == 0
    captured = capsys.readouterr()
    assert "frames read 1, frames written 1 (the video ended before its declared frame count)" in captured.out
    assert captured.err.startswith(f"mocapdb: warning: {truncated_video}: the container promised 20 frames, "
                                   "1 could be read") and "Traceback" not in captured.err
    assert sorted(f.name for f in out.iterdir()) == ["camera_path.json", "cut_000000000000_keypoints.json",
                                                     "scene.json", "take.json"]
    assert len(list(read_openpose_folder(out))[0].people) == 2
    assert detect(str(truncated_video), "--model", str(yolo_model), "--out", str(out), "--every", "3") == 0
    assert "the container promised 20 frames, 1 could be read" in capsys.readouterr().err


def test_a_video_read_to_its_declared_end_or_without_a_count_is_fine(video, truncated_video):
    reader = VideoReader(str(video))
    assert len(list(reader.frames(every=3))) == 4 and reader.truncation() is None   # 10 of 10 read
    reader.close()
    reader = VideoReader(str(truncated_video))
    reader.frame_count = None                       # a container that declares no frame count
    assert len(list(reader.frames())) == 1 and reader.truncation() is None
    reader.close()
    reader = VideoReader(str(truncated_video))
    frames = reader.frames()
    next(frames)
    frames.close()                                  # stopped by the consumer: never "truncated"
    assert not reader.ended and reader.truncation() is None
    reader.close()


def test_the_live_video_source_warns_about_a_truncated_file(truncated_video, yolo_model):
    live = VideoDetections(str(truncated_video), PoseModel(yolo_model), capacity=4)
    deadline = time.monotonic() + 10
    while not live.finished and time.monotonic() < deadline:
        live.get(timeout=0.1)
    live.close()
    assert "\nwarning: " in live.report() and "the container promised 20 frames, 1 could be read" in live.report()


def test_detect_os_errors_name_the_path(video, yolo_model, tmp_path, capsys, monkeypatch):
    (tmp_path / "a_file").write_text("x")
    (tmp_path / "a_folder").mkdir()
    cases = [((str(video), "--model", str(yolo_model), "--out", str(tmp_path / "a_file")),
              f"{tmp_path / 'a_file'}: the output (--out) exists and is not a folder"),
             ((str(video), "--model", str(yolo_model), "--out", str(tmp_path / "a_file" / "sub")),
              f"{tmp_path / 'a_file' / 'sub'}: cannot create the output folder (Not a directory)"),
             ((str(tmp_path / "a_folder"), "--model", str(yolo_model), "--out", str(tmp_path / "o")),
              f"{tmp_path / 'a_folder'}: is a folder, not a file"),
             ((str(video), "--model", str(tmp_path / "a_folder"), "--out", str(tmp_path / "o")),
              f"{tmp_path / 'a_folder'}: is a folder, not a file"),
             ((str(tmp_path / "absent.avi"), "--model", str(yolo_model), "--out", str(tmp_path / "o")),
              f"{tmp_path / 'absent.avi'}: no such file")]
    for argv, message in cases:
        assert detect(*argv) == 2
        err = capsys.readouterr().err
        assert err.startswith("mocapdb detect: error: ") and message in err and "Traceback" not in err, err

    def full(*args, **kwargs):  # an OS error without a file name
        raise OSError(28, "No space left on device")

    monkeypatch.setattr("mocapdb.detect.openpose_out.write_atomic", full)
    assert detect(str(video), "--model", str(yolo_model), "--out", str(tmp_path / "kp")) == 2
    err = capsys.readouterr().err
    assert (f"{tmp_path / 'kp' / 'clip_000000000000_keypoints.json'}: cannot write the keypoints "
            "(No space left on device)") in err and "[Errno" not in err


@pytest.mark.skipif(not hasattr(os, "geteuid") or os.geteuid() == 0, reason="root reads any file")
def test_an_unreadable_video_names_it(video):
    video.chmod(0)
    with pytest.raises(DetectError, match=f"{video}: cannot read the video \\(Permission denied\\)"):
        VideoReader(str(video))


def test_reconstruct_reads_the_take_description_detect_wrote(video, human_model, small_db_path, tmp_path, capsys):
    """detect → reconstruct with nothing typed again gives exactly the result of the right options;
    an option that contradicts take.json is refused naming both; the header says what was used."""
    from mocapdb.cli.main import main

    kp = tmp_path / "kp"
    assert main(["detect", str(video), "--model", str(human_model), "--out", str(kp)]) == 0
    base = ["reconstruct", str(kp), "--db", str(small_db_path)]
    assert main([*base, "--out", str(tmp_path / "read")]) == 0
    assert main([*base, "--out", str(tmp_path / "given"), "--fps", str(VIDEO_FPS),
                 "--image-size", f"{VIDEO_W}x{VIDEO_H}", "--focal-35mm", "26"]) == 0
    read = (tmp_path / "read" / "result.jsonl").read_text().splitlines()
    given = (tmp_path / "given" / "result.jsonl").read_text().splitlines()
    assert read[1:] == given[1:] and len(read) == VIDEO_FRAMES + 1
    header = json.loads(read[0])
    assert header["fps"] == pytest.approx(VIDEO_FPS) and header["image_size"] == [VIDEO_W, VIDEO_H]
    assert header["focal_px"] == pytest.approx(26 * np.hypot(VIDEO_W, VIDEO_H) / 43.27)  # a phone's main camera
    assert header["camera_sources"] == {"fps": "read", "image_size": "read", "focal_px": "default"}
    assert json.loads(given[0])["camera_sources"] == {"fps": "given", "image_size": "given", "focal_px": "given"}
    err = capsys.readouterr().err
    assert "no --fps was given" not in err           # the frame rate is known: no warning
    assert "no focal length given: assuming a typical phone main camera, 26 mm equivalent" in err
    assert main([*base, "--out", str(tmp_path / "bad"), "--image-size", f"{VIDEO_H}x{VIDEO_W}"]) == 2
    err = capsys.readouterr().err
    assert f"--image-size {VIDEO_H}x{VIDEO_W} contradicts" in err and f"{VIDEO_W}x{VIDEO_H}" in err
    assert "take.json" in err and not (tmp_path / "bad").exists()


def test_a_broken_take_description_is_named(tmp_path):
    from mocapdb.core.formats.take import TakeError, TakeInfo, read_take, write_take

    assert read_take(tmp_path) is None
    write_take(tmp_path, TakeInfo(fps=60.0, image_size=(1080, 1920), frames=3, source="v.mp4"))
    assert read_take(tmp_path).image_size == (1080, 1920)
    for body, words in (("{", "not a take description"), ('{"format": "x"}', "format"),
                        ('{"format": "mocapdb-take", "version": 1, "fps": -1}', "fps"),
                        ('{"format": "mocapdb-take", "version": 1, "image_size": [1e20, 2]}', "image_size")):
        (tmp_path / "take.json").write_text(body)
        with pytest.raises(TakeError, match=words):
            read_take(tmp_path)


def test_detect_replaces_its_own_output_and_refuses_a_foreign_folder(video, yolo_model, tmp_path, capsys):
    """detect writes its frames in place as the video is read (live may follow the folder): an earlier
    detect output is emptied first (no stale frame of another video left), a folder holding anything
    else is refused before any work, naming a file, and kept byte for byte (OpenPose's own output:
    frame files but no take.json)."""
    out = tmp_path / "kp"
    assert detect(str(video), "--model", str(yolo_model), "--out", str(out)) == 0
    stale = out / "other_000000000099_keypoints.json"   # an earlier run's frame of another video
    stale.write_text('{"version": 1.3, "people": []}')
    assert detect(str(video), "--model", str(yolo_model), "--out", str(out)) == 0
    assert not stale.exists() and len(list(out.glob("clip_*_keypoints.json"))) == VIDEO_FRAMES
    capsys.readouterr()
    openpose = tmp_path / "openpose"
    openpose.mkdir()
    (openpose / "cam_000000000000_keypoints.json").write_text('{"version": 1.3, "people": []}')
    (out / "notes.txt").write_text("mine")
    for folder, named in ((out, "it holds notes.txt"), (openpose, "but no take.json")):
        before = {p.name: p.read_bytes() for p in folder.iterdir()}
        assert detect(str(video), "--model", str(yolo_model), "--out", str(folder)) == 2
        err = capsys.readouterr().err
        assert err.startswith("mocapdb detect: error: ") and err.count("\n") == 1, err
        assert "is not an output folder of `mocapdb detect`" in err and named in err, err
        assert {p.name: p.read_bytes() for p in folder.iterdir()} == before
