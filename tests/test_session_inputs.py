"""Input that contradicts the parameters or could blow up work: time jumps, static detections,
keypoints outside the image, missing frame rate, empty input (issue 10)."""
import json
import resource
import sys
import threading
import time

import numpy as np
import pytest

from mocapdb.cli.main import main
from mocapdb.core.cameras import DatabaseCamera
from mocapdb.core.formats.bvh import read_bvh
from mocapdb.core.formats.database_reader import load_database
from mocapdb.core.formats.keypoint_layouts import EXTREMITIES, LAYOUTS, SOURCE_INDEX
from mocapdb.core.formats.keypoints import KeypointFrame, Person
from mocapdb.core.geometry import project_views
from mocapdb.core.skeleton import PELVIS
from mocapdb.runtime.engine import Engine
from mocapdb.runtime.engine_config import EngineConfig, TrackLimits
from mocapdb.runtime.stream.session import FrameParser, InputError, Session, SinkError
from mocapdb.runtime.stream.session_options import SessionOptions
from mocapdb.runtime.stream.session_summary import SessionSummary
from mocapdb.runtime.stream.transport import Sink, StreamStats, open_sink

from .test_session import _stream_lines


def _walking_px(db, n: int, offset=(0.0, 0.0)) -> np.ndarray:
    pos = db.positions[:n].astype(np.float64)
    camera = DatabaseCamera(**db.meta["camera"])
    return project_views(pos, pos[:, PELVIS], np.array([36.0]), 0.0, camera)[:, 0, :14] + offset


def _session(db, tmp_path, **options) -> Session:
    summary = SessionSummary(stream=StreamStats())
    engine = Engine(db, EngineConfig(fps=24.0))
    return Session(engine, open_sink(str(tmp_path / "out.jsonl"), summary.stream), FrameParser(), summary,
                   SessionOptions(**options))


def test_a_jump_far_into_the_future_costs_one_frame(small_db, tmp_path):
    px = _walking_px(small_db, 20)
    session = _session(small_db, tmp_path, min_track_s=0.0)
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


def test_points_a_detector_put_beyond_its_own_video_are_unseen_not_a_contradiction(small_db, tmp_path):
    """Where the size is the video's own (read from it or detect's take description), a keypoint beyond it is a
    part out of frame whose place the detector guessed (BlazePose does, below a webcam's frame): unseen and
    counted, the frame kept, even strict; a size given or assumed still refuses such a frame."""
    px = _walking_px(small_db, 3)
    height = 1080   # the session's image: 1920 x 1080
    px[0, [0, 1]] = [500.0, height * 1.1 + 5.0]    # two points just beyond the margin below the image
    extremities = np.full((len(EXTREMITIES), 3), [800.0, 500.0, 0.9])
    extremities[0] = [800.0, height * 1.2, 0.9]
    frame = KeypointFrame(0, None, [Person(px[0], np.full(14, 0.9), extremities=extremities)])
    session = _session(small_db, tmp_path, strict=True, camera_sources={"image_size": "read"})
    session.handle_frame(frame, 0.0)
    assert session.summary.frames == 1 and session.summary.points_out_of_frame == 3
    assert "taken as unseen: 3" in session.summary.report()
    assert frame.people[0].confidence[0] == 0.9   # the caller's frame is left as it was
    with pytest.raises(InputError, match="keypoints reach"):
        _session(small_db, tmp_path, strict=True, camera_sources={"image_size": "given"}).handle_frame(frame, 0.0)


def test_cli_warns_about_an_assumed_frame_rate_and_refuses_empty_input(small_db_path, tmp_path, capsys):
    (tmp_path / "in.jsonl").write_text("\n".join(_stream_lines(load_database(small_db_path), 10)) + "\n")
    assert main(["reconstruct", str(tmp_path / "in.jsonl"), "--db", str(small_db_path),
                 "--out", str(tmp_path / "a")]) == 0
    assert "assuming 30 fps" in capsys.readouterr().err
    assert main(["reconstruct", str(tmp_path / "in.jsonl"), "--db", str(small_db_path), "--out", str(tmp_path / "b"),
                 "--fps", "24"]) == 0
    assert "assuming 30 fps" not in capsys.readouterr().err
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
    (tmp_path / "in.jsonl").write_text("\n".join(_stream_lines(small_db, 24)) + "\n")
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
    assert sorted(p.name for p in out.iterdir()) == ["result.jsonl", "track_0.bvh", "world.json"]
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
                      SessionOptions(bvh_dir=tmp_path, checkpoint_s=1e9, min_track_s=0.0))
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


# --- one message stops nothing (issue 20) -----------------------------------------------------------

HUGE_FRAME = '{"frame": 1' + "0" * 400 + ', "people": []}'   # frame 10**400


def _with_huge_frame(db, path) -> list[str]:
    """Writes 30 good lines with a frame 10**400 after the 10th to ``path``; returns the good ones."""
    lines = _stream_lines(db, 30)
    path.write_text("\n".join(lines[:10] + [HUGE_FRAME] + lines[10:]) + "\n")
    return lines


def test_reconstruct_counts_a_frame_number_beyond_any_bound_as_one_malformed_line(small_db, small_db_path, tmp_path,
                                                                                   capsys):
    _with_huge_frame(small_db, tmp_path / "in.jsonl")
    out = tmp_path / "out"
    assert main(["reconstruct", str(tmp_path / "in.jsonl"), "--db", str(small_db_path), "--out", str(out)]) == 0
    frames = [json.loads(line)["frame"] for line in (out / "result.jsonl").read_text().splitlines()[1:]]
    assert frames == list(range(30))
    report = capsys.readouterr().out
    reason = "'frame' must be a non-negative integer below 2**53"
    assert "frames 30" in report
    assert f"skipped malformed (1): {reason} (first in {tmp_path / 'in.jsonl'}:line 11)" in report


def test_live_skips_a_frame_number_beyond_any_bound_and_goes_on(small_db, small_db_path, tmp_path, monkeypatch, capsys):
    _with_huge_frame(small_db, tmp_path / "in.jsonl")
    monkeypatch.setattr(sys, "stdin", open(tmp_path / "in.jsonl"))
    assert main(["live", "--source", "-", "--db", str(small_db_path), "--sink", str(tmp_path / "out.jsonl"),
                 "--buffer", "64"]) == 0
    sys.stdin.close()
    frames = [json.loads(line)["frame"] for line in (tmp_path / "out.jsonl").read_text().splitlines()[1:]]
    assert frames == list(range(30))
    assert "skipped malformed (1): 'frame' must be a non-negative integer below 2**53" in capsys.readouterr().err


def _in_layout(px: np.ndarray, layout: str) -> list:
    """A person's universal keypoints ``[14, 2]`` as ``layout`` rows (x, y, 0.9); BODY_25 also gets the
    neck and mid-hip OpenPose makes (so it is told from BODY_25B)."""
    kp = np.zeros((len(LAYOUTS[layout]), 3))
    for universal, index in enumerate(SOURCE_INDEX[layout]):
        if index >= 0:
            kp[index] = [*px[universal], 0.9]
    if layout == "body25":
        kp[1, :2], kp[8] = kp[[2, 5], :2].mean(axis=0), [*kp[[9, 12], :2].mean(axis=0), 0.9]
    return np.round(kp, 2).tolist()


def test_a_stream_whose_layout_changes_keeps_every_frame(small_db, tmp_path, caplog):
    from mocapdb.runtime.stream.transport import RawMessage

    px = _walking_px(small_db, 150)
    session = _session(small_db, tmp_path, strict=False)
    layouts = ["body25"] * 50 + ["coco17"] * 50 + ["halpe26"] * 40 + ["body25"] * 10   # no line names its layout
    for i, layout in enumerate(layouts):
        message = json.dumps({"frame": i, "people": [{"keypoints": _in_layout(px[i], layout)}]})
        session.handle(RawMessage(message, f"line {i + 1}", time.monotonic()))
    summary = session.finish()
    assert summary.frames == 150 and not summary.malformed and summary.person_frames >= 148
    assert session.parser.known == {25: "body25", 17: "coco17", 26: "halpe26"}
    assert session.parser.layout_changes == 3
    changes = [r.getMessage() for r in caplog.records if "layout changed" in r.getMessage()]
    assert len(changes) == 1 and "from body25 to coco17 (in frame 50)" in changes[0]


# --- limits (issue 13): a hostile sender makes bounded work, memory and files -----------------------

COCO17_OF_UNIVERSAL = {0: 0, 2: 6, 3: 8, 4: 10, 5: 5, 6: 7, 7: 9, 8: 12, 9: 14, 10: 16, 11: 11, 12: 13, 13: 15}


def _coco17(px: np.ndarray) -> list:
    kp = np.zeros((17, 3))
    for u, c in COCO17_OF_UNIVERSAL.items():
        kp[c] = [px[u, 0], px[u, 1], 0.9]
    return np.round(kp, 1).tolist()


def _flood(db, n_messages: int, stay: int):
    """Message k brings a new person (walking, ~110 px tall) to one of 64 places far apart; each
    stays ``stay`` frames. Yields ``RawMessage``s, built as they go (no memory of their own)."""
    from mocapdb.runtime.stream.transport import RawMessage

    walk = _walking_px(db, stay)
    walk = (walk - walk.reshape(-1, 2).mean(axis=0)) * 0.25
    for i in range(n_messages):
        people = [{"keypoints": _coco17(walk[i - k] + [120 + 240 * (k % 64 % 8), 70 + 135 * (k % 64 // 8)])}
                  for k in range(max(i - stay + 1, 0), i + 1)]
        yield RawMessage(json.dumps({"frame": i, "time": i / 24.0, "layout": "coco17", "people": people}),
                         "flood", time.monotonic())


def _rss_bytes() -> int:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * resource.getpagesize()


def test_a_flood_of_new_people_makes_bounded_tracks_files_and_memory(small_db, tmp_path, capsys, caplog):
    summary = SessionSummary(stream=StreamStats())
    engine = Engine(small_db, EngineConfig(fps=24.0, limits=TrackLimits(max_tracks=8, max_new_per_min=60)))
    options = SessionOptions(strict=False, bvh_dir=tmp_path, max_bvh_files=20, rate_by_arrival=True)
    session = Session(engine, open_sink(str(tmp_path / "out.jsonl"), summary.stream), FrameParser(), summary, options)
    start = time.monotonic()
    for k, message in enumerate(_flood(small_db, 5000, stay=16)):
        session.handle(message)
        if k == 1000:
            rss_1000 = _rss_bytes()
        assert len(engine.book.tracks) <= 8 and len(engine.book.tracker._tracks.ids) <= 8
    minutes = (time.monotonic() - start) / 60.0
    growth = _rss_bytes() - rss_1000
    summary = session.finish()
    assert summary.frames == 5000 and summary.person_frames < 16 * 60 * (1 + minutes)
    assert 20 <= summary.tracks <= 60 * (1 + minutes)  # 5,000 without the limits
    assert sorted(tmp_path.glob("track_*.bvh")) == sorted(summary.bvh_files) and len(summary.bvh_files) == 20
    limits = summary.limits
    assert limits.over_max_tracks > 0 and limits.over_max_new > 0
    assert limits.over_max_files + limits.short_tracks == summary.tracks - 20
    assert growth < 20e6, f"RSS grew by {growth / 1e6:.0f} MB over 4,000 messages"
    assert caplog.text.count("--max-bvh-files 20 reached") == 1  # one warning, logged
    report = summary.report()
    for option in ("--max-tracks 8", "--max-new-tracks-per-min 60", "--max-bvh-files 20"):
        assert option in report


def test_the_limits_default_to_sensible_values():
    assert (TrackLimits().max_tracks, TrackLimits().max_new_per_min) == (32, 120)
    options = SessionOptions()
    assert (options.max_bvh_files, options.min_track_s, options.bvh_part_min) == (1000, 0.5, 10.0)
    with pytest.raises(ValueError):
        TrackLimits(max_tracks=-1)
    with pytest.raises(ValueError):
        SessionOptions(bvh_part_min=0)


def test_one_frame_tracks_get_no_bvh_and_are_reported(small_db, tmp_path):
    px = _walking_px(small_db, 30)
    session = _session(small_db, tmp_path, bvh_dir=tmp_path)
    for i in range(0, 600, 15):  # a person seen for 2 frames (a 1-frame track), then gone long enough to end
        for j in range(i, i + 15):
            people = [Person(px[i % 30], np.full(14, 0.9))] if j < i + 2 else []
            session.handle_frame(KeypointFrame(j, j / 24.0, people), 0.0)
    for i in range(600, 630):  # and one person for 1.25 s
        session.handle_frame(KeypointFrame(i, i / 24.0, [Person(px[i - 600], np.full(14, 0.9))]), 0.0)
    summary = session.finish()
    assert summary.limits.short_tracks == summary.tracks - 1 and len(summary.bvh_files) == 1
    assert "shorter than --min-track-s 0.5 s" in summary.report()


def test_a_long_track_is_written_in_parts_as_they_complete(small_db, tmp_path):
    px = _walking_px(small_db, 40)
    part_min = 15 / 24.0 / 60.0  # 15 frames
    session = _session(small_db, tmp_path, bvh_dir=tmp_path, bvh_part_min=part_min, checkpoint_s=0.0)
    names = []
    for i in range(40):
        session.handle_frame(KeypointFrame(i, i / 24.0, [Person(px[i], np.full(14, 0.9))]), 0.0)
        names.append(sorted(p.name for p in tmp_path.glob("track_*.bvh")))
        assert all(len(r.quaternions) < 15 for r in session.engine.open_recordings())  # memory per track
    assert names[13] == ["track_0.bvh"]  # a checkpoint of the open track (14 frames: over 0.5 s)
    assert names[14] == ["track_0_part1.bvh"]  # part 1 complete: it replaces the checkpoint
    summary = session.finish()
    assert [p.name for p in summary.bvh_files] == ["track_0_part1.bvh", "track_0_part2.bvh", "track_0_part3.bvh"]
    lengths = [len(p.read_text().split("Frame Time")[1].splitlines()) - 1 for p in summary.bvh_files]
    assert lengths == [15, 30, 40]  # 40 frames in parts of 15, 15 and 10, each padded back to input frame 0
    part2 = read_bvh(summary.bvh_files[1]).motion
    assert (part2[:15] == part2[15]).all() and (part2[15] != part2[16]).any()  # its first pose held


class _FailingSink(Sink):
    """A sink whose disk fills after ``n`` lines."""

    def __init__(self, n: int):
        super().__init__()
        self.n, self.closed = n, False

    def _put(self, text: str) -> None:
        self.n -= 1
        if self.n < 0:
            raise OSError(28, "No space left on device")

    def close(self) -> None:
        self.closed = True
        raise OSError(28, "No space left on device")  # the flush at close fails too


def test_a_sink_that_fails_stops_the_session_and_every_bvh_is_still_written(small_db, tmp_path):
    summary = SessionSummary(stream=StreamStats())
    sink = _FailingSink(25)
    session = Session(Engine(small_db, EngineConfig(fps=24.0)), sink, FrameParser(), summary,
                      SessionOptions(strict=False, bvh_dir=tmp_path, checkpoint_s=1e9))
    px = _walking_px(small_db, 40)
    with pytest.raises(SinkError, match="No space left"):
        for i in range(40):
            session.handle_frame(KeypointFrame(i, i / 24.0, [Person(px[i], np.full(14, 0.9)),
                                                             Person(px[i] + [600, 0], np.full(14, 0.9))]), 0.0)
    assert i == 24 and not list(tmp_path.glob("*.bvh"))
    summary = session.finish()
    assert sink.closed and "No space left" in summary.sink_error and "the sink failed" in summary.report()
    assert sorted(p.name for p in summary.bvh_files) == ["track_0.bvh", "track_1.bvh"]


def test_new_tracks_per_minute_count_by_arrival_time_in_live(small_db, tmp_path):
    px = _walking_px(small_db, 40)
    summary = SessionSummary(stream=StreamStats())
    engine = Engine(small_db, EngineConfig(fps=24.0, limits=TrackLimits(max_new_per_min=2)))
    session = Session(engine, open_sink(str(tmp_path / "out.jsonl"), summary.stream), FrameParser(), summary,
                      SessionOptions(strict=False, rate_by_arrival=True))
    started = []
    for i in range(40):  # three people side by side; 61 s pass (by arrival) after frame 19
        people = [Person(px[i] + [x, 0.0], np.full(14, 0.9)) for x in (-500.0, 0.0, 500.0)]
        session.handle_frame(KeypointFrame(i, i / 24.0, people), 0.0 if i < 20 else 61.0)
        started.append(engine.stats.tracks_started)
    assert started[1] == 2 and started[19] == 2 and started[20] == 3
    assert engine.stats.over_max_new == 19


def test_skip_reasons_are_whole_and_say_where(small_db, tmp_path):
    from mocapdb.runtime.stream.transport import RawMessage

    session = _session(small_db, tmp_path)
    session.handle(RawMessage('{"frame": 1, "people": [' + " " * 300 + "x]}", "in.jsonl line 7", 0.0))
    report = session.finish(tmp_path).report()
    assert "not JSON (Expecting value at line 1 column" in report and "first in in.jsonl line 7" in report


def test_checkpoints_leave_out_the_whole_takes_refit_and_the_final_files_have_it(small_db, tmp_path, monkeypatch):
    """A live checkpoint waits in the loop, so it skips the whole take's re-fit to the image (its
    costliest step); the files written when the track ends have it."""
    import mocapdb.runtime.stream.track_files as track_files_module
    from mocapdb.runtime.take import fit_take
    from mocapdb.runtime.take_params import TakeParams

    calls = []

    def recording_fit_take(rec, fps, params):
        calls.append(params.refit_prior)
        return fit_take(rec, fps, params)

    monkeypatch.setattr(track_files_module, "fit_take", recording_fit_take)
    px = _walking_px(small_db, 30)
    summary = SessionSummary(stream=StreamStats())
    engine = Engine(small_db, EngineConfig(fps=24.0, keep_take=True))
    session = Session(engine, open_sink(str(tmp_path / "out.jsonl"), summary.stream), FrameParser(), summary,
                      SessionOptions(bvh_dir=tmp_path, checkpoint_s=0.0, take=TakeParams()))
    for i in range(30):
        session.handle_frame(KeypointFrame(i, i / 24.0, [Person(px[i], np.full(14, 0.9))]), 0.0)
    checkpoints = len(calls)
    session.finish()
    assert checkpoints > 5 and set(calls[:checkpoints]) == {0.0}
    assert calls[checkpoints:] == [TakeParams().refit_prior]


def _parts_run(db, folder, background: bool) -> dict[str, bytes]:
    """40 frames of one person in 15-frame parts with a checkpoint at every frame; the files written."""
    px = _walking_px(db, 40)
    folder.mkdir()
    session = _session(db, folder, bvh_dir=folder, bvh_part_min=15 / 24.0 / 60.0, checkpoint_s=0.0,
                       write_in_background=background)
    for i in range(40):
        session.handle_frame(KeypointFrame(i, i / 24.0, [Person(px[i], np.full(14, 0.9))]), 0.0)
    summary = session.finish()
    assert summary.bvh_files == sorted(folder.glob("track_*.bvh"))
    return {p.name: p.read_bytes() for p in summary.bvh_files}


def test_track_files_written_by_the_writer_thread_are_those_written_in_the_loop(small_db, tmp_path):
    """live writes track files on a thread of its own (checkpoints, parts replacing them, the last
    part), in the order the loop asked for them: the same files, byte for byte."""
    in_loop = _parts_run(small_db, tmp_path / "loop", background=False)
    threaded = _parts_run(small_db, tmp_path / "thread", background=True)
    assert list(threaded) == ["track_0_part1.bvh", "track_0_part2.bvh", "track_0_part3.bvh"]
    assert threaded == in_loop


def test_a_writer_thread_error_reaches_the_session(small_db, tmp_path, monkeypatch):
    import mocapdb.runtime.stream.track_files as track_files_module

    def full_disk(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(track_files_module, "write_track_files", full_disk)
    px = _walking_px(small_db, 30)
    session = _session(small_db, tmp_path, bvh_dir=tmp_path, checkpoint_s=0.0, write_in_background=True)
    with pytest.raises(OSError, match="No space left"):  # a checkpoint's error, at a later frame
        for i in range(30):
            session.handle_frame(KeypointFrame(i, i / 24.0, [Person(px[i], np.full(14, 0.9))]), 0.0)
    with pytest.raises(OSError, match="No space left"):  # the files due at the end fail too
        session.finish()
    assert not any(t.name == "mocapdb-track-files" for t in threading.enumerate())  # the writer is gone


def test_a_checkpoint_on_the_writer_thread_is_of_the_track_as_it_was():
    """The engine records on while the writer thread writes an open track's checkpoint: the
    snapshot it is given keeps its frames."""
    from mocapdb.core.outputs import TrackRecording

    row = dict(quaternions=np.ones((11, 4)), root_view_m=np.zeros(3), scales=1.0, fit_quaternions=np.ones((11, 4)),
               fit_root_view_m=np.zeros(3), keypoints=np.ones((14, 3)), extremities=np.ones((8, 3)))
    rec = TrackRecording(3, 0)
    rec.frames.append(**row)
    frozen = rec.snapshot()
    for _ in range(20):  # past the first capacity: the arrays grow
        rec.frames.append(**{name: np.zeros_like(value) for name, value in row.items()})
    assert len(rec) == 21 and len(frozen) == 1
    assert all(np.array_equal(frozen.column(name)[0], value) for name, value in row.items())
    assert frozen.track == 3 and frozen.scales == [1.0]
