"""Input that contradicts the parameters or could blow up work: time jumps, static detections,
keypoints outside the image, missing frame rate, empty input (issue 10)."""
import resource

import numpy as np
import pytest

from mocapdb.cli import main
from mocapdb.database import load_database
from mocapdb.geometry import Camera, project_views
from mocapdb.keypoints import KeypointFrame, Person
from mocapdb.skeleton import PELVIS
from runtime.engine import Engine, EngineConfig
from runtime.session import FrameParser, InputError, Session, SessionOptions, SessionSummary
from runtime.streams import StreamStats, open_sink

from .test_session import _stream_lines


def _walking_px(db, n: int, offset=(0.0, 0.0)) -> np.ndarray:
    pos = db.positions[:n].astype(np.float64)
    camera = Camera(**db.meta["camera"])
    return project_views(pos, pos[:, PELVIS], np.array([36.0]), 0.0, camera)[:, 0, :14] + offset


def _session(db, tmp_path, **options) -> Session:
    summary = SessionSummary(stream=StreamStats())
    engine = Engine(db, EngineConfig(fps=24.0))
    return Session(engine, open_sink(str(tmp_path / "out.jsonl"), summary.stream), FrameParser(), summary,
                   SessionOptions(**options))


def test_a_jump_far_into_the_future_costs_one_frame(small_db, tmp_path):
    px = _walking_px(small_db, 20)
    session = _session(small_db, tmp_path)
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    for i in range(10):
        session.handle_frame(KeypointFrame(i, None, [Person(px[i], np.full(14, 0.9))]), 0.0)
    for i in range(10, 20):  # frame numbers jump by 5·10⁶ s at 24 fps
        session.handle_frame(KeypointFrame(i + 120_000_000, None, [Person(px[i], np.full(14, 0.9))]), 0.0)
    summary = session.finish(tmp_path)
    assert summary.gaps == 1 and summary.tracks == 2
    assert resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before < 200_000  # kB: nothing materialised
    lengths = sorted(len(r.read_text().split("MOTION")[1].splitlines()) for r in summary.bvh_files)
    assert max(lengths) < 20


def test_a_detection_that_never_moves_gets_no_bvh(small_db, tmp_path):
    px = _walking_px(small_db, 48)
    poster = px[0] + [-600.0, 0.0]  # the same pose, still, at the image's left
    frames = [KeypointFrame(i, i / 24.0, [Person(px[i], np.full(14, 0.9)), Person(poster, np.full(14, 1.0))])
              for i in range(48)]
    for keep, written in ((False, 1), (True, 2)):
        (tmp_path / str(keep)).mkdir()
        session = _session(small_db, tmp_path / str(keep), keep_static=keep)
        for frame in frames:
            session.handle_frame(frame, 0.0)
        summary = session.finish(tmp_path / str(keep))
        assert len(summary.static_tracks) == 1 and len(summary.bvh_files) == written
        assert "static tracks" in summary.report()


def test_keypoints_outside_the_image_size_name_the_likely_swap(small_db, tmp_path):
    px = _walking_px(small_db, 3)
    px[..., 1] += 600.0  # y up to ~1300 px in a frame said to be 1920x1080
    session = _session(small_db, tmp_path)
    with pytest.raises(InputError, match="1080x1920"):
        session.handle_frame(KeypointFrame(0, None, [Person(px[0], np.full(14, 0.9))]), 0.0)
    live = _session(small_db, tmp_path, strict=False)
    live.handle_frame(KeypointFrame(0, None, [Person(px[0], np.full(14, 0.9))]), 0.0)
    assert live.summary.malformed["keypoints outside --image-size"] == 1 and live.summary.frames == 0


def test_cli_warns_about_an_assumed_frame_rate_and_refuses_empty_input(small_db_path, tmp_path, capsys):
    (tmp_path / "in.jsonl").write_text("\n".join(_stream_lines(load_database(small_db_path), 10)) + "\n")
    assert main(["reconstruct", str(tmp_path / "in.jsonl"), "--db", str(small_db_path), "--out", str(tmp_path / "a")]) == 0
    assert "assuming 30 fps" in capsys.readouterr().err
    assert main(["reconstruct", str(tmp_path / "in.jsonl"), "--db", str(small_db_path), "--out", str(tmp_path / "b"),
                 "--fps", "24"]) == 0
    assert "assuming" not in capsys.readouterr().err
    empty = tmp_path / "empty"
    empty.mkdir()
    (empty / "notes.txt").write_text("not keypoints")
    assert main(["reconstruct", str(empty), "--db", str(small_db_path), "--out", str(tmp_path / "c")]) == 2
    assert "no keypoint frame" in capsys.readouterr().err


def test_cli_image_size_errors_name_the_argument(small_db_path, tmp_path, capsys):
    assert main(["reconstruct", str(tmp_path), "--db", str(small_db_path), "--out", str(tmp_path / "o"),
                 "--image-size", "1920by1080"]) == 2
    err = capsys.readouterr().err
    assert "--image-size" in err and "--window-weights" not in err


def test_output_that_survives(small_db, small_db_path, tmp_path, capsys):
    (tmp_path / "in.jsonl").write_text("\n".join(_stream_lines(small_db, 10)) + "\n")
    out = tmp_path / "out"
    args = ["reconstruct", str(tmp_path / "in.jsonl"), "--db", str(small_db_path), "--out", str(out), "--fps", "24"]
    assert main(args) == 0
    (out / "track_7.bvh").write_text("stale")  # as if left by an earlier run
    before = (out / "result.jsonl").read_text()
    # A failing run (missing input) leaves the earlier output as it was.
    assert main(["reconstruct", str(tmp_path / "missing"), "--db", str(small_db_path), "--out", str(out)]) == 2
    assert (out / "result.jsonl").read_text() == before and (out / "track_7.bvh").exists()
    # A new run replaces it whole: no stale files of another run.
    assert main(args) == 0
    assert sorted(p.name for p in out.iterdir()) == ["result.jsonl", "track_0.bvh"]
    # A folder holding anything else is never replaced.
    (out / "notes.txt").write_text("mine")
    assert main(args) == 2 and "not an output folder" in capsys.readouterr().err
    assert (out / "notes.txt").read_text() == "mine"
    assert not list(tmp_path.glob(".out.tmp-*"))


def test_a_track_bvh_is_written_when_the_track_ends(small_db, tmp_path):
    px = _walking_px(small_db, 40)
    summary = SessionSummary(stream=StreamStats())
    engine = Engine(small_db, EngineConfig(fps=24.0))
    session = Session(engine, open_sink(str(tmp_path / "out.jsonl"), summary.stream), FrameParser(), summary,
                      SessionOptions(bvh_dir=tmp_path, checkpoint_s=1e9))
    for i in range(20):
        session.handle_frame(KeypointFrame(i, i / 24.0, [Person(px[i], np.full(14, 0.9))]), 0.0)
    assert not (tmp_path / "track_0.bvh").exists()
    for i in range(20, 40):  # the person is gone: the track ends after its missed frames
        session.handle_frame(KeypointFrame(i, i / 24.0, []), 0.0)
    assert (tmp_path / "track_0.bvh").exists()  # before the session ends
    session.options.checkpoint_s = 0.0  # an open track's BVH so far, at every frame
    for i in range(40, 45):
        session.handle_frame(KeypointFrame(i, i / 24.0, [Person(px[i - 40], np.full(14, 0.9))]), 0.0)
    assert (tmp_path / "track_1.bvh").exists()
    assert session.finish().bvh_files == [tmp_path / "track_0.bvh", tmp_path / "track_1.bvh"]


def test_a_person_with_every_keypoint_at_one_pixel_is_skipped(small_db, tmp_path):
    session = _session(small_db, tmp_path)
    for i in range(5):
        session.handle_frame(KeypointFrame(i, i / 24.0, [Person(np.full((14, 2), 500.0), np.full(14, 0.9))]), 0.0)
    summary = session.finish(tmp_path)
    assert summary.person_frames == 0 and summary.degenerate == 5
    assert "within 4 px" in summary.report()
