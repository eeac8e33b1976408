"""The VMC sink turns the fingers as the stream does (issue 49): the online take's person with hands drawn
point by point (tests/test_online_fingers.py) sent to a VMC sink on loopback and decoded by python-osc. A
receiver's forward kinematics puts every fingertip within 1 cm of where the stream's numbers put it (computed
here with SciPy from the pose's joints, rotations and finger rotations and the rig's finger offsets); a stream
without hands sends no finger bone."""
import numpy as np
from scipy.spatial.transform import Rotation

from mocapdb.core.hand_rig import FINGER_NAMES, SIDE_NAMES, finger_nodes
from mocapdb.core.skeleton import KP, RIG_JOINTS, UNIVERSAL_HEIGHT_M
from mocapdb.runtime.stream.osc_sinks import VmcSink
from tests.test_avatar_ends import MIRROR
from tests.test_online_ends import ALL
from tests.test_online_ends import _run as run_without_hands
from tests.test_online_fingers import HANDS_PX
from tests.test_online_fingers import _run as run_with_hands
from tests.test_osc_sinks import Receiver, _vmc_frames, bone_transforms

UNITY_FINGERS = ("Thumb", "Index", "Middle", "Ring", "Little")
PHALANGES = ("Proximal", "Intermediate", "Distal")
ARM = {"Right": ("pelvis", "spine", "r_shoulder", "r_elbow"), "Left": ("pelvis", "spine", "l_shoulder", "l_elbow")}


def _sent(people) -> list:
    receiver = Receiver()
    with VmcSink("127.0.0.1", receiver.port) as sink:
        for i, pose in enumerate(people):
            sink.write_frame(i, i / 30, [pose])
    return _vmc_frames(receiver.take())


def _quat(wxyz) -> Rotation:
    return Rotation.from_quat(np.asarray(wxyz)[[1, 2, 3, 0]])


def _expected_tips(pose) -> dict[str, np.ndarray]:
    """Per Unity distal bone, its fingertip less the pelvis (Unity frame, metres) from the pose's own numbers."""
    joints_view = pose.joints_m * [1.0, 1.0, -1.0]
    local = {j: _quat(q) for j, q in zip(RIG_JOINTS, pose.quaternions)}
    assert np.allclose(pose.up_view, [0.0, 1.0, 0.0])                 # upright: no levelling
    scale = pose.height_m / UNIVERSAL_HEIGHT_M
    tips = {}
    for h, side in enumerate(SIDE_NAMES):
        hand = Rotation.identity()
        for joint in ARM[side]:
            hand = hand * local[joint]
        hand = hand * _quat(pose.end_quaternions[2 + h])
        offsets = {name: np.array(offset) * scale for name, _, offset, _ in finger_nodes(side)}
        for f, finger in enumerate(FINGER_NAMES):
            at, rot = joints_view[KP["r_wrist" if side == "Right" else "l_wrist"]], hand
            for k in range(3):
                at = at + rot.apply(offsets[f"{side}Hand{finger}{k + 1}"])
                rot = rot * _quat(pose.finger_quaternions[15 * h + 3 * f + k])
            tip = at + rot.apply(offsets[f"{side}Hand{finger}3_End"])
            tips[f"{side}{UNITY_FINGERS[f]}Distal"] = MIRROR @ (tip - joints_view[KP["pelvis"]])
    return tips


def _received_tips(frame, scale: float) -> dict[str, np.ndarray]:
    """Per distal bone, the fingertip less the Hips by the receiver's forward kinematics (Unity frame)."""
    pos, rot = bone_transforms(frame)
    bones = {m.params[0]: m.params[1:] for m in frame if m.address == "/VMC/Ext/Bone/Pos"}
    tips = {}
    for side in SIDE_NAMES:
        ends = {name: np.array(offset) * scale for name, _, offset, _ in finger_nodes(side)}
        for finger, unity in zip(FINGER_NAMES, UNITY_FINGERS):
            at, turned = pos[f"{side}Hand"], rot[f"{side}Hand"]
            for phalanx in PHALANGES:
                bone = bones[f"{side}{unity}{phalanx}"]
                at, turned = at + turned.apply(bone[:3]), turned * Rotation.from_quat(bone[3:7])
            tips[f"{side}{unity}Distal"] = at + turned.apply(MIRROR @ ends[f"{side}Hand{finger}3_End"]) - pos["Hips"]
    return tips


def test_a_vmc_receiver_puts_the_fingertips_where_the_stream_does():
    people = run_with_hands(0, lambda t: HANDS_PX)
    frames = _sent(people)
    assert len(frames) == len(people)
    errors = []
    for frame, pose in zip(frames, people):
        expected, got = _expected_tips(pose), _received_tips(frame, pose.height_m / UNIVERSAL_HEIGHT_M)
        errors += [np.linalg.norm(got[bone] - expected[bone]) for bone in expected]
    assert max(errors) < 0.01, max(errors)
    index2 = next(m.params[4:8] for m in frames[-1] if m.params[0] == "RightIndexIntermediate")
    assert abs(np.degrees(Rotation.from_quat(index2).magnitude()) - 90.0) < 1.0      # the drawn bend, sent


def test_a_stream_without_hands_sends_no_finger_bone():
    frames = _sent(run_without_hands(0, lambda t: ALL))
    names = {m.params[0] for frame in frames for m in frame if m.address == "/VMC/Ext/Bone/Pos"}
    assert len(names) == 21 and not any("Proximal" in n or "Distal" in n for n in names)
