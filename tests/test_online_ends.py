"""The online take's feet, hands and head (runtime/online_ends.py): turned to directions and a head rotation
drawn into the image by hand, at lag 0 and 3; a hand never seen at rest and flagged; a hand lost held,
then eased to rest with no step larger than the ease allows; the stream's record carries them."""
import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mocapdb.core.formats.keypoint_layouts import EXTREMITIES
from mocapdb.core.outputs import CAMERA_FROM_VIEW, Match, PersonPose, frame_line, header_line
from mocapdb.core.skeleton import (
    FACE_MODEL_M,
    HAND_LENGTH_M,
    KP,
    N_RIG_JOINTS,
    pose_from_rotations,
    universal_bone_lengths_m,
)
from mocapdb.render.results import RenderError, read_result
from mocapdb.runtime.end_joints import KNUCKLE_SLANT, KNUCKLES_APART_M
from mocapdb.runtime.head_pose import head_local
from mocapdb.runtime.online_ends import EASE_S, HOLD_S
from mocapdb.runtime.online_take import OnlineParams, OnlineTake

FPS = 30.0
CAMERA = (1000.0, 540.0, 960.0)   # focal, cx, cy (px)
ROOT_VIEW = np.array([0.0, 0.0, -4.0])
SLOPE = np.radians(12.0)          # a standing foot's heel → toe slope (a planted foot is laid at it)
# the true directions (view frame: x right, y up, z towards the camera), written out here
FEET = np.array([[np.cos(SLOPE) * np.sin(h), -np.sin(SLOPE), np.cos(SLOPE) * np.cos(h)]
                 for h in np.radians([-25.0, 20.0])])
# (the right hand away from the camera along its ray, the side its outward rest direction lifts it to)
HANDS = np.array([[-0.8, -0.5, -0.3], [0.7, 0.6, 0.2]]) / np.linalg.norm([[-0.8, -0.5, -0.3], [0.7, 0.6, 0.2]],
                                                                          axis=1, keepdims=True)
HEAD = Rotation.from_euler("YXZ", [30.0, 10.0, -5.0], degrees=True)
# the head as the humanoid Head carries it on an unturned neck (head_pose decides which of its components)
HEAD_AS_CARRIED = Rotation.from_quat(head_local(np.tile([1.0, 0.0, 0.0, 0.0], (1, N_RIG_JOINTS, 1)),
                                                HEAD.as_quat()[None, [3, 0, 1, 2]])[0, [1, 2, 3, 0]])
# each end's rest direction in its (here unturned) parent's frame: feet forwards sloping down, hands outwards
REST = np.array([[0.0, -np.sin(SLOPE), np.cos(SLOPE)]] * 2 + [[-1.0, 0.0, 0.0], [1.0, 0.0, 0.0]])


def _pixels(points_view: np.ndarray) -> np.ndarray:
    focal, cx, cy = CAMERA
    return np.column_stack([cx + focal * points_view[:, 0] / -points_view[:, 2],
                            cy - focal * points_view[:, 1] / -points_view[:, 2]])


def _segment(start_view: np.ndarray, vector_m: np.ndarray) -> np.ndarray:
    """``[2, 2]`` pixels of a segment from ``start_view`` along ``vector_m`` (view frame), projected exactly."""
    return _pixels(np.array([start_view, start_view + vector_m]))


def _hand_turns(twists_deg: tuple[float, float]) -> list[Rotation]:
    """Each hand's global rotation pointing it along :data:`HANDS` and twisted about that by ``twists_deg`` from
    the shortest turn from rest (the rig's hand basis: along ∓x, the thumb side +z)."""
    return [Rotation.from_rotvec(np.radians(twist) * HANDS[k]) * Rotation.align_vectors([HANDS[k]], [REST[2 + k]])[0]
            for k, twist in enumerate(twists_deg)]


def _pose(seen: dict[str, bool], twists_deg: tuple[float, float] | None = None) -> PersonPose:
    """A person at rest 4 m from the camera whose heels, toes, knuckles and face show :data:`FEET`,
    :data:`HANDS` and :data:`HEAD` (``seen``: which of "feet", "r_hand", "l_hand", "face" are); the index and
    little-finger knuckles on one spot, or, with ``twists_deg``, apart on the hands twisted so
    (:func:`_hand_turns`; their line slanted as the rig's)."""
    quats = np.tile([1.0, 0.0, 0.0, 0.0], (N_RIG_JOINTS, 1))
    joints = pose_from_rotations(quats[None], ROOT_VIEW[None])[0]
    keypoints = np.column_stack([_pixels(joints[:14]), np.full(14, 0.9)])
    points = np.zeros((len(EXTREMITIES), 3))
    for k, side in enumerate("rl"):
        ankle, wrist = joints[KP[f"{side}_ankle"]], joints[KP[f"{side}_wrist"]]
        points[2 * k:2 * k + 2] = np.column_stack([_segment(ankle, 0.21 * FEET[k]), np.full(2, 0.9 * seen["feet"])])
        knuckles = np.repeat(_segment(wrist, 0.08 * HANDS[k])[1:], 2, axis=0)
        if twists_deg is not None:
            thumb_side = _hand_turns(twists_deg)[k].apply([0.0, 0.0, 1.0])
            half = 0.5 * KNUCKLES_APART_M * (KNUCKLE_SLANT * HANDS[k] + thumb_side)
            knuckles = _pixels(wrist + HAND_LENGTH_M * HANDS[k] + np.array([half, -half]))
        points[4 + 2 * k:6 + 2 * k] = np.column_stack([knuckles, np.full(2, 0.9 * seen[f"{side}_hand"])])
    centre = joints[KP["head"]] - HEAD.apply(FACE_MODEL_M[0])
    face = _pixels(centre + HEAD.apply(FACE_MODEL_M))
    keypoints[0, :2] = face[0]
    points[8:] = np.column_stack([face[1:], np.full(6, 0.9 * seen["face"])])
    return PersonPose(0, joints * CAMERA_FROM_VIEW, quats, ROOT_VIEW * CAMERA_FROM_VIEW, Match("c", 0, 0.0, 0.1),
                      1.75, universal_bone_lengths_m(), keypoints_px=keypoints, extremities_px=points)


def _run(lag: int, seen_at, twists_at=lambda t: None) -> list[PersonPose]:
    """The online take's people over 90 frames; ``seen_at(t)``: what is seen in frame ``t``; ``twists_at(t)``: its
    hands' twists (:func:`_pose`)."""
    take = OnlineTake(FPS, OnlineParams(lag_frames=lag), CAMERA)
    out = []
    for t in range(90):
        out += take.push(t, t / FPS, [_pose(seen_at(t), twists_at(t))])
    return [frame[2][0] for frame in out + take.flush()]


def _angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.degrees(2 * np.arccos(np.clip(np.abs(np.sum(a * b, axis=-1)), 0.0, 1.0)))


ALL = {"feet": True, "r_hand": True, "l_hand": True, "face": True}


@pytest.mark.parametrize("lag", [0, 3])
def test_feet_hands_and_head_turn_to_what_the_image_shows(lag):
    people = _run(lag, lambda t: ALL)
    assert all(p.end_seen == (True,) * 5 for p in people)
    for pose in people[int(EASE_S * FPS) + 3:]:
        ends = Rotation.from_quat(pose.end_quaternions[:, [1, 2, 3, 0]])   # the parents are unturned
        directions = ends[:4].apply(REST)
        errors = np.degrees(np.arccos(np.clip(np.sum(directions * np.vstack([FEET, HANDS]), axis=1), -1, 1)))
        assert errors.max() < 0.5, errors
        assert np.degrees((ends[4].inv() * HEAD_AS_CARRIED).magnitude()) < 3.0


def test_a_hand_twists_with_steady_knuckles_and_not_with_scattered_ones():
    """At lag 0 without the hand model, the pose's knuckles twist each hand about its direction (here 40° and
    −30° from the shortest turn) once their twist has been steady for the window; knuckles whose line swings
    ±30° from frame to frame (a scatter far beyond 16°) leave the hands at their shortest turn."""
    steady = _run(0, lambda t: ALL, lambda t: (40.0, -30.0))
    swinging = _run(0, lambda t: ALL, lambda t: (30.0 * (-1) ** t, 30.0 * (-1) ** t))
    twisted_, shortest = _hand_turns((40.0, -30.0)), _hand_turns((0.0, 0.0))
    for k in range(2):
        scipy = [np.array([r.as_quat()[[3, 0, 1, 2]]]) for r in (twisted_[k], shortest[k])]
        late = [np.array([p.end_quaternions[2 + k] for p in run[60:]]) for run in (steady, swinging)]
        # within 3.5°: the hand's direction is lifted from the knuckles' mid-point in the image, not the image of
        # their mid-point (1.6° off on the left hand here), and the slanted line's twist follows it
        assert _angle_deg(late[0], scipy[0]).max() < 3.5
        assert _angle_deg(late[1], scipy[1]).max() < 3.5


def test_a_hand_never_seen_rests_and_one_lost_is_held_then_eased_to_rest():
    lost_at = 30
    people = _run(0, lambda t: {**ALL, "l_hand": False, "r_hand": t < lost_at})
    ends = np.array([p.end_quaternions for p in people])
    assert np.array_equal(ends[:, 3], np.tile([1.0, 0.0, 0.0, 0.0], (90, 1)))     # the left hand: rest
    assert all(p.end_seen[3] is False for p in people)
    assert [p.end_seen[2] for p in people] == [t < lost_at for t in range(90)]
    right = ends[:, 2]
    hold = lost_at + int(HOLD_S * FPS)
    assert _angle_deg(right[lost_at:hold], right[lost_at - 1]).max() < 0.5        # held …
    assert _angle_deg(right[hold + int(EASE_S * FPS) + 1:], [1.0, 0.0, 0.0, 0.0]).max() < 1e-6   # … then at rest
    turn = _angle_deg(right[lost_at - 1], [1.0, 0.0, 0.0, 0.0])
    steps = _angle_deg(right[1:], right[:-1])
    assert steps.max() <= 1.5 * turn / (EASE_S * FPS) + 0.5, steps.max()          # smoothstep's steepest, no pop


def test_the_stream_carries_the_end_rotations_and_what_was_seen_and_reads_them_back(tmp_path):
    pose = _run(0, lambda t: {**ALL, "face": False})[-1]
    header, line = header_line(FPS, lag_frames=0), frame_line(89, 89 / FPS, [pose])
    assert json.loads(header)["end_joints"] == ["r_foot", "l_foot", "r_hand", "l_hand", "head"]
    person = json.loads(line)["people"][0]
    assert person["end_seen"] == [True, True, True, True, False]
    np.testing.assert_allclose(person["end_quaternions"], pose.end_quaternions, atol=1e-5)
    assert person["end_quaternions"][4] == [1.0, 0.0, 0.0, 0.0]
    (tmp_path / "result.jsonl").write_text(f"{header}\n{line}\n")
    np.testing.assert_allclose(read_result(tmp_path).frames[0].people[0].end_quaternions, pose.end_quaternions,
                               atol=1e-5)
    bad = json.loads(line)
    bad["people"][0]["end_quaternions"] = [[1.0, 0.0, 0.0]] * 5
    (tmp_path / "result.jsonl").write_text(f"{header}\n{json.dumps(bad)}\n")
    with pytest.raises(RenderError, match="line 2: person 0 has end_quaternions"):
        read_result(tmp_path)
