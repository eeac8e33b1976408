"""Keypoints in JSON: OpenPose ``--write_json`` frames and folders (MMPose per-image JSON too), their
frame order, MMPose prediction files and the JSON-lines stream messages; every person is mapped onto
the universal 14 (:mod:`mocapdb.core.formats.keypoints`). Schema: ``data_specs/keypoint_formats.md``.
"""
from __future__ import annotations

import itertools
import json
import logging
import os
import re
from collections.abc import Container, Iterator, Mapping, Sequence
from pathlib import Path
from typing import NamedTuple, TypeVar

import numpy as np

from mocapdb.core.files import MIB, read_input_text
from mocapdb.core.formats.camera_path import CAMERA_PATH_FILE
from mocapdb.core.formats.face_keypoints import read_face
from mocapdb.core.formats.hand_keypoints import read_hands
from mocapdb.core.formats.keypoints import (
    KeypointError,
    KeypointFrame,
    RawPerson,
    build_frame,
    check_fps,
    check_world,
    detect_layout,
    error_source,
    frame_time,
    numeric,
    optional_layout,
    shown,
    with_scores,
)
from mocapdb.core.formats.scene import SCENE_FILE
from mocapdb.core.formats.take import TAKE_FILE

T = TypeVar("T")

WORLD_FIELD = "pose_world_landmarks_3d"   # a person's world landmarks (metres), flat or [[x, y, z], ...]

DETECT_FRAMES = 10     # a folder's or file's layout is detected from its first frames holding people
MAX_INTEGER = 2**53    # frame numbers and person ids lie below this in magnitude (exact in float64 and JSON readers)
MAX_TIME_S = 2**53 / 1e6   # |time| below this (about 285 years): exact to the microsecond the output writes
MAX_NAMED = 10         # entries named in a warning about skipped folder entries
MAX_FRAME_FILE_BYTES = 16 * MIB     # one frame's JSON (a crowd of 1,000 people takes under 1 MiB)
MAX_PREDICTIONS_BYTES = 128 * MIB   # an MMPose prediction file: an hour of one person at 30 fps takes ~65 MiB

LOG = logging.getLogger(__name__)


def _load_json(text: str) -> dict | list:
    """A JSON object or list (the reasons avoid ": ", which stream reports take as a source prefix)."""
    try:
        obj = json.loads(text)
    except json.JSONDecodeError as err:
        raise KeypointError(f"not JSON ({err.msg} at line {err.lineno} column {err.colno})") from None
    except (ValueError, RecursionError):
        raise KeypointError("not JSON (a number too long or nesting too deep)") from None
    if not isinstance(obj, (dict, list)):
        raise KeypointError("not a JSON object or list")
    return obj


def _read_text(path: Path, max_bytes: int) -> str:
    """The text of a regular keypoint file of at most ``max_bytes`` (errors name the file)."""
    return read_input_text(path, max_bytes, KeypointError, "keypoint file")


def _person_id(value: object) -> int | None:
    """``id`` or OpenPose ``person_id`` (an int, or a list holding one); -1 means none."""
    if isinstance(value, list) and len(value) == 1:
        value = value[0]
    if value is None:
        return None
    if not isinstance(value, int) or isinstance(value, bool) or not abs(value) < MAX_INTEGER:
        raise KeypointError(f"person id {shown(value)} is not an integer between -2**53 and 2**53")
    return None if value == -1 else value


def _raw_person(obj: object, i: int) -> RawPerson:
    """A person entry: ``keypoints`` [[x, y, c], ...] (or MMPose's [[x, y], ...] with ``keypoint_scores``)
    or OpenPose ``pose_keypoints_2d`` [x, y, c, ...]."""
    if not isinstance(obj, dict):
        raise KeypointError(f"person {i} is not a JSON object")
    if "keypoints" in obj:
        raw = numeric(obj["keypoints"], f"person {i} keypoints")
        if "keypoint_scores" in obj:
            scores = numeric(obj["keypoint_scores"], f"person {i} keypoint_scores")
            raw = with_scores(raw, scores, f"person {i} keypoint_scores")
        if raw.ndim != 2 or raw.shape[1] != 3:
            raise KeypointError(f"person {i} keypoints must be [[x, y, confidence], ...] "
                                f"or [[x, y], ...] with keypoint_scores")
    elif "pose_keypoints_2d" in obj:
        flat = numeric(obj["pose_keypoints_2d"], f"person {i} pose_keypoints_2d")
        if flat.ndim != 1 or flat.size % 3:
            raise KeypointError(f"person {i} pose_keypoints_2d holds {flat.size} values, not a multiple of 3")
        raw = flat.reshape(-1, 3)
    else:
        raise KeypointError(f"person {i} has neither 'keypoints' nor 'pose_keypoints_2d'")
    given, world = obj.get(WORLD_FIELD), None
    if given is not None and given != []:   # absent, null or [] (as Pose2Sim's empty fields): none
        what = f"person {i} {WORLD_FIELD}"
        world = check_world(numeric(given, what), len(raw), what)
    return RawPerson(raw, _person_id(obj.get("id", obj.get("person_id"))), optional_layout(obj.get("layout")), world,
                     read_hands(obj, f"person {i}"), read_face(obj, f"person {i}"))


def _raw_people(obj: dict | list) -> list[RawPerson]:
    """The people of an OpenPose-style object (its ``people``) or of an MMPose list of instances.

    An entry without keypoints (``"pose_keypoints_2d": []``, as Pose2Sim writes) is an absent person."""
    people = obj if isinstance(obj, list) else obj.get("people")
    if not isinstance(people, list):
        raise KeypointError("no 'people' list")
    if people and isinstance(people[0], dict) and "instances" in people[0]:
        raise KeypointError("an MMPose video file (a list of frames), to be read as a file of its own")
    return [p for p in (_raw_person(p, i) for i, p in enumerate(people)) if len(p.raw)]


def parse_openpose_json(text: str, index: int, layout: str | None = None, source: str = "") -> KeypointFrame:
    """One OpenPose ``--write_json`` frame (``{"people": [{"pose_keypoints_2d": [x, y, c, ...]}]}``)
    or MMPose per-image prediction (``[{"keypoints": [[x, y], ...], "keypoint_scores": [...]}, ...]``).

    ``layout`` None: detected from this frame's people. Errors: KeypointError naming ``source``.
    """
    with error_source(source or "<OpenPose JSON>"):
        return build_frame(index, None, _raw_people(_load_json(text)), optional_layout(layout))


_OPENPOSE_FRAME = re.compile(r"_([0-9]+)_keypoints\.json$")   # <stem>_<frame>_keypoints.json
_DIGIT_RUNS = re.compile(r"([0-9]+)")


def frame_order_key(name: str) -> tuple[int, int, tuple[str | int, ...], str]:
    """Sort key putting keypoint file names (no folder part) in frame order; used by every folder
    reader (:func:`read_openpose_folder`, the live folder source of ``mocapdb.runtime.stream.sources``).

    1. OpenPose names ``<stem>_<frame>_keypoints.json`` (OpenPose writes 12 digits; any count is
       read) come first, by frame number: the number decides, not the stem, so ``b_…2`` is before
       ``a_…10`` (a stem is one video or camera; a folder normally holds one).
    2. Any other name after them, in natural order: case-insensitive text, runs of ASCII digits
       compared as numbers (``f2.json`` before ``f10.json``). Natural order also breaks ties
       between OpenPose names with the same frame number.
    3. The name itself last, so names equal so far (``F1.json``, ``f01.json``) still come in one
       fixed order whatever the directory listing gives.

    Only ASCII digits count as digits (Unicode digits such as ``٣`` or ``²`` are text), so every
    name has a key and no comparison mixes a number with text.
    """
    parts = _DIGIT_RUNS.split(name)   # text, digits, text, ...: odd positions are digit runs
    natural = tuple(int(part) if i % 2 else part.lower() for i, part in enumerate(parts))
    match = _OPENPOSE_FRAME.search(name)
    return (0, int(match[1]), natural, name) if match else (1, 0, natural, name)


def is_frame_file(name: str) -> bool:
    """Whether a file in a keypoint folder is a frame: a ``.json`` file other than the take
    description (``take.json``, :mod:`mocapdb.core.formats.take`) and the camera's path
    (``camera_path.json``, :mod:`mocapdb.core.formats.camera_path`) and the scene's lines
    (``scene.json``, :mod:`mocapdb.core.formats.scene`)."""
    return name.lower().endswith(".json") and name not in (TAKE_FILE, CAMERA_PATH_FILE, SCENE_FILE)


def _is_regular(entry: os.DirEntry) -> bool:
    """Whether ``entry`` is a regular file, a symlink followed (a symlink loop is not one)."""
    try:
        return entry.is_file()
    except OSError:
        return False


def frame_entries(folder: Path, known: Container[str] = ()) -> tuple[list[str], list[str]]:
    """The names of ``folder``'s frame files (:func:`is_frame_file`) not in ``known``, as listed:
    the regular files (symlinks to one included), and the others (a dangling or looping symlink, a
    FIFO, a device, a folder), which no reader opens and one warning names. Shared by every folder
    reader (:func:`read_openpose_folder`, the live folder source); OSError if it cannot be listed."""
    files: list[str] = []
    others: list[str] = []
    with os.scandir(folder) as entries:
        for entry in entries:
            if is_frame_file(entry.name) and entry.name not in known:
                (files if _is_regular(entry) else others).append(entry.name)
    if others:
        named = ", ".join(sorted(others)[:MAX_NAMED])
        more = f" and {len(others) - MAX_NAMED} more" if len(others) > MAX_NAMED else ""
        LOG.warning("%s: skipped %d .json entries that are not regular files (a dangling or looping symlink, "
                    "a FIFO, a device or a folder): %s%s", folder, len(others), named, more)
    return files, others


def _frame_files(folder: Path) -> list[Path]:
    """The folder's frame files (:func:`frame_entries`) in frame order (:func:`frame_order_key`)."""
    if not folder.is_dir():
        raise KeypointError(f"{folder}: not a folder")
    names = frame_entries(folder)[0]
    if not names:
        raise KeypointError(f"{folder}: no .json keypoint files")
    return [folder / name for name in sorted(names, key=frame_order_key)]


class _ParsedFrame(NamedTuple):
    """A frame's people as its file holds them, and the frame's own number and time (seconds) when
    it gives them (``frame``, ``time``: as a stream line's), else None."""

    people: list[RawPerson]
    number: int | None = None
    time_s: float | None = None


def _read_frame_file(path: Path) -> _ParsedFrame:
    text = _read_text(path, MAX_FRAME_FILE_BYTES)
    with error_source(path):
        obj = _load_json(text)
        index, time_s = _frame_and_time(obj) if isinstance(obj, dict) else (None, None)
        return _ParsedFrame(_raw_people(obj), index, time_s)


def read_openpose_folder(folder: str | Path, layout: str | None = None,
                         fps: float | None = None) -> Iterator[KeypointFrame]:
    """The frames of an OpenPose ``--write_json`` folder (or of MMPose per-image files), in frame-number order.

    ``index`` is the file's own ``frame`` (`mocapdb detect` writes it: the frame's number on the
    video's nominal timeline), else one more than the frame before (the position in that order
    when no file gives one), as `reconstruct` numbers them; ``time_s`` the file's own ``time``, else
    ``index / fps`` (seconds) when ``fps`` (Hz) is given. ``layout`` None: detected once from the
    first :data:`DETECT_FRAMES` frames holding people, then fixed. Folder errors are raised at once,
    file errors when the file is reached.
    """
    files = _frame_files(Path(folder))
    check_fps(fps)
    return _detected_frames((_read_frame_file(p) for p in files), files, optional_layout(layout), fps,
                            files[0].parent)


def read_raw_folder(folder: str | Path) -> list[list[RawPerson]]:
    """Each frame's people of a keypoint folder as its files hold them (the source layout, not mapped
    onto the universal 14), in frame order (:func:`frame_order_key`); errors name the file."""
    return [_read_frame_file(p).people for p in _frame_files(Path(folder))]


def _detected_frames(parsed: Iterator[_ParsedFrame], names: Sequence[object], layout: str | None,
                     fps: float | None, pool_name: object) -> Iterator[KeypointFrame]:
    """Frames of ``parsed`` (frame i is ``names[i]`` in errors), numbered and timed as
    :func:`read_openpose_folder` says; ``layout`` None: detected once from the first
    :data:`DETECT_FRAMES` frames holding people (``pool_name`` in errors)."""
    buffered: list[_ParsedFrame] = []
    if layout is None:
        with_people = 0
        for item in parsed:
            buffered.append(item)
            with_people += bool(item.people)
            if with_people >= DETECT_FRAMES:
                break
        pool = [p.raw for b in buffered for p in b.people]
        if pool:
            with error_source(pool_name):
                if len({len(r) for r in pool}) > 1:
                    raise KeypointError("the first frames mix people with different keypoint counts")
                layout = detect_layout(np.stack(pool))
    next_index = 0
    for position, own in enumerate(itertools.chain(buffered, parsed)):
        index = next_index if own.number is None else own.number
        time_s = frame_time(index, fps) if own.time_s is None else own.time_s
        with error_source(names[position]):
            frame = build_frame(index, time_s, own.people, layout)
        next_index = index + 1
        yield frame


def _mmpose_frame(frame: object, i: int) -> list[RawPerson]:
    with error_source(f"frame {i}"):
        instances = frame.get("instances") if isinstance(frame, dict) else None
        if not isinstance(instances, list):
            raise KeypointError("no 'instances' list")
        return _raw_people(instances)


def _mmpose_people(obj: dict | list) -> list[list[RawPerson]]:
    """Each frame's people in a parsed MMPose prediction file."""
    if isinstance(obj, dict):
        info = obj.get("instance_info")
        if not isinstance(info, list):
            raise KeypointError("not an MMPose prediction file (no 'instance_info' list)")
        obj = info
    if obj and isinstance(obj[0], dict) and "instances" in obj[0]:
        return [_mmpose_frame(frame, i) for i, frame in enumerate(obj)]
    return [_raw_people(obj)]  # one image's instances


def read_mmpose_json(path: str | Path, layout: str | None = None, fps: float | None = None) -> list[KeypointFrame]:
    """The frames of an MMPose prediction file, read and checked at once (errors name the file).

    A list of instances ``{"keypoints": [[x, y], ...], "keypoint_scores": [...]}`` (one image), a list
    of frames ``{"frame_id": n, "instances": [...]}`` (a video), or either under ``"instance_info"``
    (the demo scripts). ``index`` is the frame's position, ``time_s = index / fps`` when ``fps`` is
    given; ``layout`` None: detected as for a folder.
    """
    path = Path(path)
    check_fps(fps)
    text = _read_text(path, MAX_PREDICTIONS_BYTES)
    with error_source(path):
        people = _mmpose_people(_load_json(text))
        names = [f"frame {i}" for i in range(len(people))]
        return list(_detected_frames(map(_ParsedFrame, people), names, optional_layout(layout), fps, None))


def _field(obj: dict, key: str, kinds: tuple[type[T], ...], what: str) -> T | None:
    """``obj[key]`` if it is one of ``kinds`` (never a bool), None if absent or null."""
    value = obj.get(key)
    if value is not None and (not isinstance(value, kinds) or isinstance(value, bool)):
        raise KeypointError(f"'{key}' must be {what}")
    return value


def parse_stream_line(line: str, default_layout: str | None = None,
                      known: Mapping[int, str] | None = None) -> KeypointFrame:
    """One JSON-lines input frame (schema: ``data_specs/keypoint_formats.md``).

    ``{"frame": 12, "time": 0.4, "layout": "coco17", "people": [{"id": 3, "keypoints": [[x, y, c], ...]}]}``,
    an OpenPose-style object or an MMPose per-image list of instances. A missing ``frame`` gives
    index -1 (the caller numbers the frame); ``time`` is in seconds. ``known``: layouts by keypoint
    count for people whose layout neither they, their line nor ``default_layout`` give
    (:func:`build_frame`). Any bad input raises KeypointError with a short reason, nothing else.
    """
    obj = _load_json(line)
    if isinstance(obj, list):
        return build_frame(-1, None, _raw_people(obj), optional_layout(default_layout), known)
    index, time_s = _frame_and_time(obj)
    layout = optional_layout(obj.get("layout", default_layout))
    return build_frame(-1 if index is None else index, time_s, _raw_people(obj), layout, known)


def _frame_and_time(obj: dict) -> tuple[int | None, float | None]:
    """A frame object's own ``frame`` number and ``time`` (seconds), each None when absent or null;
    KeypointError when out of range (:data:`MAX_INTEGER`, :data:`MAX_TIME_S`)."""
    index = _field(obj, "frame", (int,), "a non-negative integer")
    if index is not None and not 0 <= index < MAX_INTEGER:
        raise KeypointError("'frame' must be a non-negative integer below 2**53")
    time_s = _field(obj, "time", (int, float), "a number of seconds")
    if time_s is not None and not abs(time_s) < MAX_TIME_S:  # NaN, infinite, or beyond any take
        raise KeypointError(f"'time' must be a finite number of seconds below {MAX_TIME_S:,.0f} in magnitude")
    return index, None if time_s is None else float(time_s)
