"""The take description's camera against the options (mocapdb.core.formats.take.resolve_camera)."""
from __future__ import annotations

import logging

import pytest

from mocapdb.core.errors import UsageError
from mocapdb.core.formats.take import TakeInfo, resolve_camera

TAKE = TakeInfo(fps=60.0, image_size=(1080, 1920), frames=100, source="cam01.mp4", focal_px=None)


def test_the_description_fills_what_no_option_gives():
    camera = resolve_camera(TAKE, "take.json")
    assert (camera.fps, camera.image_size) == (60.0, (1080, 1920))
    assert camera.sources["fps"] == camera.sources["image_size"] == "read" and camera.sources["focal_px"] == "default"


def test_a_contradicting_option_names_both():
    with pytest.raises(UsageError, match=r"--image-size 1920x1080 contradicts take.json, which says 1080x1920"):
        resolve_camera(TAKE, "take.json", image_size=(1920, 1080))
    with pytest.raises(UsageError, match=r"--fps 30 contradicts take.json, which says 60"):
        resolve_camera(TAKE, "take.json", fps=30.0)


def test_a_codec_padded_size_is_the_same_image(caplog):
    """A calibration made on 1088-line frames and a video decoded at 1080 lines (H.264 codes whole
    16-px blocks): the same image, the given size used, with one warning."""
    caplog.set_level(logging.WARNING)
    camera = resolve_camera(TAKE, "take.json", image_size=(1088, 1920),
                            given_as={"image_size": "cam01's size in Calib.qca.txt"})
    assert camera.image_size == (1088, 1920) and camera.sources["image_size"] == "given"
    assert [r.getMessage() for r in caplog.records] == [
        "cam01's size in Calib.qca.txt 1088x1920 and take.json (1080x1920) differ by less than a codec block "
        "(16 px): the same image, padded or cropped by the video codec; using 1088x1920"]
    with pytest.raises(UsageError, match="contradicts"):
        resolve_camera(TAKE, "take.json", image_size=(1096, 1920))


def test_the_frames_of_a_keypoint_input_are_its_frame_files_or_its_lines(tmp_path):
    """A folder counts its frame files, not take.json, scene.json or camera_path.json; a JSON-lines file
    its lines, a last one without its newline included; anything else is None."""
    from mocapdb.core.formats.folder_size import frames_in_input

    folder = tmp_path / "kp"
    folder.mkdir()
    for name in ("a_000000000000_keypoints.json", "take.json", "scene.json", "camera_path.json", "notes.txt"):
        (folder / name).write_text("{}")
    assert frames_in_input(folder) == 1
    (tmp_path / "a.jsonl").write_text('{"people": []}\n{"people": []}')
    (tmp_path / "b.jsonl").write_text('{"people": []}\n')
    (tmp_path / "c.jsonl").write_text("")
    assert [frames_in_input(tmp_path / f"{n}.jsonl") for n in "abc"] == [2, 1, 0]
    assert frames_in_input(tmp_path / "absent") is None
