"""The reconstruct/live loop: outputs, malformed input, BVH files, TCP streaming, the CLI."""
import json
import socket
import threading
import time

import numpy as np
import pytest

from mocapdb.cli.main import main
from mocapdb.core.cameras import DatabaseCamera
from mocapdb.core.formats.bvh import forward_kinematics, read_bvh
from mocapdb.core.formats.trc import read_trc
from mocapdb.core.geometry import project_views
from mocapdb.core.skeleton import PELVIS
from mocapdb.runtime.engine import Engine
from mocapdb.runtime.engine_config import EngineConfig
from mocapdb.runtime.stream.session import FrameParser, Session, run_live, run_offline
from mocapdb.runtime.stream.session_options import SessionOptions
from mocapdb.runtime.stream.session_summary import SessionSummary
from mocapdb.runtime.stream.transport import StreamStats, open_sink, open_source

from .conftest import SAMPLE_KEYPOINTS

BVH_NODE_OF_JOINT = {"r_knee_End": 10, "l_elbow_End": 7, "neck_End": 0, "pelvis": 14, "r_shoulder": 2}


def _stream_lines(db, n_frames: int = 30) -> list[str]:
    """JSON-lines input (COCO-17 layout) of a database clip seen from the database camera."""
    pos = db.positions[:n_frames].astype(np.float64)
    px = project_views(pos, pos[:, PELVIS], np.array([36.0]), 0.0, DatabaseCamera(**db.meta["camera"]))[:, 0, :14]
    coco_of_universal = {0: 0, 2: 6, 3: 8, 4: 10, 5: 5, 6: 7, 7: 9, 8: 12, 9: 14, 10: 16, 11: 11, 12: 13, 13: 15}
    lines = []
    for i in range(n_frames):
        kp = np.zeros((17, 3))
        for u, c in coco_of_universal.items():
            kp[c] = [px[i, u, 0], px[i, u, 1], 0.9]
        lines.append(json.dumps({"frame": i, "layout": "coco17", "people": [{"keypoints": kp.tolist()}]}))
    return lines


def test_offline_session_outputs_and_bvh_agree(small_db, tmp_path):
    lines = _stream_lines(small_db)
    lines.insert(5, "{not json")
    lines.insert(9, json.dumps({"frame": 99, "people": [{"keypoints": [[1, 2]]}]}))
    (tmp_path / "in.jsonl").write_text("\n".join(lines) + "\n")
    summary = SessionSummary(stream=StreamStats())
    engine = Engine(small_db, EngineConfig(fps=24.0))
    session = Session(engine, open_sink(str(tmp_path / "out.jsonl"), summary.stream), FrameParser(), summary,
                      SessionOptions(online_take=False))  # the per-frame stream, as the per-frame track files
    run_offline(session, open_source(str(tmp_path / "in.jsonl"), stats=summary.stream))
    session.finish(tmp_path)
    assert summary.frames == 30 and sum(summary.malformed.values()) == 2
    out = [json.loads(line) for line in (tmp_path / "out.jsonl").read_text().splitlines()]
    assert out[0]["format"] == "mocapdb-stream" and len(out) == 31
    people = [f["people"][0] for f in out[1:] if f["people"]]
    assert len(people) == 29 and all(len(p["joints"]) == 15 and len(p["quaternions"]) == 11 for p in people)
    bvh = read_bvh(tmp_path / "track_0.bvh")
    assert bvh.n_frames == 30 and bvh.fps == pytest.approx(24.0)  # from the first detection: a frame before the stream
    fk = forward_kinematics(bvh)[0][1:]
    # The BVH holds the track's final body; the stream's bones are the running estimate, which moves
    # by millimetres while it settles: the last frames (settled) agree to 2 mm, all to 1 cm.
    for name, joint in BVH_NODE_OF_JOINT.items():
        view = np.array([p["joints"][joint] for p in people]) * [1, 1, -1]  # camera-aligned → BVH frame
        np.testing.assert_allclose(fk[-8:, bvh.index(name)], view[-8:], atol=2e-3)
        np.testing.assert_allclose(fk[:, bvh.index(name)], view, atol=1e-2)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_live_over_tcp(small_db, tmp_path):
    port = _free_port()
    summary = SessionSummary(stream=StreamStats())
    session = Session(Engine(small_db, EngineConfig(fps=24.0)), open_sink(str(tmp_path / "live.jsonl"), summary.stream),
                      FrameParser(), summary)
    source = open_source(f"tcp://127.0.0.1:{port}", stats=summary.stream)
    stop = threading.Event()
    loop = threading.Thread(target=run_live, args=(session, source, stop))
    loop.start()
    lines = _stream_lines(small_db, 20)
    with socket.create_connection(("127.0.0.1", port), timeout=2) as client:
        for line in lines[:10] + ["garbage"] + lines[10:]:
            client.sendall((line + "\n").encode())
            time.sleep(0.01)
    deadline = time.monotonic() + 5
    while summary.frames + summary.stream.dropped_stale < 20 and time.monotonic() < deadline:
        time.sleep(0.02)
    stop.set()
    loop.join(timeout=5)
    assert not loop.is_alive()
    session.finish(tmp_path / "bvh")
    assert summary.frames + summary.stream.dropped_stale == 20
    assert sum(summary.malformed.values()) == 1
    assert (tmp_path / "bvh" / "track_0.bvh").exists()
    assert "latency capture → send p50" in summary.report()


def test_cli_reconstruct_real_openpose_folder(small_db_path, tmp_path, capsys):
    args = ["reconstruct", str(SAMPLE_KEYPOINTS), "--db", str(small_db_path), "--out", str(tmp_path),
            "--fps", "60", "--image-size", "1088x1920", "--focal", "1681"]
    assert main(args) == 0
    report = capsys.readouterr().out
    assert "frames 100" in report
    frames = (tmp_path / "result.jsonl").read_text().splitlines()
    assert len(frames) == 101
    assert list(tmp_path.glob("track_*.bvh"))


@pytest.mark.parametrize("args, message", [
    (["reconstruct", "nowhere", "--db", "{db}", "--out", "{tmp}"], "argument input: nowhere: no such file or folder"),
    (["reconstruct", "{keypoints}", "--db", "{tmp}/missing", "--out", "{tmp}"], "missing: no such folder"),
    (["reconstruct", "{keypoints}", "--db", "{db}", "--out", "{tmp}", "--image-size", "big"], "WIDTHxHEIGHT"),
    (["live", "--source", "tcp://nohostport", "--db", "{db}"], "HOST:PORT"),
])
def test_cli_bad_inputs_give_clear_errors(small_db_path, tmp_path, capsys, args, message):
    fill = {"db": str(small_db_path), "tmp": str(tmp_path), "keypoints": str(SAMPLE_KEYPOINTS)}
    assert main([a.format(**fill) for a in args]) == 2
    assert message in capsys.readouterr().err


def test_cli_reconstruct_coco17_array(small_db, small_db_path, tmp_path, capsys):
    lines = [json.loads(line) for line in _stream_lines(small_db, 24)]
    array = np.array([frame["people"][0]["keypoints"] for frame in lines])  # [T, 17, 3]
    np.save(tmp_path / "kp.npy", array)
    assert main(["reconstruct", str(tmp_path / "kp.npy"), "--db", str(small_db_path), "--out", str(tmp_path / "out"),
                 "--fps", "24"]) == 0
    assert "frames 24" in capsys.readouterr().out
    assert (tmp_path / "out" / "track_0.bvh").exists()


@pytest.mark.parametrize("start, bvh_frames", [("input", 36), ("track", 24)])
def test_cli_track_files_line_up_with_the_input(small_db, small_db_path, tmp_path, start, bvh_frames):
    # The person comes in at input frame 12 (24 fps): the BVH starts at input frame 0, the track's first
    # pose held until then, unless --bvh-start track; TRC Frame# and CSV frame are the input's either way.
    lines = [json.dumps({"frame": i, "people": []}) for i in range(12)]
    lines += [json.dumps({**json.loads(line), "frame": 12 + i}) for i, line in enumerate(_stream_lines(small_db, 24))]
    (tmp_path / "in.jsonl").write_text("\n".join(lines) + "\n")
    out = tmp_path / "out"
    assert main(["reconstruct", str(tmp_path / "in.jsonl"), "--db", str(small_db_path), "--out", str(out),
                 "--fps", "24", "--format", "bvh,trc,csv", "--bvh-start", start]) == 0
    bvh = read_bvh(out / "track_0.bvh")
    assert bvh.n_frames == bvh_frames and (bvh.motion[: bvh_frames - 23] == bvh.motion[bvh_frames - 24]).all()
    assert (bvh.motion[bvh_frames - 24] != bvh.motion[bvh_frames - 1]).any()
    trc = read_trc(out / "track_0.trc")
    np.testing.assert_array_equal(trc.frame_numbers, np.arange(13, 37))
    np.testing.assert_allclose(trc.times_s, np.arange(12, 36) / 24.0, atol=1e-6)
    csv_frames = [int(row.split(",")[0]) for row in (out / "track_0.csv").read_text().splitlines()[1:]]
    assert csv_frames == list(range(12, 36))


def test_live_process_stops_cleanly_on_sigint(small_db, small_db_path, tmp_path):
    import signal
    import subprocess
    import sys

    port = _free_port()
    proc = subprocess.Popen([sys.executable, "-m", "mocapdb", "live", "--source", f"tcp://127.0.0.1:{port}",
                             "--db", str(small_db_path), "--sink", str(tmp_path / "out.jsonl"),
                             "--bvh-dir", str(tmp_path)], stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 20
    while True:  # wait until the process listens
        try:
            client = socket.create_connection(("127.0.0.1", port), timeout=1)
            break
        except OSError:
            assert time.monotonic() < deadline and proc.poll() is None
            time.sleep(0.05)
    with client:
        for line in _stream_lines(small_db, 30):
            client.sendall((line + "\n").encode())
            time.sleep(1 / 30)  # a 30 fps detector
    time.sleep(0.5)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=20)
    assert proc.returncode == 0, err
    processed = int(err.split("frames ")[1].split(",")[0])
    stale = int(err.split("stale ")[1].split(",")[0])
    assert processed + stale == 30 and processed >= 15
    assert (tmp_path / "track_0.bvh").exists()


def _live_process(small_db_path, tmp_path, *extra, **popen):
    import subprocess
    import sys

    return subprocess.Popen([sys.executable, "-m", "mocapdb", "live", "--db", str(small_db_path), "--fps", "30",
                             "--bvh-dir", str(tmp_path), *extra], stderr=subprocess.PIPE, text=True, **popen)


def _connect(port: int, proc) -> socket.socket:
    deadline = time.monotonic() + 20
    while True:  # wait until the process listens
        try:
            return socket.create_connection(("127.0.0.1", port), timeout=1)
        except OSError:
            assert time.monotonic() < deadline and proc.poll() is None
            time.sleep(0.05)


def test_live_process_writes_its_bvh_files_through_a_second_sigterm(small_db, small_db_path, tmp_path):
    import signal

    port = _free_port()
    # --buffer 1000: on a loaded machine the engine may fall behind a 30 fps stream for a moment, and
    # the default buffer of 2 would then drop frames (what is tested here is the signals, not the rate)
    proc = _live_process(small_db_path, tmp_path, "--source", f"tcp://127.0.0.1:{port}",
                         "--sink", str(tmp_path / "out.jsonl"), "--buffer", "1000")
    with _connect(port, proc) as client:
        for line in _stream_lines(small_db, 30):
            client.sendall((line + "\n").encode())
            time.sleep(1 / 30)
        time.sleep(0.5)
        proc.send_signal(signal.SIGTERM)
        time.sleep(0.005)
        proc.send_signal(signal.SIGTERM)  # while it stops: ignored, never fatal
        _, err = proc.communicate(timeout=20)
    assert proc.returncode == 0, err
    assert "further signals are ignored" in err and "frames 30" in err
    assert read_bvh(tmp_path / "track_0.bvh").n_frames == 30


def test_live_process_whose_stdout_closes_stops_and_still_writes_its_bvh_files(small_db, small_db_path, tmp_path):
    import subprocess

    proc = _live_process(small_db_path, tmp_path, "--source", "-", "--sink", "-", "--buffer", "1000",
                         stdin=subprocess.PIPE, stdout=subprocess.PIPE)
    proc.stdin.write("".join(line + "\n" for line in _stream_lines(small_db, 60)))
    proc.stdin.flush()
    for _ in range(21):  # the header and 20 frames, then the consumer goes away
        assert proc.stdout.readline()
    proc.stdout.close()
    _, err = proc.communicate(timeout=20)
    assert proc.returncode == 1, err
    assert "mocapdb live: error: the sink - failed" in err and "wrote 1 BVH file(s)" in err
    assert "Traceback" not in err and "Exception ignored" not in err
    assert 20 <= read_bvh(tmp_path / "track_0.bvh").n_frames < 59


def test_live_cli_with_a_failing_sink_exits_non_zero_after_writing_the_bvh_files(small_db, small_db_path, tmp_path,
                                                                                  capsys, monkeypatch):
    import mocapdb.runtime.stream.transport
    from mocapdb.runtime.stream.sinks import Sink

    class FullDisk(Sink):
        def __init__(self, stats):
            super().__init__(stats)
            self.lines = 0

        def _put(self, text):
            self.lines += 1
            if self.lines > 20:
                raise OSError(28, "No space left on device")

        def close(self):
            pass

    monkeypatch.setattr(mocapdb.runtime.stream.transport, "open_sink", lambda spec, stats, *vmc_track: FullDisk(stats))
    (tmp_path / "in.jsonl").write_text("\n".join(_stream_lines(small_db, 40)) + "\n")
    assert main(["live", "--source", str(tmp_path / "in.jsonl"), "--db", str(small_db_path), "--fps", "24",
                 "--sink", str(tmp_path / "out.jsonl"), "--bvh-dir", str(tmp_path / "bvh"), "--buffer", "100",
                 "--idle-timeout", "5"]) == 1
    err = capsys.readouterr().err
    assert "out.jsonl failed ([Errno 28] No space left on device): the stream stopped there" in err
    assert "output stopped: the sink failed" in err
    assert read_bvh(tmp_path / "bvh" / "track_0.bvh").n_frames == 20  # frames 0–19: the last one failed to go out


def test_track_files_hold_the_person_from_the_first_frame_and_the_static_track_stays_out(small_db_path, tmp_path):
    # The sample's person is detected in all its 100 frames, as is a false person that never moves. The
    # stream is causal: a track is confirmed on its second frame and shown from there; its files hold
    # the frame before as well (they used to start at frame 1: 99 frames for 100).
    out = tmp_path / "out"
    assert main(["reconstruct", str(SAMPLE_KEYPOINTS), "--db", str(small_db_path), "--out", str(out), "--fps", "60",
                 "--image-size", "1088x1920", "--focal", "1681", "--format", "bvh,csv"]) == 0
    stream = [json.loads(line) for line in (out / "result.jsonl").read_text().splitlines()[1:]]
    assert [f["frame"] for f in stream if any(p["track"] == 1 for p in f["people"])] == list(range(1, 100))
    assert sorted(p.name for p in out.glob("track_*")) == ["track_1.bvh", "track_1.csv"]  # static track 0: none
    assert read_bvh(out / "track_1.bvh").n_frames == 100
    assert [int(row.split(",")[0]) for row in (out / "track_1.csv").read_text().splitlines()[1:]] == list(range(100))


@pytest.mark.parametrize("option, value", [("--max-tracks", "-1"), ("--max-bvh-files", "-5"),
                                           ("--min-track-s", "-0.1"), ("--bvh-part-min", "0")])
def test_cli_rejects_bad_limits(small_db_path, tmp_path, capsys, option, value):
    assert main(["reconstruct", str(SAMPLE_KEYPOINTS), "--db", str(small_db_path), "--out", str(tmp_path / "o"),
                 option, value]) == 2
    assert option in capsys.readouterr().err


def test_cli_reports_what_the_limits_held_back(small_db_path, tmp_path, capsys):
    assert main(["reconstruct", str(SAMPLE_KEYPOINTS), "--db", str(small_db_path), "--out", str(tmp_path),
                 "--fps", "60", "--image-size", "1088x1920", "--focal", "1681", "--max-tracks", "1"]) == 0
    out = capsys.readouterr().out
    # The one track goes to the leftmost detection: the false one at the image's edge (static, no BVH).
    assert "limits: detections not tracked (--max-tracks 1 alive): 100" in out and "static tracks" in out
    assert not list(tmp_path.glob("track_*.bvh"))


def test_live_never_writes_over_earlier_track_files_nor_touches_others(small_db_path, tmp_path, capsys):
    """``--bvh-dir`` holding an earlier run's track file is refused before any work; a folder of the
    user's other files gets the new track files beside them, the others untouched."""
    import shutil

    frames = tmp_path / "frames"
    shutil.copytree(SAMPLE_KEYPOINTS, frames)
    earlier, users = tmp_path / "earlier", tmp_path / "users"
    earlier.mkdir()
    (earlier / "track_1.bvh").write_text("an earlier capture")
    users.mkdir()
    (users / "notes.txt").write_text("the user's notes")
    live = ["live", "--source", str(frames), "--db", str(small_db_path), "--sink", str(tmp_path / "out.jsonl"),
            "--idle-timeout", "1", "--buffer", "10000", "--fps", "60", "--image-size", "1088x1920", "--focal", "1681"]
    assert main([*live, "--bvh-dir", str(earlier)]) == 2
    err = capsys.readouterr().err
    assert "--bvh-dir already holds track files (track_1.bvh)" in err and err.count("\n") == 1
    assert (earlier / "track_1.bvh").read_text() == "an earlier capture" and not (tmp_path / "out.jsonl").exists()
    assert main([*live, "--bvh-dir", str(users)]) == 0
    assert (users / "notes.txt").read_text() == "the user's notes"
    assert sorted(p.name for p in users.iterdir()) == ["notes.txt", "track_1.bvh"]


def test_the_summary_s_throughput_counts_from_the_first_frame_processed():
    """11 frames, the last 10 in 2 s after the first was processed, in a 10 s session (models loaded,
    the first frame compiled): 5 frames/s, not 1.1."""
    report = SessionSummary(frames=11, wall_s=10.0, steady_s=2.0).report()
    assert "throughput 5.0 frames/s from the first frame processed (over 2.00 s), session 10.00 s" in report
