"""Keypoint input: layout orders, the universal mapping, layout detection, OpenPose and MMPose JSON,
streams, arrays and their corrupt forms."""
import io
import json
import tracemalloc
import zipfile

import numpy as np
import pytest

from mocapdb.cli.main import main
from mocapdb.core.formats.keypoint_arrays import frames_from_arrays, read_keypoint_array, read_keypoint_file
from mocapdb.core.formats.keypoints import (
    CONFIDENCE_THRESHOLD,
    LAYOUTS,
    KeypointError,
    Person,
    detect_layout,
    to_universal,
    visible,
)
from mocapdb.core.formats.openpose import (
    frame_order_key,
    parse_openpose_json,
    parse_stream_line,
    read_mmpose_json,
    read_openpose_folder,
)
from mocapdb.core.skeleton import KP, N_KEYPOINTS_2D

from .conftest import REAL_TAKE, SAMPLE_KEYPOINTS

BODY25B_DIR = REAL_TAKE / "openpose_body25b"

# A person standing, facing the camera (their right on the image's left), pixels, y down.
FIGURE = {
    "nose": (300, 100), "r_eye": (290, 92), "l_eye": (310, 92), "r_ear": (280, 98), "l_ear": (320, 98),
    "head_top": (300, 60), "upper_neck": (300, 135), "neck": (301, 152),
    "r_sho": (260, 150), "l_sho": (340, 150), "r_elb": (250, 230), "l_elb": (350, 230),
    "r_wri": (245, 300), "l_wri": (355, 300), "mid_hip": (300, 302),
    "r_hip": (275, 300), "l_hip": (325, 300), "r_kne": (272, 400), "l_kne": (328, 400),
    "r_ank": (270, 500), "l_ank": (330, 500),
    "r_bigtoe": (265, 520), "r_smalltoe": (255, 515), "r_heel": (272, 505),
    "l_bigtoe": (335, 520), "l_smalltoe": (345, 515), "l_heel": (328, 505),
    # MediaPipe's extra points
    "r_eye_in": (294, 93), "r_eye_out": (286, 93), "l_eye_in": (306, 93), "l_eye_out": (314, 93),
    "r_mouth": (294, 115), "l_mouth": (306, 115), "r_pinky": (242, 320), "l_pinky": (358, 320),
    "r_index": (246, 322), "l_index": (354, 322), "r_thumb": (250, 312), "l_thumb": (350, 312),
    "r_foot_idx": (266, 522), "l_foot_idx": (334, 522),
    "other": (1, 1),  # COCO-WholeBody's face and hand points
}
# Each concept gets its own confidence, so the mapping of confidences is checked too.
CONF = {name: 0.5 + 0.01 * i for i, name in enumerate(FIGURE)}

# The layout orders, typed from the format documentation (independently of the module's tables).
ORDERS = {
    "body25": ("nose", "neck", "r_sho", "r_elb", "r_wri", "l_sho", "l_elb", "l_wri", "mid_hip",
               "r_hip", "r_kne", "r_ank", "l_hip", "l_kne", "l_ank", "r_eye", "l_eye", "r_ear", "l_ear",
               "l_bigtoe", "l_smalltoe", "l_heel", "r_bigtoe", "r_smalltoe", "r_heel"),
    "body25b": ("nose", "l_eye", "r_eye", "l_ear", "r_ear", "l_sho", "r_sho", "l_elb", "r_elb", "l_wri",
                "r_wri", "l_hip", "r_hip", "l_kne", "r_kne", "l_ank", "r_ank", "upper_neck", "head_top",
                "l_bigtoe", "l_smalltoe", "l_heel", "r_bigtoe", "r_smalltoe", "r_heel"),
    "coco18": ("nose", "neck", "r_sho", "r_elb", "r_wri", "l_sho", "l_elb", "l_wri", "r_hip", "r_kne",
               "r_ank", "l_hip", "l_kne", "l_ank", "r_eye", "l_eye", "r_ear", "l_ear"),
    "coco17": ("nose", "l_eye", "r_eye", "l_ear", "r_ear", "l_sho", "r_sho", "l_elb", "r_elb", "l_wri",
               "r_wri", "l_hip", "r_hip", "l_kne", "r_kne", "l_ank", "r_ank"),
    "halpe26": ("nose", "l_eye", "r_eye", "l_ear", "r_ear", "l_sho", "r_sho", "l_elb", "r_elb", "l_wri",
                "r_wri", "l_hip", "r_hip", "l_kne", "r_kne", "l_ank", "r_ank", "head_top", "neck", "mid_hip",
                "l_bigtoe", "r_bigtoe", "l_smalltoe", "r_smalltoe", "l_heel", "r_heel"),
    "wholebody133": ("nose", "l_eye", "r_eye", "l_ear", "r_ear", "l_sho", "r_sho", "l_elb", "r_elb", "l_wri",
                     "r_wri", "l_hip", "r_hip", "l_kne", "r_kne", "l_ank", "r_ank", "l_bigtoe", "l_smalltoe",
                     "l_heel", "r_bigtoe", "r_smalltoe", "r_heel") + ("other",) * (68 + 21 + 21),
    "mediapipe33": ("nose", "l_eye_in", "l_eye", "l_eye_out", "r_eye_in", "r_eye", "r_eye_out", "l_ear", "r_ear",
                    "l_mouth", "r_mouth", "l_sho", "r_sho", "l_elb", "r_elb", "l_wri", "r_wri", "l_pinky",
                    "r_pinky", "l_index", "r_index", "l_thumb", "r_thumb", "l_hip", "r_hip", "l_kne", "r_kne",
                    "l_ank", "r_ank", "l_heel", "r_heel", "l_foot_idx", "r_foot_idx"),
}
# Universal index → concept (the neck is checked separately).
UNIVERSAL = ("nose", None, "r_sho", "r_elb", "r_wri", "l_sho", "l_elb", "l_wri",
             "r_hip", "r_kne", "r_ank", "l_hip", "l_kne", "l_ank")


def raw_person(layout: str, conf: dict | None = None) -> np.ndarray:
    """The figure as one ``[K, 3]`` row set in ``layout``."""
    conf = CONF if conf is None else conf
    return np.array([(*FIGURE[name], conf[name]) for name in ORDERS[layout]], dtype=float)


def openpose_json(people: list[np.ndarray]) -> str:
    return json.dumps({"version": 1.3, "people": [
        {"person_id": [-1], "pose_keypoints_2d": p.ravel().tolist(), "face_keypoints_2d": []} for p in people]})


@pytest.mark.parametrize("layout", list(ORDERS))
def test_layout_tables(layout):
    assert len(LAYOUTS[layout]) == len(ORDERS[layout])
    assert len(set(LAYOUTS[layout])) == len(LAYOUTS[layout])


@pytest.mark.parametrize("layout", list(ORDERS))
def test_mapping_index_by_index(layout):
    points, conf = to_universal(raw_person(layout)[None], layout)
    assert points.shape == (1, N_KEYPOINTS_2D, 2) and conf.shape == (1, N_KEYPOINTS_2D)
    for k, name in enumerate(UNIVERSAL):
        if name is not None:
            np.testing.assert_array_equal(points[0, k], FIGURE[name], err_msg=f"{layout} universal {k}")
            assert conf[0, k] == pytest.approx(CONF[name]), f"{layout} universal {k}"
    # Both shoulders confident: the neck is their mid-point with the smaller confidence.
    np.testing.assert_allclose(points[0, KP["neck"]], (300, 150))
    assert conf[0, KP["neck"]] == pytest.approx(min(CONF["r_sho"], CONF["l_sho"]))


@pytest.mark.parametrize("layout, neck", [("body25", FIGURE["neck"]), ("coco18", FIGURE["neck"]),
                                          ("halpe26", FIGURE["neck"]), ("body25b", None), ("coco17", None),
                                          ("wholebody133", None), ("mediapipe33", None)])
def test_neck_without_confident_shoulders(layout, neck):
    conf = dict(CONF, r_sho=0.1)
    points, c = to_universal(raw_person(layout, conf)[None], layout)
    if neck is None:  # no neck keypoint of its own (BODY_25B's upper neck is not one)
        assert c[0, KP["neck"]] == 0 and np.isnan(points[0, KP["neck"]]).all()
    else:
        np.testing.assert_array_equal(points[0, KP["neck"]], neck)
        assert c[0, KP["neck"]] == pytest.approx(CONF["neck"])
    assert c[0, KP["r_shoulder"]] == pytest.approx(0.1)


def test_missing_entries_and_confidence_range():
    raw = raw_person("coco17")
    raw[0] = (0, 0, 0)                    # OpenPose's "not found"
    raw[9] = (np.nan, 300, 0.9)           # non-finite
    raw[10, 2] = 1.7                      # some detectors score above 1
    raw[11, 2] = -0.2
    points, conf = to_universal(raw[None], "coco17")
    for k in (KP["head"], KP["l_wrist"], KP["l_hip"]):
        assert conf[0, k] == 0 and np.isnan(points[0, k]).all()
    assert conf[0, KP["r_wrist"]] == 1.0
    assert ((conf >= 0) & (conf <= 1)).all()


def test_to_universal_rejects_wrong_shape_and_layout():
    with pytest.raises(KeypointError, match="needs \\[P, 17, 3\\]"):
        to_universal(raw_person("coco18")[None], "coco17")
    with pytest.raises(KeypointError, match="unknown keypoint layout"):
        to_universal(raw_person("coco17")[None], "halpe_26")


def test_mediapipe_left_right_by_index():
    """MediaPipe's odd indices are the subject's left: 11 left shoulder, 12 right, ..., 27 left ankle."""
    raw = np.zeros((1, 33, 3))
    for index, (x, y) in {11: (340, 150), 12: (260, 150), 13: (350, 230), 14: (250, 230), 15: (355, 300),
                          16: (245, 300), 23: (325, 300), 24: (275, 300), 25: (328, 400), 26: (272, 400),
                          27: (330, 500), 28: (270, 500), 0: (300, 100)}.items():
        raw[0, index] = (x, y, 0.9)
    points = to_universal(raw, "mediapipe33")[0][0]
    assert points[KP["head"]].tolist() == [300, 100]
    for part in ("shoulder", "elbow", "wrist", "hip", "knee", "ankle"):
        assert points[KP[f"l_{part}"], 0] > 300 > points[KP[f"r_{part}"], 0], part  # facing the camera


def test_mediapipe_normalised_positions_refused():
    raw = raw_person("mediapipe33")
    raw[:, :2] /= (600, 600)
    with pytest.raises(KeypointError, match="normalised"):
        to_universal(raw[None], "mediapipe33")


def test_visible_threshold():
    conf = np.linspace(0, 1, N_KEYPOINTS_2D)
    person = Person(np.zeros((N_KEYPOINTS_2D, 2)), conf)
    np.testing.assert_array_equal(visible(person), conf >= CONFIDENCE_THRESHOLD)
    np.testing.assert_array_equal(visible(person, 0.0), conf > 0)


@pytest.mark.parametrize("layout", list(ORDERS))
def test_detect_hand_made(layout):
    assert detect_layout(raw_person(layout)[None]) == layout


def test_detect_weak_evidence_asks_for_layout():
    raw = raw_person("body25")
    raw[[0, 1, 8, 17, 18], 2] = 0  # no nose, neck, mid-hip, ears: no relation can be checked
    with pytest.raises(KeypointError, match="give --keypoints body25 or body25b"):
        detect_layout(raw[None])
    with pytest.raises(KeypointError, match="20 keypoints per person fit no known layout \\(17, 18, 25, 26, 33 or 133"):
        detect_layout(np.zeros((1, 20, 3)))


def _real_body25b(cam: int = 1) -> np.ndarray:
    """Every person of one camera's real BODY_25B files, pooled ``[P, 25, 3]``."""
    people = [p["pose_keypoints_2d"] for f in sorted((BODY25B_DIR / f"cam0{cam}_json").glob("*.json"))
              for p in json.loads(f.read_text())["people"]]
    return np.array(people).reshape(len(people), 25, 3)


def _as_body25(raw: np.ndarray) -> np.ndarray:
    """Real BODY_25B people re-ordered into BODY_25, with a mid-shoulder neck and a mid-hip, jittered."""
    pos = {name: raw[:, i] for i, name in enumerate(ORDERS["body25b"])}
    pos["neck"] = 0.5 * (pos["r_sho"] + pos["l_sho"])
    pos["mid_hip"] = 0.5 * (pos["r_hip"] + pos["l_hip"])
    out = np.stack([pos[name] for name in ORDERS["body25"]], axis=1)
    out[..., :2] += np.random.default_rng(0).normal(scale=3.0, size=out[..., :2].shape)
    return out


@pytest.mark.parametrize("cam", [1, 2, 3, 4])
def test_detect_real_body25b(cam):
    raw = _real_body25b(cam)
    assert detect_layout(raw) == "body25b"
    assert detect_layout(_as_body25(raw)) == "body25"


def test_read_real_folder():
    frames = list(read_openpose_folder(BODY25B_DIR / "cam01_json", fps=60.0))
    assert [f.index for f in frames] == list(range(100))
    assert frames[99].time_s == pytest.approx(99 / 60)
    assert max(len(f.people) for f in frames) >= 2  # the false second person is kept (not our job here)
    person = frames[0].people[0]
    assert visible(person).all()
    shoulders_y = person.points_px[[KP["r_shoulder"], KP["l_shoulder"]], 1]
    hips_y = person.points_px[[KP["r_hip"], KP["l_hip"]], 1]
    assert hips_y.min() > shoulders_y.max() + 100  # hips well below the shoulders (y down)
    assert person.points_px[KP["head"], 1] < shoulders_y.min()
    # The subject faces the camera here: their right shoulder is on the image's left.
    assert person.points_px[KP["r_shoulder"], 0] < person.points_px[KP["l_shoulder"], 0]
    shoulders = person.points_px[[KP["r_shoulder"], KP["l_shoulder"]]]
    np.testing.assert_allclose(person.points_px[KP["neck"]], shoulders.mean(axis=0))


def test_parse_openpose_json_layouts():
    text = openpose_json([raw_person("body25"), raw_person("body25")])
    frame = parse_openpose_json(text, 7)
    assert frame.index == 7 and frame.time_s is None and len(frame.people) == 2
    assert frame.people[0].person_id is None
    np.testing.assert_array_equal(frame.people[1].points_px[KP["r_knee"]], FIGURE["r_kne"])
    # A given layout always wins, even against the geometry.
    forced = parse_openpose_json(text, 7, layout="body25b")
    np.testing.assert_array_equal(forced.people[0].points_px[KP["r_shoulder"]], FIGURE["l_elb"])  # BODY_25 index 6
    assert parse_openpose_json('{"version": 1.3, "people": []}', 0).people == []


@pytest.mark.parametrize("text, reason", [
    ("{not json", "not JSON"),
    ("[1, 2]", "not a JSON object"),
    ('{"version": 1.3}', "no 'people' list"),
    ('{"people": {"a": 1}}', "no 'people' list"),
    ('{"people": [{"pose_keypoints_2d": [1, 2, 3, 4]}]}', "not a multiple of 3"),
    ('{"people": [{"pose_keypoints_2d": [' + ",".join(["1"] * 60) + "]}]}", "20 keypoints"),
    ('{"people": [{"pose_keypoints_2d": ["1", 2, 3]}]}', "non-numeric"),
    ('{"people": [{"pose_keypoints_2d": [null, 2, 3]}]}', "non-numeric"),
    ('{"people": [{"face_keypoints_2d": []}]}', "neither"),
    ('{"people": [{"person_id": "x", "pose_keypoints_2d": [' + ",".join(["1"] * 51) + "]}]}", "person id"),
])
def test_parse_openpose_json_errors(text, reason):
    with pytest.raises(KeypointError, match=reason) as err:
        parse_openpose_json(text, 0, source="cam1_000000000003_keypoints.json")
    assert str(err.value).startswith("cam1_000000000003_keypoints.json: ")


def test_parse_openpose_json_count_against_layout():
    with pytest.raises(KeypointError, match="person 0 has 17 keypoints; layout coco18 has 18"):
        parse_openpose_json(openpose_json([raw_person("coco17")]), 0, layout="coco18", source="f.json")


def test_folder_order_and_fixed_layout(tmp_path):
    ambiguous = raw_person("body25")
    ambiguous[[0, 1, 8, 17, 18], 2] = 0
    contents = {12: [raw_person("body25")], 2: [], 3: [ambiguous], 10: [raw_person("body25")] * 2}
    for number, people in contents.items():  # the frame number decides, not the name's prefix
        (tmp_path / f"{'ab'[number % 2]}_{number:012d}_keypoints.json").write_text(openpose_json(people))
    frames = list(read_openpose_folder(tmp_path, fps=10.0))
    assert [len(f.people) for f in frames] == [0, 1, 2, 1]  # frames 2, 3, 10, 12
    assert [f.time_s for f in frames] == [0.0, 0.1, 0.2, 0.3]
    # The layout found from the first frames holds for the ambiguous one.
    np.testing.assert_array_equal(frames[1].people[0].points_px[KP["l_ankle"]], FIGURE["l_ank"])


def test_empty_person_entries_are_absent_people(tmp_path):
    """Pose2Sim writes ``"pose_keypoints_2d": []`` for a person it lost: an absent person, never a
    layout conflict (it used to stop a folder: "the first frames mix people with different keypoint counts")."""
    empty = {"person_id": [-1], "pose_keypoints_2d": []}
    for t in range(3):
        obj = json.loads(openpose_json([raw_person("body25b")]))
        obj["people"].insert(t % 2, empty)
        (tmp_path / f"take_{t:012d}_keypoints.json").write_text(json.dumps(obj))
    (tmp_path / f"take_{3:012d}_keypoints.json").write_text(json.dumps({"people": [empty]}))
    frames = list(read_openpose_folder(tmp_path))
    assert [len(f.people) for f in frames] == [1, 1, 1, 0]
    np.testing.assert_array_equal(frames[1].people[0].points_px[KP["head"]], FIGURE["nose"])
    assert parse_openpose_json(json.dumps({"people": [empty]}), 0).people == []


def test_folder_natural_order_and_errors(tmp_path):
    for name in ("f10.json", "f2.json", "f1.json"):
        (tmp_path / name).write_text(openpose_json([raw_person("coco18")] * int(name[1:-5])))
    assert [len(f.people) for f in read_openpose_folder(tmp_path)] == [1, 2, 10]
    (tmp_path / "f3.json").write_text('{"people": 1}')
    with pytest.raises(KeypointError, match="f3.json: no 'people' list"):
        list(read_openpose_folder(tmp_path))
    with pytest.raises(KeypointError, match="not a folder"):
        read_openpose_folder(tmp_path / "nothing")
    (tmp_path / "empty").mkdir()
    with pytest.raises(KeypointError, match="no .json"):
        read_openpose_folder(tmp_path / "empty")


def test_frame_order_key_openpose_names_first_by_number_then_natural_order():
    names = ["f10.json", "b_000000000002_keypoints.json", "F2.json", "a_000000000010_keypoints.json",
             "f1.json", "x_7_keypoints.json", "f01.json", "n\u0663.json", "f\u00b2.json", "1\u00b23.json"]
    assert sorted(names, key=frame_order_key) == [
        "b_000000000002_keypoints.json", "x_7_keypoints.json", "a_000000000010_keypoints.json",  # frames 2, 7, 10
        "1\u00b23.json",                       # natural: a number before text; only ASCII digits are numbers
        "f01.json", "f1.json",                 # equal natural keys: the exact name decides
        "F2.json", "f10.json", "f\u00b2.json", "n\u0663.json"]
    # Deterministic whatever order the folder lists them in.
    assert sorted(names[::-1], key=frame_order_key) == sorted(names, key=frame_order_key)


def test_folder_reader_uses_frame_order_key(tmp_path):
    names = ["z_000000000001_keypoints.json", "a_000000000000_keypoints.json", "f10.json", "F2.json", "f01.json"]
    for count, name in enumerate(names):
        (tmp_path / name).write_text(openpose_json([raw_person("coco18")] * count))
    expected = [names.index(n) for n in sorted(names, key=frame_order_key)]
    assert [len(f.people) for f in read_openpose_folder(tmp_path)] == expected == [1, 0, 4, 3, 2]


def _line(**fields) -> str:
    return json.dumps(fields)


def test_stream_line_schema():
    frame = parse_stream_line(_line(frame=12, time=0.4, layout="coco17", people=[
        {"id": 3, "keypoints": raw_person("coco17").tolist()},
        {"layout": "coco18", "keypoints": raw_person("coco18").tolist()}]))
    assert (frame.index, frame.time_s) == (12, 0.4)
    assert [p.person_id for p in frame.people] == [3, None]
    for person in frame.people:
        np.testing.assert_array_equal(person.points_px[KP["l_elbow"]], FIGURE["l_elb"])
    bare = parse_stream_line(_line(frame=0, people=[{"keypoints": raw_person("body25b").tolist()}]),
                             default_layout="body25b")
    assert bare.time_s is None and bare.people[0].confidence[KP["r_ankle"]] == pytest.approx(CONF["r_ank"])
    assert parse_stream_line(_line(frame=5, people=[])).people == []


def test_stream_line_openpose_style():
    frame = parse_stream_line(openpose_json([raw_person("coco18")]))
    assert frame.index == -1 and len(frame.people) == 1  # unnumbered: the caller numbers it
    np.testing.assert_array_equal(frame.people[0].points_px[KP["r_hip"]], FIGURE["r_hip"])


@pytest.mark.parametrize("line, reason", [
    ("", "not JSON"),
    ('{"frame": 1, "people": [', "not JSON"),
    ("[" * 100000, "not JSON"),
    ("3", "not a JSON object"),
    (_line(frame=1), "no 'people' list"),
    (_line(frame=-1, people=[]), "'frame'"),
    (_line(frame="1", people=[]), "'frame'"),
    (_line(frame=True, people=[]), "'frame'"),
    (_line(frame=1.5, people=[]), "'frame'"),
    (_line(frame=1, time="now", people=[]), "'time'"),
    ('{"frame": 1, "time": NaN, "people": []}', "'time'"),
    (_line(frame=1, time=10**400, people=[]), "'time'"),
    (_line(frame=1, layout="body_25", people=[]), "unknown keypoint layout"),
    (_line(frame=1, layout=["coco17"], people=[]), "unknown keypoint layout"),
    (_line(frame=1, people=[3]), "not a JSON object"),
    (_line(frame=1, people=[{"keypoints": [[1, 2, 3], [1, 2]]}]), "keypoints"),
    (_line(frame=1, people=[{"keypoints": [[1, 2]] * 17}]), "x, y, confidence"),
    (_line(frame=1, people=[{"keypoints": [["a", 2, 3]] * 17}]), "non-numeric"),
    (_line(frame=1, people=[{"keypoints": [[1, 2, 3]] * 20}]), "20 keypoints"),
    (_line(frame=1, people=[{"keypoints": [[1, 2, 3]] * 25}]), "--keypoints"),
    (_line(frame=1, people=[{"id": [1, 2], "keypoints": [[1, 2, 3]] * 17}]), "person id"),
    (_line(frame=1, layout="coco18", people=[{"keypoints": [[1, 2, 3]] * 17}]), "layout coco18 has 18"),
])
def test_stream_line_errors(line, reason):
    with pytest.raises(KeypointError, match=reason):
        parse_stream_line(line)


def test_stream_line_numbers_are_bounded_where_parsed():
    """Every number of a line that reaches the engine is bounded (issue 20): frame numbers and ids
    below 2**53, times below 2**53 µs, finite positions within 10**6 px (NaN stays a missing point)."""
    person = raw_person("coco17")
    person[KP["head"], 0] = np.nan
    edge = parse_stream_line(_line(frame=2**53 - 1, time=1.7e9,   # a Unix time in seconds
                                   people=[{"id": 1 - 2**53, "keypoints": person.tolist()}]))
    assert (edge.index, edge.time_s, edge.people[0].person_id) == (2**53 - 1, 1.7e9, 1 - 2**53)
    assert edge.people[0].confidence[KP["head"]] == 0
    far = raw_person("coco17")
    far[3, 1] = -1.5e6   # an ear, with its confidence
    refused = [(_line(frame=10**400, people=[]), "'frame'"), (_line(frame=2**53, people=[]), "'frame'"),
               (_line(frame=1, time=-2**53, people=[]), "'time'"), (_line(frame=1, time=1e10, people=[]), "'time'"),
               (_line(people=[{"id": 10**400, "keypoints": person.tolist()}]), "person id"),
               (_line(people=[{"person_id": [2**53], "keypoints": person.tolist()}]), "person id"),
               (_line(people=[{"keypoints": far.tolist()}]), "beyond 1,000,000 px")]
    for line, reason in refused:
        with pytest.raises(KeypointError, match=reason) as err:
            parse_stream_line(line)
        assert ": " not in str(err.value) and len(str(err.value)) <= 120, str(err.value)


ODD_VALUES = (None, "x", True, -1, 2.5, 10**30, 10**400, float("nan"), [], {}, [[1, 2, 3]], {"people": []})


def _mangle(value, rng):
    """``value`` with one randomly chosen part (or itself) replaced by an odd JSON value."""
    if isinstance(value, (dict, list)) and len(value) and rng.random() < 0.7:
        keys = list(value) if isinstance(value, dict) else list(range(len(value)))
        key = keys[rng.integers(len(keys))]
        copy = dict(value) if isinstance(value, dict) else list(value)
        copy[key] = _mangle(value[key], rng)
        return copy
    return ODD_VALUES[rng.integers(len(ODD_VALUES))]


def test_stream_line_only_keypoint_errors():
    """Mangled lines either parse or raise KeypointError, never anything else."""
    obj = {"frame": 3, "time": 0.1, "layout": "coco17",
           "people": [{"id": 1, "keypoints": raw_person("coco17").round(1).tolist()}]}
    line = json.dumps(obj)
    rng = np.random.default_rng(1)
    outcomes = {"parsed": 0, "rejected": 0}
    for i in range(3000):
        if i % 2:
            mangled = json.dumps(_mangle(obj, rng))
        else:  # damaged text
            chars = list(line)
            for pos in rng.integers(0, len(chars), size=3):
                chars[pos] = rng.choice(list('{}[],:"0123456789.-eE aN'))
            mangled = "".join(chars)
        try:
            parse_stream_line(mangled)
            outcomes["parsed"] += 1
        except KeypointError:
            outcomes["rejected"] += 1
    assert min(outcomes.values()) > 100


def test_frames_from_arrays_single_person():
    seq = np.stack([raw_person("coco17") + [t, 0, 0] for t in range(3)])  # [T, K, 3]
    frames = list(frames_from_arrays(seq, fps=30.0))
    assert [f.index for f in frames] == [0, 1, 2]
    assert frames[2].time_s == pytest.approx(2 / 30)
    np.testing.assert_array_equal(frames[2].people[0].points_px[KP["r_wrist"]], np.add(FIGURE["r_wri"], (2, 0)))


def test_frames_from_arrays_people_and_padding():
    seq = np.zeros((2, 3, 18, 3))  # [T, P, K, 3]; unused slots are zero padding
    seq[0, 0] = seq[1, 0] = seq[1, 2] = raw_person("coco18")
    frames = list(frames_from_arrays(seq, layout="coco18"))
    assert [len(f.people) for f in frames] == [1, 2]
    assert frames[0].time_s is None and frames[1].people[1].person_id is None
    np.testing.assert_array_equal(frames[1].people[1].points_px[KP["head"]], FIGURE["nose"])


@pytest.mark.parametrize("array, reason", [
    (np.zeros((4, 17, 2)), "expected \\[T, K, 3\\]"),
    (np.zeros((17, 3)), "expected \\[T, K, 3\\]"),
    (np.full((4, 17, 3), "x"), "non-numeric"),
    (np.zeros((4, 20, 3)), "20 keypoints"),
    (np.full((4, 17, 3), 1e300), "beyond 1,000,000 px"),
])
def test_frames_from_arrays_errors(array, reason):
    with pytest.raises(KeypointError, match=reason):
        frames_from_arrays(array)


@pytest.mark.parametrize("layout", ["coco17", "coco18", "halpe26", "mediapipe33", "wholebody133"])
def test_frames_from_arrays_layout_by_count_and_override(layout):
    seq = np.stack([[raw_person(layout)]] * 2)  # [T, P, K, 3]
    frame = next(frames_from_arrays(seq))
    np.testing.assert_array_equal(frame.people[0].points_px[KP["l_knee"]], FIGURE["l_kne"])
    other = "coco18" if layout == "coco17" else "coco17"
    with pytest.raises(KeypointError, match=f"does not fit layout {other}"):  # the given layout wins
        frames_from_arrays(seq, layout=other)


def test_keypoint_array_files(tmp_path):
    seq = np.stack([[raw_person("coco17")]] * 4)
    np.save(tmp_path / "kp.npy", seq)
    np.savez(tmp_path / "kp.npz", keypoints=seq, scores=seq[..., 2])
    for name in ("kp.npy", "kp.npz"):
        loaded = read_keypoint_array(tmp_path / name)
        np.testing.assert_array_equal(loaded, seq)
        assert len(list(frames_from_arrays(loaded))) == 4
    np.savez(tmp_path / "other.npz", poses=seq)
    with pytest.raises(KeypointError, match="other.npz: no 'keypoints'"):
        read_keypoint_array(tmp_path / "other.npz")
    with pytest.raises(KeypointError, match="not a .npy or .npz"):
        read_keypoint_array(tmp_path / "kp.csv")


def test_refusal_messages_are_complete():
    """Reasons for refused lines survive stream reports whole: no ": " (taken as a source prefix), <= 120 characters."""
    ambiguous = raw_person("body25")
    ambiguous[[0, 1, 8, 17, 18], 2] = 0
    refused = [_line(people=[{"keypoints": [[1, 2, 3]] * 20}]),
               _line(people=[{"keypoints": ambiguous.tolist()}]),
               _line(layout="halpe_26", people=[]),
               _line(layout="x" * 500, people=[]),
               _line(people=[{"id": "y" * 500, "keypoints": [[1, 2, 3]] * 17}]),
               _line(layout="coco18", people=[{"keypoints": raw_person("halpe26").tolist()}]),
               _line(people=[{"keypoints": (raw_person("mediapipe33") / 1000).tolist()}]),
               '{"people": [', "[" * 100000, "7"]
    for line in refused:
        with pytest.raises(KeypointError) as err:
            parse_stream_line(line)
        assert ": " not in str(err.value) and len(str(err.value)) <= 120, str(err.value)


def test_stream_line_new_layouts_by_count():
    for layout in ("halpe26", "mediapipe33", "wholebody133"):
        frame = parse_stream_line(_line(people=[{"keypoints": raw_person(layout).tolist()}]))
        assert frame.layout == layout
        np.testing.assert_array_equal(frame.people[0].points_px[KP["r_ankle"]], FIGURE["r_ank"])
    with pytest.raises(KeypointError, match="person 0 has 26 keypoints; layout mediapipe33 has 33"):
        parse_stream_line(_line(people=[{"keypoints": raw_person("halpe26").tolist()}]), default_layout="mediapipe33")


def mmpose_instance(layout: str) -> dict:
    """One person as MMPose's inferencer writes it (``split_instances``)."""
    raw = raw_person(layout)
    return {"keypoints": raw[:, :2].tolist(), "keypoint_scores": raw[:, 2].tolist(),
            "bbox": [[240.0, 60.0, 360.0, 520.0]], "bbox_score": 0.97}


def _check_mmpose_frames(frames, n_frames: int, fps: float | None = None) -> None:
    assert [f.index for f in frames] == list(range(n_frames))
    if fps:
        assert frames[-1].time_s == pytest.approx((n_frames - 1) / fps)
    person = frames[-1].people[0]
    np.testing.assert_array_equal(person.points_px[KP["l_wrist"]], FIGURE["l_wri"])
    assert person.confidence[KP["r_knee"]] == pytest.approx(CONF["r_kne"])
    assert person.person_id is None


@pytest.mark.parametrize("layout", ["coco17", "halpe26", "wholebody133"])
def test_mmpose_video_forms(tmp_path, layout):
    frames = [{"frame_id": i, "instances": [mmpose_instance(layout)] * (1 + i % 2)} for i in range(3)]
    (tmp_path / "inferencer.json").write_text(json.dumps(frames, indent="  "))  # --pred-out-dir, a video
    demo = {"meta_info": {"dataset_name": "coco"},
            "instance_info": [dict(f, frame_id=f["frame_id"] + 1) for f in frames]}
    (tmp_path / "demo.json").write_text(json.dumps(demo, indent="\t"))  # topdown_demo_with_mmdet --save-predictions
    for name in ("inferencer.json", "demo.json"):
        read = read_mmpose_json(tmp_path / name, fps=25.0)
        _check_mmpose_frames(read, 3, 25.0)
        assert [len(f.people) for f in read] == [1, 2, 1] and read[0].layout == layout
        _check_mmpose_frames(list(read_keypoint_file(tmp_path / name)), 3)


def test_mmpose_per_image_forms(tmp_path):
    image = [mmpose_instance("halpe26"), mmpose_instance("halpe26")]
    (tmp_path / "img.json").write_text(json.dumps(image))
    _check_mmpose_frames(read_mmpose_json(tmp_path / "img.json"), 1)
    (tmp_path / "demo_img.json").write_text(json.dumps({"meta_info": {}, "instance_info": image}))
    _check_mmpose_frames(read_mmpose_json(tmp_path / "demo_img.json"), 1)
    # A folder of per-image files, as frames: through the folder reader and as stream messages.
    folder = tmp_path / "pred"
    folder.mkdir()
    for i in range(3):
        (folder / f"frame_{i}.json").write_text(json.dumps(image[:1 + i % 2]))
    _check_mmpose_frames(list(read_openpose_folder(folder)), 3)
    assert len(parse_stream_line(json.dumps(image)).people) == 2
    assert parse_stream_line("[]").people == []


@pytest.mark.parametrize("content, reason", [
    ({"meta_info": {}}, "not an MMPose prediction file"),
    ([{"frame_id": 0, "instances": [mmpose_instance("coco17")]}, {"frame_id": 1}], "frame 1: no 'instances' list"),
    ([{"keypoints": [[1, 2]] * 17}], "person 0 keypoints must be"),
    ([dict(mmpose_instance("coco17"), keypoint_scores=[0.9] * 16)], "keypoint_scores of shape \\(16,\\)"),
    ([{"keypoints": [[1, 2, 3]] * 17, "keypoint_scores": [0.9] * 17}], "keypoint_scores"),  # 3D
    ([{"keypoints": [[1, 2]] * 20, "keypoint_scores": [0.9] * 20}], "20 keypoints"),
    ("not json", "not JSON"),
])
def test_mmpose_errors_name_the_file(tmp_path, content, reason):
    path = tmp_path / "pred.json"
    path.write_text(content if isinstance(content, str) else json.dumps(content))
    with pytest.raises(KeypointError, match=reason) as err:
        read_keypoint_file(path)
    assert str(err.value).startswith(f"{path}: ")


def test_mmpose_video_file_as_stream_message():
    video = json.dumps([{"frame_id": 0, "instances": [mmpose_instance("coco17")]}])
    with pytest.raises(KeypointError, match="MMPose video file"):
        parse_stream_line(video)


def test_rtmlib_separate_arrays(tmp_path):
    seq = np.zeros((3, 2, 26, 3))  # RTMLib's Body/Wholebody per frame: keypoints [P, K, 2], scores [P, K]
    seq[:, 0] = raw_person("halpe26")
    seq[1, 1] = raw_person("halpe26")
    np.savez(tmp_path / "rtmlib.npz", keypoints=seq[..., :2], scores=seq[..., 2])
    np.testing.assert_array_equal(read_keypoint_array(tmp_path / "rtmlib.npz"), seq)
    frames = list(read_keypoint_file(tmp_path / "rtmlib.npz", fps=30.0))
    assert [len(f.people) for f in frames] == [1, 2, 1] and frames[2].time_s == pytest.approx(2 / 30)
    np.testing.assert_array_equal(frames[1].people[1].points_px[KP["neck"]], (300, 150))
    np.savez_compressed(tmp_path / "compressed.npz", keypoints=seq[..., :2].astype(np.float32), scores=seq[..., 2])
    assert len(list(read_keypoint_file(tmp_path / "compressed.npz", layout="halpe26"))) == 3
    with pytest.raises(KeypointError, match="does not fit layout coco17"):  # a given layout wins
        read_keypoint_file(tmp_path / "rtmlib.npz", layout="coco17")


def _npy_bytes(array: np.ndarray, **save) -> bytes:
    buffer = io.BytesIO()
    np.save(buffer, array, **save)
    return buffer.getvalue()


def _npz_bytes(**arrays: bytes) -> bytes:
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as zf:
        for name, data in arrays.items():
            zf.writestr(f"{name}.npy", data)
    return buffer.getvalue()


def _npy_claiming(shape: tuple, data: bytes) -> bytes:
    """A .npy header claiming ``shape`` of float64, followed by ``data``."""
    buffer = io.BytesIO()
    np.lib.format.write_array_header_1_0(buffer, {"descr": "<f8", "fortran_order": False, "shape": shape})
    return buffer.getvalue() + data


GOOD = np.stack([[raw_person("coco17")]] * 4)
GOOD_NPY = _npy_bytes(GOOD)
ABSURD_NPY = _npy_claiming((5_000_000_000_000,), GOOD.tobytes())
NAN, INF = GOOD.copy(), GOOD.copy()
NAN[2, 0, 5, 1] = np.nan
INF[3, 0, 0, 2] = np.inf


@pytest.mark.parametrize("name, data, reason", [
    ("truncated.npz", _npz_bytes(keypoints=GOOD_NPY)[:900], "not a readable .npz \\(zip\\) file"),
    ("not_zip.npz", b"keypoints, scores\n1, 2\n", "not a readable .npz \\(zip\\) file"),
    ("npy_named.npz", GOOD_NPY, "not a readable .npz \\(zip\\) file"),
    ("text.npy", b"not numpy", "not a .npy array \\(missing or damaged header\\)"),
    ("header.npy", GOOD_NPY.replace(b"'shape': (4, 1, 17, 3)", b"'shape': (4, 1, 17, x)"), "damaged header"),
    ("header_cut.npy", GOOD_NPY[:30], "damaged header"),
    ("absurd.npy", ABSURD_NPY, "header says shape \\(5000000000000,\\) of float64 \\(40000000000000 bytes\\) but "
                               "1632 bytes follow it"),
    ("absurd.npz", _npz_bytes(keypoints=ABSURD_NPY), "array 'keypoints'.*5000000000000"),
    ("truncated.npy", GOOD_NPY[:-8], "but 1624 bytes follow it"),
    ("negative.npy", _npy_claiming((-4, 1, 17, 3), GOOD.tobytes()), "negative size"),
    ("object.npy", _npy_bytes(np.array([{"x": 1}, None], dtype=object), allow_pickle=True), "holds object values"),
    ("object.npz", _npz_bytes(keypoints=_npy_bytes(np.array([[1.0], None], dtype=object), allow_pickle=True)),
     "array 'keypoints'.*holds object values"),
    ("strings.npy", _npy_bytes(np.full((4, 17, 3), "x")), "holds <U1 values, not numbers"),
    ("shape.npy", _npy_bytes(np.zeros((4, 17, 5))), "keypoints of shape \\(4, 17, 5\\), expected"),
    ("flat.npy", _npy_bytes(np.zeros(51)), "keypoints of shape \\(51,\\), expected"),
    ("positions.npy", _npy_bytes(np.zeros((4, 17, 2))), "positions \\[..., 2\\] with scores"),
    ("scores.npz", _npz_bytes(keypoints=_npy_bytes(np.zeros((4, 17, 2))), scores=_npy_bytes(np.zeros((4, 16)))),
     "scores of shape \\(4, 16\\) do not fit positions of shape \\(4, 17, 2\\)"),
    ("empty.npy", _npy_bytes(np.zeros((0, 17, 3))), "hold no values"),
    ("nan.npy", _npy_bytes(NAN), "1 non-finite values \\(NaN or infinite\\), the first at index \\(2, 0, 5, 1\\)"),
    ("inf.npz", _npz_bytes(keypoints=_npy_bytes(INF)), "the first at index \\(3, 0, 0, 2\\)"),
    ("no_keypoints.npz", _npz_bytes(poses=GOOD_NPY), "no 'keypoints' array"),
    ("text.csv", b"1,2,3", "not a .npy or .npz keypoint file"),
])
def test_corrupt_arrays_fail_clearly(tmp_path, name, data, reason):
    path = tmp_path / name
    path.write_bytes(data)
    tracemalloc.start()
    try:
        with pytest.raises(KeypointError, match=reason) as err:
            read_keypoint_array(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert str(err.value).startswith(f"{path}: ")
    assert peak < 2_000_000  # nothing the size of a header's claim is allocated


def test_damaged_array_files_only_raise_keypoint_errors(tmp_path):
    """Truncated or byte-flipped .npy/.npz files either read or raise KeypointError, nothing else."""
    rng = np.random.default_rng(2)
    seq = rng.random((3, 2, 17, 3)) * 100
    originals = {"a.npy": _npy_bytes(seq), "a.npz": _npz_bytes(keypoints=_npy_bytes(seq[..., :2]),
                                                                scores=_npy_bytes(seq[..., 2]))}
    np.savez_compressed(tmp_path / "c.npz", keypoints=seq)
    originals["c.npz"] = (tmp_path / "c.npz").read_bytes()
    rejected = 0
    for name, data in originals.items():
        for _ in range(300):
            damaged = bytearray(data[:rng.integers(1, len(data))] if rng.random() < 0.3 else data)
            for pos in rng.integers(0, len(damaged), size=rng.integers(1, 4)):
                damaged[pos] = rng.integers(256)
            (tmp_path / name).write_bytes(bytes(damaged))
            try:
                read_keypoint_array(tmp_path / name)
            except KeypointError:
                rejected += 1
    assert rejected > 300


def _halpe_from_body25b(raw: np.ndarray) -> np.ndarray:
    """Real BODY_25B people ``[P, 25, 3]`` re-written as HALPE_26 (head = head top, neck and hip the mid-points)."""
    pos = {name: raw[:, i] for i, name in enumerate(ORDERS["body25b"])}
    pos["neck"] = 0.5 * (pos["r_sho"] + pos["l_sho"])
    pos["mid_hip"] = 0.5 * (pos["r_hip"] + pos["l_hip"])
    return np.stack([pos[name] for name in ORDERS["halpe26"]], axis=1)


def test_halpe26_openpose_folder_end_to_end(small_db_path, tmp_path, capsys):
    """Pose2Sim's default: OpenPose-style JSON with 26 HALPE points, read by count, reconstructed."""
    folder = tmp_path / "halpe"
    folder.mkdir()
    for path in sorted(SAMPLE_KEYPOINTS.glob("*.json"))[:40]:
        people = [np.reshape(p["pose_keypoints_2d"], (25, 3)) for p in json.loads(path.read_text())["people"]]
        halpe = [_halpe_from_body25b(p[None])[0] for p in people]
        (folder / path.name).write_text(openpose_json(halpe))
    frames = list(read_openpose_folder(folder, fps=60.0))
    body25b = list(read_openpose_folder(SAMPLE_KEYPOINTS, fps=60.0))[:40]
    assert len(frames) == 40 and frames[0].layout == "halpe26"
    for got, want in zip(frames, body25b):
        assert len(got.people) == len(want.people)
        for a, b in zip(got.people, want.people):
            both = (b.confidence > 0) & (np.arange(N_KEYPOINTS_2D) != KP["neck"])
            np.testing.assert_array_equal(a.points_px[both], b.points_px[both])
    args = ["reconstruct", str(folder), "--db", str(small_db_path), "--out", str(tmp_path / "out"),
            "--fps", "60", "--image-size", "1088x1920", "--focal", "1681"]
    assert main(args) == 0
    assert "frames 40" in capsys.readouterr().out
    lines = (tmp_path / "out" / "result.jsonl").read_text().splitlines()
    assert len(lines) == 41 and any(json.loads(line).get("people") for line in lines[1:])


def test_cli_reads_keypoint_files_before_writing(small_db_path, tmp_path, capsys):
    (tmp_path / "bad.npz").write_bytes(b"PK\x03\x04 truncated")
    out = tmp_path / "out"
    assert main(["reconstruct", str(tmp_path / "bad.npz"), "--db", str(small_db_path), "--out", str(out)]) == 2
    assert f"{tmp_path / 'bad.npz'}: not a readable .npz" in capsys.readouterr().err
    assert not out.exists()
    seq = np.stack([[raw_person("mediapipe33")]] * 5)
    np.save(tmp_path / "mp.npy", seq)
    assert main(["reconstruct", str(tmp_path / "mp.npy"), "--db", str(small_db_path), "--out", str(out),
                 "--fps", "30"]) == 0
    assert "frames 5" in capsys.readouterr().out
    assert main(["reconstruct", str(tmp_path / "mp.npy"), "--db", str(small_db_path), "--out", str(out),
                 "--keypoints", "halpe26"]) == 2
    assert "does not fit layout halpe26" in capsys.readouterr().err


def _npy_bytes_header(shape: tuple[int, ...]) -> bytes:
    buffer = io.BytesIO()
    np.lib.format.write_array_header_1_0(buffer, {"descr": "<f8", "fortran_order": False, "shape": shape})
    return buffer.getvalue()


def _zip_bomb(path, n_frames: int) -> None:
    """An .npz whose ``keypoints`` member is ``n_frames`` × 25 × 3 zeros, deflated (about 1000:1)."""
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as zf, zf.open("keypoints.npy", "w", force_zip64=True) as f:
        f.write(_npy_bytes_header((n_frames, 25, 3)))
        zeros = bytes(25 * 3 * 8 * 1000)
        for _ in range(n_frames // 1000):
            f.write(zeros)


def test_an_npz_bomb_is_refused_before_it_is_inflated(tmp_path, monkeypatch):
    from mocapdb.core.formats import keypoint_arrays

    _zip_bomb(tmp_path / "bomb.npz", 20_000)  # 12 MB of zeros in ~12 kB
    assert (tmp_path / "bomb.npz").stat().st_size < 100_000
    monkeypatch.setattr(keypoint_arrays, "MAX_ARRAY_BYTES", 4_000_000)
    tracemalloc.start()
    with pytest.raises(KeypointError, match=r"bomb.npz: array 'keypoints': 12,000,128 bytes uncompressed, more than"):
        read_keypoint_array(tmp_path / "bomb.npz")
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert peak < 1_000_000, peak


def test_an_npz_member_claiming_terabytes_is_refused(tmp_path):
    """The zip's index claims 4 GiB for a small member: refused by its claim, nothing allocated."""
    np.savez(tmp_path / "liar.npz", keypoints=np.zeros((2, 17, 3)))
    data = bytearray((tmp_path / "liar.npz").read_bytes())
    central = data.index(b"PK\x01\x02")
    data[central + 24:central + 28] = (0xFFFFFFFE).to_bytes(4, "little")  # uncompressed size
    (tmp_path / "liar.npz").write_bytes(bytes(data))
    with pytest.raises(KeypointError, match=r"liar.npz: array 'keypoints': 4,294,967,294 bytes uncompressed"):
        read_keypoint_array(tmp_path / "liar.npz")


@pytest.mark.parametrize("name", ["kp.npy", "kp.npz", "predictions.json"])
def test_keypoint_files_must_be_regular(tmp_path, name):
    """A FIFO would block the reader: it is refused before it is opened for a read."""
    import os

    os.mkfifo(tmp_path / name)
    with pytest.raises(KeypointError, match=f"{name}: a FIFO"):
        read_keypoint_file(tmp_path / name)


def test_world_landmarks_round_trip_and_people_without_them(tmp_path):
    """BlazePose's world landmarks as `detect` writes them (`pose_world_landmarks_3d`) read back on the
    universal 14; a person without them, and every other layout, has none; bad ones are refused."""
    from mocapdb.detect.openpose_out import openpose_json as detect_json

    people = np.stack([raw_person("mediapipe33")] * 2)
    world = np.random.default_rng(3).uniform(-0.8, 0.8, (2, 33, 3))
    body = json.loads(detect_json(people, "mediapipe33", world))
    assert len(body["people"][0]["pose_world_landmarks_3d"]) == 99
    del body["people"][1]["pose_world_landmarks_3d"]
    (tmp_path / "v_000000000000_keypoints.json").write_text(json.dumps(body))
    (frame,) = read_openpose_folder(tmp_path)
    got, index = frame.people[0].world_m, ORDERS["mediapipe33"].index
    for k, concept in enumerate(UNIVERSAL):
        if concept is not None:
            np.testing.assert_allclose(got[k], world[0, index(concept)], atol=5e-5)   # written to 0.1 mm
    np.testing.assert_allclose(got[KP["neck"]], (got[KP["r_shoulder"]] + got[KP["l_shoulder"]]) / 2)
    assert frame.people[1].world_m is None
    assert parse_openpose_json(openpose_json([raw_person("coco17")]), 0).people[0].world_m is None
    nested = {"keypoints": people[0].tolist(), "pose_world_landmarks_3d": world[0].tolist()}
    np.testing.assert_allclose(parse_stream_line(json.dumps({"people": [nested]})).people[0].world_m, got, atol=5e-5)
    empty = {"keypoints": people[0].tolist(), "pose_world_landmarks_3d": []}   # Pose2Sim's empty fields: none
    assert parse_stream_line(json.dumps({"people": [empty]})).people[0].world_m is None
    for bad, reason in ((world[0, :5].tolist(), "holds 15 values; 33 keypoints need 99"),
                        ((world[0] * 1000).tolist(), "beyond 100 m"), ("x", "non-numeric")):
        line = json.dumps({"people": [{"keypoints": people[0].tolist(), "pose_world_landmarks_3d": bad}]})
        with pytest.raises(KeypointError, match=reason) as err:
            parse_stream_line(line)
        assert ": " not in str(err.value) and len(str(err.value)) <= 120
