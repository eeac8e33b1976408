"""The online take's fingers (runtime/online_fingers.py): a hand drawn point by point gives, at lag 3, the whole
take's finger rotations (runtime/hand_pose.finger_rotations) and its index finger's 90° bend; a hand lost is
held, then eased to the relaxed rest with no step larger than the ease allows; the stream carries them."""
import json
from dataclasses import replace

import numpy as np
import pytest

from mocapdb.core.hand_rig import FINGER_JOINTS, RELAXED_DEG
from mocapdb.core.outputs import frame_line, header_line
from mocapdb.render.results import RenderError, read_result
from mocapdb.runtime.hand_pose import EASE_S, finger_quaternions, finger_rotations, hand_points_view, palm_frames
from mocapdb.runtime.online_fingers import HOLD_S
from mocapdb.runtime.online_take import OnlineParams, OnlineTake
from mocapdb.runtime.take_params import TakeParams
from tests.test_online_ends import ALL, CAMERA, FPS, _angle_deg, _pose

FRAMES = 90
# A right hand (view frame, x right, y up, z towards the camera; units of 10 px from the wrist): the palm up
# the image, the index finger bent 90° at its middle joint towards the palm (+z), the others straight
RIGHT_VIEW = 10.0 * np.array([
    [0, 0, 0], [2, 2, 1], [4, 4, 1.5], [5.5, 5.5, 1.5], [6.5, 6.5, 1.5],      # wrist, thumb
    [2, 9, 0], [2, 13, 0], [2, 13, 3], [2, 13, 5],                            # index, bent at the PIP
    [0.5, 9.2, 0], [0.5, 13, 0], [0.5, 16, 0], [0.5, 18, 0],                  # middle
    [-1, 9, 0], [-1, 12.5, 0], [-1, 15, 0], [-1, 17, 0],                      # ring
    [-2.5, 8.5, 0], [-2.5, 11, 0], [-2.5, 13, 0], [-2.5, 14.5, 0]])           # pinky
WRIST_PX = np.array([300.0, 500.0, 0.0])
# image px (x right, y down, z: smaller nearer); the left hand the right one mirrored
HANDS_PX = np.stack([WRIST_PX + RIGHT_VIEW * [1, -1, -1], WRIST_PX + RIGHT_VIEW * [-1, -1, -1]])
INDEX2 = FINGER_JOINTS.index("RightHandIndex2")
REST = finger_quaternions(RELAXED_DEG[None, None].repeat(2, axis=1))[0]


def _run(lag: int, hands_at) -> list:
    """The online take's person over :data:`FRAMES` frames; ``hands_at(t)``: its hands [2, 21, 3] in frame t."""
    take = OnlineTake(FPS, OnlineParams(lag_frames=lag), CAMERA)
    out = []
    for t in range(FRAMES):
        out += take.push(t, t / FPS, [_with_hands(hands_at(t))])
    return [frame[2][0] for frame in out + take.flush()]


def _with_hands(hands_px):
    return replace(_pose(ALL), hands_px=hands_px)


def test_a_drawn_hand_turns_the_fingers_as_the_whole_take_does():
    people = _run(3, lambda t: HANDS_PX)
    fingers = np.array([p.finger_quaternions for p in people])
    points = hand_points_view(np.repeat(HANDS_PX[None], FRAMES, axis=0))
    whole = finger_rotations(points, palm_frames(points), FPS, TakeParams())
    settled = slice(int(EASE_S * FPS) + 1, None)
    assert _angle_deg(fingers[settled], whole[settled]).max() < 1e-3
    assert abs(_angle_deg(fingers[-1, INDEX2], [1.0, 0.0, 0.0, 0.0]) - 90.0) < 1.0     # the bend drawn
    assert all(p.fingers_seen == (True, True) for p in people)


@pytest.mark.parametrize("lag", [0, 3])
def test_a_hand_lost_is_held_then_eased_to_rest_without_a_jump(lag):
    lost_at = 30
    absent = np.full((21, 3), np.nan)
    people = _run(lag, lambda t: np.stack([HANDS_PX[0] if t < lost_at else absent, absent]))
    fingers = np.array([p.finger_quaternions for p in people])
    assert [p.fingers_seen for p in people] == [(t < lost_at, False) for t in range(FRAMES)]
    assert _angle_deg(fingers[:, 15:], REST[15:]).max() < 1e-4                      # never seen: rest
    hold = lost_at + int(HOLD_S * FPS)
    assert _angle_deg(fingers[lost_at:hold, :15], fingers[lost_at - 1, :15]).max() < 0.5     # held …
    assert _angle_deg(fingers[hold + int(EASE_S * FPS) + 1:, :15], REST[:15]).max() < 1e-4  # … then at rest
    turn = _angle_deg(fingers[lost_at - 1, :15], REST[:15])
    steps = _angle_deg(fingers[lost_at:, :15], fingers[lost_at - 1:-1, :15])
    assert (steps <= 1.5 * turn / (EASE_S * FPS) + 0.5).all(), steps.max()


def test_the_stream_carries_the_fingers_only_with_hands_and_reads_them_back(tmp_path):
    pose = _run(0, lambda t: HANDS_PX)[-1]
    header, line = header_line(FPS, lag_frames=0), frame_line(89, 89 / FPS, [pose])
    person = json.loads(line)["people"][0]
    assert person["fingers_seen"] == [True, True]
    np.testing.assert_allclose(person["finger_quaternions"], pose.finger_quaternions.reshape(2, 15, 4), atol=1e-5)
    (tmp_path / "result.jsonl").write_text(f"{header}\n{line}\n")
    np.testing.assert_allclose(read_result(tmp_path).frames[0].people[0].finger_quaternions,
                               pose.finger_quaternions, atol=1e-5)
    bad = json.loads(line)
    bad["people"][0]["finger_quaternions"] = [[[1.0, 0.0, 0.0, 0.0]] * 14] * 2
    (tmp_path / "result.jsonl").write_text(f"{header}\n{json.dumps(bad)}\n")
    with pytest.raises(RenderError, match="line 2: person 0 has finger_quaternions"):
        read_result(tmp_path)
    no_hands = _run(0, lambda t: np.full((2, 21, 3), np.nan))[-1]     # the input's hands, none ever seen
    without = json.loads(frame_line(89, 89 / FPS, [no_hands]))["people"][0]
    assert "finger_quaternions" not in without and "fingers_seen" not in without
