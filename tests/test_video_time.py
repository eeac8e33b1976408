"""Videos as players read them (issue 52, item 4): frame times from the container's timestamps, a
file cut short read to its last frame with a warning, a gap in the timestamps kept in the keypoint
files, the result stream and the BVH.

The videos are real MP4 files written by OpenCV and edited box by box (``tests/mp4_edit.py``): the
references are what the edit put there (frame k at k / 30 s, or k + 6 frame times after the gap;
the frames a plain OpenCV loop decodes), not what mocapdb reads. The timestamp checks against
nonsense run on a fake capture that returns a known ``CAP_PROP_POS_MSEC`` sequence.
"""
import json
import math

import cv2
import numpy as np
import pytest

from mocapdb.cli.main import main
from mocapdb.core.formats.bvh import read_bvh
from mocapdb.core.formats.openpose import read_openpose_folder
from mocapdb.detect.video import MAX_TIMESTAMP_JUMP_S, FrameClock, VideoReader
from tests import test_detect
from tests.mp4_edit import moov_first, with_gap, write_mp4
from tests.test_detect import VIDEO_H, VIDEO_W

human_model = test_detect.human_model   # the fixture: a YOLO-pose model that always sees one person

FPS, FRAMES, GAP_AFTER, GAP_FRAMES = 30.0, 20, 9, 6   # frames 10.. come 6 frame times (200 ms) late


def container_times(k: np.ndarray) -> np.ndarray:
    """Seconds of frame k of the gap video, as its edited sample durations say."""
    return np.where(k <= GAP_AFTER, k, k + GAP_FRAMES) / FPS


@pytest.fixture
def plain_mp4(tmp_path):
    return write_mp4(tmp_path / "plain.mp4", FRAMES, FPS, (VIDEO_W, VIDEO_H))


@pytest.fixture
def gap_mp4(plain_mp4, tmp_path):
    path = tmp_path / "gap.mp4"
    path.write_bytes(with_gap(plain_mp4.read_bytes(), GAP_AFTER, GAP_FRAMES))
    return path


@pytest.fixture
def cut_mp4(plain_mp4, tmp_path):
    """The index first (as phones write it), the last third of the file gone."""
    data = moov_first(plain_mp4.read_bytes())
    path = tmp_path / "cut.mp4"
    path.write_bytes(data[:len(data) * 2 // 3])
    return path


def decodable_frames(path) -> int:
    """Frames a plain OpenCV read loop gets from ``path``."""
    cap, count = cv2.VideoCapture(str(path)), 0
    while cap.read()[0]:
        count += 1
    cap.release()
    return count


def read_all(path, every: int = 1):
    reader = VideoReader(str(path))
    frames = list(reader.frames(every))
    reader.close()
    return reader, frames


def test_a_plain_video_s_frames_are_at_k_over_its_rate(plain_mp4):
    reader, frames = read_all(plain_mp4)
    assert reader.fps == FPS and reader.frame_count == FRAMES and reader.time_warnings() == []
    np.testing.assert_allclose([f.time_s for f in frames], np.arange(FRAMES) / FPS, atol=1e-9)
    clock = FrameClock(reader.fps)
    assert [clock.number(f.time_s) for f in frames] == list(range(FRAMES)) and clock.report() is None
    reader, frames = read_all(plain_mp4, every=3)
    clock = FrameClock(reader.fps / 3)
    assert [clock.number(f.time_s) for f in frames] == list(range(7))


def test_a_gap_in_the_timestamps_keeps_its_length(gap_mp4):
    reader, frames = read_all(gap_mp4)
    assert len(frames) == FRAMES and reader.truncation() is None
    np.testing.assert_allclose([f.time_s for f in frames], container_times(np.arange(FRAMES)), atol=1e-9)
    # FFmpeg's average rate counts the gap (20 frames over 26 frame times: 23.08 fps): the timestamps' rate wins
    assert reader.fps == FPS and len(reader.time_warnings()) == 1
    assert f"its timestamps keep 30 fps (median interval of the first {FRAMES} frames)" in reader.time_warnings()[0]
    clock = FrameClock(reader.fps)
    numbers = [clock.number(f.time_s) for f in frames]
    assert numbers == list(range(GAP_AFTER + 1)) + list(range(GAP_AFTER + 1 + GAP_FRAMES, FRAMES + GAP_FRAMES))
    assert (clock.gaps, clock.missing) == (1, GAP_FRAMES)
    assert "longest 233 ms between two frames): 6 frame time(s) at 30 Hz hold no frame" in clock.report()


def test_detect_on_a_file_cut_short_writes_every_decodable_frame(cut_mp4, human_model, tmp_path, capsys):
    decodable = decodable_frames(cut_mp4)
    assert 0 < decodable < FRAMES
    out = tmp_path / "kp"
    assert main(["detect", str(cut_mp4), "--model", str(human_model), "--out", str(out)]) == 0
    captured = capsys.readouterr()
    assert (f"mocapdb: warning: {cut_mp4}: the container promised {FRAMES} frames, {decodable} could be read: "
            "the file looks cut short") in captured.err
    assert f"frames read {decodable}, frames written {decodable}" in captured.out
    files = sorted(out.glob("*_keypoints.json"))
    bodies = [json.loads(f.read_text()) for f in files]
    assert [b["frame"] for b in bodies] == list(range(decodable))
    np.testing.assert_allclose([b["time"] for b in bodies], np.arange(decodable) / FPS, atol=1e-6)
    take = json.loads((out / "take.json").read_text())
    assert take["frames"] == decodable and take["fps"] == FPS


def test_a_gap_reaches_the_keypoints_the_stream_and_the_bvh(gap_mp4, human_model, small_db_path, tmp_path, capsys):
    """detect writes each frame's number on the 30 fps timeline and its container time; reconstruct's
    stream keeps both; the BVH (frame time 1/30 s, padded back to frame 0) holds the gap's frames, so
    its frame k is at k / 30 s: as many frames as the last frame's number + 1."""
    kp = tmp_path / "kp"
    assert main(["detect", str(gap_mp4), "--model", str(human_model), "--out", str(kp)]) == 0
    assert "frame times: the timestamps jump 1 time(s)" in capsys.readouterr().out
    numbers = np.array(sorted(json.loads(f.read_text())["frame"] for f in kp.glob("*_keypoints.json")))
    expected = np.concatenate([np.arange(GAP_AFTER + 1), np.arange(GAP_AFTER + 1, FRAMES) + GAP_FRAMES])
    np.testing.assert_array_equal(numbers, expected)
    assert json.loads((kp / "take.json").read_text())["fps"] == FPS
    read_back = list(read_openpose_folder(kp))   # numbered and timed as reconstruct numbers them
    assert [f.index for f in read_back] == expected.tolist()
    np.testing.assert_allclose([f.time_s for f in read_back], container_times(np.arange(FRAMES)), atol=1e-6)

    assert main(["reconstruct", str(kp), "--db", str(small_db_path), "--out", str(tmp_path / "out")]) == 0
    _check_stream_and_bvh(tmp_path / "out" / "result.jsonl", tmp_path / "out" / "track_0.bvh", expected)


def test_live_on_a_video_with_a_gap(gap_mp4, human_model, small_db_path, tmp_path, capsys):
    """As detect → reconstruct; the model on whole frames (its fixed output would drift in crops)."""
    assert main(["live", "--source", str(gap_mp4), "--model", str(human_model), "--detector", "full",
                 "--db", str(small_db_path), "--sink", str(tmp_path / "live.jsonl"), "--bvh-dir", str(tmp_path),
                 "--buffer", str(FRAMES)]) == 0
    err = capsys.readouterr().err
    assert "frame times: the timestamps jump 1 time(s)" in err and "its timestamps keep 30 fps" in err
    expected = np.concatenate([np.arange(GAP_AFTER + 1), np.arange(GAP_AFTER + 1, FRAMES) + GAP_FRAMES])
    _check_stream_and_bvh(tmp_path / "live.jsonl", tmp_path / "track_0.bvh", expected)


def _check_stream_and_bvh(stream, bvh_path, expected_numbers: np.ndarray) -> None:
    lines = [json.loads(line) for line in stream.read_text().splitlines()]
    assert lines[0]["fps"] == FPS
    frames = lines[1:]
    assert [f["frame"] for f in frames] == expected_numbers.tolist()
    np.testing.assert_allclose([f["time"] for f in frames], container_times(np.arange(FRAMES)), atol=1e-6)
    bvh = read_bvh(bvh_path)
    assert bvh.frame_time == pytest.approx(1 / FPS, abs=1e-6)
    assert len(bvh.motion) == expected_numbers[-1] + 1 == FRAMES + GAP_FRAMES


# --- timestamps the container gets wrong (a fake capture) ------------------------------------------

class FakeCapture:
    """A capture of ``len(times_ms)`` black frames whose ``CAP_PROP_POS_MSEC`` after each read is the
    next of ``times_ms``; ``fps`` and ``count`` as the container's."""

    def __init__(self, times_ms, fps, count):
        self.times_ms, self.fps, self.count, self.read_so_far = list(times_ms), fps, count, 0

    def isOpened(self):  # noqa: N802 (OpenCV's name)
        return True

    def grab(self):
        if self.read_so_far >= len(self.times_ms):
            return False
        self.read_so_far += 1
        return True

    def read(self):
        return (True, np.zeros((4, 4, 3), np.uint8)) if self.grab() else (False, None)

    def get(self, prop):
        if prop == cv2.CAP_PROP_POS_MSEC:
            return self.times_ms[self.read_so_far - 1] if self.read_so_far else 0.0
        return {cv2.CAP_PROP_FPS: self.fps, cv2.CAP_PROP_FRAME_COUNT: self.count}[prop]

    def set(self, prop, value):
        return False

    def release(self):
        pass


def fake_times(monkeypatch, tmp_path, times_ms, fps=25.0):
    """The frame times a VideoReader gives for a container saying ``times_ms`` at ``fps``, and the reader."""
    monkeypatch.setattr("mocapdb.detect.video.cv2.VideoCapture",
                        lambda source: FakeCapture(times_ms, fps, len(times_ms)))
    path = tmp_path / "fake.mp4"
    path.write_bytes(b"\0")
    reader = VideoReader(str(path))
    times = [f.time_s for f in reader.frames()]
    return times, reader


def test_container_timestamps_that_are_nonsense_are_replaced_and_counted(monkeypatch, tmp_path):
    jump_ms = (MAX_TIMESTAMP_JUMP_S + 1) * 1000
    # every 40 ms from 40 ms, but for frames 2 (NaN), 4 (repeated), 5 (earlier), 6 (too far ahead), 9 (infinite)
    given = [40.0, 80.0, math.nan, 160.0, 160.0, 120.0, 280.0 + jump_ms, 320.0, 360.0, math.inf, 440.0]
    times, reader = fake_times(monkeypatch, tmp_path, given)
    expected_ms = np.arange(len(given)) * 40.0   # from the first frame; the bad ones 40 ms after the frame before
    np.testing.assert_allclose(times, expected_ms / 1000, atol=1e-9)
    assert reader.times_guessed == 5 and reader.times_decoded == len(given)
    assert reader.time_warnings() == [f"{reader.label}: 5 of 11 frames had no usable timestamp in the container "
                                      "(missing, not increasing, or jumping more than 60 s): their times are "
                                      "counted from the frame rate"]


def test_a_container_without_timestamps_gets_index_over_fps(monkeypatch, tmp_path):
    times, reader = fake_times(monkeypatch, tmp_path, [0.0] * 6)
    np.testing.assert_allclose(times, np.arange(6) / 25.0, atol=1e-12)
    assert reader.fps == 25.0 and reader.times_guessed == 5


def test_a_clock_without_a_rate_or_times_counts_frames():
    clock = FrameClock(None)
    assert [clock.number(t) for t in (0.0, 0.5, None, 9.0)] == [0, 1, 2, 3] and clock.report() is None
    clock = FrameClock(10.0)   # frames faster than the rate keep increasing numbers
    assert [clock.number(t) for t in (0.0, 0.04, 0.08, 0.3, None)] == [0, 1, 2, 3, 4] and clock.gaps == 0
