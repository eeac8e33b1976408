"""Property-based tests of the readers (issue 20, item 2): random and mutated BVH, OpenPose JSON,
JSON-lines and keypoint-array inputs never raise anything but the project's own error
(:class:`MocapdbError`), and stay within bounded time (hypothesis' deadline) and memory
(``tracemalloc``: a bounded multiple of the input's size).

Mutations start from real files (the bundled BVH clip and OpenPose frames) and flip, delete,
duplicate or replace bytes, lines and numbers, so they reach deep into each parser.
"""
from __future__ import annotations

import io
import json
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mocapdb.core.errors import MocapdbError
from mocapdb.core.formats.bvh import parse_bvh
from mocapdb.core.formats.keypoint_arrays import read_keypoint_array
from mocapdb.core.formats.openpose import parse_openpose_json, parse_stream_line

from .conftest import SAMPLE_BVH, SAMPLE_KEYPOINTS

SETTINGS = settings(max_examples=150, deadline=2000, suppress_health_check=[HealthCheck.too_slow,
                                                                            HealthCheck.function_scoped_fixture])
# A small real clip: its first 40 motion rows (the parser's work is linear in the rows).
_CLIP_LINES = (SAMPLE_BVH / "002_01.bvh").read_text().splitlines()
_MOTION_AT = _CLIP_LINES.index("MOTION")
BVH_TEXT = "\n".join(_CLIP_LINES[:_MOTION_AT] + ["MOTION", "Frames: 40", _CLIP_LINES[_MOTION_AT + 2]]
                     + _CLIP_LINES[_MOTION_AT + 3:_MOTION_AT + 43]) + "\n"
OPENPOSE_TEXT = sorted(SAMPLE_KEYPOINTS.glob("*.json"))[50].read_text()
NUMBERS = st.sampled_from(["nan", "inf", "-inf", "1e308", "-1e400", "1" + "0" * 400, "-0", "0x10", "1e-320", "",
                           "[]", "{}", "null", "true", '"7"', "99999999999999999999"])
MEMORY_FACTOR = 64       # peak memory of a parse: at most this many times the input's size ...
MEMORY_FLOOR = 4 << 20   # ... or this many bytes


def _within_memory(parse, text: str | bytes) -> None:
    """Run ``parse``: it returns or raises MocapdbError, with a bounded peak of memory."""
    tracemalloc.start()
    try:
        parse()
    except MocapdbError:
        pass
    finally:
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
    assert peak <= max(MEMORY_FLOOR, MEMORY_FACTOR * len(text)), peak


@st.composite
def mutated(draw, base: str) -> str:
    """``base`` with 1-4 edits: a byte range replaced, deleted or repeated, a line dropped or
    doubled, or a number replaced by a hostile one."""
    text = base
    for _ in range(draw(st.integers(1, 4))):
        kind = draw(st.sampled_from(["replace", "delete", "repeat", "line", "number"]))
        i = draw(st.integers(0, max(len(text) - 1, 0)))
        j = min(len(text), i + draw(st.integers(0, 40)))
        if kind == "replace":
            text = text[:i] + draw(st.text(max_size=12)) + text[j:]
        elif kind == "delete":
            text = text[:i] + text[j:]
        elif kind == "repeat":
            text = text[:j] + text[i:j] * draw(st.integers(1, 50)) + text[j:]
        elif kind == "line":
            lines = text.split("\n")
            k = draw(st.integers(0, len(lines) - 1))
            lines[k:k + 1] = [] if draw(st.booleans()) else [lines[k], lines[k]]
            text = "\n".join(lines)
        else:
            tokens = text.split(" ")
            k = draw(st.integers(0, len(tokens) - 1))
            tokens[k] = draw(NUMBERS)
            text = " ".join(tokens)
    return text


@SETTINGS
@given(mutated(BVH_TEXT))
def test_mutated_bvh_reads_or_raises_bvh_error(text):
    _within_memory(lambda: parse_bvh(text, "fuzz.bvh"), text)


@SETTINGS
@given(st.text(max_size=400).map(lambda t: "HIERARCHY\n" + t))
def test_random_bvh_reads_or_raises_bvh_error(text):
    _within_memory(lambda: parse_bvh(text, "fuzz.bvh"), text)


@SETTINGS
@given(mutated(OPENPOSE_TEXT))
def test_mutated_openpose_json_reads_or_raises_keypoint_error(text):
    _within_memory(lambda: parse_openpose_json(text, 0, source="fuzz.json"), text)


JSON_VALUES = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=5),
    lambda inner: st.lists(inner, max_size=6) | st.dictionaries(st.sampled_from(
        ["frame", "time", "layout", "people", "id", "keypoints", "pose_keypoints_2d", "keypoint_scores",
         "person_id", "instances"]), inner, max_size=5), max_leaves=40)


@SETTINGS
@given(JSON_VALUES)
def test_random_stream_messages_parse_or_raise_keypoint_error(value):
    line = json.dumps(value)
    _within_memory(lambda: parse_stream_line(line), line)


@SETTINGS
@given(mutated(json.dumps({"frame": 3, "time": 0.05, "people": [{"id": 1, "keypoints": json.loads(
    OPENPOSE_TEXT)["people"][0]["pose_keypoints_2d"]}]})))
def test_mutated_stream_lines_parse_or_raise_keypoint_error(line):
    _within_memory(lambda: parse_stream_line(line), line)


def _npy_bytes(array: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    np.save(buffer, array)
    return buffer.getvalue()


NPY_BASE = _npy_bytes(np.arange(4 * 17 * 3, dtype=np.float64).reshape(4, 17, 3))


@SETTINGS
@given(st.binary(max_size=64), st.integers(0, len(NPY_BASE)), st.sampled_from([".npy", ".npz"]))
def test_mutated_arrays_read_or_raise_keypoint_error(tmp_path_factory, patch, at, suffix):
    data = NPY_BASE[:at] + patch + NPY_BASE[at + len(patch):]
    if suffix == ".npz":
        buffer = io.BytesIO()
        import zipfile

        with zipfile.ZipFile(buffer, "w") as zf:
            zf.writestr("keypoints.npy", data)
        data = bytearray(buffer.getvalue())
        data[at % len(data)] ^= 0x5A
        data = bytes(data)
    path = Path(tmp_path_factory.mktemp("arrays")) / f"fuzz{suffix}"
    path.write_bytes(data)
    _within_memory(lambda: read_keypoint_array(path), data)


def test_the_fuzzed_readers_accept_their_unmutated_bases():
    """The bases are valid: the properties above explore from inputs that parse."""
    assert parse_bvh(BVH_TEXT).n_frames == 40
    assert parse_openpose_json(OPENPOSE_TEXT, 0).people
    buffer = io.BytesIO(NPY_BASE)
    assert np.load(buffer).shape == (4, 17, 3)


@pytest.mark.parametrize("line", ['{"frame": 1' + "0" * 400 + ', "people": []}', '{"frame": -1, "people": []}',
                                  '{"frame": 1, "time": 1e400, "people": []}', "[" * 100_000 + "]" * 100_000])
def test_hostile_stream_lines_raise_keypoint_error(line):
    from mocapdb.core.formats.keypoints import KeypointError

    with pytest.raises(KeypointError):
        parse_stream_line(line)
