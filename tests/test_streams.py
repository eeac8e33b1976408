"""Sources, sinks, the drop-oldest live buffer and the stop signals, over real loopback sockets."""
import io
import json
import os
import signal
import socket
import sys
import threading
import time

import pytest

from mocapdb.cli.signals import install_stop_handlers
from mocapdb.runtime.stream.transport import (
    LiveInput,
    NetworkLimits,
    RawMessage,
    StreamSpecError,
    StreamStats,
    open_sink,
    open_source,
)

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


def test_folder_source_waits_for_a_file_created_empty(tmp_path):
    empty = tmp_path / "cam_000000000000_keypoints.json"
    empty.touch()
    with LiveInput(open_source(str(tmp_path), follow=True, settle_s=5.0), capacity=4) as live:
        assert live.get(timeout=0.15) is None
        empty.write_text('{"frame": 0}')
        assert payloads(drain(live, 1)) == ['{"frame": 0}']


def test_folder_source_offline_reads_existing_files_in_natural_order(tmp_path):
    for name in ("f10.json", "f2.json", "f1.json"):
        (tmp_path / name).write_text(f'{{"name": "{name}"}}')
    (tmp_path / "f3.json").write_bytes(b'{"bad": "\xff"}')
    with open_source(str(tmp_path)) as source:
        names = [m.origin.rsplit(os.sep, 1)[1] for m in source]
    assert names == ["f1.json", "f2.json", "f10.json"]
    assert source.stats.decode_errors == 1


def test_folder_source_and_offline_reader_share_the_frame_order(tmp_path):
    from mocapdb.core.formats.openpose import read_openpose_folder

    names = ["z_000000000001_keypoints.json", "a_000000000000_keypoints.json", "f10.json", "F2.json", "f01.json"]
    for count, name in enumerate(names):
        (tmp_path / name).write_text(json.dumps({"people": [{"pose_keypoints_2d": [1.0, 2.0, 0.9] * 18}] * count}))
    with open_source(str(tmp_path)) as source:
        live_order = [m.origin.rsplit(os.sep, 1)[1] for m in source]
    assert live_order == ["a_000000000000_keypoints.json", "z_000000000001_keypoints.json",
                          "f01.json", "F2.json", "f10.json"]
    assert [len(f.people) for f in read_openpose_folder(tmp_path)] == [names.index(n) for n in live_order]


def not_regular_entries(folder) -> list[str]:
    """Entries named like frame files that are not regular files: a symlink loop, a dangling symlink,
    a FIFO, a folder and a symlink to a device. Returns their names."""
    (folder / "loop.json").symlink_to("loop.json")
    (folder / "gone.json").symlink_to("nowhere.json")
    os.mkfifo(folder / "pipe_000000000003_keypoints.json")
    (folder / "sub_000000000004_keypoints.json").mkdir()
    (folder / "null.json").symlink_to(os.devnull)
    return ["loop.json", "gone.json", "pipe_000000000003_keypoints.json", "sub_000000000004_keypoints.json",
            "null.json"]


@pytest.mark.parametrize("follow", [False, True])
def test_folder_source_skips_entries_that_are_not_regular_files(tmp_path, caplog, follow):
    expected = [frame_file(tmp_path, i) for i in range(100)]
    names = not_regular_entries(tmp_path)
    source = open_source(str(tmp_path), follow=follow)
    if follow:
        with LiveInput(source, capacity=128) as live:
            got = payloads(drain(live, 100, timeout_s=5.0))
            time.sleep(0.1)   # more polls: nothing more, no second warning
            assert live.get(timeout=0) is None
    else:
        with source:
            got = payloads(list(source))
    assert got == expected
    assert source.stats.not_regular == 5
    warnings = [r.getMessage() for r in caplog.records if "not regular files" in r.getMessage()]
    assert len(warnings) == 1 and all(name in warnings[0] for name in names), warnings


def test_reconstruct_and_the_offline_reader_skip_entries_that_are_not_regular_files(small_db, small_db_path,
                                                                                     tmp_path, capsys):
    from mocapdb.cli.main import main
    from mocapdb.core.formats.openpose import read_openpose_folder

    from .test_session import _stream_lines

    folder = tmp_path / "frames"
    folder.mkdir()
    for i, line in enumerate(_stream_lines(small_db, 20)):
        (folder / f"cam_{i:012d}_keypoints.json").write_text(line)
    names = not_regular_entries(folder)
    assert main(["reconstruct", str(folder), "--db", str(small_db_path), "--out", str(tmp_path / "out")]) == 0
    out, err = capsys.readouterr()
    assert "frames 20," in out and "folder entries not regular files 5" in out
    assert err.count("not regular files") == 1 and all(name in err for name in names)
    assert len(list(read_openpose_folder(folder))) == 20


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
    """A live stream (here a file read as one: not lossless) outrunning a slow engine: the oldest
    messages are dropped and counted, the newest kept."""
    path = tmp_path / "burst.jsonl"
    path.write_text("".join(f"{i}\n" for i in range(100)))
    got: list[int] = []
    source = open_source(str(path))
    source.lossless = False  # as a socket or a pipe
    with LiveInput(source, capacity=2) as live:
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


@pytest.mark.parametrize("kind", ["file", "folder"])
def test_files_already_written_are_never_dropped_however_slow_the_engine(tmp_path, kind):
    """A JSON-lines file or a folder of frames read by `live`: the reader waits for the engine, so
    every message arrives, in order, none counted stale."""
    if kind == "file":
        (tmp_path / "burst.jsonl").write_text("".join(f"{i}\n" for i in range(60)))
        source = open_source(str(tmp_path / "burst.jsonl"))
    else:
        for i in range(60):
            frame_file(tmp_path, i)
        source = open_source(str(tmp_path))
    got = []
    with LiveInput(source, capacity=2) as live:
        while len(got) < 60 and (msg := live.get(timeout=5.0)) is not None:
            got.append(msg.payload)
            time.sleep(0.005)   # a slow engine
    assert len(got) == 60 and live.stats.dropped_stale == 0
    if kind == "file":
        assert [int(p) for p in got] == list(range(60))


def test_open_source_rejects_unknown_specs(tmp_path):
    with pytest.raises(StreamSpecError):
        open_source(str(tmp_path / "video.mp4"))
    with pytest.raises(StreamSpecError):
        open_source("tcp://127.0.0.1")


# --- live sources that one sender cannot take down -----------------------------------------------

def connect(source, timeout_s: float = 1.0) -> socket.socket:
    return socket.create_connection((LOOPBACK, source.address[1]), timeout=timeout_s)


def wait_for(condition, timeout_s: float = 2.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while not condition() and time.monotonic() < deadline:
        time.sleep(0.01)
    return condition()


def test_tcp_source_serves_other_clients_while_one_sends_nothing():
    with LiveInput(open_source(f"tcp://{LOOPBACK}:0"), capacity=16) as live:
        with connect(live.source) as idle, connect(live.source) as partial, connect(live.source) as sender:
            partial.sendall(b'{"half": ')
            for i in range(3):
                sender.sendall(f'{{"b": {i}}}\n'.encode())
            assert payloads(drain(live, 3)) == [f'{{"b": {i}}}' for i in range(3)]
            partial.sendall(b'1}\n')   # its own line splitter kept the first half
            idle.sendall(b'{"late": 1}\n')
            assert sorted(payloads(drain(live, 2))) == ['{"half": 1}', '{"late": 1}']
            assert live.source.client_count == 3
    assert live.stats.reconnects == 2
    assert no_stream_threads()


def test_tcp_source_closes_a_client_without_a_line_after_the_timeout(capsys, caplog):
    source = open_source(f"tcp://{LOOPBACK}:0", limits=NetworkLimits(client_timeout_s=0.2))
    with LiveInput(source, capacity=4) as live:
        with connect(source) as silent, connect(source) as talker:
            silent.sendall(b'{"never": "ends"')
            start = time.monotonic()
            for i in range(8):   # a line every 0.1 s keeps the talker open
                talker.sendall(f"{i}\n".encode())
                time.sleep(0.1)
            assert silent.recv(16) == b""   # closed by the source
            assert time.monotonic() - start < 2.0
            assert source.client_count == 1
            assert live.stats.clients_timed_out == 1
            assert len(drain(live, 4)) == 4   # the talker's newest lines (capacity 4)
    assert "no complete line for 0.2 s" in caplog.text


def test_tcp_source_refuses_clients_over_the_limit(capsys, caplog):
    source = open_source(f"tcp://{LOOPBACK}:0", limits=NetworkLimits(max_clients=2))
    with LiveInput(source, capacity=16) as live:
        first, second = connect(source), connect(source)
        assert wait_for(lambda: source.client_count == 2)
        with connect(source) as third:
            assert third.recv(16) == b""   # accepted and closed at once
        assert wait_for(lambda: live.stats.clients_refused == 1)
        first.close()
        assert wait_for(lambda: source.client_count == 1)
        with connect(source) as fourth:   # a freed slot is taken again
            fourth.sendall(b'{"four": 4}\n')
            assert payloads(drain(live, 1)) == ['{"four": 4}']
        second.close()
    assert "2 clients already connected" in caplog.text


def test_tcp_source_refusals_are_logged_at_most_once_a_second(capsys, caplog):
    source = open_source(f"tcp://{LOOPBACK}:0", limits=NetworkLimits(max_clients=1))
    with LiveInput(source), connect(source):
        assert wait_for(lambda: source.client_count == 1)
        for _ in range(3):
            with connect(source) as refused:
                assert refused.recv(16) == b""
        assert wait_for(lambda: source.stats.clients_refused == 3)
    err = caplog.text
    assert err.count("tcp source: refused tcp:127.0.0.1:") == 1   # one line per second, not per connection
    assert "1 clients already connected" in err


def idle_source(kind: str, tmp_path, monkeypatch, **options):
    """An open source of ``kind`` whose input stays open and silent."""
    if kind == "stdin":
        read_fd, write_fd = os.pipe()   # the write end stays open: no end of input
        monkeypatch.setattr(sys, "stdin", os.fdopen(read_fd))
        return open_source("-", **options), write_fd
    spec = {"tcp": f"tcp://{LOOPBACK}:0", "udp": f"udp://{LOOPBACK}:0", "folder": str(tmp_path)}[kind]
    return open_source(spec, follow=True, **options), None


@pytest.mark.parametrize("kind", ["tcp", "udp", "stdin", "folder"])
def test_idle_timeout_ends_every_source(kind, tmp_path, monkeypatch):
    source, write_fd = idle_source(kind, tmp_path, monkeypatch, idle_timeout_s=0.3)
    start = time.monotonic()
    with LiveInput(source) as live:
        if kind == "tcp":
            with connect(source):   # a connected client that sends nothing is no message
                assert wait_for(lambda: live.finished)
        assert wait_for(lambda: live.finished)
    assert 0.3 <= time.monotonic() - start < 2.0
    if write_fd is not None:
        os.close(write_fd)
        sys.stdin.close()


@pytest.mark.parametrize("kind", ["tcp", "udp", "stdin", "folder"])
def test_every_source_stops_promptly_while_waiting(kind, tmp_path, monkeypatch):
    source, write_fd = idle_source(kind, tmp_path, monkeypatch)
    live = LiveInput(source)
    client = connect(source) if kind == "tcp" else None   # the old single-client source blocked on it
    time.sleep(0.1)
    start = time.monotonic()
    live.close()
    assert time.monotonic() - start < 0.5
    assert not live._thread.is_alive()
    for closable in (client, write_fd and os.fdopen(write_fd), kind == "stdin" and sys.stdin):
        if closable:
            closable.close()


def test_tcp_source_drops_and_counts_messages_over_a_senders_rate():
    source = open_source(f"tcp://{LOOPBACK}:0", limits=NetworkLimits(max_rate=10))
    with LiveInput(source, capacity=100) as live:
        with connect(source) as a, connect(source) as b:   # one address: one budget for both
            a.sendall(b"".join(f"{i}\n".encode() for i in range(40)))
            b.sendall(b"".join(f"{i}\n".encode() for i in range(40)))
            assert wait_for(lambda: live.stats.messages_in + live.stats.rate_limited == 80)
            time.sleep(0.3)   # about 3 tokens come back
            a.sendall(b"again\n")
            assert "again" in payloads(drain(live, 100, timeout_s=0.5))
    assert 10 <= live.stats.messages_in <= 14
    assert live.stats.rate_limited == 81 - live.stats.messages_in


def test_udp_source_rate_limit_counts_every_message_of_a_datagram():
    source = open_source(f"udp://{LOOPBACK}:0", limits=NetworkLimits(max_rate=5))
    with LiveInput(source, capacity=100) as live, socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sender:
        for _ in range(4):
            sender.sendto(b"1\n2\n3\n4\n5\n", source.address)
        assert wait_for(lambda: live.stats.messages_in + live.stats.rate_limited == 20)
    assert live.stats.messages_in in (5, 6)
    assert live.stats.rate_limited == 20 - live.stats.messages_in


def test_rate_limit_zero_means_no_limit():
    source = open_source(f"udp://{LOOPBACK}:0", limits=NetworkLimits(max_rate=0))
    with LiveInput(source, capacity=5000) as live, socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sender:
        sender.sendto(b"".join(f"{i}\n".encode() for i in range(3000)), source.address)
        assert wait_for(lambda: live.stats.messages_in == 3000)
    assert live.stats.rate_limited == 0


@pytest.mark.parametrize("limits", [dict(max_clients=0), dict(client_timeout_s=0), dict(max_rate=-1)])
def test_network_limits_are_checked(limits):
    from mocapdb.core.domains import DomainError

    with pytest.raises(DomainError, match=next(iter(limits))):
        NetworkLimits(**limits)
    with pytest.raises(StreamSpecError):
        open_source("-", idle_timeout_s=0)


def test_folder_source_idles_cheaply_and_still_sees_new_files(tmp_path):
    for i in range(3000):
        frame_file(tmp_path, i)
    source = open_source(str(tmp_path), follow=True)
    with LiveInput(source, capacity=2) as live:
        taken = 0
        while taken < 3000 and live.get(timeout=30) is not None:  # lossless: read as they are taken
            taken += 1
        assert taken == 3000 and live.get(timeout=0.2) is None
        started = time.process_time()
        time.sleep(2.0)
        idle_cpu = time.process_time() - started
        written_later = frame_file(tmp_path, 3000)
        assert payloads(drain(live, 1)) == [written_later]
    assert idle_cpu < 0.1, f"{idle_cpu:.3f} s of CPU in 2 s idle"


def test_folder_source_lists_again_only_when_the_folder_changes(tmp_path):
    old_ns = time.time_ns() - 3600 * 10**9
    frame_file(tmp_path, 0)
    os.utime(tmp_path, ns=(old_ns, old_ns))
    source = open_source(str(tmp_path), follow=True)
    with LiveInput(source, capacity=8) as live:
        assert len(drain(live, 1)) == 1
        scans = source.scans
        time.sleep(0.3)
        assert source.scans == scans   # an unchanged folder is not listed
        later = frame_file(tmp_path, 1)
        assert payloads(drain(live, 1)) == [later]
        assert source.scans > scans


def test_folder_source_rescans_a_folder_whose_time_stamp_hides_a_new_file(tmp_path):
    from mocapdb.runtime.stream.transport import FolderSource

    old_ns = time.time_ns() - 3600 * 10**9
    os.utime(tmp_path, ns=(old_ns, old_ns))
    source = FolderSource(tmp_path, follow=True, rescan_s=0.5)
    polls = source._poll()   # driven here, without a thread: messages, and None once per poll
    assert next(polls) is None and source.scans == 1
    hidden = frame_file(tmp_path, 0)
    os.utime(tmp_path, ns=(old_ns, old_ns))   # as a coarse or lagging file system might leave it
    assert next(polls) is None and source.scans == 1
    time.sleep(0.5)
    assert next(polls).payload == hidden
    assert source.scans == 2


@pytest.mark.parametrize("scheme", ["tcp", "udp"])
def test_listening_beyond_loopback_warns(scheme, caplog):
    with open_source(f"{scheme}://0.0.0.0:0"):
        pass
    assert ("listening on 0.0.0.0: anyone on the network can send poses (there is no authentication)"
            in caplog.text)
    caplog.clear()
    with open_source(f"{scheme}://{LOOPBACK}:0"):
        pass
    assert not caplog.records  # loopback: nobody else can send


def test_live_cli_stops_after_the_idle_timeout(small_db_path, tmp_path, capsys):
    from mocapdb.cli.main import main

    start = time.monotonic()
    assert main(["live", "--source", f"udp://{LOOPBACK}:0", "--db", str(small_db_path),
                 "--sink", str(tmp_path / "out.jsonl"), "--idle-timeout", "0.3"]) == 0
    assert time.monotonic() - start < 10
    assert "frames 0" in capsys.readouterr().err


def test_live_cli_rejects_bad_limits(small_db_path, capsys):
    from mocapdb.cli.main import main

    assert main(["live", "--source", f"tcp://{LOOPBACK}:0", "--db", str(small_db_path), "--max-clients", "0"]) == 2
    assert "argument --max-clients: '0': must be a number of clients" in capsys.readouterr().err


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


def test_further_signals_are_ignored_while_stopping_without_force_quit(capfd):
    stop = threading.Event()
    before = signal.getsignal(signal.SIGINT)  # Python's default; SIG_IGN when a shell started pytest in the background
    with install_stop_handlers(stop, force_quit=False):
        os.kill(os.getpid(), signal.SIGTERM)
        assert stop.wait(1.0)
        for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGINT):  # nothing raised, nothing killed
            os.kill(os.getpid(), sig)
            time.sleep(0.05)
        assert signal.getsignal(signal.SIGTERM) not in (signal.SIG_DFL, None)
    assert capfd.readouterr().err.count("further signals are ignored") == 1
    assert signal.getsignal(signal.SIGINT) is before
