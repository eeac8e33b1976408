"""Sources, sinks, the drop-oldest live buffer and the stop signals, over real loopback sockets."""
import io
import os
import signal
import socket
import sys
import threading
import time

import pytest

from runtime.streams import (LiveInput, RawMessage, StreamSpecError, StreamStats, install_stop_handlers,
                             open_sink, open_source)

LOOPBACK = "127.0.0.1"


def drain(live: LiveInput, n: int, timeout_s: float = 1.0) -> list[RawMessage]:
    """Up to n messages, waiting at most timeout_s in all."""
    deadline, got = time.monotonic() + timeout_s, []
    while len(got) < n and (left := deadline - time.monotonic()) > 0:
        if (msg := live.get(timeout=left)) is not None:
            got.append(msg)
    return got


def payloads(messages: list[RawMessage]) -> list[str]:
    return [m.payload for m in messages]


def frame_file(folder, frame: int) -> str:
    """Writes an OpenPose-named frame file; returns its text."""
    text = f'{{"frame": {frame}}}'
    (folder / f"cam_{frame:012d}_keypoints.json").write_text(text)
    return text


def no_stream_threads() -> bool:
    return not any(t.name.startswith("mocapdb-") for t in threading.enumerate())


def free_port() -> int:
    with socket.socket() as s:
        s.bind((LOOPBACK, 0))
        return s.getsockname()[1]


# --- sources -------------------------------------------------------------------------------------

def test_folder_source_follows_new_files_in_frame_order_and_waits_for_half_written(tmp_path):
    expected = [frame_file(tmp_path, 1), frame_file(tmp_path, 0)][::-1]
    (tmp_path / "notes.txt").write_text("not a frame")
    with LiveInput(open_source(str(tmp_path), follow=True, settle_s=5.0), capacity=16) as live:
        assert payloads(drain(live, 2)) == expected
        written_later = frame_file(tmp_path, 2)
        assert payloads(drain(live, 1)) == [written_later]
        half = tmp_path / f"cam_{3:012d}_keypoints.json"
        with open(half, "w") as f:
            f.write('{"frame": 3, "people": [')
            f.flush()
            later = frame_file(tmp_path, 4)
            time.sleep(0.15)   # several polls with the file unchanged
            assert live.get(timeout=0) is None   # neither the half file nor the frame after it
            f.write("]}")
        got = drain(live, 2)
    assert payloads(got) == ['{"frame": 3, "people": []}', later]
    assert got[0].origin == str(half)
    assert live.stats.messages_in == 5
    assert no_stream_threads()


def test_folder_source_passes_on_an_unparsable_file_once_settled(tmp_path):
    (tmp_path / "cam_000000000000_keypoints.json").write_text("{broken")
    with LiveInput(open_source(str(tmp_path), follow=True, settle_s=0.1), capacity=4) as live:
        assert payloads(drain(live, 1)) == ["{broken"]


def test_folder_source_offline_reads_existing_files_in_natural_order(tmp_path):
    for name in ("f10.json", "f2.json", "f1.json"):
        (tmp_path / name).write_text(f'{{"name": "{name}"}}')
    (tmp_path / "f3.json").write_bytes(b'{"bad": "\xff"}')
    with open_source(str(tmp_path)) as source:
        names = [m.origin.rsplit(os.sep, 1)[1] for m in source]
    assert names == ["f1.json", "f2.json", "f10.json"]
    assert source.stats.decode_errors == 1


def test_folder_source_ends_after_idle_timeout(tmp_path):
    frame_file(tmp_path, 0)
    with LiveInput(open_source(str(tmp_path), follow=True, idle_timeout_s=0.1)) as live:
        assert len(drain(live, 1)) == 1
        deadline = time.monotonic() + 1.0
        while not live.finished and time.monotonic() < deadline:
            time.sleep(0.01)
        assert live.finished


def test_jsonl_file_source_skips_blank_and_non_utf8_lines(tmp_path):
    path = tmp_path / "keypoints.jsonl"
    path.write_bytes(b'{"a": 1}\r\n\n   \n{"b": 2}\n\xff\xfe\n{"c": 3}')
    with open_source(str(path)) as source:
        got = list(source)
    assert payloads(got) == ['{"a": 1}', '{"b": 2}', '{"c": 3}']
    assert [m.origin for m in got] == [f"{path}:line {n}" for n in (1, 4, 6)]
    assert (source.stats.messages_in, source.stats.decode_errors) == (3, 1)


@pytest.mark.parametrize("kind", ["stringio", "pipe"])
def test_stdin_source(monkeypatch, kind):
    data = '{"a": 1}\n\n{"b": 2}\n'
    if kind == "stringio":
        stream = io.StringIO(data)
    else:
        read_fd, write_fd = os.pipe()
        os.write(write_fd, data.encode())
        os.close(write_fd)
        stream = os.fdopen(read_fd)
    monkeypatch.setattr(sys, "stdin", stream)
    with stream, open_source("-") as source:
        got = list(source)
    assert payloads(got) == ['{"a": 1}', '{"b": 2}']
    assert [m.origin for m in got] == ["stdin:line 1", "stdin:line 3"]


def test_tcp_source_joins_split_lines_and_accepts_the_next_client():
    with LiveInput(open_source(f"tcp://{LOOPBACK}:0"), capacity=16) as live:
        port = live.source.address[1]
        with socket.create_connection((LOOPBACK, port), timeout=1.0) as client:
            for part in (b'{"a":', b' 1}\n{"b"', b': 2}\n'):
                client.sendall(part)
                time.sleep(0.02)   # separate reads on the server
        with socket.create_connection((LOOPBACK, port), timeout=1.0) as client:
            client.sendall(b'{"c": 3}\n')
        got = drain(live, 3)
    live.close()   # idempotent
    assert payloads(got) == ['{"a": 1}', '{"b": 2}', '{"c": 3}']
    assert all(m.origin.startswith(f"tcp:{LOOPBACK}:") for m in got)
    assert live.stats.reconnects == 1
    assert no_stream_threads()


def test_tcp_source_drops_and_counts_an_oversized_line():
    with LiveInput(open_source(f"tcp://{LOOPBACK}:0", max_message_bytes=64), capacity=4) as live:
        with socket.create_connection((LOOPBACK, live.source.address[1]), timeout=1.0) as client:
            client.sendall(b"x" * 50)
            time.sleep(0.02)
            client.sendall(b"x" * 50 + b'\n{"ok": 1}\n')
        got = drain(live, 1)
    assert payloads(got) == ['{"ok": 1}']
    assert live.stats.oversized == 1


def test_udp_source_splits_datagrams_and_counts_non_utf8():
    with LiveInput(open_source(f"udp://{LOOPBACK}:0"), capacity=16) as live:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sender:
            for datagram in (b'{"a": 1}', b"\xff\xfe\n", b'{"b": 2}\n{"c": 3}\n'):
                sender.sendto(datagram, live.source.address)
            got = drain(live, 3)
    assert payloads(got) == ['{"a": 1}', '{"b": 2}', '{"c": 3}']
    assert got[0].origin.startswith(f"udp:{LOOPBACK}:")
    assert live.stats.decode_errors == 1


def test_live_input_drops_the_oldest_when_the_consumer_is_slow(tmp_path):
    path = tmp_path / "burst.jsonl"
    path.write_text("".join(f"{i}\n" for i in range(100)))
    got: list[int] = []
    with LiveInput(open_source(str(path)), capacity=2) as live:
        for _ in range(50):
            if live.finished:
                break
            if (msg := live.get(timeout=0.5)) is not None:
                got.append(int(msg.payload))
            time.sleep(0.02)   # a slow engine
    assert live.finished
    assert live.stats.dropped_stale > 0
    assert len(got) + live.stats.dropped_stale == 100
    assert got == sorted(got) and got[-2:] == [98, 99]


def test_open_source_rejects_unknown_specs(tmp_path):
    with pytest.raises(StreamSpecError):
        open_source(str(tmp_path / "video.mp4"))
    with pytest.raises(StreamSpecError):
        open_source("tcp://127.0.0.1")


# --- sinks ---------------------------------------------------------------------------------------

def test_file_sink_writes_through_and_is_complete_after_close(tmp_path):
    path = tmp_path / "out.jsonl"
    sink = open_sink(str(path))
    sink.write('{"frame": 0}')
    assert path.read_text() == '{"frame": 0}\n'   # visible while running
    with pytest.raises(ValueError):
        sink.write("two\nlines")
    sink.write('{"frame": 1}')
    sink.close()
    sink.close()
    assert path.read_text() == '{"frame": 0}\n{"frame": 1}\n'


def test_stdout_sink(capsys):
    with open_sink("-") as sink:
        sink.write("a")
    assert capsys.readouterr().out == "a\n"


def read_lines(conn: socket.socket, n: int, timeout_s: float = 1.0) -> list[str]:
    conn.settimeout(timeout_s)
    data = b""
    while data.count(b"\n") < n and (chunk := conn.recv(4096)):
        data += chunk
    return data.decode().splitlines()


def test_tcp_sink_delivers_lines_to_a_loopback_listener():
    with socket.create_server((LOOPBACK, 0)) as server:
        server.settimeout(1.0)
        sink = open_sink(f"tcp://{LOOPBACK}:{server.getsockname()[1]}")
        for i in range(3):
            sink.write(f'{{"frame": {i}}}')
        conn, _ = server.accept()
        with conn:
            sink.close()
            assert read_lines(conn, 3) == [f'{{"frame": {i}}}' for i in range(3)]
    assert sink.stats.sink_dropped == 0
    assert no_stream_threads()


def test_tcp_sink_without_listener_drops_without_blocking():
    sink = open_sink(f"tcp://{LOOPBACK}:{free_port()}")
    start = time.monotonic()
    sink.write("lost")
    assert time.monotonic() - start < 0.05
    deadline = time.monotonic() + 1.0
    while sink.stats.sink_dropped == 0 and time.monotonic() < deadline:
        time.sleep(0.01)
    start = time.monotonic()
    sink.write("lost too")   # while disconnected: refused at once
    assert time.monotonic() - start < 0.05
    sink.close()
    assert sink.stats.sink_dropped == 2


def test_tcp_sink_reconnects_after_the_consumer_restarts():
    server = socket.create_server((LOOPBACK, 0))
    port = server.getsockname()[1]
    sink = open_sink(f"tcp://{LOOPBACK}:{port}")
    sink.write("one")
    server.settimeout(1.0)
    conn, _ = server.accept()
    assert read_lines(conn, 1) == ["one"]
    conn.close()
    server.close()
    deadline = time.monotonic() + 1.0
    while sink.stats.sink_dropped == 0 and time.monotonic() < deadline:
        sink.write("lost")
        time.sleep(0.01)
    with socket.create_server((LOOPBACK, port)) as server:
        server.settimeout(0.02)
        conn = None
        while conn is None and time.monotonic() < deadline + 1.0:
            sink.write("again")
            try:
                conn, _ = server.accept()
            except TimeoutError:
                pass
        assert conn is not None
        with conn:
            sink.write("two")
            sink.close()
            assert read_lines(conn, 100)[-1] == "two"
    assert sink.stats.sink_dropped > 0
    assert sink.stats.reconnects == 1


def test_udp_sink_sends_datagrams_and_drops_oversized_lines():
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as receiver:
        receiver.bind((LOOPBACK, 0))
        receiver.settimeout(1.0)
        stats = StreamStats()
        with open_sink(f"udp://{LOOPBACK}:{receiver.getsockname()[1]}", stats) as sink:
            sink.write("x" * 70_000)
            sink.write('{"frame": 0}')
        assert receiver.recv(65535) == b'{"frame": 0}\n'
    assert stats.sink_dropped == 1


# --- signals -------------------------------------------------------------------------------------

def test_sigterm_sets_the_stop_event_and_handlers_are_restored():
    before = signal.getsignal(signal.SIGTERM)
    stop = threading.Event()
    with install_stop_handlers(stop):
        os.kill(os.getpid(), signal.SIGTERM)
        assert stop.wait(1.0)
    assert signal.getsignal(signal.SIGTERM) is before


def test_second_sigint_forces_quit():
    stop = threading.Event()
    with install_stop_handlers(stop):
        os.kill(os.getpid(), signal.SIGINT)
        assert stop.wait(1.0)
        with pytest.raises(KeyboardInterrupt):
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(1.0)
