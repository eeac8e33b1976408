"""Track files: TRC read back by mocapdb and by OpenSim, CSV by pandas, the humanoid rig, the floor."""
import os
import subprocess

import numpy as np
import pandas as pd
import pytest
from scipy.spatial.transform import Rotation

from mocapdb.core import exports
from mocapdb.core.clips import ClipOptions, process_clip
from mocapdb.core.exports import TrackExport, write_track_files
from mocapdb.core.formats.bvh import format_bvh, forward_kinematics, read_bvh
from mocapdb.core.formats.trc import format_trc, read_trc
from mocapdb.core.geometry import axis_rotation_matrices, matrix_to_quat, quat_mul
from mocapdb.core.hand_rig import FINGER_JOINTS
from mocapdb.core.joint_map import detect_mapping
from mocapdb.core.motion import FrameRecorder, Motion
from mocapdb.core.motion_ops import on_floor
from mocapdb.core.outputs import TrackRecording, motion_bvh
from mocapdb.core.skeleton import (
    ANKLE_HEIGHT_M,
    FACE_NAMES,
    HUMANOID_NODE_OF_KEYPOINT,
    KEYPOINTS,
    KP,
    N_RIG_JOINTS,
    NODE_OF_POINT,
    PELVIS,
    pose_from_rotations,
)

from .conftest import MISSING, SAMPLE_BVH

OPENSIM_PYTHON_ENV = "MOCAPDB_OPENSIM_PYTHON"  # a Python with `pip install opensim` (CI sets it)
# Bones Unity's Humanoid avatar requires, and HumanIK's characterisation needs, by Mixamo name.
REQUIRED_BONES = ("Hips", "Spine", "Neck", "Head", "LeftUpLeg", "LeftLeg", "LeftFoot", "RightUpLeg", "RightLeg",
                  "RightFoot", "LeftArm", "LeftForeArm", "LeftHand", "RightArm", "RightForeArm", "RightHand",
                  "LeftShoulder", "RightShoulder", "LeftToeBase", "RightToeBase")


@pytest.fixture(scope="module")
def walk():
    """A captured walk on the universal skeleton: rotations, pelvis (floor at y = 0), positions."""
    from mocapdb.core.skeleton import retarget

    clip = process_clip(SAMPLE_BVH / "002_01.bvh", SAMPLE_BVH, ClipOptions(fps=30.0))
    positions = clip.positions.astype(np.float64)
    quats, fitted = retarget(positions)
    return quats, fitted[:, PELVIS], fitted


def _recording(quats, root_m, first_frame=0, scale=1.0):
    frames = FrameRecorder.of(quaternions=quats, root_view_m=root_m, scales=np.full(len(quats), scale))
    return TrackRecording(3, first_frame, frames, first_s=first_frame / 30.0,
                          last_s=(first_frame + len(quats) - 1) / 30.0)


def _seen_from_a_pitched_camera(quats, root_m, pitch_deg, shift):
    """The motion as a camera pitched down by ``pitch_deg`` sees it, moved by ``shift`` metres."""
    turn = axis_rotation_matrices("X", np.radians(-pitch_deg))
    quats = quats.copy()
    quats[:, 0] = quat_mul(matrix_to_quat(turn), quats[:, 0])
    return quats, root_m @ turn.T + shift


def test_floor_levels_a_pitched_camera_and_puts_the_feet_on_y0(walk):
    quats, root, truth = walk
    seen_q, seen_root = _seen_from_a_pitched_camera(quats, root, 12.0, [0.4, -1.3, -5.0])
    assert np.ptp(pose_from_rotations(seen_q, seen_root)[:, KP["r_ankle"], 1]) > 0.3  # tilted: feet not level
    level = on_floor(Motion(seen_q, seen_root, 30.0, "view"))
    level_q, level_root = level.rotations, level.root_m
    assert level.coordinate_frame == "world"
    joints = pose_from_rotations(level_q, level_root)
    lowest = joints[:, [KP["r_ankle"], KP["l_ankle"]], 1].min(axis=1)
    assert abs(np.percentile(lowest, 5) - ANKLE_HEIGHT_M) < 1e-9
    np.testing.assert_allclose(joints[..., 1], truth[..., 1] - np.percentile(truth[:, [KP["r_ankle"], KP["l_ankle"]], 1]
                                                                          .min(axis=1), 5) + ANKLE_HEIGHT_M, atol=0.02)
    np.testing.assert_allclose(level_root[0, [0, 2]], 0.0, atol=1e-9)


def test_floor_without_depth_motion_only_shifts(walk):
    quats, root, _ = walk
    still_q = np.repeat(quats[:1], 5, axis=0)  # one pose held: no depth to measure a pitch on
    still_root = np.repeat(root[:1], 5, axis=0) + [0.0, -1.2, -4.0]
    level = on_floor(Motion(still_q, still_root, 30.0, "view"))
    level_q, level_root = level.rotations, level.root_m
    np.testing.assert_allclose(level_q, still_q)
    np.testing.assert_allclose(np.diff(level_root, axis=0), np.diff(still_root, axis=0))


def test_trc_and_csv_carry_the_joints(walk, tmp_path):
    quats, root, _ = walk
    rec = _recording(quats[:40], root[:40] + [0.0, 0.0, -4.0], first_frame=10, scale=1.1)
    paths = write_track_files(rec, tmp_path, "track_3", 30.0, TrackExport(("bvh", "trc", "csv"), pad_to_input=False))
    assert [p.name for p in paths] == ["track_3.bvh", "track_3.trc", "track_3.csv"]
    joints = pose_from_rotations(quats[:40], root[:40] + [0.0, 0.0, -4.0], 1.1)
    trc = read_trc(tmp_path / "track_3.trc")
    assert trc.markers == list(KEYPOINTS + FACE_NAMES) and trc.rate_hz == 30.0 and trc.frame_numbers[0] == 11
    np.testing.assert_allclose(trc.positions[:, :len(KEYPOINTS)], joints, atol=1e-5)     # input frame 10 above
    np.testing.assert_allclose(trc.times_s, (10 + np.arange(40)) / 30.0, atol=1e-6)
    table = pd.read_csv(tmp_path / "track_3.csv")
    assert table["frame"].dtype == np.int64 and list(table.columns[:5]) == ["frame", "time_s", "head_x", "head_y",
                                                                            "head_z"]
    np.testing.assert_allclose(table[["l_ankle_x", "l_ankle_y", "l_ankle_z"]].to_numpy(), joints[:, KP["l_ankle"]],
                               atol=1e-5)
    np.testing.assert_allclose(table[["l_ear_x", "l_ear_y", "l_ear_z"]].to_numpy(),
                               trc.positions[:, trc.markers.index("l_ear")], atol=1e-5)


def test_the_face_points_turn_with_the_head(tmp_path):
    """At rest (every global rotation the identity) with the Head turned 40 deg about the vertical and 10 about its
    side: the face's points are the face model's, scaled and turned by that, about the humanoid's nose (by hand:
    the ears' line (0.15 cos 40, 0, -0.15 sin 40) m x scale; the eyes' mid-point 0.035 up and 0.02 back from the
    nose, turned)."""
    turn = Rotation.from_euler("YX", [40.0, 10.0], degrees=True)
    ends = np.tile([1.0, 0.0, 0.0, 0.0], (3, 5, 1))
    ends[:, 4] = turn.as_quat(scalar_first=True)
    motion = Motion(np.tile([1.0, 0.0, 0.0, 0.0], (3, N_RIG_JOINTS, 1)), np.zeros((3, 3)), 30.0, "view", scale=1.2,
                    end_rotations=ends)
    exports.write_motion(motion, tmp_path, "m", TrackExport(("trc",)))
    trc = read_trc(tmp_path / "m.trc")
    face = {name: trc.positions[:, trc.markers.index(name)] for name in FACE_NAMES}
    ears = face["l_ear"] - face["r_ear"]
    np.testing.assert_allclose(ears, np.tile(0.15 * 1.2 * turn.apply([1.0, 0.0, 0.0]), (3, 1)), atol=1e-5)
    bvh = motion_bvh(motion, "m", "humanoid")
    nose = forward_kinematics(bvh, [bvh.names.index("Head_End")])[0][:, 0]
    eyes = 0.5 * (face["l_eye"] + face["r_eye"])
    np.testing.assert_allclose(eyes - nose, np.tile(turn.apply([0.0, 0.035, -0.02]) * 1.2, (3, 1)), atol=1e-5)


def test_track_files_line_up_with_the_input(walk, tmp_path):
    # A track starting at input frame 37 (30 fps): its BVH holds frame 37's pose for input frames 0-36,
    # then its own 40 frames; TRC Frame# 38-77 at 37/30 s on, CSV frames 37-76 (issue 27, item 4).
    quats, root, _ = walk
    root = root[:40] + [0.3, -0.9, -4.0]
    write_track_files(_recording(quats[:40], root, first_frame=37, scale=1.1), tmp_path, "t", 30.0,
                      TrackExport(formats=("bvh", "trc", "csv")))
    bvh = read_bvh(tmp_path / "t.bvh")
    joints = pose_from_rotations(quats[:40], root, 1.1)
    assert bvh.n_frames == 77 and bvh.fps == pytest.approx(30.0)
    fk = forward_kinematics(bvh)[0][:, NODE_OF_POINT]
    np.testing.assert_allclose(fk[:37], np.broadcast_to(joints[0], (37, *joints[0].shape)), atol=1e-5)
    np.testing.assert_allclose(fk[37:], joints, atol=1e-5)
    assert (bvh.motion[:37] == bvh.motion[37]).all() and (np.abs(bvh.motion[37] - bvh.motion[38]) > 1e-4).any()
    trc = read_trc(tmp_path / "t.trc")
    np.testing.assert_array_equal(trc.frame_numbers, np.arange(38, 78))
    np.testing.assert_allclose(trc.times_s, np.arange(37, 77) / 30.0, atol=1e-6)
    header = dict(zip(*[line.split("\t") for line in (tmp_path / "t.trc").read_text().splitlines()[1:3]]))
    assert (header["NumFrames"], header["OrigDataStartFrame"], header["OrigNumFrames"]) == ("40", "38", "40")
    table = pd.read_csv(tmp_path / "t.csv")
    np.testing.assert_array_equal(table["frame"], np.arange(37, 77))
    np.testing.assert_allclose(table["time_s"], np.arange(37, 77) / 30.0, atol=1e-6)


def test_bvh_from_the_track_start_and_past_the_padding_limit(walk, tmp_path, monkeypatch, caplog):
    quats, root, _ = walk
    rec = _recording(quats[:20], root[:20], first_frame=37)
    write_track_files(rec, tmp_path, "own", 30.0, TrackExport(pad_to_input=False))  # --bvh-start track
    own = read_bvh(tmp_path / "own.bvh")
    assert own.n_frames == 20
    np.testing.assert_allclose(forward_kinematics(own)[0][:, NODE_OF_POINT], pose_from_rotations(quats[:20], root[:20]),
                               atol=1e-5)
    monkeypatch.setattr(exports, "MAX_BVH_PAD_FRAMES", 37)
    monkeypatch.setattr(exports, "_WARNED_UNPADDED", False)
    write_track_files(rec, tmp_path, "at_limit", 30.0)
    assert read_bvh(tmp_path / "at_limit.bvh").n_frames == 57 and not caplog.records
    write_track_files(_recording(quats[:20], root[:20], first_frame=38), tmp_path, "past", 30.0)
    write_track_files(_recording(quats[:20], root[:20], first_frame=39), tmp_path, "past2", 30.0)
    assert read_bvh(tmp_path / "past.bvh").n_frames == read_bvh(tmp_path / "past2.bvh").n_frames == 20
    assert [r.getMessage().split(" starts")[0] for r in caplog.records] == ["past.bvh"]  # logged once


@pytest.mark.parametrize("lead", [-1, 3])
def test_bvh_lead_frames_need_a_first_frame(lead):
    bvh = motion_bvh(Motion(np.zeros((0, 11, 4)), np.zeros((0, 3)), 30.0))
    if lead < 0:
        bvh = motion_bvh(Motion(np.tile([1.0, 0, 0, 0], (2, 11, 1)), np.zeros((2, 3)), 30.0))
    with pytest.raises(ValueError, match="lead frames"):
        format_bvh(bvh, lead_frames=lead)


@pytest.mark.skipif(not os.environ.get(OPENSIM_PYTHON_ENV), reason=f"{MISSING}OpenSim: set ${OPENSIM_PYTHON_ENV}")
def test_opensim_reads_the_trc(tmp_path):
    positions = np.random.default_rng(1).normal(size=(12, len(KEYPOINTS), 3))
    (tmp_path / "m.trc").write_text(format_trc(list(KEYPOINTS), positions, 60.0, np.arange(5, 17)))
    script = ("import sys, opensim\nt = opensim.TimeSeriesTableVec3(sys.argv[1])  # OpenSim's TRC reader\n"
              "meta = t.getTableMetaDataAsString\n"
              "print(t.getNumRows(), t.getNumColumns(), meta('DataRate'), meta('Units'))\n"
              "print(' '.join(t.getColumnLabels()))\n"
              "r = t.getRowAtIndex(3)\n"
              "print(' '.join(f'{r[j][i]:.5f}' for j in range(t.getNumColumns()) for i in range(3)))\n"
              "print(' '.join(f'{x:.6f}' for x in t.getIndependentColumn()))")
    run = subprocess.run([os.environ[OPENSIM_PYTHON_ENV], "-c", script, str(tmp_path / "m.trc")],
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    shape, labels, row, times = run.stdout.strip().splitlines()[-4:]
    assert shape.split() == ["12", str(len(KEYPOINTS)), "60", "m"] and labels.split() == list(KEYPOINTS)
    np.testing.assert_allclose(np.array(row.split(), dtype=float), positions[3].ravel(), atol=1e-5)
    np.testing.assert_allclose(np.array(times.split(), dtype=float), np.arange(12) / 60.0, atol=1e-6)


def test_humanoid_rig_has_the_bones_auto_mappers_need_at_the_same_places(walk, tmp_path):
    quats, root, _ = walk
    universal = forward_kinematics(motion_bvh(Motion(quats[:20], root[:20], 30.0, scale=1.1), "cm"))[0]
    write_track_files(_recording(quats[:20], root[:20], scale=1.1), tmp_path, "h", 30.0,
                      TrackExport(unit="cm", rig="humanoid"))
    humanoid = read_bvh(tmp_path / "h.bvh")
    assert set(REQUIRED_BONES) <= set(humanoid.names)
    positions = forward_kinematics(humanoid)[0]
    for k, name in enumerate(KEYPOINTS):
        np.testing.assert_allclose(positions[:, humanoid.index(HUMANOID_NODE_OF_KEYPOINT[name])],
                                   universal[:, NODE_OF_POINT[k]], atol=1e-3, err_msg=name)  # cm
    assert detect_mapping(humanoid).convention == "motionbuilder_mixamo"  # mocapdb build reads it back


@pytest.mark.parametrize("rig", ["universal", "humanoid"])
def test_no_bvh_bone_is_zero_length_and_every_joint_stays_in_place(walk, tmp_path, rig):
    # Blender ends a bone at its End Site, else at the mean of its children's offsets: the root (hips
    # either side of the pelvis, the spine at it) was zero length ("zero length node found: Hips").
    quats, root, _ = walk
    write_track_files(_recording(quats[:20], root[:20], scale=1.1), tmp_path, "t", 30.0, TrackExport(rig=rig))
    bvh = read_bvh(tmp_path / "t.bvh")
    for j in np.flatnonzero(~bvh.end_site):
        children = bvh.children(j)
        ends = [c for c in children if bvh.end_site[c]]
        tail = bvh.offsets[ends[-1]] if ends else bvh.offsets[children].mean(axis=0)
        finger = bvh.names[j] in FINGER_JOINTS                  # finger bones: 1.7-5.2 cm (core.hand_rig)
        assert np.linalg.norm(tail) > (0.015 if finger else 0.05), bvh.names[j]  # metres
    nodes = NODE_OF_POINT if rig == "universal" else [bvh.index(HUMANOID_NODE_OF_KEYPOINT[k]) for k in KEYPOINTS]
    np.testing.assert_allclose(forward_kinematics(bvh)[0][:, nodes],
                               pose_from_rotations(quats[:20], root[:20], 1.1), atol=1e-5)  # the motion as it was


def test_export_options_are_checked():
    with pytest.raises(ValueError, match="unknown output format fbx"):
        TrackExport(formats=("bvh", "fbx"))
    with pytest.raises(ValueError, match="unknown rig"):
        TrackExport(rig="mixamo")


def test_reconstruct_writes_every_format_on_the_floor_and_a_preview(small_db_path, tmp_path, capsys):
    from mocapdb.cli.main import main

    from .conftest import SAMPLE_KEYPOINTS

    out = tmp_path / "out"
    code = main(["reconstruct", str(SAMPLE_KEYPOINTS), "--db", str(small_db_path), "--out", str(out), "--fps", "60",
                 "--image-size", "1088x1920", "--focal", "1681", "--format", "bvh,trc,csv", "--rig", "humanoid",
                 "--floor", "--preview"])
    assert code == 0, capsys.readouterr().err
    tracks = sorted(p.stem for p in out.glob("track_*.bvh"))
    assert tracks and all((out / f"{t}.trc").is_file() and (out / f"{t}.csv").is_file() for t in tracks)
    assert (out / "preview.png").stat().st_size > 10_000
    for stem in tracks:
        bvh = read_bvh(out / f"{stem}.bvh")
        assert "LeftToeBase" in bvh.names
        feet = read_trc(out / f"{stem}.trc").positions[:, [KP["r_ankle"], KP["l_ankle"]], 1].min(axis=1)
        assert abs(np.percentile(feet, 5) - ANKLE_HEIGHT_M * 1.0) < 0.05  # on the floor (body scale 1)
    assert main(["reconstruct", str(SAMPLE_KEYPOINTS), "--db", str(small_db_path), "--out", str(tmp_path / "x"),
                 "--format", "bvh,fbx"]) == 2
    assert "unknown output format fbx" in capsys.readouterr().err


def test_calibration_toml_round_trip(tmp_path):
    import tomllib

    from mocapdb.core.cameras import format_calibration_toml, read_calibration_toml

    from .conftest import ROOT

    path = ROOT / "data" / "sample_keypoints" / "calibration.toml"
    cameras = read_calibration_toml(path)
    text = format_calibration_toml(list(cameras.values()), "note")
    parsed = tomllib.loads(text)
    assert list(parsed) == [*cameras, "metadata"] and parsed["cam_01"]["fisheye"] is False
    (tmp_path / "calibration.toml").write_text(text)
    again = read_calibration_toml(tmp_path / "calibration.toml")
    for name, cam in cameras.items():
        np.testing.assert_allclose(again[name].K, cam.K)
        np.testing.assert_allclose(again[name].R, cam.R, atol=1e-12)
        np.testing.assert_allclose(again[name].t, cam.t)
        assert again[name].size == cam.size
