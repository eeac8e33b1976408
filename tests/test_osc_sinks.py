"""The avatar sinks (runtime/stream/osc_sinks.py, core/avatar.py): what a VMC or VRChat receiver gets,
decoded by python-osc from real UDP datagrams, puts the person's joints where the pose has them in
Unity's frame (levelled, x negated, on the floor); bundles fit 1,500 bytes; a receiver that is not
listening costs nothing; memory stays flat over ten minutes of frames."""
from __future__ import annotations

import socket
import statistics
import threading
import time
import tracemalloc

import numpy as np
import pytest
from pythonosc.osc_bundle import OscBundle
from pythonosc.osc_message import OscMessage
from scipy.spatial.transform import Rotation

from mocapdb.cli.main import main
from mocapdb.core.avatar import UNITY_BONES, VIEW_UP, avatar_pose
from mocapdb.core.clips import read_motion
from mocapdb.core.outputs import PersonPose
from mocapdb.core.skeleton import (
    KP,
    UNIVERSAL_HEIGHT_M,
    body_offsets_m,
    pose_from_rotations,
    universal_bone_lengths_m,
)
from mocapdb.runtime.stream.osc_sinks import VmcSink, VrchatSink
from mocapdb.runtime.stream.transport import StreamSpecError, StreamStats, open_sink
from tests.conftest import SAMPLE_BVH

HEIGHT_M = 1.62
CAMERA_WORLD = np.array([0.4, 1.3, 3.5])   # the camera in the motion's world (y up, floor y = 0), metres
# the Unity humanoid hierarchy, written out here independently of the module's tables
PARENT = {"Hips": None, "Spine": "Hips", "Chest": "Spine", "Neck": "Chest", "Head": "Neck",
          **{f"{s}{b}": p for s in ("Left", "Right") for b, p in (
              ("UpperLeg", "Hips"), ("LowerLeg", f"{s}UpperLeg"), ("Foot", f"{s}LowerLeg"), ("Toes", f"{s}Foot"),
              ("Shoulder", "Chest"), ("UpperArm", f"{s}Shoulder"), ("LowerArm", f"{s}UpperArm"),
              ("Hand", f"{s}LowerArm"))}}
JOINT_BONES = {"pelvis": "Hips", "neck": "Neck",
               **{f"{s}_{j}": f"{side}{b}" for s, side in (("r", "Right"), ("l", "Left"))
                  for j, b in (("hip", "UpperLeg"), ("knee", "LowerLeg"), ("ankle", "Foot"), ("shoulder", "UpperArm"),
                               ("elbow", "LowerArm"), ("wrist", "Hand"))}}


class Scene:
    """Real motion (a bundled BVH clip) seen by a camera pitched by ``pitch_deg``, as stream poses, and
    where each joint is in the Unity frame the sinks promise."""

    def __init__(self, pitch_deg: float, frames: int = 40) -> None:
        motion = read_motion(SAMPLE_BVH / "002_01.bvh", fps=60.0)
        self.pitch = Rotation.from_euler("x", pitch_deg, degrees=True)
        scale = HEIGHT_M / UNIVERSAL_HEIGHT_M
        proportions = universal_bone_lengths_m() * np.array([1.05, 0.97, 1.08, 0.95, 1.1, 0.93, 1.02, 1.06])
        self.bones_m = proportions * scale
        idx = np.arange(frames) % len(motion)
        quats = motion.rotations[idx].astype(np.float64)
        pelvis_world = motion.root_m[idx].astype(np.float64) * scale
        self.world = pose_from_rotations(quats, pelvis_world, scale, body_offsets_m(proportions))  # [F, 15, 3]
        root_world = Rotation.from_quat(quats[:, 0, [1, 2, 3, 0]])
        quats_view = quats.copy()
        quats_view[:, 0] = (self.pitch * root_world).as_quat()[:, [3, 0, 1, 2]]
        self.view = self.pitch.apply((self.world - CAMERA_WORLD).reshape(-1, 3)).reshape(self.world.shape)
        self.hips_rot = root_world                 # the pelvis's rotation in the level world
        self.poses = [PersonPose(7, joints * [1, 1, -1], q, joints[KP["pelvis"]] * [1, 1, -1], None, HEIGHT_M,
                                 self.bones_m) for joints, q in zip(self.view, quats_view)]
        self.up_view = self.pitch.apply([0.0, 1.0, 0.0])
        self.floor_offset_m = -CAMERA_WORLD[1]

    def estimated(self) -> list[PersonPose]:
        """The poses with the world's up and floor, as the online fit gives them."""
        for pose in self.poses:
            pose.up_view, pose.floor_offset_m = self.up_view, self.floor_offset_m
        return self.poses

    def unity(self, points_world: np.ndarray) -> np.ndarray:
        """World points in the Unity frame: x negated about the camera, y above the floor, from the first
        frame's pelvis on the floor."""
        out = (points_world - CAMERA_WORLD * [1, 0, 1]) * [-1, 1, 1]
        first = (self.world[0, KP["pelvis"]] - CAMERA_WORLD) * [-1, 0, 1]
        return out - first


class Receiver:
    """A UDP socket on 127.0.0.1 that keeps every datagram."""

    def __init__(self) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 22)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.5)
        self.port = self.sock.getsockname()[1]

    def take(self) -> list[bytes]:
        """Every datagram arrived so far (waits until none arrives for 0.1 s)."""
        out = []
        self.sock.settimeout(0.1)
        while True:
            try:
                out.append(self.sock.recv(65536))
            except TimeoutError:
                return out


def _messages(datagram: bytes) -> list[OscMessage]:
    if OscBundle.dgram_is_bundle(datagram):
        return [m for content in OscBundle(datagram) for m in _messages(content.dgram)]
    return [OscMessage(datagram)]


def _vmc_frames(datagrams: list[bytes]) -> list[list[OscMessage]]:
    """Messages grouped by frame: a frame ends with /VMC/Ext/T."""
    frames, current = [], []
    for datagram in datagrams:
        for message in _messages(datagram):
            current.append(message)
            if message.address == "/VMC/Ext/T":
                frames.append(current)
                current = []
    assert not current
    return frames


def _forward_kinematics(frame: list[OscMessage]) -> dict[str, np.ndarray]:
    """Each bone's position (Unity world) from the root and the bones' local transforms."""
    return bone_transforms(frame)[0]


def bone_transforms(frame: list[OscMessage]) -> tuple[dict[str, np.ndarray], dict[str, Rotation]]:
    """Each bone's position and global rotation (Unity world) from the root and the bones' local transforms."""
    root = next(m.params for m in frame if m.address == "/VMC/Ext/Root/Pos")
    bones = {m.params[0]: m.params[1:] for m in frame if m.address == "/VMC/Ext/Bone/Pos"}
    pos, rot = {}, {}
    for name in PARENT:   # parents first
        parent = PARENT[name]
        p_pos, p_rot = (np.array(root[1:4]), Rotation.from_quat(root[4:8])) if parent is None else (pos[parent],
                                                                                                   rot[parent])
        pos[name] = p_pos + p_rot.apply(bones[name][:3])
        rot[name] = p_rot * Rotation.from_quat(bones[name][3:7])
    return pos, rot


@pytest.fixture(scope="module", params=[0.0, 20.0], ids=["level", "pitched20"])
def vmc_run(request):
    """A VMC sink's datagrams for a scene, to a real receiver."""
    scene, receiver = Scene(request.param), Receiver()
    with VmcSink("127.0.0.1", receiver.port) as sink:
        sink.write('{"format": "mocapdb-stream"}')
        for i, pose in enumerate(scene.estimated()):
            sink.write_frame(i, i / 30, [pose])
    yield scene, receiver.take()
    receiver.sock.close()


def test_vmc_bones_put_the_joints_where_the_pose_has_them(vmc_run):
    scene, datagrams = vmc_run
    frames = _vmc_frames(datagrams)
    assert len(frames) == len(scene.poses)
    errors = []
    for frame, world in zip(frames, scene.world):
        pos = _forward_kinematics(frame)
        expected = scene.unity(world)
        errors += [np.linalg.norm(pos[bone] - expected[KP[joint]]) for joint, bone in JOINT_BONES.items()]
        root = np.array(next(m.params for m in frame if m.address == "/VMC/Ext/Root/Pos")[1:8])
        assert root[1] == 0.0 and np.allclose(root[3:], [0, 0, 0, 1])   # on the floor, no turn
    assert max(errors) < 0.01, max(errors)
    assert np.allclose(_forward_kinematics(frames[0])["Hips"] * [1, 0, 1], 0.0, atol=1e-4)   # the origin


def test_vmc_bundles_fit_1500_bytes_and_carry_every_bone(vmc_run):
    scene, datagrams = vmc_run
    assert all(OscBundle.dgram_is_bundle(d) and len(d) <= 1500 for d in datagrams)
    for frame in _vmc_frames(datagrams):
        bones = [m.params[0] for m in frame if m.address == "/VMC/Ext/Bone/Pos"]
        assert sorted(bones) == sorted(PARENT)
        assert all(len(m.params) == 8 and all(isinstance(v, float) for v in m.params[1:])
                   for m in frame if m.address == "/VMC/Ext/Bone/Pos")
        assert [m.params for m in frame if m.address == "/VMC/Ext/OK"] == [[1]]
        assert [m.address for m in frame].count("/VMC/Ext/Root/Pos") == 1


def test_vmc_absent_person_sends_ok_0_and_time():
    scene, receiver = Scene(0.0, frames=3), Receiver()
    with VmcSink("127.0.0.1", receiver.port, track=7) as sink:
        sink.write_frame(0, 0.0, [scene.poses[0]])
        sink.write_frame(1, 0.5, [])
        other = PersonPose(8, *(getattr(scene.poses[1], f) for f in ("joints_m", "quaternions", "root_m", "match")))
        sink.write_frame(2, 1.0, [other])   # only track 7 is sent
    frames = _vmc_frames(receiver.take())
    assert [[m.address for m in f] for f in frames[1:]] == [["/VMC/Ext/OK", "/VMC/Ext/T"]] * 2
    assert [f[0].params for f in frames[1:]] == [[0], [0]] and frames[2][1].params == [1.0]


def test_vmc_main_track_is_kept_while_present():
    scene, receiver = Scene(0.0, frames=30), Receiver()
    moved = [PersonPose(3, p.joints_m + [2.0, 0, 0], p.quaternions, p.root_m + [2.0, 0, 0], None, HEIGHT_M,
                        p.bones_m) for p in scene.poses]
    people = ([[scene.poses[i]] for i in range(5)] + [[scene.poses[i], moved[i]] for i in range(5, 15)]
              + [[moved[i]] for i in range(15, 20)] + [[scene.poses[i], moved[i]] for i in range(20, 30)])
    with VmcSink("127.0.0.1", receiver.port) as sink:
        for i, frame_people in enumerate(people):
            sink.write_frame(i, i / 30, frame_people)
    hips_x = [_forward_kinematics(f)["Hips"][0] - scene.unity(w)[KP["pelvis"], 0]
              for f, w in zip(_vmc_frames(receiver.take()), scene.world)]
    # track 7 until it leaves at frame 15; then track 3 (2 m to the camera's right: Unity -x), kept after 7 is back
    assert np.allclose(hips_x[:15], 0.0, atol=0.01) and np.allclose(hips_x[15:], -2.0, atol=0.01)


def test_vmc_main_track_at_the_start_is_the_nearest():
    scene, receiver = Scene(0.0, frames=5), Receiver()
    farther = [PersonPose(2, p.joints_m + [0, 0, 2.0], p.quaternions, p.root_m + [0, 0, 2.0], None, HEIGHT_M,
                          p.bones_m) for p in scene.poses]
    with VmcSink("127.0.0.1", receiver.port) as sink:
        for i, pose in enumerate(scene.estimated()):
            sink.write_frame(i, i / 30, [farther[i], pose])
    hips = [_forward_kinematics(f)["Hips"] for f in _vmc_frames(receiver.take())]
    assert np.allclose([h - scene.unity(w)[KP["pelvis"]] for h, w in zip(hips, scene.world)], 0.0, atol=0.01)


def test_vmc_without_an_estimated_floor_stands_on_the_lowest_recent_ankle():
    scene, receiver = Scene(0.0, frames=80), Receiver()
    with VmcSink("127.0.0.1", receiver.port) as sink:
        for i, pose in enumerate(scene.poses):   # up_view and floor_offset_m None: the view's +y, the ankles
            sink.write_frame(i, i / 30, [pose])
    ankles = scene.view[:, [KP["r_ankle"], KP["l_ankle"]], 1].min(axis=1) - 0.08 * HEIGHT_M / UNIVERSAL_HEIGHT_M
    for i, frame in enumerate(_vmc_frames(receiver.take())):
        hips = next(m.params for m in frame if m.params[0] == "Hips")
        floor = ankles[max(i - 59, 0):i + 1].min()
        assert hips[2] == pytest.approx(scene.view[i, KP["pelvis"], 1] - floor, abs=1e-4)


def test_a_receiver_not_listening_costs_nothing():
    scene = Scene(20.0, frames=40)
    closed = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    closed.bind(("127.0.0.1", 0))
    port = closed.getsockname()[1]
    closed.close()
    stats = StreamStats()
    with VmcSink("127.0.0.1", port, stats) as sink:
        poses = scene.estimated()
        sink.write_frame(0, 0.0, [poses[0]])   # warm up (numba, caches)
        times = []
        for i in range(600):
            start = time.perf_counter()
            sink.write_frame(i, i / 60, [poses[i % len(poses)]])
            times.append(time.perf_counter() - start)
    assert statistics.median(times) < 0.001, statistics.median(times)
    assert stats.sink_dropped > 0   # ECONNREFUSED, reported on the sends after the first


def test_memory_stays_flat_over_ten_minutes_of_frames():
    scene, receiver = Scene(20.0, frames=60), Receiver()
    stop, received = threading.Event(), [0]

    def drain():
        while not stop.is_set():
            try:
                received[0] += len(receiver.sock.recv(65536))
            except TimeoutError:
                pass

    thread = threading.Thread(target=drain, daemon=True)
    thread.start()
    poses = scene.estimated()
    with VmcSink("127.0.0.1", receiver.port) as sink:
        tracemalloc.start()
        try:
            for i in range(36_000):
                sink.write_frame(i, i / 60, [poses[i % len(poses)]])
                if i == 999:
                    early = tracemalloc.get_traced_memory()[0]
            late = tracemalloc.get_traced_memory()[0]
        finally:
            tracemalloc.stop()
    stop.set()
    thread.join()
    receiver.sock.close()
    assert late - early < 1_000_000, (early, late)
    assert received[0] > 0


def test_vrchat_trackers_sit_at_the_joints():
    scene, receiver = Scene(20.0, frames=30), Receiver()
    with VrchatSink("127.0.0.1", receiver.port) as sink:
        for i, pose in enumerate(scene.estimated()):
            sink.write_frame(i, i / 30, [pose])
    messages = [m for d in receiver.take() for m in _messages(d)]
    assert len(messages) == 18 * len(scene.poses)
    joints = {"1": ["pelvis"], "2": ["pelvis", "neck"], "3": ["l_ankle"], "4": ["r_ankle"], "5": ["l_knee"],
              "6": ["r_knee"], "7": ["l_elbow"], "8": ["r_elbow"]}
    for i, world in enumerate(scene.world):
        frame = {m.address: np.array(m.params) for m in messages[18 * i:18 * (i + 1)]}
        for tracker, names in joints.items():
            expected = scene.unity(world)[[KP[n] for n in names]].mean(axis=0)   # the chest: mid-torso
            assert np.linalg.norm(frame[f"/tracking/trackers/{tracker}/position"] - expected) < 0.01
        x, y, z = frame["/tracking/trackers/1/rotation"]
        hips = Rotation.from_euler("zxy", [z, x, y], degrees=True)   # Unity: about z, then x, then y
        mirror = np.diag([-1.0, 1.0, 1.0])
        expected_rot = Rotation.from_matrix(mirror @ scene.hips_rot[i].as_matrix() @ mirror)
        assert (hips.inv() * expected_rot).magnitude() < np.radians(1.0)
        assert "/tracking/trackers/head/position" in frame


@pytest.mark.parametrize("spec, kind, port", [("vmc://127.0.0.1", VmcSink, 39539), ("vmc://127.0.0.1:40001", VmcSink,
                                                                                     40001),
                                              ("vrchat://localhost", VrchatSink, 9000),
                                              ("vrchat://127.0.0.1:9123", VrchatSink, 9123)])
def test_avatar_sink_specs(spec, kind, port):
    with open_sink(spec) as sink:
        assert isinstance(sink, kind) and sink._sock.getpeername()[1] == port


@pytest.mark.parametrize("spec, message", [("vmc://", "expected vmc://HOST[:PORT]"),
                                           ("vmc://host:port", "PORT from 0 to 65535"),
                                           ("vmc://127.0.0.1:70000", "PORT from 0 to 65535"),
                                           ("vrchat://:9000", "expected vrchat://HOST[:PORT]")])
def test_bad_avatar_sink_specs_are_refused(spec, message):
    with pytest.raises(StreamSpecError, match=message.replace("[", r"\[").replace("]", r"\]")):
        open_sink(spec)


def test_vmc_track_needs_a_vmc_sink(tmp_path, capsys):
    with pytest.raises(StreamSpecError, match="needs a vmc://"):
        open_sink("udp://127.0.0.1:9000", vmc_track=2)
    assert main(["live", "--source", str(tmp_path), "--db", str(tmp_path), "--sink", "vrchat://127.0.0.1",
                 "--vmc-track", "2"]) == 2
    assert "--vmc-track 2 needs a vmc://HOST[:PORT] sink" in capsys.readouterr().err


def test_a_person_facing_the_camera_gives_an_avatar_facing_plus_z():
    rest = np.tile([1.0, 0.0, 0.0, 0.0], (11, 1))   # the rest pose: facing the camera
    pelvis_view = np.array([0.0, -0.7, -3.0])
    joints = pose_from_rotations(rest[None], pelvis_view[None])[0] * [1, 1, -1]
    avatar = avatar_pose(PersonPose(0, joints, rest, pelvis_view * [1, 1, -1], None), VIEW_UP, -1.6)
    at = dict(zip(UNITY_BONES, avatar.world_m))
    assert at["RightHand"][0] > at["Hips"][0] > at["LeftHand"][0]      # its right hand at +x, as Unity's avatars
    assert at["LeftToes"][2] > at["LeftFoot"][2]                        # toes forward: facing +z
    assert np.allclose(avatar.world_rot, np.eye(3)) and at["Hips"][1] == pytest.approx(0.9)
