"""Inputs are read within bounds: regular files only, sizes checked before reading (issue 20, item 3).

Every reader of the project goes through :func:`mocapdb.core.files.open_input`; this file checks the
primitive by hand-made cases and then each reader on a FIFO (which would block an ordinary open),
``/dev/zero`` (which never ends) and a folder with the reader's file name.
"""
from __future__ import annotations

import os
import re
import threading

import pytest

from mocapdb.core.errors import MocapdbError
from mocapdb.core.files import read_input_bytes, read_input_text


class Refused(MocapdbError):
    pass


@pytest.fixture
def odd_paths(tmp_path):
    os.mkfifo(tmp_path / "fifo")
    (tmp_path / "zero").symlink_to("/dev/zero")
    (tmp_path / "folder").mkdir()
    (tmp_path / "loop").symlink_to(tmp_path / "loop")
    return tmp_path


@pytest.mark.parametrize("name, message", [
    ("fifo", "fifo: a FIFO (named pipe), not a thing"), ("zero", "zero: a device, not a thing"),
    ("folder", "folder: a folder, not a thing"), ("loop", "loop: cannot read the thing (Too many levels"),
    ("missing", "missing: cannot read the thing (No such file"),
])
def test_only_regular_files_are_opened(odd_paths, name, message):
    with pytest.raises(Refused, match=re.escape(message)):
        read_input_bytes(odd_paths / name, 100, Refused, "thing")


def test_the_size_is_checked_before_reading(tmp_path):
    (tmp_path / "f").write_bytes(b"x" * 101)
    assert read_input_bytes(tmp_path / "f", 101, Refused, "thing") == b"x" * 101
    with pytest.raises(Refused, match=r"f: 101 bytes, more than a thing may hold \(100 bytes\)"):
        read_input_bytes(tmp_path / "f", 100, Refused, "thing")


def test_text_is_utf8_with_the_bad_line_named(tmp_path):
    (tmp_path / "t").write_bytes(b"\xef\xbb\xbfok\nstill ok\nbad \xff here\n")
    with pytest.raises(Refused, match=r"t, line 3: not UTF-8 text, not a thing"):
        read_input_text(tmp_path / "t", 100, Refused, "thing")
    assert read_input_text(tmp_path / "t", 100, Refused, "thing", errors="replace").startswith("ok\n")


def _readers():
    from mocapdb.core.cameras import read_calibration_toml
    from mocapdb.core.formats.bvh import read_bvh
    from mocapdb.core.formats.keypoint_arrays import read_keypoint_file
    from mocapdb.core.formats.trc import read_trc
    from mocapdb.core.joint_map import load_joint_map_file
    from mocapdb.render.results import read_result

    return {"x.bvh": read_bvh, "x.toml": read_calibration_toml, "x.trc": read_trc, "map.toml": load_joint_map_file,
            "x.npy": read_keypoint_file, "x.npz": read_keypoint_file, "x.json": read_keypoint_file,
            "result.jsonl": read_result}


@pytest.mark.parametrize("target", ["fifo", "zero", "folder"])
@pytest.mark.parametrize("name", list(_readers()))
def test_every_reader_refuses_special_files_at_once(odd_paths, name, target):
    """Each reader refuses, with its own error naming the file, within a second (a FIFO read
    would block forever, /dev/zero would fill the memory)."""
    path = odd_paths / f"as_{target}_{name}"
    path.symlink_to(odd_paths / target)
    outcome: list[BaseException] = []

    def read() -> None:
        try:
            _readers()[name](path)
        except BaseException as exc:  # noqa: BLE001 - the outcome is checked below
            outcome.append(exc)

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    reader.join(timeout=10)
    assert not reader.is_alive(), f"{name} on a {target} hangs"
    assert outcome and isinstance(outcome[0], MocapdbError), outcome
    assert str(path) in str(outcome[0]) and re.search("not a|no result.jsonl", str(outcome[0])), outcome[0]


def test_the_take_description_and_manifest_refuse_special_files(odd_paths):
    from mocapdb.core.formats.database import DatabaseError
    from mocapdb.core.formats.database_reader import load_database
    from mocapdb.core.formats.take import TakeError, read_take

    take = odd_paths / "take"
    take.mkdir()
    os.mkfifo(take / "take.json")
    with pytest.raises(TakeError, match="take.json: a FIFO"):
        read_take(take)
    db = odd_paths / "db"
    db.mkdir()
    (db / "manifest.json").symlink_to("/dev/zero")
    with pytest.raises(DatabaseError):
        load_database(db)
