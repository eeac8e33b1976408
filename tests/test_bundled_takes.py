"""The bundled keypoint folders carry their take description (``take.json``), so the README's commands
run without their frame rate, image size and focal typed; a folder without one takes its image size
from its keypoints, and keypoints outside an assumed size stop the run at once, naming the fix."""
import json
import shutil
import tomllib

import numpy as np
import pytest

from mocapdb.cli.main import main
from mocapdb.core.formats.keypoints import CONFIDENCE_THRESHOLD
from mocapdb.core.formats.openpose import read_openpose_folder
from mocapdb.core.formats.take import read_take

from .conftest import ROOT

SAMPLE = ROOT / "data" / "sample_keypoints"
CALIBRATED = {"pose2sim_cam01": "cam_01", "pose2sim_cam04": "cam_04", "blazepose_cam01": "cam_01"}


@pytest.mark.parametrize("folder", sorted(p.name for p in SAMPLE.iterdir() if p.is_dir()))
def test_every_bundled_folder_describes_its_take(folder):
    take = read_take(SAMPLE / folder)
    files = [p for p in (SAMPLE / folder).glob("*.json") if p.name != "take.json"]
    assert take is not None and take.fps and take.image_size and take.frames == len(files)


@pytest.mark.parametrize("folder, camera", sorted(CALIBRATED.items()))
def test_the_calibrated_cameras_take_their_focal_and_size_from_the_calibration(folder, camera):
    """Checked against the TOML's own numbers: focal the mean of fx and fy (cam_01: 1681.24 and
    1681.08 px; cam_04: 1675.23 and 1675.20 px), 60 fps; OpenPose's frames are the calibration's
    1088 × 1920, the video decoded for BlazePose 1080 × 1920 (the codec's 8 padding lines cropped)."""
    calibration = tomllib.loads((SAMPLE / "calibration.toml").read_text())[camera]
    take = read_take(SAMPLE / folder)
    assert take.focal_px == pytest.approx(np.mean([calibration["matrix"][0][0], calibration["matrix"][1][1]]), abs=0.05)
    assert take.fps == 60.0
    width, height = (int(v) for v in calibration["size"])
    assert take.image_size == ((width, height) if folder.startswith("pose2sim") else (1080, 1920))


def _live(source, db, out, *options):
    assert main(["live", "--source", str(source), "--db", str(db), "--sink", str(out), "--idle-timeout", "0.5",
                 *options]) == 0
    lines = out.read_text().splitlines()
    return json.loads(lines[0]), len(lines) - 1


def test_live_on_the_bundled_folder_without_options_keeps_every_frame(small_db_path, tmp_path, capsys):
    header, frames = _live(SAMPLE / "pose2sim_cam01", small_db_path, tmp_path / "out.jsonl")
    assert frames == 100 and "malformed" not in capsys.readouterr().out
    assert header["fps"] == 60.0 and header["image_size"] == [1088, 1920] and header["focal_px"] == 1681.2
    assert set(header["camera_sources"].values()) == {"read"}


def test_a_folder_without_its_take_description_takes_its_size_from_the_keypoints(small_db_path, tmp_path, capsys):
    """The bundled camera 1 without take.json: 1080 × 1920, the smallest standard size holding its
    keypoints (they reach y = 1288 px, beyond 1920 × 1080 and its 10 % margin), every frame kept."""
    copy = tmp_path / "cam01"
    shutil.copytree(SAMPLE / "pose2sim_cam01", copy)
    (copy / "take.json").unlink()
    header, frames = _live(copy, small_db_path, tmp_path / "out.jsonl")
    assert frames == 100 and header["image_size"] == [1080, 1920]
    assert header["camera_sources"]["image_size"] == "keypoints"
    assert "taking 1080x1920" in capsys.readouterr().err


def test_keypoints_outside_an_assumed_size_stop_live_at_that_frame_with_the_fix(small_db_path, tmp_path, capsys):
    """A stream with no size anywhere (JSON lines): the first frame outside the assumed 1920 × 1080
    stops the run, naming the frame and the fix, where it used to skip such frames one by one."""
    files = sorted((SAMPLE / "pose2sim_cam01").glob("cam01.*.json"))
    lines = [json.dumps({"frame": index, "people": [{"keypoints": np.reshape(p["pose_keypoints_2d"], (-1, 3)).tolist()}
                                                    for p in json.loads(path.read_text())["people"]]})
             for index, path in enumerate(files)]
    frames = read_openpose_folder(SAMPLE / "pose2sim_cam01")  # the keypoints the session checks
    stream = tmp_path / "cam01.jsonl"
    stream.write_text("\n".join(lines) + "\n")
    assert main(["live", "--source", str(stream), "--db", str(small_db_path), "--sink", str(tmp_path / "out.jsonl"),
                 "--idle-timeout", "0.5"]) != 0
    error = capsys.readouterr().err
    assert "a size assumed" in error and "give --image-size" in error and "take.json" in error
    first_outside = next(f.index for f in frames if any(
        p.points_px[p.confidence >= CONFIDENCE_THRESHOLD, 1].max() > 1.1 * 1080 for p in f.people))
    assert f"frame {first_outside}:" in error
    assert len((tmp_path / "out.jsonl").read_text().splitlines()) == 1 + first_outside  # the frames before it
