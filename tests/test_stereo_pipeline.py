"""`mocapdb stereo`: person selection, several people, loading checks, outputs (JSON lines, cameras, BVH),
real data, TRC."""
import json
import os
import re
import shutil
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from mocapdb.cli.main import main
from mocapdb.core.cameras import CalibrationError, CameraModel, format_calibration_toml, read_calibration_toml
from mocapdb.core.clips import ClipOptions, process_clip
from mocapdb.core.formats.bvh import read_bvh
from mocapdb.core.formats.database_reader import load_database
from mocapdb.core.formats.keypoints import KeypointFrame, Person
from mocapdb.core.formats.take import TakeInfo, write_take
from mocapdb.core.formats.trc import TrcError, parse_trc, read_trc, trc_keypoints
from mocapdb.core.joint_map import detect_mapping, extract_keypoints
from mocapdb.core.skeleton import KEYPOINTS, N_KEYPOINTS_2D, RIG_JOINTS
from mocapdb.evaluation import stereo as eval_stereo
from mocapdb.stereo import StereoConfig, StereoError
from mocapdb.stereo import outputs as stereo_outputs
from mocapdb.stereo import views as stereo_views
from mocapdb.stereo.epipolar_pairs import MIRROR
from mocapdb.stereo.motion import CAMERA_ALIGNED, in_front_check
from mocapdb.stereo.people import match_people
from mocapdb.stereo.pipeline import select_people
from mocapdb.stereo.relative_pose import rotation_angle_deg
from mocapdb.stereo.views import load_views

from .conftest import REAL_TAKE, SAMPLE_BVH, SAMPLE_KEYPOINTS

POSE2SIM = REAL_TAKE


@pytest.fixture(scope="module")
def motion():
    """A bundled clip (sideways dance steps, a pirouette) on the universal skeleton, 30 fps:
    positions ``[148, 15, 3]`` m, y up."""
    clip = process_clip(SAMPLE_BVH / "005_11.bvh", SAMPLE_BVH, ClipOptions(fps=30.0))
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


def test_a_body_split_in_two_detections_is_put_back_together(motion):
    """OpenPose split a body (the Pose2Sim take, camera 1, frame 37): upper and lower half as two
    detections of one frame. Both halves lie on the other view's person: they are one body again. A
    half that does not (another person's legs, 150 px lower) is not joined and is reported."""
    (cam1, cam2), (x1, c1), (x2, c2) = _views(motion[:90], 1.0)
    upper = np.arange(N_KEYPOINTS_2D) < 7
    frames1 = _frames(x1, c1)
    for t in (10, 11, 40):
        frames1[t] = KeypointFrame(t, None, [Person(x1[t], np.where(upper, 0.0, c1[t])),
                                             Person(x1[t], np.where(upper, c1[t], 0.0))])
    frames1[60] = KeypointFrame(60, None, [Person(x1[60], np.where(upper, c1[60], 0.0)),
                                           Person(x1[60] + [0.0, 150.0], np.where(upper, 0.0, c1[60]))])
    people = match_people(frames1, _frames(x2, c2), cam1, cam2, StereoConfig())
    selection = people.persons[0]
    assert len(people.persons) == 1 and selection.kept.all()
    for t in (10, 11, 40):
        np.testing.assert_array_equal(selection.x1[t], x1[t])
        np.testing.assert_array_equal(selection.c1[t], c1[t])
    assert (selection.c1[60][~upper] == 0).all()  # the legs 150 px off are not joined
    assert selection.correspondences == int(((selection.c1 > 0) & (selection.c2 > 0)).sum())
    assert len(people.unmatched) == 1 and "1 detections in 1 frames (frames 60)" in people.unmatched[0]


def test_a_still_person_far_behind_and_a_biased_moving_one_are_both_matched(motion):
    """The demo video's cameras 1 and 2 (issue 19): a still person far behind, and a moving one whose detections
    a camera geometry fits only to several pixels (a detector's systematic, viewpoint-dependent error; here view 2
    sees the moving person as a camera turned 2° would). Each one's own essential matrix misses the other, so the
    matching kept the still person alone (on the demo then refused as having no parallax); the two together propose
    the matrix that fits both. The moving one is the main person (track 0) although the still one has more joints
    seen by both views."""
    positions = motion[:90]
    cam1, cam2 = eval_stereo.pair_cameras("front", positions.mean(axis=(0, 1)))
    turn = cv2.Rodrigues(np.array([np.radians(2.0), 0.0, 0.0]))[0]
    biased = CameraModel(cam2.K, cam2.dist, turn @ cam2.R, turn @ cam2.t, cam2.size)
    centre = positions.mean(axis=(0, 1))
    away = centre - 0.5 * (cam1.center_m + cam2.center_m)
    away = away * [1.0, 0.0, 1.0] / np.linalg.norm(away * [1.0, 0.0, 1.0])
    place = centre + 10.0 * away + np.cross(away, [0.0, 1.0, 0.0])     # 10 m behind, 1 m aside
    still = np.repeat(positions[40:41] - positions[40].mean(axis=0) + place, len(positions), axis=0)
    rng = np.random.default_rng(0)
    (x1, c1), (x2, c2) = (eval_stereo.render(positions, cam, rng, 3.0, 0.0) for cam in (cam1, biased))
    c1[:, HEAD] = 0.0                                                  # its nose never seen by camera 1
    (s1, k1), (s2, k2) = (eval_stereo.render(still, cam, rng, 1.0, 0.0) for cam in (cam1, cam2))
    people = match_people(_frames(x1, c1, [(s1, k1)]), _frames(x2, c2, [(s2, k2)]), cam1, cam2, StereoConfig())
    assert len(people.persons) == 2 and all(p.kept.all() for p in people.persons)
    main_person, behind = people.persons
    np.testing.assert_array_equal(main_person.x2, x2)
    np.testing.assert_array_equal(behind.x2, s2)
    assert not main_person.still and behind.still and main_person.correspondences < behind.correspondences


def test_a_still_track_never_pairs_with_a_moving_one(motion):
    """An essential matrix fitted to a still person of one view and a moving one of the other puts every moving
    joint on its fixed epipolar line (the demo video: camera 2's still woman behind paired with camera 4's
    performer, consistent in 99 of 100 frames, beat the true pairing's 72). Here view 2's person slides sideways
    at the still one's heights, exactly on the epipolar lines of a sideways baseline: no one, both reported."""
    (cam1, _), (x1, c1), _ = _views(motion[:60], 0.0)
    pose = x1[30]
    rng = np.random.default_rng(0)
    still = pose + rng.normal(0.0, 0.5, x1.shape)
    slide = 80.0 * np.sin(np.arange(60)[:, None] / 6.0 + np.arange(N_KEYPOINTS_2D)[None] / 3.0)
    moving = pose + np.stack([slide, np.zeros_like(slide)], axis=-1)
    people = match_people(_frames(still, c1), _frames(moving, c1), cam1, cam1, StereoConfig())
    assert people.persons == [] and len(people.unmatched) == 2


def test_noisy_detections_of_linked_tracks_are_kept(motion):
    """A noisier detector (YOLO11n-pose on the demo video: the true pairs 10-15 px off the epipolar geometry,
    a lunge up to 36-43 px) spreads a person's frames beyond the 20 px that finds who is who; once the two 2D
    tracks are linked, every frame of theirs within 4 times their median is that person (here σ 12 px, and
    frames 30-39 with view 2's arm and legs 60 px off: they were lost)."""
    positions = motion[:90]
    cam1, cam2 = eval_stereo.pair_cameras("front", positions.mean(axis=(0, 1)))
    rng = np.random.default_rng(1)
    (x1, c1), (x2, c2) = (eval_stereo.render(positions, cam, rng, 12.0, 0.0) for cam in (cam1, cam2))
    x2[30:40, 5:] += [0.0, 60.0]
    selection = select_people(_frames(x1, c1), _frames(x2, c2), cam1, cam2, StereoConfig())
    assert selection.kept.all() and selection.dropped == {}
    assert np.nanmax(selection.distance_px[30:40]) > 20
    np.testing.assert_array_equal(selection.x2, x2)


def test_a_detection_with_left_and_right_swapped_is_turned_back(motion):
    """A detector sometimes swaps a body's left and right (the demo video: camera 1's frame 87, camera 2's 10 and
    81); the pair is then consistent only with them swapped back. The frames were lost; now the detection of the
    view that the swap brings closer to its own 2D track is turned back."""
    positions = motion[:90]
    cam1, cam2 = eval_stereo.pair_cameras("front", positions.mean(axis=(0, 1)))
    rng = np.random.default_rng(0)
    (x1, c1), (x2, c2) = (eval_stereo.render(positions, cam, rng, 2.0, 0.0) for cam in (cam1, cam2))
    flipped1, flipped2 = x1.copy(), x2.copy()
    flipped1[68] = x1[68][MIRROR]
    flipped2[[65, 71]] = x2[[65, 71]][:, MIRROR]
    selection = select_people(_frames(flipped1, c1), _frames(flipped2, c2), cam1, cam2, StereoConfig())
    assert selection.kept.all()
    np.testing.assert_array_equal(selection.x1, x1)
    np.testing.assert_array_equal(selection.x2, x2)


def test_mismatched_frame_counts(tmp_path, motion, capsys):
    (_, _), (x1, c1), (x2, c2) = _views(motion[:6], 0.0)
    _write_openpose(tmp_path / "a", x1, c1)
    _write_openpose(tmp_path / "b", x2[:5], c2[:5])
    with pytest.raises(StereoError, match=r"has 6 frames, view 2 .* has 5.*--trim"):
        load_views(tmp_path / "a", tmp_path / "b")
    frames1, frames2, warnings = load_views(tmp_path / "a", tmp_path / "b", trim=True)
    assert len(frames1) == len(frames2) == 5 and "trimmed" in warnings[0]
    code = _stereo([str(tmp_path / "a"), str(tmp_path / "b"), "--out", str(tmp_path / "out"),
                    "--focal", "1145", "--image-size", "1000x1000"])
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
                    "--image-size", "1000x1000", "--camera-distance", f"{distance:.6f}", "--fps", "30"])
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
    assert cameras["converged"] == (min(cameras["epsilons"]) < StereoConfig().epsilon)
    rel = cam2.R @ cam1.R.T
    assert np.degrees(np.arccos((np.trace(np.array(cameras["cameras"][1]["R"]) @ rel.T) - 1) / 2)) < 1.0

    # The same two cameras for Pose2Sim: calibration.toml in a z-up world, origin at camera 1.
    calibration = list(read_calibration_toml(out / "calibration.toml").values())
    assert len(calibration) == 2 and np.allclose(calibration[0].t, 0.0)
    np.testing.assert_allclose(calibration[1].R @ calibration[0].R.T, cameras["cameras"][1]["R"], atol=1e-9)
    assert np.linalg.norm(calibration[1].center_m) == pytest.approx(distance, rel=1e-6)
    in_world = (joints @ CAMERA_ALIGNED) @ calibration[0].R  # camera 1 → world (x_w = R1ᵀ x_1)
    up_world = in_world[:, KEYPOINTS.index("neck")] - in_world[:, KEYPOINTS.index("pelvis")]
    assert np.median(up_world[:, 2] / np.linalg.norm(up_world, axis=1)) > 0.99

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


def test_stereo_reads_each_views_take_description(tmp_path, motion, capsys, caplog):
    """Frame rate and image size from each view folder's take.json (what `mocapdb detect` writes);
    options that contradict it, and views whose rates differ, are refused naming both."""
    (_, _), (x1, c1), (x2, c2) = _views(motion[:90], 0.0)
    v1, v2 = tmp_path / "v1", tmp_path / "v2"
    for folder, x, c in ((v1, x1, c1), (v2, x2, c2)):
        _write_openpose(folder, x, c)
    with caplog.at_level("WARNING", logger="mocapdb"):
        assert _stereo([str(v1), str(v2), "--focal", "1145", "--image-size", "1000x1000",
                        "--out", str(tmp_path / "bare")]) == 0
    assert "no frame rate given: the views were taken as 30 Hz" in caplog.text
    for folder in (v1, v2):
        write_take(folder, TakeInfo(fps=25.0, image_size=(1000, 1000), frames=90, source="cam.mp4"))
    caplog.clear()
    with caplog.at_level("WARNING", logger="mocapdb"):
        assert _stereo([str(v1), str(v2), "--focal", "1145", "--out", str(tmp_path / "out")]) == 0
    assert "no frame rate" not in caplog.text
    assert json.loads((tmp_path / "out" / "result.jsonl").read_text().splitlines()[0])["fps"] == 25.0
    assert json.loads((tmp_path / "out" / "cameras.json").read_text())["cameras"][0]["size"] == [1000, 1000]
    out, _ = tmp_path / "refused", capsys.readouterr()
    _refused([str(v1), str(v2), "--focal", "1145", "--fps", "60"], capsys, out,
             f"--fps 60 contradicts {v1 / 'take.json'}, which says 25")
    _refused([str(v1), str(v2), "--focal", "1145", "--image-size", "1920x1080"], capsys, out,
             f"--image-size 1920x1080 contradicts {v1 / 'take.json'}, which says 1000x1000")
    _refused([str(v1), str(v2)], capsys, out, "give the intrinsics", "take.json give --focal PX")
    _refused([str(v1), str(v2), "--calibration", str(CALIBRATION), "--cameras", "cam_01", "cam_04"], capsys, out,
             f"the image size of cam_01 in {CALIBRATION} 1088x1920 contradicts {v1 / 'take.json'}, which says "
             "1000x1000: correct one of them")
    write_take(v2, TakeInfo(fps=50.0, image_size=(1000, 1000), frames=90, source="cam2.mp4"))
    _refused([str(v1), str(v2), "--focal", "1145"], capsys, out,
             f"{v1}/take.json says 25 Hz, {v2}/take.json says 50 Hz: the views must be synchronised")


def test_every_real_pair_keeps_every_frame_and_joint_both_views_see():
    """Issue 19, item 3 (tools/eval_stereo_pairs.py): on all 6 pairs of the Pose2Sim take, no frame where
    both views see the person is lost (target ≤ 2 %), and no joint both see is written null (camera 1's
    frame 37 holds the body split in two detections)."""
    from mocapdb.evaluation.stereo_pairs import TARGET_MISSING, all_pairs

    rows = all_pairs(POSE2SIM)
    assert len(rows) == 6
    for row in rows:
        assert row.both_see >= 95 and row.missing <= TARGET_MISSING and row.null_seen == 0, row


def test_pairs_of_keypoint_folders_are_scored_against_the_calibration(tmp_path, motion):
    """tools/eval_stereo_pairs.py --views ... --calibration ... (issue 19, item 3): without a TRC the reference
    is the person the most views agree on under the calibration's cameras, triangulated from all of them; a
    still person seen by two cameras only and a detection with left and right swapped change nothing. Every
    pair then runs through `mocapdb stereo` and is scored against it."""
    from mocapdb.evaluation.stereo_pairs import calibrated_pairs, reference_person

    positions = motion[:90]
    target = positions.mean(axis=(0, 1))
    cams = [eval_stereo.look_at(target + [4.6 * np.cos(np.radians(a)), 1.7 - target[1], 4.6 * np.sin(np.radians(a))],
                                target, f"cam{k}") for k, a in enumerate((-60.0, -120.0, 150.0), start=1)]
    rng = np.random.default_rng(0)
    views = [eval_stereo.render(positions, cam, rng, 1.0, 0.0) for cam in cams]
    bystander = np.repeat(positions[:1] + [0.0, 0.0, 2.5], len(positions), axis=0)  # behind, seen by cameras 1, 2
    frames = [_frames(x, c, [eval_stereo.render(bystander, cam, rng, 1.0, 0.0)] if k < 2 else [])
              for k, ((x, c), cam) in enumerate(zip(views, cams))]
    frames[2][40].people[0] = Person(views[2][0][40][MIRROR], views[2][1][40][MIRROR])
    reference = reference_person(frames, cams, StereoConfig().confidence)
    assert np.abs(reference[:, :N_KEYPOINTS_2D] - positions[:, :N_KEYPOINTS_2D]).max() < 0.02

    folders = []
    for k, (x, c) in enumerate(views, start=1):
        _write_openpose(tmp_path / f"cam{k}", x, c)
        folders.append(tmp_path / f"cam{k}")
    (tmp_path / "calibration.toml").write_text(format_calibration_toml(cams))
    rows = calibrated_pairs(folders, tmp_path / "calibration.toml", ["cam1", "cam2", "cam3"], 30.0)
    assert [r.pair for r in rows] == ["cam1–cam2", "cam1–cam3", "cam2–cam3"]
    for row in rows:
        assert row.both_see == 90 and row.reconstructed == 90 and not row.refused, row
        assert row.rotation_error_deg < 2.0 and row.pa_mpjpe_mm < 30.0, row


def test_real_pose2sim_pair(tmp_path, capsys):
    json_dir = POSE2SIM / "openpose_body25b"
    code = _stereo([str(json_dir / "cam01_json"), str(json_dir / "cam02_json"), "--out", str(tmp_path),
                    "--calibration", str(POSE2SIM / "calibration.toml"), "--cameras", "cam_01", "cam_02",
                    "--fps", "60", "--camera-distance", "2.85"])
    assert code == 0, capsys.readouterr().err
    frames = [json.loads(line) for line in (tmp_path / "result.jsonl").read_text().splitlines()[1:]]
    assert len(frames) == 100
    main = [[p for p in f["people"] if p["track"] == 0] for f in frames]
    assert sum(bool(m) for m in main) == 100
    joints = np.array([m[0]["joints"] for m in main], dtype=np.float64)
    joints = joints @ CAMERA_ALIGNED  # back to a right-handed frame (camera 1's OpenCV axes)
    assert np.isfinite(joints[:, KEYPOINTS.index("head")]).all(axis=-1).sum() >= 98  # both see the nose
    # A static partial figure at the image edge that both cameras see consistently is a second
    # person: joints only (its neck is never seen), no BVH.
    tracks = json.loads((tmp_path / "cameras.json").read_text())["tracks"]
    assert [(t["track"], t["bvh"]) for t in tracks] == [(0, "stereo.bvh"), (1, None)]
    truth = trc_keypoints(read_trc(POSE2SIM / "triangulated_4cam.trc"))
    errors = eval_stereo.masked_pa_mpjpe(joints[:, :N_KEYPOINTS_2D], truth[:, :N_KEYPOINTS_2D],
                                         np.isfinite(joints[:, :N_KEYPOINTS_2D]).all(axis=-1))
    assert len(errors) >= 80 and np.mean(errors) < 0.06


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
                    "--image-size", "1000x1000", "--fps", "30"]) == 0
    assert "the head follows the torso" in capsys.readouterr().out
    frames = [json.loads(line) for line in (out / "result.jsonl").read_text().splitlines()[1:]]
    assert all(f["people"][0]["joints"][KEYPOINTS.index("head")] == [None, None, None] for f in frames)
    world = extract_keypoints(read_bvh(out / "stereo.bvh"), detect_mapping(read_bvh(out / "stereo.bvh")))
    head_up = world[:, KEYPOINTS.index("head"), 1] - world[:, KEYPOINTS.index("neck"), 1]
    assert np.all(head_up > 0.1)                          # above the neck, as in the rest pose


# --------------------------------------------------------------------------- several people

# BODY_25B index of each universal keypoint (the neck is the shoulders' midpoint, not written).
BODY25B_OF = {0: 0, 2: 6, 3: 8, 4: 10, 5: 5, 6: 7, 7: 9, 8: 12, 9: 14, 10: 16, 11: 11, 12: 13, 13: 15}
HEAD, NECK = KEYPOINTS.index("head"), KEYPOINTS.index("neck")


def _render_body25b(positions, cam, rng, noise_px=1.0):
    """OpenPose BODY_25B keypoints ``[T, 25, 3]`` of ``positions [T, 15, 3]`` (m) seen by ``cam``:
    the universal joints, an upper neck and a head top on the neck → nose line, the face and feet
    left undetected (0, 0, 0); 1 px noise; confidence 0.9 inside the image."""
    pts = np.zeros((len(positions), 25, 3))
    for u, b in BODY25B_OF.items():
        pts[:, b] = positions[:, u]
    up = positions[:, HEAD] - positions[:, NECK]
    pts[:, 17], pts[:, 18] = positions[:, NECK] + 0.4 * up, positions[:, NECK] + 1.5 * up
    used = sorted(BODY25B_OF.values()) + [17, 18]
    px = cam.project(pts) + rng.normal(0.0, noise_px, pts.shape[:2] + (2,))
    inside = np.all((px >= 0) & (px < np.array(cam.size)), axis=-1) & ((pts @ cam.R.T + cam.t)[..., 2] > 0)
    raw = np.zeros((len(positions), 25, 3))
    raw[:, used, :2], raw[:, used, 2] = px[:, used], 0.9
    raw[~inside] = 0.0
    return raw


def _write_body25b(folder, people_per_frame):
    """One OpenPose JSON per frame; each frame's list of ``[25, 3]`` arrays, or None for Pose2Sim's empty entry."""
    folder.mkdir(parents=True)
    for t, people in enumerate(people_per_frame):
        entries = [{"person_id": [-1], "pose_keypoints_2d": [] if raw is None else raw.ravel().tolist()}
                   for raw in people]
        (folder / f"scene_{t:012d}_keypoints.json").write_text(json.dumps({"version": 1.3, "people": entries}))


@pytest.fixture(scope="module")
def scene():
    """Two CMU clips in one scene, 120 frames at 30 fps: a dancer (005_11) and, 2.6 m away, a jumper
    (002_04): positions ``[2, T, 15, 3]`` m, y up; and two cameras 6.5 m from them, 90° apart, that
    see both people apart (≥ 150 px between their boxes) and whole."""
    a = process_clip(SAMPLE_BVH / "005_11.bvh", SAMPLE_BVH, ClipOptions(fps=30.0)).positions[:120]
    b = process_clip(SAMPLE_BVH / "002_04.bvh", SAMPLE_BVH, ClipOptions(fps=30.0)).positions[:120]
    positions = np.stack([a, b + [2.25, 0.0, -1.3]]).astype(np.float64)
    target = positions.mean(axis=(0, 1, 2))
    cams = [eval_stereo.look_at(target + [6.5 * np.cos(np.radians(az)), height - target[1],
                                          6.5 * np.sin(np.radians(az))], target, f"cam{k}")
            for k, (az, height) in enumerate(((20.0, 1.6), (-70.0, 1.9)), start=1)]
    return positions, cams


def test_two_people_each_get_a_track_and_a_bvh(tmp_path, scene, capsys):
    two_people, (cam1, cam2) = scene
    n = two_people.shape[1]
    rng = np.random.default_rng(3)
    raw1 = [_render_body25b(p, cam1, rng) for p in two_people]
    raw2 = [_render_body25b(p, cam2, rng) for p in two_people]
    assert all((r[:, list(BODY25B_OF.values()), 2] > 0).all() for r in raw1 + raw2)  # every joint in both views
    raw2[1][30:40, 0] = 0.0          # camera 2 loses person B's nose for 10 frames
    gone = range(60, 64)             # and person B altogether for 4 frames (a gap its 2D track bridges)
    # A false detection in view 1 only, frames 20-79: person A's pose of another moment, half size,
    # above and between the two people.
    decoy = raw1[0][np.arange(n) - 37].copy()
    centre = decoy[:, :, :2].sum(axis=1, keepdims=True) / (decoy[:, :, 2:] > 0).sum(axis=1, keepdims=True)
    decoy[..., :2] = np.where(decoy[..., 2:] > 0, 0.5 * (decoy[..., :2] - centre) + [540.0, 180.0], 0.0)
    frames1, frames2 = [], []
    for t in range(n):
        people1 = [raw1[0][t], None, raw1[1][t]] + ([decoy[t]] if 20 <= t < 80 else [])
        people2 = [None, raw2[0][t]] + ([] if t in gone else [raw2[1][t]])
        frames1.append(people1[::-1] if t % 2 else people1)  # the order of the entries means nothing
        frames2.append(people2[::-1] if t % 3 else people2)
    _write_body25b(tmp_path / "v1", frames1)
    _write_body25b(tmp_path / "v2", frames2)
    out = tmp_path / "out"
    distance = np.linalg.norm(cam1.center_m - cam2.center_m)
    assert _stereo([str(tmp_path / "v1"), str(tmp_path / "v2"), "--out", str(out), "--focal", "1145",
                    "--image-size", "1000x1000", "--camera-distance", f"{distance:.6f}", "--fps", "30"]) == 0
    printed = capsys.readouterr().out
    assert "people 2" in printed and "not a person: view 1: 1 2D track(s), 60 detections" in printed

    # One track per person, the same person throughout; every joint both views see is there.
    frames = [json.loads(line) for line in (out / "result.jsonl").read_text().splitlines()[1:]]
    truth = two_people @ cam1.R.T + cam1.t  # camera 1's OpenCV axes
    tracks = {}
    for t, f in enumerate(frames):
        assert sorted(p["track"] for p in f["people"]) == ([0] if t in gone else [0, 1])
        for p in f["people"]:
            joints = np.array(p["joints"], dtype=np.float64) @ CAMERA_ALIGNED
            errors = np.linalg.norm(joints[None] - truth[:, t], axis=-1)  # against both people
            who = int(np.argmin(np.nanmedian(errors, axis=1)))
            tracks.setdefault(p["track"], set()).add(who)
            null = sorted(np.flatnonzero(np.isnan(joints).any(axis=1)))
            assert null == ([HEAD] if who == 1 and 30 <= t < 40 else []), (t, p["track"])  # seen by one view
            assert np.nanmax(errors[who]) < 0.1
    assert len(tracks[0]) == 1 and len(tracks[1]) == 1 and tracks[0] != tracks[1]

    cameras = json.loads((out / "cameras.json").read_text())
    rel = cam2.R @ cam1.R.T
    assert rotation_angle_deg(np.array(cameras["cameras"][1]["R"]) @ rel.T) < 2.0
    assert [t["bvh"] for t in cameras["tracks"]] == ["stereo.bvh", "stereo_track_1.bvh"]
    assert sorted(t["frames"] for t in cameras["tracks"]) == [n - len(gone), n]
    assert len(cameras["not_people"]) == 1 and cameras["dropped_frames"] == {}

    # A BVH per person, both in one levelled world: each maps back onto its own JSON joints.
    bvh_from_camera = np.array(cameras["bvh_from_camera1"])
    for track, name in ((0, "stereo.bvh"), (1, "stereo_track_1.bvh")):
        bvh = read_bvh(out / name)
        assert bvh.n_frames == n
        world = extract_keypoints(bvh, detect_mapping(bvh)) @ bvh_from_camera @ CAMERA_ALIGNED
        mine = [(t, p) for t, f in enumerate(frames) for p in f["people"] if p["track"] == track]
        pelvis = np.array([p["root"] for _, p in mine])
        np.testing.assert_allclose(world[[t for t, _ in mine], KEYPOINTS.index("pelvis")], pelvis, atol=0.005)


def test_matching_pairs_each_person_across_views_and_reports_a_lone_one(scene):
    """The matching itself: both people paired right whatever the order of the entries, a person
    seen by camera 1 only reported, not reconstructed."""
    two_people, (cam1, cam2) = scene
    (x1a, c1a), (x1b, c1b) = (eval_stereo.render(p, cam1, np.random.default_rng(0), 1.0, 0.0) for p in two_people)
    (x2a, c2a), (x2b, c2b) = (eval_stereo.render(p, cam2, np.random.default_rng(1), 1.0, 0.0) for p in two_people)
    n = len(x1a)
    lone, lone_c = x1a[::-1] + [300.0, 0.0], c1a[::-1]  # another moment of person A, 300 px to the right
    frames1 = [KeypointFrame(t, None, [Person(x1b[t], c1b[t]), Person(lone[t], lone_c[t]), Person(x1a[t], c1a[t])])
               for t in range(n)]
    frames2 = [KeypointFrame(t, None, [Person(x2a[t], c2a[t]), Person(x2b[t], c2b[t])][::(-1) ** t])
               for t in range(n)]
    people = match_people(frames1, frames2, cam1, cam2, StereoConfig())
    assert [p.track for p in people.persons] == [0, 1] and people.dropped == {}
    assert all(p.kept.all() for p in people.persons)
    is_b = [np.array_equal(p.x1, x1b, equal_nan=True) for p in people.persons]
    assert sorted(is_b) == [False, True]
    for p, b in zip(people.persons, is_b):
        np.testing.assert_array_equal(p.x1, x1b if b else x1a)
        np.testing.assert_array_equal(p.x2, x2b if b else x2a)
    assert len(people.unmatched) == 1 and people.unmatched[0].startswith("view 1: 1 2D track(s), 120 detections")


def test_bundled_pose2sim_pair_one_person_good_camera(tmp_path, capsys):
    """The quickstart's pair (camera 1 has a false second person; camera 4 never sees the nose)."""
    calibration = SAMPLE_KEYPOINTS.parent / "calibration.toml"
    code = _stereo([str(SAMPLE_KEYPOINTS), str(SAMPLE_KEYPOINTS.parent / "pose2sim_cam04"), "--out", str(tmp_path),
                    "--calibration", str(calibration), "--cameras", "cam_01", "cam_04", "--fps", "60",
                    "--camera-distance", "5.24"])
    assert code == 0, capsys.readouterr().err
    assert "not a person: view 1" in capsys.readouterr().out
    cameras = json.loads((tmp_path / "cameras.json").read_text())
    tracks = [(t["track"], t["frames"], t["first_frame"], t["last_frame"]) for t in cameras["tracks"]]
    assert tracks == [(0, 100, 0, 99)]
    assert sorted(p.name for p in tmp_path.glob("*.bvh")) == ["stereo.bvh"]
    cams = read_calibration_toml(calibration)
    rel = cams["cam_04"].R @ cams["cam_01"].R.T
    assert rotation_angle_deg(np.array(cameras["cameras"][1]["R"]) @ rel.T) < 3.0


# --------------------------------------------------------------------------- sanity checks (issue 13)

BUNDLED = SAMPLE_KEYPOINTS.parent
CALIBRATION = BUNDLED / "calibration.toml"
BUNDLED_ARGS = ["--calibration", str(CALIBRATION), "--cameras", "cam_01", "cam_04", "--fps", "60"]


def _refused(argv, capsys, out, *messages):
    """The command exits 2 with each message on stderr, no traceback, and writes nothing."""
    assert _stereo([*argv, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("mocapdb stereo: error: ") and "Traceback" not in err
    for message in messages:
        assert message in err, err
    assert not out.exists()
    return err


def test_the_same_folder_twice_is_refused(tmp_path, capsys):
    link = tmp_path / "link"
    link.symlink_to(BUNDLED / "pose2sim_cam04", target_is_directory=True)
    for second in (str(BUNDLED / "pose2sim_cam04"), str(BUNDLED / "pose2sim_cam04") + "/", str(link)):
        _refused([str(BUNDLED / "pose2sim_cam04"), second, *BUNDLED_ARGS], capsys, tmp_path / "out",
                 "view 1 and view 2 are the same folder", "no parallax")


def test_copied_keypoints_are_refused(tmp_path, motion, capsys):
    """A copy of a view (here with 1 px of noise, as the same video detected twice) is the same view."""
    (_, _), (x1, c1), _ = _views(motion[:60], 1.0)
    _write_openpose(tmp_path / "a", x1, c1)
    _write_openpose(tmp_path / "b", x1 + np.random.default_rng(5).normal(0.0, 1.0, x1.shape), c1)
    with pytest.raises(StereoError, match="hold the same keypoints: .* in 60 of the 60 frames"):
        load_views(tmp_path / "a", tmp_path / "b")
    shutil.copytree(BUNDLED / "pose2sim_cam01", tmp_path / "cam01_copy")
    _refused([str(BUNDLED / "pose2sim_cam01"), str(tmp_path / "cam01_copy"), *BUNDLED_ARGS], capsys,
             tmp_path / "out", "hold the same keypoints", "in 100 of the 100 frames")


@pytest.mark.parametrize("change", ["shifted", "scaled", "mirrored"])
def test_a_transformed_copy_has_no_parallax(tmp_path, motion, capsys, change):
    """The same view shifted, scaled or mirrored is not a copy, but one homography maps it: no parallax."""
    (_, _), (x1, c1), _ = _views(motion[:90], 1.0)
    x2 = {"shifted": x1 + [60.0, 25.0], "scaled": 500.0 + 1.15 * (x1 - 500.0),
          "mirrored": np.stack([1000.0 - x1[..., 0], x1[..., 1]], axis=-1)}[change]
    _write_openpose(tmp_path / "a", x1, c1)
    _write_openpose(tmp_path / "b", x2, c1)
    _refused([str(tmp_path / "a"), str(tmp_path / "b"), "--focal", "1145", "--image-size", "1000x1000"], capsys,
             tmp_path / "out", "the two views have no parallax: one homography maps view 1's keypoints")


@pytest.mark.parametrize("options, message", [
    (["--focal", "-1000", "--image-size", "1088x1920"], "argument --focal: '-1000': must be a focal length in pixels"),
    (["--focal", "0", "--image-size", "1088x1920"], "argument --focal: '0': must be a focal length in pixels"),
    (["--focal", "nan", "--image-size", "1088x1920"], "argument --focal: 'nan': must be a focal length in pixels"),
    (["--focal", "1000", "--image-size", "0x0"], "argument --image-size: '0x0': width and height must each be a whole"),
    (["--focal", "1000", "--image-size", "5x10"], "argument --image-size: '5x10': width and height must each be"),
    (["--focal", "1000", "--image-size", "1088x1920", "--center", "nan", "5"],
     "argument --center: 'nan': must be a pixel coordinate"),
    (["--image-size", "1088x1920", "--center", "5000", "10"],  # the focal: each folder's take.json
     "principal point (5000, 10) px is far outside the 1088 × 1920 px image"),
    ([*BUNDLED_ARGS, "--camera-distance", "0"], "argument --camera-distance: '0': must be a distance"),
    ([*BUNDLED_ARGS, "--camera-distance", "-5"], "argument --camera-distance: '-5': must be a distance"),
    ([*BUNDLED_ARGS, "--camera-distance", "inf"], "argument --camera-distance: 'inf': must be a distance"),
    ([*BUNDLED_ARGS, "--focal", "1000"], "--calibration gives the intrinsics: leave out --focal"),
    (["--cameras", "cam_01", "cam_04", "--focal", "1000", "--image-size", "900x900"], "--cameras names cameras of"),
    (["--calibration", str(CALIBRATION), "--cameras", "cam_01", "cam_09"],
     "has no camera cam_09 (it has cam_01, cam_02, cam_03, cam_04)"),
])
def test_bad_options_are_refused_before_any_work(tmp_path, capsys, options, message):
    _refused([str(BUNDLED / "pose2sim_cam01"), str(BUNDLED / "pose2sim_cam04"), *options], capsys,
             tmp_path / "out", message)


CAM_01 = CALIBRATION.read_text().split("[cam_02]")[0]   # one section, as written by Pose2Sim
GOOD_MATRIX = ("[ [ 1681.244873046875, 0.0, 532.97369384375], [ 0.0, 1681.075439453125, 948.137390140625], "
               "[ 0.0, 0.0, 1.0]]")


@pytest.mark.parametrize("matrix, size, message", [
    ("[[0, 0, 0], [0, 0, 0], [0, 0, 0]]", None, "is singular (no inverse)"),
    ("[[1000, 0, 500], [2000, 0, 900], [0, 0, 1]]", None, "is singular (no inverse)"),
    ("[[nan, 0, 500], [0, 1000, 900], [0, 0, 1]]", None, "'matrix' holds a non-finite value"),
    ("[[inf, 0, 500], [0, 1000, 900], [0, 0, 1]]", None, "'matrix' holds a non-finite value"),
    ("[[-1000, 0, 500], [0, 1000, 900], [0, 0, 1]]", None, "focal lengths fx = -1000, fy = 1000 px must be positive"),
    ("[[1000, 0, 500], [0, 1000, 900], [0, 0, 2]]", None, "last row is [0., 0., 2.], not [0, 0, 1]"),
    ("[[1000, 0, 9000], [0, 1000, 900], [0, 0, 1]]", None,
     "principal point (9000, 900) px is far outside the 1088 × 1920 px image"),
    (GOOD_MATRIX, "[ 0.0, 1920.0]", "image size 0 × 1920 px is not two positive numbers"),
])
def test_unusable_camera_matrices_are_refused(tmp_path, capsys, matrix, size, message):
    text = CAM_01.replace(GOOD_MATRIX, matrix)
    if size:
        text = text.replace("size = [ 1088.0, 1920.0]", f"size = {size}")
    assert text != CAM_01
    path = tmp_path / "calibration.toml"
    path.write_text(text + CALIBRATION.read_text()[len(CAM_01):])
    with pytest.raises(CalibrationError, match=re.escape(f"{path} [cam_01]: ") + ".*" + re.escape(message)):
        read_calibration_toml(path)
    args = ["--calibration", str(path), "--cameras", "cam_01", "cam_04"]
    _refused([str(BUNDLED / "pose2sim_cam01"), str(BUNDLED / "pose2sim_cam04"), *args], capsys, tmp_path / "out",
             f"{path} [cam_01]", message)


@pytest.mark.parametrize("content, message", [
    (b"\x7fELF\x02\x01\x01\x00\x00\x00garbage", "a binary file, not a calibration TOML"),
    ("[cam_01]\nname = \"caméra\"\n".encode("latin-1"), "line 2: not UTF-8 text"),
    (b"[cam_01]\nname = \"cam_01\"\nsize = [1088.0, 1920.0\nmatrix = 3\n", "line 4, column 1: not valid TOML"),
    (b"[cam_01]\nmatrix = [1, 0, 0\n", "at its end: not valid TOML (Unclosed array)"),
])
def test_unreadable_calibration_files_name_the_file(tmp_path, capsys, content, message):
    path = tmp_path / "calibration.toml"
    path.write_bytes(content)
    with pytest.raises(CalibrationError, match=re.escape(f"{path}") + ".*" + re.escape(message)):
        read_calibration_toml(path)
    _refused([str(BUNDLED / "pose2sim_cam01"), str(BUNDLED / "pose2sim_cam04"), "--calibration", str(path),
              "--cameras", "cam_01", "cam_04"], capsys, tmp_path / "out", str(path), message)


def test_os_errors_name_the_path(tmp_path, capsys, monkeypatch):
    missing, folder = tmp_path / "absent.toml", tmp_path / "a_folder"
    folder.mkdir()
    with pytest.raises(CalibrationError, match=re.escape(f"{missing}: cannot read the calibration file (No such file")):
        read_calibration_toml(missing)
    with pytest.raises(CalibrationError, match=re.escape(f"{folder}: a folder, not a calibration file")):
        read_calibration_toml(folder)
    views = [str(BUNDLED / "pose2sim_cam01"), str(BUNDLED / "pose2sim_cam04")]
    _refused([views[0], str(tmp_path / "no_such_folder"), *BUNDLED_ARGS], capsys, tmp_path / "out",
             str(tmp_path / "no_such_folder"))
    (tmp_path / "a_file").write_text("x")
    assert _stereo([*views, *BUNDLED_ARGS, "--out", str(tmp_path / "a_file")]) == 2
    assert f"{tmp_path / 'a_file'}: the output (--out) exists and is not a folder" in capsys.readouterr().err

    # OS errors that carry no file name (as some do) get the path added.
    def denied(*args, **kwargs):
        raise PermissionError(13, "Permission denied")

    from mocapdb.core import files

    with monkeypatch.context() as patch:
        patch.setattr(files.os, "open", denied)
        with pytest.raises(CalibrationError, match=re.escape(f"{CALIBRATION}: cannot read the calibration file "
                                                             "(Permission denied)")):
            read_calibration_toml(CALIBRATION)
    monkeypatch.setattr(stereo_views, "read_openpose_folder", denied)
    _refused([*views, *BUNDLED_ARGS], capsys, tmp_path / "out",
             f"{views[0]}: cannot read the keypoint folder (Permission denied)")
    monkeypatch.undo()

    def full(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(stereo_outputs, "write_atomic", full)
    assert _stereo([*views, *BUNDLED_ARGS, "--out", str(tmp_path / "full")]) == 2
    err = capsys.readouterr().err
    assert f"{tmp_path / 'full'}: cannot write the output (No space left on device)" in err and "[Errno" not in err


@pytest.mark.skipif(not hasattr(os, "geteuid") or os.geteuid() == 0, reason="root reads any file")
def test_an_unreadable_calibration_file_names_it(tmp_path):
    path = tmp_path / "calibration.toml"
    path.write_text(CALIBRATION.read_text())
    path.chmod(0)
    with pytest.raises(CalibrationError,
                       match=re.escape(f"{path}: cannot read the calibration file (Permission denied)")):
        read_calibration_toml(path)


def test_a_main_person_behind_a_camera_is_refused_others_warned():
    """Per person: the main person behind a camera in most frames stops the run, another is a warning."""
    rng = np.random.default_rng(0)
    points = rng.normal(0.0, 0.3, (40, 14, 3)) + [0.0, 0.0, 4.0]    # 4 m in front of camera 1
    valid = np.ones((40, 14), bool)
    turned = SimpleNamespace(R=np.diag([-1.0, 1.0, -1.0]), t=np.array([1.0, 0.0, 0.0]))  # camera 2 looks away
    with pytest.raises(StereoError, match=r"rotation 180.0°.* puts the main person \(track 0\) behind camera 2 in "
                                          r"40 of 40 frames: it cannot be right"):
        in_front_check(points, valid, turned, 0)
    assert in_front_check(points, valid, turned, 1) == [
        "behind camera 2 in 40 of its 40 frames: not a person both cameras see (a false match?), or a wrong "
        "camera estimate"]
    facing = SimpleNamespace(R=np.diag([-1.0, 1.0, -1.0]), t=np.array([0.0, 0.0, 8.0]))  # opposite, 8 m away
    assert in_front_check(points, valid, facing, 0) == []
    points[:5, :, 2] *= -1                                          # 5 of 40 frames behind camera 1
    assert in_front_check(points, valid, facing, 0)[0].startswith("track 0 (the main person) is behind camera 1 "
                                                                  "in 5 of its 40 frames")


# --------------------------------------------------------------------------- outputs and synchronisation (issue 20)


def _view_copy(folder, order):
    """Camera 4's bundled frames renamed in the given order (a view of another moment of the take)."""
    folder.mkdir()
    frames = sorted((BUNDLED / "pose2sim_cam04").glob("cam04.*.json"))
    for k, source in enumerate(frames[i] for i in order):
        shutil.copy(source, folder / f"cam04.{k:04d}.json")
    return folder


def test_stereo_replaces_its_own_output_and_refuses_anything_else(tmp_path, capsys):
    """The output folder is swapped in whole once complete: an earlier stereo output is replaced (no
    stale person left), a folder holding anything else (a user's calibration.toml and result.jsonl)
    is refused naming one of its files, before any work, and kept byte for byte."""
    views = [str(BUNDLED / "pose2sim_cam01"), str(BUNDLED / "pose2sim_cam04")]
    out = tmp_path / "out"
    assert _stereo([*views, *BUNDLED_ARGS, "--out", str(out)]) == 0
    (out / "stereo_track_7.bvh").write_text("stale")   # as if a person of an earlier run
    assert _stereo([*views, *BUNDLED_ARGS, "--out", str(out)]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["calibration.toml", "cameras.json", "result.jsonl", "stereo.bvh"]
    capsys.readouterr()
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "calibration.toml").write_text("[cam_01]\n# my calibration\n")
    (mine / "result.jsonl").write_text("my results\n")
    (out / "notes.txt").write_text("mine")
    for folder, named in ((mine, "no cameras.json"), (out, "it holds notes.txt")):
        before = {p.name: p.read_bytes() for p in folder.iterdir()}
        assert _stereo([*views, *BUNDLED_ARGS, "--out", str(folder)]) == 2
        err = capsys.readouterr().err
        assert err.startswith("mocapdb stereo: error: ") and err.count("\n") == 1, err
        assert "is not an output folder of `mocapdb stereo`" in err and named in err, err
        assert {p.name: p.read_bytes() for p in folder.iterdir()} == before
    (tmp_path / "a_file").write_text("x")
    assert _stereo([*views, *BUNDLED_ARGS, "--out", str(tmp_path / "a_file")]) == 2
    assert f"{tmp_path / 'a_file'}: the output (--out) exists and is not a folder" in capsys.readouterr().err
    assert not list(tmp_path.glob(".*"))   # no temporary folder left


@pytest.mark.parametrize("order", [range(99, -1, -1), [(i + 50) % 100 for i in range(100)]],
                         ids=["reversed", "shifted-50-frames"])
def test_unsynchronised_views_are_refused(tmp_path, capsys, order):
    """Camera 4's frames reversed or shifted by half the take: the person's keypoints fit the epipolar
    geometry better with view 2 shifted in time (once a traceback from the ellipsoid fit; then refused only
    because camera 1's still figure matched camera 4's person by chance): one line saying so, exit 2,
    nothing written."""
    view2 = _view_copy(tmp_path / "cam04", list(order))
    err = _refused([str(BUNDLED / "pose2sim_cam01"), str(view2), *BUNDLED_ARGS], capsys, tmp_path / "out",
                   "the views do not look synchronised: the main person's keypoints fit one camera geometry "
                   "better with view 2")
    assert err.count("\n") == 1
