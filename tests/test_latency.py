"""End-to-end latency (issue 50, item 3): the bookkeeping on known timestamps, and a real VMC receiver on
loopback (tools/vmc_receiver.py, python-osc, its own process) whose arrival times agree with what the
session reports, the stream's lag included."""
import json
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from mocapdb.runtime.engine import Engine
from mocapdb.runtime.engine_config import EngineConfig
from mocapdb.runtime.stream.latency import MAX_PENDING, LatencyBook, steady_stream
from mocapdb.runtime.stream.osc_sinks import VmcSink
from mocapdb.runtime.stream.session import FrameParser, Session
from mocapdb.runtime.stream.session_options import SessionOptions
from mocapdb.runtime.stream.session_summary import SessionSummary
from mocapdb.runtime.stream.sinks import FileSink, Sink, TcpSink, TeeSink
from mocapdb.runtime.stream.transport import RawMessage, StreamStats

from .test_session import _stream_lines

RECEIVER = Path(__file__).resolve().parents[1] / "tools" / "vmc_receiver.py"
FPS = 24.0
FRAME_GAP_S = 0.04   # the frames are handed to the session this far apart, as a camera would


def test_percentiles_and_lag_from_known_timestamps():
    """A start-up frame (captured at 0 s, sent at 1 s), then five frames captured 100 ms apart from 1.1 s at
    10 fps, each sent two frames later: latencies 250, 230, 270, 210, 290 ms; by hand, p50 250 ms, p99
    270 + 0.96 × 20 = 289.2 ms (linear between the 4th and 5th); the lag 2 frames, 200 ms at 10 fps; the
    start-up frame left out."""
    book = LatencyBook(fps=10.0)
    book.captured(0, 0.0)
    book.sent(0, 1.0)
    latencies = [0.25, 0.23, 0.27, 0.21, 0.29]
    for i in range(2, 9):
        book.captured(i, 1.1 + 0.1 * (i - 2))
        if i >= 4:
            book.sent(i - 2, 1.1 + 0.1 * (i - 4) + latencies[i - 4])
    assert book.startup_frames == 1               # frame 0, captured before the first send
    assert book.percentiles_ms() == pytest.approx((250.0, 289.2))
    assert book.lag() == pytest.approx((2.0, 200.0))
    assert book.line() == ("latency capture → send p50 250.00 ms, p99 289.20 ms (5 frames, 1 start-up frames left "
                           "out); lag 2 frames (200.0 ms at 10 fps)")


def test_a_frame_is_counted_once_and_frames_never_sent_are_forgotten():
    book = LatencyBook(fps=30.0)
    book.captured(5, 0.0)
    book.sent(5, 0.9)           # the first send (its frame a start-up one)
    book.captured(0, 1.0)
    book.captured(1, 1.1)
    book.sent(1, 1.2)           # frame 0 was never sent (an avatar not finite): forgotten, not counted
    book.sent(1, 5.0)           # sent again (a second sink): the first send counts
    book.sent(0, 1.3)
    book.sent(7, 1.4)           # never taken
    assert book.latencies_s == pytest.approx([0.1]) and book.lags == [0] and book.startup_frames == 1
    for i in range(MAX_PENDING + 10):   # frames taken, none sent: memory stays bounded
        book.captured(100 + i, 2.0)
    assert len(book._pending) == MAX_PENDING
    assert LatencyBook().line().startswith("latency capture → send p50 nan ms, p99 nan ms (0 frames, 0 start-up")


class _Recording(Sink):
    def __init__(self) -> None:
        super().__init__()
        self.lines: list[str] = []

    def _put(self, text: str) -> None:
        self.lines.append(text)

    def close(self) -> None:
        pass


def test_a_steady_stream_sets_the_start_up_aside_from_the_collector_and_gives_it_back(monkeypatch):
    """Inside steady_stream the objects alive at its start are frozen (gc.get_freeze_count), a cycle made
    inside is still collected, and on leaving (an error too) nothing stays frozen; the cached kernels are
    loaded on entry (load_cached_kernels: tests/test_kernel_cache.py)."""
    import gc

    from mocapdb.runtime.stream import latency

    loads = []
    monkeypatch.setattr(latency, "load_cached_kernels", lambda: loads.append(gc.get_freeze_count()))
    alive = [object() for _ in range(1000)]
    with steady_stream():
        assert loads == [0] and gc.get_freeze_count() >= len(alive)
        cycle: list = []
        cycle.append(cycle)
        del cycle
        assert gc.collect() >= 1
    assert gc.get_freeze_count() == 0
    with pytest.raises(RuntimeError), steady_stream():
        raise RuntimeError("the stream failed")
    assert gc.get_freeze_count() == 0 and len(loads) == 2


def test_a_tee_reports_its_first_sink_s_send_and_tcp_its_sender_thread_s(tmp_path):
    sent: list[int] = []
    first, second = _Recording(), _Recording()
    tee = TeeSink([first, second])
    tee.notify_sent(sent.append)
    tee.write_frame(4, 0.1, [])
    assert sent == [4] and len(first.lines) == len(second.lines) == 1
    with socket.socket() as server:
        server.bind(("127.0.0.1", 0))
        server.listen(1)
        sink = TcpSink("127.0.0.1", server.getsockname()[1])
        tcp_sent: list[int] = []
        sink.notify_sent(tcp_sent.append)
        conn, _ = server.accept()
        with conn:
            sink.write_frame(9, 0.2, [])
            received = b""
            while not received.endswith(b"\n"):
                received += conn.recv(65536)
            sink.close()
    assert tcp_sent == [9] and json.loads(received)["frame"] == 9
    file_sink = FileSink(tmp_path / "out.jsonl")
    file_sink.notify_sent(sent.append)
    file_sink.write("a header")    # a line, not a frame: nothing sent
    file_sink.write_frame(5, 0.2, [])
    file_sink.close()
    assert sent == [4, 5]


def _receiver(times: Path) -> tuple[subprocess.Popen, int]:
    proc = subprocess.Popen([sys.executable, str(RECEIVER), "--port", "0", "--seconds", "60", "--times", str(times)],
                            stdout=subprocess.PIPE, text=True)
    line = proc.stdout.readline()
    assert line.startswith("listening on 127.0.0.1:"), line
    return proc, int(line.rsplit(":", 1)[1])


@pytest.mark.parametrize("lag", [0, 3])
def test_a_vmc_receiver_sees_the_latency_and_the_lag_the_session_reports(small_db, tmp_path, lag):
    """A person walking (30 frames) handed to the session 40 ms apart, each captured 0-16 ms before it is
    taken (as if it waited in the input buffer), sent by the VMC sink to tools/vmc_receiver.py in its own
    process. Each frame's arrival there less its capture time is the latency the session reports within
    3 ms at the median and 10 ms at p99 (loopback delivery and the receiver's wake-up on a busy machine),
    the frames captured before the first one arrived (start-up: lag + 1 of them) left out on both sides;
    frame k arrives after frame k + lag was taken and before frame k + lag + 1 was (the lag reported)."""
    times = tmp_path / "arrivals.txt"
    proc, port = _receiver(times)
    summary = SessionSummary(stream=StreamStats())
    session = Session(Engine(small_db, EngineConfig(fps=FPS)), VmcSink("127.0.0.1", port), FrameParser(), summary,
                      SessionOptions(lag_frames=lag))
    capture, taken = {}, {}
    try:
        for k, line in enumerate(_stream_lines(small_db)):
            time.sleep(FRAME_GAP_S)
            frame = session.parser(RawMessage(line, "test", time.monotonic()))
            taken[k] = time.monotonic()
            capture[k] = taken[k] - 0.004 * (k % 5)
            session.handle_frame(frame, capture[k])
        session.finish()
        time.sleep(0.2)
    finally:
        proc.send_signal(signal.SIGINT)
        proc.communicate(timeout=10)
    arrivals = np.loadtxt(times, ndmin=2)
    frames = np.rint(arrivals[:, 1] * FPS).astype(int)
    assert list(frames) == list(range(len(capture)))          # every frame, in order, once
    steady = [k for k in frames if capture[k] >= arrivals[0, 0]]   # captured after the first frame arrived
    seen_ms = (arrivals[steady, 0] - np.array([capture[k] for k in steady])) * 1000.0
    reported = summary.latency
    assert reported.startup_frames == lag + 1
    assert len(reported.latencies_s) == len(steady) == len(frames) - lag - 1
    p50, p99 = reported.percentiles_ms()
    assert abs(np.percentile(seen_ms, 50) - p50) <= 3.0 and abs(np.percentile(seen_ms, 99) - p99) <= 10.0
    assert reported.lag() == pytest.approx((lag, lag * 1000.0 / FPS))
    held = [k for k in frames if k + lag + 1 in taken]   # the last frames are sent at the end (finish)
    assert all(taken[k + lag] < arrivals[k, 0] < taken[k + lag + 1] for k in held)
    assert f"lag {lag} frames ({lag * 1000.0 / FPS:.1f} ms at 24 fps)" in summary.report()
