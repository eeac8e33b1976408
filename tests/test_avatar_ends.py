"""The avatar sinks turn the feet, hands and head as the stream does (issue 49): the bundled BlazePose take
reconstructed, its stream's lines sent to a VMC and a VRChat sink on loopback and decoded by python-osc. A
receiver's forward kinematics puts points 20 cm along each foot, hand and head bone within 1 cm of where
the stream's numbers put them (computed here with SciPy from the line's rotations, joints and up); VRChat's
head and feet trackers turn as those bones; a hand never seen is sent at rest."""
import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mocapdb.cli.main import main
from mocapdb.core.outputs import PersonPose
from mocapdb.core.skeleton import KP, MEASURED_BONE_NAMES, RIG_JOINTS, universal_bone_lengths_m
from mocapdb.runtime.stream.osc_sinks import VmcSink, VrchatSink
from tests.conftest import ROOT
from tests.test_online_ends import ALL, _run
from tests.test_osc_sinks import Receiver, _messages, _vmc_frames, bone_transforms

BLAZEPOSE = ROOT / "data" / "sample_keypoints" / "blazepose_cam01"
MIRROR = np.diag([-1.0, 1.0, 1.0])   # Unity's x is the levelled frame's −x
# per end joint of the stream (its end_joints order): the Unity bone, the universal rig joints from the root
# to the bone it hangs from, the joint (or "skull base") it sits at, and a point 20 cm along it at rest
ENDS = (("RightFoot", ("pelvis", "r_hip", "r_knee"), "r_ankle", (0.0, 0.0, 0.2)),
        ("LeftFoot", ("pelvis", "l_hip", "l_knee"), "l_ankle", (0.0, 0.0, 0.2)),
        ("RightHand", ("pelvis", "spine", "r_shoulder", "r_elbow"), "r_wrist", (-0.2, 0.0, 0.0)),
        ("LeftHand", ("pelvis", "spine", "l_shoulder", "l_elbow"), "l_wrist", (0.2, 0.0, 0.0)),
        ("Head", ("pelvis", "spine", "neck"), "skull base", (0.0, 0.2, 0.0)))
HEAD_BASE_M = 0.10   # neck → skull base at the universal neck → nose, in proportion to it


def _pose(person: dict) -> PersonPose:
    """A stream line's person as the sinks take it."""
    return PersonPose(person["track"], np.array(person["joints"]), np.array(person["quaternions"]),
                      np.array(person["root"]), None, person["height"],
                      np.array([person["bones"][b] for b in MEASURED_BONE_NAMES]), np.array(person["up"]),
                      person.get("floor"), end_quaternions=np.array(person["end_quaternions"]),
                      end_seen=tuple(person["end_seen"]))


def _levelling(up: np.ndarray) -> Rotation:
    """The shortest rotation taking ``up`` to +y."""
    axis = np.cross(up, [0.0, 1.0, 0.0])
    return Rotation.from_rotvec(axis / np.linalg.norm(axis) * np.arccos(np.clip(up[1], -1.0, 1.0)))


def _expected(person: dict) -> tuple[np.ndarray, np.ndarray]:
    """Per end bone, its 20 cm point less the pelvis ``[5, 3]`` and its global rotation ``[5, 3, 3]`` in Unity's
    frame, from the stream line's own numbers."""
    joints_view = np.array(person["joints"]) * [1.0, 1.0, -1.0]
    local = {j: Rotation.from_quat(np.array(q)[[1, 2, 3, 0]]) for j, q in zip(RIG_JOINTS, person["quaternions"])}
    level = _levelling(np.array(person["up"]))
    skull = HEAD_BASE_M * person["bones"]["neck_nose"] / universal_bone_lengths_m()[MEASURED_BONE_NAMES.index(
        "neck_nose")]
    points, rotations = [], []
    for (_, chain, at, tip), end in zip(ENDS, person["end_quaternions"]):
        parent = Rotation.identity()
        for joint in chain:
            parent = parent * local[joint]
        origin = joints_view[KP["neck"]] + parent.apply([0.0, skull, 0.0]) if at == "skull base" \
            else joints_view[KP[at]]
        bone = parent * Rotation.from_quat(np.array(end)[[1, 2, 3, 0]])
        points.append(MIRROR @ level.apply(origin + bone.apply(tip) - joints_view[KP["pelvis"]]))
        rotations.append(MIRROR @ (level * bone).as_matrix() @ MIRROR)
    return np.array(points), np.array(rotations)


@pytest.fixture(scope="module")
def stream(small_db_path, tmp_path_factory) -> list[tuple[float, dict]]:
    """The main track's person of each line (time, record) of the bundled take's stream, once a floor is known."""
    out = tmp_path_factory.mktemp("ends") / "out"
    assert main(["reconstruct", str(BLAZEPOSE), "--db", str(small_db_path), "--out", str(out), "-q"]) == 0
    lines = [json.loads(line) for line in (out / "result.jsonl").read_text().splitlines()[1:]]
    people = [(line["time"], p) for line in lines for p in line["people"] if p["track"] == 0 and "floor" in p]
    assert len(people) > 50 and all("end_quaternions" in p for _, p in people)
    return people


def test_a_vmc_receiver_puts_the_feet_hands_and_head_where_the_stream_does(stream):
    receiver = Receiver()
    with VmcSink("127.0.0.1", receiver.port) as sink:
        for i, (time_s, person) in enumerate(stream):
            sink.write_frame(i, time_s, [_pose(person)])
    frames = _vmc_frames(receiver.take())
    assert len(frames) == len(stream)
    errors, turned = [], []
    for frame, (_, person) in zip(frames, stream):
        pos, rot = bone_transforms(frame)
        expected, _ = _expected(person)
        for (bone, _, _, tip), point in zip(ENDS, expected):
            got = pos[bone] + rot[bone].apply(MIRROR @ tip) - pos["Hips"]
            errors.append(np.linalg.norm(got - point))
        turned.append([Rotation.from_quat(m.params[4:8]).magnitude() for m in frame if m.params[0] in
                       {b for b, *_ in ENDS}])
    assert max(errors) < 0.01, max(errors)
    assert np.median(np.degrees(turned)) > 2.0       # they do turn (the stream's feet, hands and head)


def test_vrchat_head_and_feet_trackers_turn_as_those_bones(stream):
    receiver = Receiver()
    with VrchatSink("127.0.0.1", receiver.port) as sink:
        for i, (time_s, person) in enumerate(stream):
            sink.write_frame(i, time_s, [_pose(person)])
    messages = [m for d in receiver.take() for m in _messages(d)]
    assert len(messages) == 18 * len(stream)
    for i, (_, person) in enumerate(stream):
        frame = {m.address: np.array(m.params) for m in messages[18 * i:18 * (i + 1)]}
        rotations = dict(zip([b for b, *_ in ENDS], _expected(person)[1]))
        for tracker, bone in (("head", "Head"), ("3", "LeftFoot"), ("4", "RightFoot")):
            x, y, z = frame[f"/tracking/trackers/{tracker}/rotation"]
            got = Rotation.from_euler("zxy", [z, x, y], degrees=True)   # Unity: about z, then x, then y
            assert (got.inv() * Rotation.from_matrix(rotations[bone])).magnitude() < np.radians(1.0)


def test_a_hand_never_seen_is_sent_at_rest():
    people = _run(0, lambda t: {**ALL, "l_hand": False})
    receiver = Receiver()
    with VmcSink("127.0.0.1", receiver.port) as sink:
        for i, pose in enumerate(people):
            sink.write_frame(i, i / 30, [pose])
    frames = _vmc_frames(receiver.take())
    left = [next(m.params[4:8] for m in f if m.params[0] == "LeftHand") for f in frames]
    right = [next(m.params[4:8] for m in f if m.params[0] == "RightHand") for f in frames]
    assert np.array_equal(left, np.tile([0.0, 0.0, 0.0, 1.0], (len(frames), 1)))   # (x, y, z, w): identity
    assert Rotation.from_quat(right[-1]).magnitude() > np.radians(10.0)          # the right hand, seen, turns
