"""The one motion type: Motion, FrameRecorder and the operations on motions, against brute force
and closed forms."""
import numpy as np
import pytest

from mocapdb.core.motion import FrameRecorder, Motion
from mocapdb.core.motion_ops import from_points, on_floor, scaled_about_origin
from mocapdb.core.outputs import TrackRecording
from mocapdb.core.skeleton import (
    MEASURED_BONE_NAMES,
    N_RIG_JOINTS,
    PELVIS,
    pose_from_rotations,
    rest_positions_m,
    universal_bone_lengths_m,
)


def _random_motion(frames: int = 12, seed: int = 0) -> Motion:
    rng = np.random.default_rng(seed)
    points = rest_positions_m() + rng.normal(scale=0.04, size=(frames, 15, 3)) + [0.2, 0.0, -4.0]
    return from_points(points, 30.0, "view")[0]


def test_a_recorder_holds_every_appended_row_as_one_array():
    rng = np.random.default_rng(1)
    rows = [dict(q=rng.normal(size=(N_RIG_JOINTS, 4)), s=float(rng.normal()), k=rng.integers(0, 9, size=3))
            for _ in range(100)]  # past several doublings of the first capacity (8)
    recorder = FrameRecorder()
    for row in rows:
        recorder.append(**row)
    assert len(recorder) == 100 and recorder.names() == ("q", "s", "k")
    np.testing.assert_array_equal(recorder["q"], np.stack([r["q"] for r in rows]))
    np.testing.assert_array_equal(recorder["s"], np.array([r["s"] for r in rows]))
    assert recorder["k"].dtype == rows[0]["k"].dtype  # each name keeps its first row's dtype
    np.testing.assert_array_equal(recorder.last()["k"], rows[-1]["k"])


def test_a_snapshot_stays_as_it_was_while_the_recorder_grows():
    recorder = FrameRecorder()
    recorder.append(x=np.zeros(3))
    snapshot = recorder.snapshot()
    for i in range(1, 50):
        recorder.append(x=np.full(3, float(i)))
    assert len(snapshot) == 1 and len(recorder) == 50
    np.testing.assert_array_equal(snapshot["x"], np.zeros((1, 3)))
    snapshot.append(x=np.full(3, -1.0))  # never into the rows the recorder holds
    np.testing.assert_array_equal(recorder["x"][1], np.ones(3))


def test_a_recorder_refuses_a_frame_with_other_names_and_columns_of_other_lengths():
    recorder = FrameRecorder()
    recorder.append(a=1.0, b=2.0)
    with pytest.raises(ValueError, match="a frame needs"):
        recorder.append(a=1.0)
    with pytest.raises(ValueError, match="different lengths"):
        FrameRecorder.of(a=np.zeros(3), b=np.zeros(4))
    empty = FrameRecorder.of(a=np.zeros((0, 2)))  # no rows yet: appending still grows it
    empty.append(a=np.ones(2))
    np.testing.assert_array_equal(empty["a"], [[1.0, 1.0]])


def test_a_motion_checks_its_shapes_frame_and_body():
    rotations, root = np.tile([1.0, 0, 0, 0], (5, N_RIG_JOINTS, 1)), np.zeros((5, 3))
    with pytest.raises(ValueError, match="rotations"):
        Motion(rotations[:, :3], root, 30.0)
    with pytest.raises(ValueError, match="coordinate frame"):
        Motion(rotations, root, 30.0, "screen")
    with pytest.raises(ValueError, match="positive"):
        Motion(rotations, root, 30.0, scale=-1.0)
    with pytest.raises(ValueError, match="end rotations"):
        Motion(rotations, root, 30.0, end_rotations=np.zeros((5, 3, 4)))


def test_forward_kinematics_bones_and_windows():
    motion = _random_motion()
    tall = Motion(motion.rotations, motion.root_m, 30.0, "view", 7, scale=1.2)
    np.testing.assert_allclose(tall.joints_m(), pose_from_rotations(motion.rotations, motion.root_m, 1.2))
    assert tall.height_m == pytest.approx(1.75 * 1.2)
    np.testing.assert_allclose(tall.bones_m(), universal_bone_lengths_m() * 1.2)
    assert len(tall.bones_m()) == len(MEASURED_BONE_NAMES)
    part = tall.window(3, 8)
    assert len(part) == 5 and part.first_frame == 10
    np.testing.assert_allclose(part.joints_m(), tall.joints_m()[3:8])
    np.testing.assert_allclose(part.times_s(), np.arange(10, 15) / 30.0)


def test_from_points_gives_the_motion_whose_joints_it_returns():
    rng = np.random.default_rng(3)
    points = rest_positions_m() + rng.normal(scale=0.03, size=(6, 15, 3))
    motion, joints = from_points(points, 24.0)
    np.testing.assert_allclose(motion.joints_m(), joints, atol=1e-12)
    np.testing.assert_allclose(motion.root_m, points[:, PELVIS], atol=1e-12)


def test_scaling_about_the_camera_keeps_the_image():
    """A pinhole at the origin sees the same picture of a body k times as tall and k times as far."""
    motion = _random_motion()
    big = scaled_about_origin(motion, 1.3)
    image = motion.joints_m()[..., :2] / motion.joints_m()[..., 2:]
    np.testing.assert_allclose(big.joints_m()[..., :2] / big.joints_m()[..., 2:], image, atol=1e-12)
    assert big.height_m == pytest.approx(1.3 * motion.height_m)


def test_on_floor_keeps_the_body_and_sets_the_world_frame():
    motion = _random_motion(frames=20)
    floor = on_floor(motion, (np.array([0.0, 1.0, 0.0]), -1.5))
    assert floor.coordinate_frame == "world"
    np.testing.assert_allclose(floor.root_m, motion.root_m + [0.0, 1.5, 0.0], atol=1e-12)
    np.testing.assert_allclose(floor.joints_m(), motion.joints_m() + [0.0, 1.5, 0.0], atol=1e-12)


def test_a_track_motion_moves_each_root_to_the_final_scale():
    """Hand-computed: a root 4 m away at scale 1.0 becomes 5 m away at the final scale 1.25."""
    quats = np.tile([1.0, 0, 0, 0], (2, N_RIG_JOINTS, 1))
    frames = FrameRecorder.of(quaternions=quats, root_view_m=np.array([[0.0, 0.0, -4.0], [0.0, 0.0, -5.0]]),
                              scales=np.array([1.0, 1.25]))
    motion = TrackRecording(2, 40, frames).motion(25.0)
    np.testing.assert_allclose(motion.root_m, [[0.0, 0.0, -5.0], [0.0, 0.0, -5.0]])
    assert motion.scale == 1.25 and motion.first_frame == 40 and motion.coordinate_frame == "view"


def test_a_motion_written_as_bvh_reads_back_as_the_same_motion(tmp_path):
    """write_motion and read_motion are counterparts: mocapdb's own rig is recognised, and the
    motion read back (24 fps, the universal body, world frame) has the written joints."""
    from mocapdb.core.clips import read_motion
    from mocapdb.core.exports import TrackExport, write_motion
    from mocapdb.core.skeleton import ANKLE_HEIGHT_M, KP

    rng = np.random.default_rng(4)
    t = np.arange(48)[:, None, None] / 24.0
    points = rest_positions_m() + 0.03 * np.sin(2 * np.pi * t + rng.uniform(0, 6, size=(1, 15, 3)))
    motion, _ = from_points(points + [0.0, 0.0, 0.5] * t, 24.0)  # walking 0.5 m/s away
    lowest = motion.joints_m()[:, [KP["r_ankle"], KP["l_ankle"]], 1].min()
    motion.root_m = motion.root_m - [0.0, lowest - ANKLE_HEIGHT_M, 0.0]  # on the floor, as clips are
    (path,) = write_motion(motion, tmp_path, "walk", TrackExport(formats=("bvh",), unit="cm"))
    again = read_motion(path, fps=24.0)
    assert len(again) == len(motion) and again.coordinate_frame == "world" and again.fps == 24.0
    np.testing.assert_allclose(again.joints_m(), motion.joints_m(), atol=1e-4)  # metres


def test_a_track_recording_names_its_columns():
    rec = TrackRecording(1, 0)
    assert len(rec) == 0 and rec.column("keypoints").size == 0  # not recorded yet: empty
    with pytest.raises(KeyError, match="records no 'keypoint'"):
        rec.column("keypoint")
