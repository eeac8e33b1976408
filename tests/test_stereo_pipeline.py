"""`mocapdb stereo`: person selection, loading checks, outputs (JSON lines, cameras, BVH), real data, TRC."""
import importlib.util
import json
import sys

import numpy as np
import pytest

from mocapdb.builder import BuildConfig, process_clip
from mocapdb.bvh import read_bvh
from mocapdb.joint_map import detect_mapping, extract_keypoints
from mocapdb.keypoints import KeypointFrame, Person
from mocapdb.skeleton import KEYPOINTS, N_KEYPOINTS_2D, RIG_JOINTS
from mocapdb.stereo import StereoConfig, StereoError
from mocapdb.cli import main
from mocapdb.database import load_database
from mocapdb.stereo_pipeline import CAMERA_ALIGNED, load_views, select_people
from mocapdb.trc import TrcError, parse_trc, read_trc, trc_keypoints

from .conftest import ROOT, SAMPLE_BVH, SHARED_DATA

POSE2SIM = SHARED_DATA / "pose2sim_balancing"
_spec = importlib.util.spec_from_file_location("eval_stereo", ROOT / "tools" / "eval_stereo.py")
eval_stereo = sys.modules.setdefault("eval_stereo", importlib.util.module_from_spec(_spec))
_spec.loader.exec_module(eval_stereo)


@pytest.fixture(scope="module")
def motion():
    """A bundled clip (sideways dance steps, a pirouette) on the universal skeleton, 30 fps:
    positions ``[148, 15, 3]`` m, y up."""
    clip = process_clip(SAMPLE_BVH / "005_11.bvh", SAMPLE_BVH, BuildConfig(fps=30.0))
    return clip.positions.astype(np.float64)


def _views(positions, noise_px, seed=0):
    cam1, cam2 = eval_stereo.pair_cameras("side", positions.mean(axis=(0, 1)))
    rng = np.random.default_rng(seed)
    return (cam1, cam2), eval_stereo.render(positions, cam1, rng, noise_px, 0.0), \
        eval_stereo.render(positions, cam2, rng, noise_px, 0.0)


def _frames(x, c, decoys=()):
    """KeypointFrames of one view: the person, plus per frame any decoy ``(x, c)`` listed first."""
    return [KeypointFrame(t, None, [Person(dx[t], dc[t]) for dx, dc in decoys] + [Person(x[t], c[t])])
            for t in range(len(x))]


def _write_openpose(folder, x, c):
    """OpenPose COCO-18 JSON files (the universal 14 first, then 4 face points left empty)."""
    folder.mkdir(parents=True)
    for t in range(len(x)):
        raw = np.zeros((18, 3))
        raw[:N_KEYPOINTS_2D, :2] = np.nan_to_num(x[t])
        raw[:N_KEYPOINTS_2D, 2] = c[t]
        people = [{"pose_keypoints_2d": raw.ravel().tolist()}]
        (folder / f"take_{t:012d}_keypoints.json").write_text(json.dumps({"version": 1.3, "people": people}))


def _stereo(argv):
    return main(["stereo", *argv])


def test_selection_rejects_a_false_person(motion):
    positions = motion[:90]
    (cam1, cam2), (x1, c1), (x2, c2) = _views(positions, 2.0)
    # The false person: the subject's pose of another moment, 120 px lower, in view 1 only; larger
    # (more prominent) than the subject in every fourth frame, smaller otherwise.
    centre = np.nanmean(x1, axis=1, keepdims=True)
    grow = np.where(np.arange(len(x1)) % 4 == 0, 1.2, 0.8)[:, None, None]
    decoy = np.roll(centre + grow * (x1 - centre), 45, axis=0) + [0.0, 120.0]
    selection = select_people(_frames(x1, c1, [(decoy, c1)]), _frames(x2, c2), cam1, cam2, StereoConfig())
    assert selection.dropped == {} and selection.kept.all()
    np.testing.assert_array_equal(selection.x1, x1)
    np.testing.assert_array_equal(selection.x2, x2)
    assert np.nanmax(selection.distance_px) < 10


def test_inconsistent_frames_are_dropped_not_removed(motion):
    positions = motion[:90]
    (cam1, cam2), (x1, c1), (x2, c2) = _views(positions, 2.0)
    x1_bad = x1.copy()
    x1_bad[10] += [0.0, 150.0]  # only an inconsistent person in frame 10 of view 1
    frames2 = _frames(x2, c2)
    frames2[20] = KeypointFrame(20, None, [])
    selection = select_people(_frames(x1_bad, c1), frames2, cam1, cam2, StereoConfig())
    assert len(selection.kept) == 90 and list(np.flatnonzero(~selection.kept)) == [10, 20]
    assert selection.dropped == {"no person in view 2": [20],
                                 "no pair within 20 px of the epipolar geometry": [10]}
    assert np.isnan(selection.x1[10]).all() and (selection.c1[10] == 0).all()


def test_mismatched_frame_counts(tmp_path, motion, capsys):
    (_, _), (x1, c1), (x2, c2) = _views(motion[:6], 0.0)
    _write_openpose(tmp_path / "a", x1, c1)
    _write_openpose(tmp_path / "b", x2[:5], c2[:5])
    with pytest.raises(StereoError, match=r"has 6 frames, view 2 .* has 5.*--trim"):
        load_views(tmp_path / "a", tmp_path / "b")
    frames1, frames2, warnings = load_views(tmp_path / "a", tmp_path / "b", trim=True)
    assert len(frames1) == len(frames2) == 5 and "trimmed" in warnings[0]
    code = _stereo([str(tmp_path / "a"), str(tmp_path / "b"), "--out", str(tmp_path / "out"),
                    "--focal", "1145", "--size", "1000", "1000"])
    assert code == 2
    err = capsys.readouterr().err
    assert err.startswith("mocapdb stereo: error:") and "Traceback" not in err


def test_run_stereo_writes_stream_cameras_and_bvh(tmp_path, motion, capsys):
    positions = motion[:120]
    (cam1, cam2), (x1, c1), (x2, c2) = _views(positions, 0.0)
    _write_openpose(tmp_path / "v1", x1, c1)
    _write_openpose(tmp_path / "v2", x2, c2)
    distance = np.linalg.norm(cam1.center_m - cam2.center_m)
    out = tmp_path / "out"
    code = _stereo([str(tmp_path / "v1"), str(tmp_path / "v2"), "--out", str(out), "--focal", "1145",
                    "--size", "1000", "1000", "--camera-distance", f"{distance:.6f}", "--fps", "30"])
    assert code == 0
    printed = capsys.readouterr().out
    assert "frames 120" in printed and "kept round" in printed

    lines = (out / "result.jsonl").read_text().splitlines()
    header, frames = json.loads(lines[0]), [json.loads(line) for line in lines[1:]]
    assert header["format"] == "mocapdb-stream" and header["joints"] == list(KEYPOINTS)
    assert header["rotations"] == list(RIG_JOINTS) and header["fps"] == 30.0
    assert len(frames) == 120 and all(len(f["people"]) == 1 for f in frames)
    person = frames[5]["people"][0]
    assert person["track"] == 0 and person["match"] is None
    assert len(person["joints"]) == 15 and len(person["quaternions"]) == 11
    joints = np.array([f["people"][0]["joints"] for f in frames], dtype=np.float64)

    # The JSON joints are the truth in camera 1's camera-aligned frame (noise-free views).
    truth_cv = positions @ cam1.R.T + cam1.t
    np.testing.assert_allclose(joints, truth_cv @ CAMERA_ALIGNED, atol=0.02)

    cameras = json.loads((out / "cameras.json").read_text())
    assert cameras["scaled"] and cameras["baseline_m"] == pytest.approx(distance, rel=1e-6)
    assert len(cameras["cameras"]) == 2 and len(cameras["epsilons"]) >= 1
    rel = cam2.R @ cam1.R.T
    assert np.degrees(np.arccos((np.trace(np.array(cameras["cameras"][1]["R"]) @ rel.T) - 1) / 2)) < 1.0

    # The BVH (universal rig, levelled y-up world) maps back onto the JSON joints.
    bvh = read_bvh(out / "stereo.bvh")
    assert bvh.n_frames == 120 and bvh.fps == pytest.approx(30.0)
    world = extract_keypoints(bvh, detect_mapping(bvh))
    bvh_from_camera = np.array(cameras["bvh_from_camera1"])
    in_json_frame = world @ bvh_from_camera @ CAMERA_ALIGNED
    np.testing.assert_allclose(in_json_frame, joints, atol=0.005)
    up = world[:, KEYPOINTS.index("neck")] - world[:, KEYPOINTS.index("pelvis")]
    assert np.median(up[:, 1] / np.linalg.norm(up, axis=1)) > 0.99

    # `mocapdb build` takes the stereo BVH as a source like any other.
    db_dir = tmp_path / "db"
    assert main(["build", str(out / "stereo.bvh"), "--out", str(db_dir), "--clusters", "8",
                 "--landmarks", "100", "--workers", "1"]) == 0
    db = load_database(db_dir)
    assert db.n_frames > 50 and db.n_projections == 30 * db.n_frames


@pytest.mark.skipif(not POSE2SIM.is_dir(), reason="shared Pose2Sim data not present")
def test_real_pose2sim_pair(tmp_path, capsys):
    json_dir = POSE2SIM / "openpose_body25b"
    code = _stereo([str(json_dir / "cam01_json"), str(json_dir / "cam02_json"), "--out", str(tmp_path),
                    "--calibration", str(POSE2SIM / "calibration.toml"), "--cameras", "cam_01", "cam_02",
                    "--fps", "60", "--camera-distance", "2.85"])
    assert code == 0, capsys.readouterr().err
    frames = [json.loads(line) for line in (tmp_path / "result.jsonl").read_text().splitlines()[1:]]
    assert len(frames) == 100
    joints = np.array([f["people"][0]["joints"] if f["people"] else [[None] * 3] * 15 for f in frames],
                      dtype=np.float64)
    joints = joints @ CAMERA_ALIGNED  # back to a right-handed frame (camera 1's OpenCV axes)
    truth = trc_keypoints(read_trc(POSE2SIM / "triangulated_4cam.trc"))
    errors = eval_stereo.masked_pa_mpjpe(joints[:, :N_KEYPOINTS_2D], truth[:, :N_KEYPOINTS_2D],
                                         np.isfinite(joints[:, :N_KEYPOINTS_2D]).all(axis=-1))
    assert len(errors) >= 80 and np.mean(errors) < 0.06


@pytest.mark.skipif(not POSE2SIM.is_dir(), reason="shared Pose2Sim data not present")
def test_trc_reader_on_the_real_file():
    trc = read_trc(POSE2SIM / "triangulated_4cam.trc")
    assert trc.positions.shape == (100, 21, 3) and trc.rate_hz == 60.0
    assert trc.markers[:3] == ["RHip", "RKnee", "RAnkle"] and "Nose" in trc.markers
    assert trc.frame_numbers[0] == 1 and trc.times_s[1] == pytest.approx(2 / 60)
    points = trc_keypoints(trc)
    assert points.shape == (100, 15, 3) and np.isfinite(points).all()
    shoulders = trc.positions[:, [trc.markers.index("RShoulder"), trc.markers.index("LShoulder")]]
    np.testing.assert_allclose(points[:, KEYPOINTS.index("neck")], shoulders.mean(axis=1))
    ankles = points[:, [KEYPOINTS.index("r_ankle"), KEYPOINTS.index("l_ankle")], 1].min(axis=1)
    assert 1.3 < np.median(points[:, 0, 1] - ankles) < 1.9  # y up, metres


TRC = ("PathFileType\t4\t(X/Y/Z)\tx.trc\n"
       "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\n60\t60\t2\t2\tmm\n"
       "Frame#\tTime\tNose\t\t\tRHip\t\t\n\t\tX1\tY1\tZ1\tX2\tY2\tZ2\n\n"
       "1\t0.0\t1\t2\t3\t4\t5\t6\n2\t0.0166\t7\t8\t9\t\t\t\n")


def test_trc_reader_small_file_and_units():
    trc = parse_trc(TRC)
    assert trc.markers == ["Nose", "RHip"]
    np.testing.assert_allclose(trc.positions[0], [[0.001, 0.002, 0.003], [0.004, 0.005, 0.006]])
    assert np.isnan(trc.positions[1, 1]).all()


@pytest.mark.parametrize("text, message", [
    ("hello\n", "not a TRC file"),
    (TRC.replace("NumMarkers", "Markers"), "lacks NumMarkers"),
    (TRC.replace("\tmm\n", "\tfurlong\n"), "unit 'furlong'"),
    (TRC.replace("\tRHip\t\t\n", "\n"), "2 marker names, got 1"),
    (TRC.replace("5\t6\n", "5\n"), ":7: 7 values, expected 8"),
    (TRC.replace("\t8\t", "\tx\t"), ":8: non-numeric"),
    (TRC.replace("2\t0.0166\t7\t8\t9\t\t\t\n", ""), "only 1 are present"),
])
def test_trc_reader_malformed(text, message):
    with pytest.raises(TrcError, match=message):
        parse_trc(text, "bad.trc")


def test_a_head_no_camera_pair_sees_follows_the_torso(tmp_path, motion, capsys):
    positions = motion[:90]
    (cam1, cam2), (x1, c1), (x2, c2) = _views(positions, 0.5)
    c2[:, KEYPOINTS.index("head")] = 0.0                 # camera 2 films the back of the head
    _write_openpose(tmp_path / "v1", x1, c1)
    _write_openpose(tmp_path / "v2", x2, c2)
    out = tmp_path / "out"
    assert _stereo([str(tmp_path / "v1"), str(tmp_path / "v2"), "--out", str(out), "--focal", "1145",
                    "--size", "1000", "1000", "--fps", "30"]) == 0
    assert "the head follows the torso" in capsys.readouterr().out
    frames = [json.loads(line) for line in (out / "result.jsonl").read_text().splitlines()[1:]]
    assert all(f["people"][0]["joints"][KEYPOINTS.index("head")] == [None, None, None] for f in frames)
    world = extract_keypoints(read_bvh(out / "stereo.bvh"), detect_mapping(read_bvh(out / "stereo.bvh")))
    head_up = world[:, KEYPOINTS.index("head"), 1] - world[:, KEYPOINTS.index("neck"), 1]
    assert np.all(head_up > 0.1)                          # above the neck, as in the rest pose
