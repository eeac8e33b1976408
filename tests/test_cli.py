"""The `mocapdb` command: every subcommand answers --help; unknown input exits 2 without a traceback."""
import argparse

import pytest

from mocapdb.cli.main import main, parser


def _subcommands() -> list[str]:
    actions = [a for a in parser()._actions if isinstance(a, argparse._SubParsersAction)]
    return sorted(actions[0].choices)


def test_every_product_command_is_there():
    assert {"build", "inspect", "reconstruct", "live", "eval", "detect", "stereo"} <= set(_subcommands())


@pytest.mark.parametrize("command", _subcommands())
def test_help(command, capsys):
    assert main([command, "--help"]) == 0
    assert capsys.readouterr().out.startswith(f"usage: mocapdb {command}")


def test_stereo_without_intrinsics_is_a_clear_error(tmp_path, capsys):
    (tmp_path / "view").mkdir()
    assert main(["stereo", str(tmp_path / "view"), str(tmp_path / "view"), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "--calibration" in err and "Traceback" not in err


def test_eval_reports_are_strict_json():
    import json

    from mocapdb.cli.evaluate import _report_json

    text = _report_json({"mpjpe_cm": float("nan"), "rows": [1.5, float("inf")], "nested": {"x": -float("inf")}})
    assert json.loads(text) == {"mpjpe_cm": None, "rows": [1.5, None], "nested": {"x": None}}
    assert "NaN" not in text and "Infinity" not in text


def test_quiet_and_verbose_work_before_and_after_the_command():
    from mocapdb.cli.main import parser

    from .conftest import SAMPLE_BVH

    bvh = str(next(SAMPLE_BVH.glob("*.bvh")))

    for argv in (["-q", "inspect", bvh], ["inspect", bvh, "-q"], ["inspect", "-q", bvh]):
        args = parser().parse_args(argv)
        assert args.quiet is True and args.verbose == 0, argv
    assert parser().parse_args(["inspect", bvh, "-vv"]).verbose == 2
    assert parser().parse_args(["-v", "inspect", bvh]).verbose == 1
    assert parser().parse_args(["inspect", bvh]).quiet is False


def test_the_summary_counts_track_files_per_format(small_db_path, tmp_path, capsys):
    from mocapdb.cli.main import main

    from .conftest import SAMPLE_KEYPOINTS

    assert main(["reconstruct", str(SAMPLE_KEYPOINTS), "--db", str(small_db_path), "--out", str(tmp_path / "o"),
                 "--fps", "60", "--image-size", "1088x1920", "--focal", "1681", "--format", "bvh,trc,csv"]) == 0
    assert "track files 3 (1 BVH, 1 TRC, 1 CSV)" in capsys.readouterr().out


def test_write_tracks_leaves_static_tracks_out_as_reconstruct_does(tmp_path):
    import numpy as np

    from mocapdb.core.exports import write_tracks
    from mocapdb.core.motion import FrameRecorder
    from mocapdb.core.outputs import TrackRecording

    quats = np.tile([1.0, 0.0, 0.0, 0.0], (11, 1))
    recordings = []
    for track, static in ((0, True), (1, False)):
        frames = FrameRecorder.of(quaternions=np.stack([quats] * 3), root_view_m=np.tile([0.0, 0.0, -4.0], (3, 1)),
                                  scales=np.ones(3))
        rec = TrackRecording(track, 0, frames, static=static)
        recordings.append(rec)
    assert [p.name for p in write_tracks(recordings, tmp_path / "a", 30.0)] == ["track_1.bvh"]
    assert len(write_tracks(recordings, tmp_path / "b", 30.0, keep_static=True)) == 2


def test_the_camera_in_ordinary_terms(small_db_path, tmp_path, capsys):
    """--fov (horizontal degrees) and --focal-35mm (35 mm equivalent) become pixels for the image;
    the header records the focal used; out-of-range values and two at once are refused."""
    import json
    import shutil

    import numpy as np
    import pytest

    from mocapdb.cli.main import main
    from mocapdb.core.formats.take import focal_from_35mm, focal_from_fov

    from .conftest import SAMPLE_KEYPOINTS

    assert focal_from_fov(90.0, (1920, 1080)) == pytest.approx(960.0)           # by hand: 960 / tan 45°
    assert focal_from_35mm(26.0, (1920, 1080)) == pytest.approx(26 * 2202.907 / 43.27, rel=1e-5)
    source = tmp_path / "cam01"  # without its take.json, which gives a focal length
    shutil.copytree(SAMPLE_KEYPOINTS, source)
    (source / "take.json").unlink()
    common = [str(source), "--db", str(small_db_path), "--fps", "60", "--image-size", "1088x1920"]
    for option, expected in ((["--fov", "90"], 544.0), (["--focal-35mm", "43.27"], float(np.hypot(1088, 1920)))):
        out = tmp_path / option[0].strip("-")
        assert main(["reconstruct", *common, "--out", str(out), *option]) == 0
        header = json.loads((out / "result.jsonl").read_text().splitlines()[0])
        assert header["focal_px"] == pytest.approx(expected) and header["camera_sources"]["focal_px"] == "given"
    capsys.readouterr()
    assert main(["reconstruct", *common, "--out", str(tmp_path / "x"), "--fov", "0"]) == 2
    assert "argument --fov: '0': must be" in capsys.readouterr().err
    assert main(["reconstruct", *common, "--out", str(tmp_path / "y"), "--fov", "60", "--focal", "1000"]) == 2


def _photo_folder(folder, frames: list[int]):
    """A keypoint folder of the bundled BlazePose take's ``frames`` (its take.json beside them)."""
    import shutil

    from .conftest import ROOT

    source = ROOT / "data" / "sample_keypoints" / "blazepose_cam01"
    folder.mkdir()
    shutil.copy(source / "take.json", folder)
    for n, frame in enumerate(frames):
        shutil.copy(source / f"cam01_{frame:012d}_keypoints.json", folder / f"cam01_{n:012d}_keypoints.json")
    return folder


def test_a_photo_gets_its_people_from_its_one_frame(small_db_path, tmp_path, capsys):
    """One frame (a photo): each person detected is a track with a one-frame BVH, whose pose re-projects
    onto its keypoints (the pinhole by hand); two frames still confirm a track only on its second sighting."""
    import json

    import numpy as np

    from mocapdb.cli.main import main
    from mocapdb.core.formats.bvh import read_bvh

    photo = _photo_folder(tmp_path / "photo", [60])
    assert main(["reconstruct", str(photo), "--db", str(small_db_path), "--out", str(tmp_path / "o")]) == 0
    out = capsys.readouterr()
    assert "one frame (a photo)" in out.err and "tracks 2, track files 2 (2 BVH)" in out.out
    assert [read_bvh(tmp_path / "o" / f"track_{t}.bvh").motion.shape[0] for t in (0, 1)] == [1, 1]
    header, frame = (json.loads(line) for line in (tmp_path / "o" / "result.jsonl").read_text().splitlines())
    (width, height), focal = header["image_size"], header["focal_px"]
    seen = [np.array(p["pose_keypoints_2d"]).reshape(-1, 3)
            for p in json.loads((photo / "cam01_000000000000_keypoints.json").read_text())["people"]]
    limbs = {"r_shoulder": 12, "l_shoulder": 11, "r_elbow": 14, "l_elbow": 13, "r_wrist": 16, "l_wrist": 15,
             "r_knee": 26, "l_knee": 25, "r_ankle": 28, "l_ankle": 27}   # BlazePose's indices
    rows = [header["joints"].index(name) for name in limbs]
    for person in frame["people"]:
        x, y, z = np.array(person["joints"])[rows].T
        image = np.stack([width / 2 + focal * x / z, height / 2 - focal * y / z], axis=1)
        errors = [np.median(np.linalg.norm(image - kp[list(limbs.values()), :2], axis=1)) / np.ptp(kp[:, 1])
                  for kp in seen]
        assert min(errors) < 0.03, errors     # within 3 % of the person's height, on the one it is
    assert main(["reconstruct", str(_photo_folder(tmp_path / "two", [60, 61])), "--db", str(small_db_path),
                 "--out", str(tmp_path / "o2")]) == 0
    out = capsys.readouterr()
    # seen on the first frame, each is confirmed on the second (the stream shows it from there), and
    # 0.08 s is under --min-track-s
    assert "one frame" not in out.err and "frames 2, people 2 person-frames, tracks 2, track files 0" in out.out
