"""`mocapdb eval --real-take`: the TRC's axes against the calibration, the camera → TRC transform,
the scores, and one real run (camera 1 of the Pose2Sim balancing take on a small database)."""
import json
import tomllib

import cv2
import numpy as np
import pytest

from mocapdb.cli.main import main
from mocapdb.core.cameras import read_calibration_toml
from mocapdb.core.formats.openpose import read_openpose_folder
from mocapdb.core.formats.trc import read_trc, trc_keypoints
from mocapdb.core.skeleton import KP, PELVIS, rest_positions_m
from mocapdb.evaluation.real_take import camera_to_trc, score, trc_to_world

from .conftest import REAL_TAKE

TAKE = REAL_TAKE


def _trc() -> np.ndarray:
    return trc_keypoints(read_trc(TAKE / "triangulated_4cam.trc"))


def _projection_errors_px(name: str, section: dict, world: np.ndarray) -> np.ndarray:
    """Per frame and confident keypoint: distance (px) from ``world [F, 15, 3]`` projected by
    cv2.projectPoints with the TOML's raw values to the nearest OpenPose person's keypoint."""
    px, _ = cv2.projectPoints(world[:, :14].reshape(-1, 1, 3), np.array(section["rotation"], dtype=np.float64),
                              np.array(section["translation"], dtype=np.float64),
                              np.array(section["matrix"], dtype=np.float64),
                              np.array(section["distortions"], dtype=np.float64))
    px = px.reshape(len(world), 14, 2)
    errors = []
    for frame in read_openpose_folder(TAKE / "openpose_body25b" / f"cam{name[-2:]}_json"):
        per_person = [np.linalg.norm(p.points_px - px[frame.index], axis=-1)[p.confidence >= 0.3]
                      for p in frame.people if (p.confidence >= 0.3).any()]
        errors.append(min(per_person, key=np.median))
    return np.concatenate(errors)


def test_trc_projects_onto_each_cameras_openpose_keypoints():
    calibration = tomllib.loads((TAKE / "calibration.toml").read_text())
    trc = _trc()
    world = trc_to_world(trc)  # the module's axes: TRC (X, Y, Z) = world (Y, Z, X)
    errors = {name: _projection_errors_px(name, calibration[name], world) for name in calibration if name != "metadata"}
    assert len(errors) == 4 and np.median(np.concatenate(list(errors.values()))) < 15.0
    # Camera 3 sees the person from behind: OpenPose puts the hidden right hip and shoulder ~50 px
    # from the triangulation (the other cameras outvote it), so its own median is ~21 px.
    assert all(np.median(e) < 25.0 for e in errors.values()), {n: np.median(e) for n, e in errors.items()}
    assert np.median(_projection_errors_px("cam_01", calibration["cam_01"], trc)) > 100.0  # TRC axes as world: far off
    cam = read_calibration_toml(TAKE / "calibration.toml")["cam_01"]
    reference, _ = cv2.projectPoints(world[0].reshape(-1, 1, 3), np.array(calibration["cam_01"]["rotation"]),
                                     np.array(calibration["cam_01"]["translation"]), cam.K, cam.dist)
    assert np.allclose(cam.project(world[0]), reference.reshape(-1, 2), atol=1e-6)


def test_camera_aligned_points_go_back_to_the_trc():
    trc = _trc()
    world = trc[..., [2, 0, 1]]  # world x, y, z = TRC z, x, y
    for cam in read_calibration_toml(TAKE / "calibration.toml").values():
        opencv = world @ cam.R.T + cam.t           # x right, y down, z forward
        aligned = opencv * np.array([1.0, -1.0, 1.0])  # x right, y up, z away from the camera
        assert np.allclose(camera_to_trc(aligned, cam), trc, atol=1e-12)


def _standing_truth(frames: int = 30) -> np.ndarray:
    """The rest pose standing 3 m in front of the origin (y up, ankles 8 cm up), swaying its arms."""
    pose = rest_positions_m()
    pose = pose - [0.0, pose[:, 1].min() - 0.08, 3.0]
    truth = np.repeat(pose[None], frames, axis=0)
    truth[:, KP["r_wrist"], 2] += 0.05 * np.sin(np.linspace(0, np.pi, frames))
    return truth


def test_scores_are_zero_on_the_truth_and_the_shift_on_a_shifted_truth():
    truth, centre = _standing_truth(), np.zeros(3)
    exact = score(truth, truth, centre, 60.0)
    assert exact["frames_with_output"] == exact["frames"] == 30
    assert exact["mpjpe_cm"] == pytest.approx(0, abs=1e-9) and exact["pa_mpjpe_cm"] == pytest.approx(0, abs=1e-6)
    assert exact["root_error_m"] == pytest.approx(0, abs=1e-12)
    assert exact["bone_length_cm"]["mean_error_7"] == pytest.approx(0, abs=1e-9)
    assert exact["foot_skating_cm_per_s"]["mean"] == pytest.approx(0, abs=1e-9)
    assert exact["planted_foot_height_error_cm"]["mean"] == pytest.approx(0, abs=1e-9)

    shift = np.array([0.3, -0.4, 1.2])  # 1.3 m
    pred = truth + shift
    pred[:5] = np.nan  # no output in the first frames
    moved = score(pred, truth, centre, 60.0)
    assert moved["frames_with_output"] == 25
    assert moved["root_error_m"] == pytest.approx(1.3)
    distance = np.linalg.norm(truth[5:, PELVIS], axis=-1)
    assert moved["root_error_pct_distance"] == pytest.approx(np.mean(130.0 / distance))
    assert moved["mpjpe_cm"] == pytest.approx(0, abs=1e-9) and moved["bone_length_cm"]["mean_error_7"] < 1e-9
    assert moved["planted_foot_height_error_cm"]["mean"] == pytest.approx(-40.0)


def test_real_take_command_on_one_camera(small_db_path, tmp_path, capsys):
    out = tmp_path / "real_take.json"
    args = ["eval", "--db", str(small_db_path), "--real-take", str(TAKE), "--cameras", "cam_01", "--out", str(out)]
    assert main(args) == 0
    printed = capsys.readouterr().out
    assert "| cam_01 | refined |" in printed and "| cam_01 | published |" in printed and "PA-MPJPE" in printed
    assert "| cam_01 | whole take |" in printed
    report = json.loads(out.read_text())
    assert list(report["cameras"]) == ["cam_01"] and 1.5 < report["cameras"]["cam_01"]["camera_height_m"] < 2.2
    runs = [r for modes in report["cameras"]["cam_01"]["runs"].values() for r in modes.values()]
    # refined and whole take in both size modes, published and the default stream (lag 0) with nothing given
    assert len(runs) == 6 and "| cam_01 | stream, lag 0 |" in printed
    whole = report["cameras"]["cam_01"]["runs"]["whole take"]["nothing_given"]
    assert whole["foot_skating_cm_per_s"]["mean"] < report["cameras"]["cam_01"]["runs"]["refined"]["nothing_given"][
        "foot_skating_cm_per_s"]["mean"]  # the whole take holds planted feet still
    for r in runs:
        assert r["frames_with_output"] > 50
        assert all(np.isfinite([r["mpjpe_cm"], r["pa_mpjpe_cm"], r["root_error_m"], r["root_error_pct_distance"],
                                r["bone_length_cm"]["mean_error_7"]]))
    camera = report["cameras"]["cam_01"]["world_camera"]
    assert abs(camera["truth"]["height_m"] - 1.90) < 0.02 and abs(camera["truth"]["pitch_deg"] - 23.1) < 0.2
    assert np.isfinite([camera["height_error_pct"], camera["pitch_error_deg"], camera["roll_error_deg"]]).all()
    assert "world camera: height off" in printed and "| cam_01 | " in printed.split("The world's camera")[1]
    assert main(["eval", "--db", str(small_db_path), "--real-take", str(TAKE), "--bvh", str(tmp_path)]) == 2
    assert "--real-take" in capsys.readouterr().err


def test_a_camera_folders_take_description_must_agree_with_the_take(tmp_path):
    """A camera folder that `mocapdb detect` wrote holds a take.json: its rate and image size must be the
    TRC's and the calibration's (here the video was detected at half its rate)."""
    import shutil

    from mocapdb.core.errors import UsageError
    from mocapdb.core.formats.take import TakeInfo, write_take
    from mocapdb.evaluation.real_take import load_take

    for name in ("calibration.toml", "triangulated_4cam.trc"):
        shutil.copy(TAKE / name, tmp_path / name)
    folder = tmp_path / "openpose_body25b" / "cam01_json"
    shutil.copytree(TAKE / "openpose_body25b" / "cam01_json", folder)
    write_take(folder, TakeInfo(fps=60.0, image_size=(1088, 1920), frames=100, source="cam01.mp4"))
    assert load_take(tmp_path, ["cam_01"]).fps == 60.0
    write_take(folder, TakeInfo(fps=30.0, image_size=(1088, 1920), frames=100, source="cam01.mp4"))
    with pytest.raises(UsageError, match=f"the rate of {tmp_path / 'triangulated_4cam.trc'} 60 contradicts "
                                         f"{folder / 'take.json'}, which says 30: correct one of them"):
        load_take(tmp_path, ["cam_01"])
    write_take(folder, TakeInfo(fps=60.0, image_size=(1920, 1080), frames=100, source="cam01.mp4"))
    with pytest.raises(UsageError, match="the image size of cam_01 in .*calibration.toml 1088x1920 contradicts"):
        load_take(tmp_path, ["cam_01"])
