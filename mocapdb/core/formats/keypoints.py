"""2D body keypoints in: OpenPose and MMPose JSON, JSON-lines streams and detector arrays, on the universal 14.

Every input layout (OpenPose BODY_25, BODY_25B, COCO-18; COCO-17, HALPE_26 and COCO-WholeBody-133
from MMPose, RTMLib or YOLO-pose; MediaPipe BlazePose 33; tables in :mod:`mocapdb.core.formats.keypoint_layouts`)
is mapped onto the 14 keypoints of :data:`mocapdb.core.skeleton.KEYPOINTS` (pixels, x right, y down).
Orders, mapping, layout detection, file forms and the JSON-lines schema: ``data_specs/keypoint_formats.md``.
"""
from __future__ import annotations

import itertools
import json
import math
import os
import re
import zipfile
import zlib
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from tokenize import TokenError
from typing import BinaryIO, NamedTuple

import numpy as np

from mocapdb.core.errors import MocapdbError
from mocapdb.core.formats.keypoint_layouts import LAYOUT_OF_COUNT, LAYOUTS, SOURCE_INDEX
from mocapdb.core.skeleton import KP, N_KEYPOINTS_2D

CONFIDENCE_THRESHOLD = 0.3  # a keypoint is confident (visible) at or above this confidence

# BODY_25 / BODY_25B detection. A relation "holds" for a person when its residual is below
# LAYOUT_FIT times the person's size (diagonal of the box around the confident keypoints).
LAYOUT_FIT = 0.04
UPPER_NECK_SPAN_NOSE = (0.2, 1.0)      # BODY_25B upper neck: fraction of the way nose → mid-shoulder
UPPER_NECK_SPAN_HEAD_TOP = (0.05, 0.9)  # and of the way mid-shoulder → head top
LAYOUT_VOTE_RATIO = 3  # the winning layout needs more than this times the loser's votes
NORMALISED_EXTENT = 2.0  # a MediaPipe person whose points all lie within this of 0 is not in pixels
DETECT_FRAMES = 10     # a folder's or file's layout is detected from its first frames holding people


class KeypointError(MocapdbError, ValueError):
    """Keypoint input that cannot be read; the message names the source and the problem."""


@dataclass
class Person:
    """One person's universal keypoints; a missing keypoint has confidence 0 and NaN position."""
    points_px: np.ndarray   # [14, 2] float64, pixels, x right, y down
    confidence: np.ndarray  # [14] float64 in [0, 1], 0 = missing
    person_id: int | None = None


@dataclass
class KeypointFrame:
    """The people of one frame; ``index`` counts frames from 0, ``time_s`` is in seconds."""
    index: int
    time_s: float | None
    people: list[Person]
    layout: str | None = None  # the layout of its people, when they share one


class _RawPerson(NamedTuple):
    raw: np.ndarray      # [K, 3] x, y, confidence in the source layout
    person_id: int | None
    layout: str | None   # the person's own layout, if the input names one


def visible(person: Person, threshold: float = CONFIDENCE_THRESHOLD) -> np.ndarray:
    """Which of the 14 keypoints are confident: ``bool [14]`` (confidence > 0 and >= threshold)."""
    return (person.confidence > 0) & (person.confidence >= threshold)


def _shown(value: object) -> str:
    """``repr(value)``, shortened to at most 20 characters for error messages."""
    text = repr(value)
    return text if len(text) <= 20 else text[:17] + "..."


def _check_layout(layout: object) -> str:
    if not isinstance(layout, str) or layout not in LAYOUTS:
        raise KeypointError(f"unknown keypoint layout {_shown(layout)} (known {', '.join(LAYOUTS)})")
    return layout


def _optional_layout(layout: object) -> str | None:
    return None if layout is None else _check_layout(layout)


def _numeric(values: object, what: str) -> np.ndarray:
    """``values`` as a float64 array; KeypointError unless all are numbers."""
    try:
        arr = np.asarray(values)
    except ValueError:
        raise KeypointError(f"{what} is not a regular array of numbers") from None
    if arr.dtype.kind not in "iuf":
        raise KeypointError(f"{what} holds non-numeric values")
    return arr.astype(np.float64)


def to_universal(raw: np.ndarray, layout: str) -> tuple[np.ndarray, np.ndarray]:
    """Map ``raw [P, K, 3]`` (x px, y px, confidence) in ``layout`` onto the universal 14.

    Returns ``points [P, 14, 2]`` (pixels; NaN where missing) and ``confidence [P, 14]`` (clipped
    to [0, 1]; 0 where missing: non-finite values, confidence <= 0, or no such keypoint). The neck
    is the mid-shoulder point whenever both shoulders are confident, else the layout's own neck.
    MediaPipe positions normalised to [0, 1] instead of pixels raise KeypointError.
    """
    names = LAYOUTS[_check_layout(layout)]
    raw = _numeric(raw, "keypoint array")
    if raw.ndim != 3 or raw.shape[1:] != (len(names), 3):
        raise KeypointError(f"keypoint array of shape {raw.shape} does not fit layout {layout}, "
                            f"which needs [P, {len(names)}, 3]")
    if layout == "mediapipe33":
        _refuse_normalised(raw)
    source = np.array(SOURCE_INDEX[layout])
    picked = raw[:, np.maximum(source, 0)]
    ok = np.isfinite(picked).all(axis=-1) & (picked[..., 2] > 0) & (source >= 0)
    conf = np.where(ok, np.clip(picked[..., 2], 0.0, 1.0), 0.0)
    points = np.where(ok[..., None], picked[..., :2], np.nan)
    r, l, neck = KP["r_shoulder"], KP["l_shoulder"], KP["neck"]
    both = (conf[:, r] >= CONFIDENCE_THRESHOLD) & (conf[:, l] >= CONFIDENCE_THRESHOLD)
    points[:, neck] = np.where(both[:, None], 0.5 * (points[:, r] + points[:, l]), points[:, neck])
    conf[:, neck] = np.where(both, np.minimum(conf[:, r], conf[:, l]), conf[:, neck])
    return points, conf


def _refuse_normalised(raw: np.ndarray) -> None:
    """KeypointError if a person's found points all lie within 2 of the origin: MediaPipe's normalised
    image coordinates (fractions of the width and height), not pixels."""
    found = np.isfinite(raw).all(axis=-1) & (raw[..., 2] > 0)
    extent = np.where(found, np.abs(raw[..., :2]).max(axis=-1, initial=0.0), 0.0).max(axis=-1)
    if np.any(found.any(axis=-1) & (extent <= NORMALISED_EXTENT)):
        raise KeypointError("MediaPipe positions look normalised to [0, 1], not pixels; "
                            "give x times the image width and y times its height")


def _segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray, span: tuple[float, float]) -> np.ndarray:
    """Distance from ``p`` to the part ``span`` (fractions of the way) of the segments a → b."""
    v = b - a
    t = np.clip(np.sum((p - a) * v, axis=-1) / np.maximum(np.sum(v * v, axis=-1), 1e-12), *span)
    return np.linalg.norm(p - a - t[..., None] * v, axis=-1)


def _layout_residuals(raw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per person, the relative residuals ``[P]`` of the BODY_25 and of the BODY_25B relations.

    NaN where a relation's keypoints are not all confident; each is the worst holding relation.
    """
    ok = np.isfinite(raw).all(axis=-1) & (raw[..., 2] >= CONFIDENCE_THRESHOLD)
    xy = np.where(ok[..., None], raw[..., :2], np.nan)
    size = np.linalg.norm(np.fmax.reduce(xy, axis=1) - np.fmin.reduce(xy, axis=1), axis=-1)
    size = np.where(size > 0, size, np.nan)
    i25, i25b = LAYOUTS["body25"].index, LAYOUTS["body25b"].index
    p25 = {n: xy[:, i25(n)] for n in ("Neck", "RShoulder", "LShoulder", "MidHip", "RHip", "LHip")}
    neck = np.linalg.norm(p25["Neck"] - 0.5 * (p25["RShoulder"] + p25["LShoulder"]), axis=-1)
    mid_hip = np.linalg.norm(p25["MidHip"] - 0.5 * (p25["RHip"] + p25["LHip"]), axis=-1)
    p25b = {n: xy[:, i25b(n)] for n in ("nose", "left_shoulder", "right_shoulder", "upper_neck", "head_top")}
    mid_shoulder = 0.5 * (p25b["left_shoulder"] + p25b["right_shoulder"])
    below_nose = _segment_distance(p25b["upper_neck"], p25b["nose"], mid_shoulder, UPPER_NECK_SPAN_NOSE)
    below_top = _segment_distance(p25b["upper_neck"], mid_shoulder, p25b["head_top"], UPPER_NECK_SPAN_HEAD_TOP)
    return np.fmax(neck, mid_hip) / size, np.fmax(below_nose, below_top) / size


def detect_layout(raw: np.ndarray) -> str:
    """The layout of ``raw [P, K, 3]`` (people possibly pooled from several frames).

    By the keypoint count (17 coco17, 18 coco18, 26 halpe26, 33 mediapipe33, 133 wholebody133); 25 is
    BODY_25 or BODY_25B, told apart by geometry: each person votes for the layout whose relations
    hold while the other's do not (BODY_25: neck at the mid-shoulder and MidHip at the mid-hip;
    BODY_25B: upper neck between the mid-shoulder and both the nose and the head top).
    KeypointError for any other count, or when the votes do not settle it.
    """
    raw = _numeric(raw, "keypoint array")
    if raw.ndim != 3 or raw.shape[-1] != 3:
        raise KeypointError(f"keypoint array of shape {raw.shape} is not [P, K, 3]")
    count = raw.shape[1]
    if count in LAYOUT_OF_COUNT:
        return LAYOUT_OF_COUNT[count]
    if count != len(LAYOUTS["body25"]):
        counts = sorted({len(names) for names in LAYOUTS.values()})
        raise KeypointError(f"{count} keypoints per person fit no known layout "
                            f"({', '.join(map(str, counts[:-1]))} or {counts[-1]} keypoints)")
    e25, e25b = _layout_residuals(raw)
    votes = {"body25": int(np.sum((e25 < LAYOUT_FIT) & ~(e25b < LAYOUT_FIT))),
             "body25b": int(np.sum((e25b < LAYOUT_FIT) & ~(e25 < LAYOUT_FIT)))}
    (winner, won), (_, lost) = sorted(votes.items(), key=lambda kv: -kv[1])
    if won > LAYOUT_VOTE_RATIO * lost:
        return winner
    raise KeypointError(f"25 keypoints, BODY_25 or BODY_25B undecided (votes {votes['body25']} body25, "
                        f"{votes['body25b']} body25b of {len(raw)} people); give --keypoints body25 or body25b")


@contextmanager
def _source(name: object) -> Iterator[None]:
    """Prefix the message of any KeypointError raised inside with the source name (None: no prefix)."""
    try:
        yield
    except KeypointError as err:
        if name is None:
            raise
        raise KeypointError(f"{name}: {err}") from None


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


def _read_text(path: Path) -> str:
    try:
        return path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise KeypointError("not UTF-8 text") from None


def _person_id(value: object) -> int | None:
    """``id`` or OpenPose ``person_id`` (an int, or a list holding one); -1 means none."""
    if isinstance(value, list) and len(value) == 1:
        value = value[0]
    if value is None:
        return None
    if not isinstance(value, int) or isinstance(value, bool):
        raise KeypointError(f"person id {_shown(value)} is not an integer")
    return None if value == -1 else value


def _with_scores(xy: np.ndarray, scores: np.ndarray, what: str) -> np.ndarray:
    """Positions ``[..., 2]`` and their scores ``[...]`` as ``[..., 3]`` rows (x, y, confidence)."""
    if xy.shape[-1:] != (2,) or scores.shape != xy.shape[:-1]:
        raise KeypointError(f"{what} of shape {scores.shape} do not fit positions of shape {xy.shape} "
                            f"(positions [..., 2] with scores [...])")
    return np.concatenate([xy, scores[..., None]], axis=-1)


def _raw_person(obj: object, i: int) -> _RawPerson:
    """A person entry: ``keypoints`` [[x, y, c], ...] (or MMPose's [[x, y], ...] with ``keypoint_scores``)
    or OpenPose ``pose_keypoints_2d`` [x, y, c, ...]."""
    if not isinstance(obj, dict):
        raise KeypointError(f"person {i} is not a JSON object")
    if "keypoints" in obj:
        raw = _numeric(obj["keypoints"], f"person {i} keypoints")
        if "keypoint_scores" in obj:
            scores = _numeric(obj["keypoint_scores"], f"person {i} keypoint_scores")
            raw = _with_scores(raw, scores, f"person {i} keypoint_scores")
        if raw.ndim != 2 or raw.shape[1] != 3:
            raise KeypointError(f"person {i} keypoints must be [[x, y, confidence], ...] "
                                f"or [[x, y], ...] with keypoint_scores")
    elif "pose_keypoints_2d" in obj:
        flat = _numeric(obj["pose_keypoints_2d"], f"person {i} pose_keypoints_2d")
        if flat.ndim != 1 or flat.size % 3:
            raise KeypointError(f"person {i} pose_keypoints_2d holds {flat.size} values, not a multiple of 3")
        raw = flat.reshape(-1, 3)
    else:
        raise KeypointError(f"person {i} has neither 'keypoints' nor 'pose_keypoints_2d'")
    return _RawPerson(raw, _person_id(obj.get("id", obj.get("person_id"))), _optional_layout(obj.get("layout")))


def _raw_people(obj: dict | list) -> list[_RawPerson]:
    """The people of an OpenPose-style object (its ``people``) or of an MMPose list of instances.

    An entry without keypoints (``"pose_keypoints_2d": []``, as Pose2Sim writes) is an absent person."""
    people = obj if isinstance(obj, list) else obj.get("people")
    if not isinstance(people, list):
        raise KeypointError("no 'people' list")
    if people and isinstance(people[0], dict) and "instances" in people[0]:
        raise KeypointError("an MMPose video file (a list of frames), to be read as a file of its own")
    return [p for p in (_raw_person(p, i) for i, p in enumerate(people)) if len(p.raw)]


def _build_frame(index: int, time_s: float | None, people: list[_RawPerson], layout: str | None) -> KeypointFrame:
    """Map every person onto the universal 14: own layout, else ``layout``, else detected by count."""
    names = [p.layout or layout for p in people]
    undecided = [p.raw for p, name in zip(people, names) if name is None]
    detected = {k: detect_layout(np.stack([r for r in undecided if len(r) == k]))
                for k in {len(r) for r in undecided}}
    names = [name or detected[len(p.raw)] for p, name in zip(people, names)]
    out: list[Person | None] = [None] * len(people)
    for name in dict.fromkeys(names):
        members = [i for i, n in enumerate(names) if n == name]
        wrong = [i for i in members if len(people[i].raw) != len(LAYOUTS[name])]
        if wrong:
            raise KeypointError(f"person {wrong[0]} has {len(people[wrong[0]].raw)} keypoints; "
                                f"layout {name} has {len(LAYOUTS[name])}")
        points, conf = to_universal(np.stack([people[i].raw for i in members]), name)
        for j, i in enumerate(members):
            out[i] = Person(points[j], conf[j], people[i].person_id)
    return KeypointFrame(index, time_s, out, names[0] if len(set(names)) == 1 else None)


def parse_openpose_json(text: str, index: int, layout: str | None = None, source: str = "") -> KeypointFrame:
    """One OpenPose ``--write_json`` frame (``{"people": [{"pose_keypoints_2d": [x, y, c, ...]}]}``)
    or MMPose per-image prediction (``[{"keypoints": [[x, y], ...], "keypoint_scores": [...]}, ...]``).

    ``layout`` None: detected from this frame's people. Errors: KeypointError naming ``source``.
    """
    with _source(source or "<OpenPose JSON>"):
        return _build_frame(index, None, _raw_people(_load_json(text)), _optional_layout(layout))


_OPENPOSE_FRAME = re.compile(r"_([0-9]+)_keypoints\.json$")   # <stem>_<frame>_keypoints.json
_DIGIT_RUNS = re.compile(r"([0-9]+)")


def frame_order_key(name: str) -> tuple[int, int, tuple[str | int, ...], str]:
    """Sort key putting keypoint file names (no folder part) in frame order; used by every folder
    reader (:func:`read_openpose_folder`, the live folder source of ``mocapdb.runtime.sources``).

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


def _frame_files(folder: Path) -> list[Path]:
    """The folder's .json files in frame order (:func:`frame_order_key`)."""
    if not folder.is_dir():
        raise KeypointError(f"{folder}: not a folder")
    files = [p for p in folder.iterdir() if p.suffix.lower() == ".json" and p.is_file()]
    if not files:
        raise KeypointError(f"{folder}: no .json keypoint files")
    return sorted(files, key=lambda p: frame_order_key(p.name))


def _check_fps(fps: float | None) -> None:
    if fps is not None and not (math.isfinite(fps) and fps > 0):
        raise KeypointError(f"frame rate {fps!r} is not a positive number of frames per second")


def _time_s(index: int, fps: float | None) -> float | None:
    return None if fps is None else index / fps


def _read_people(path: Path) -> list[_RawPerson]:
    with _source(path):
        return _raw_people(_load_json(_read_text(path)))


def read_openpose_folder(folder: str | Path, layout: str | None = None,
                         fps: float | None = None) -> Iterator[KeypointFrame]:
    """The frames of an OpenPose ``--write_json`` folder (or of MMPose per-image files), in frame-number order.

    ``index`` is the position in that order; ``time_s = index / fps`` (seconds) when ``fps`` (Hz)
    is given. ``layout`` None: detected once from the first :data:`DETECT_FRAMES` frames holding
    people, then fixed. Folder errors are raised at once, file errors when the file is reached.
    """
    files = _frame_files(Path(folder))
    _check_fps(fps)
    return _detected_frames((_read_people(p) for p in files), files, _optional_layout(layout), fps, files[0].parent)


def _detected_frames(parsed: Iterator[list[_RawPerson]], names: Sequence[object], layout: str | None,
                     fps: float | None, pool_name: object) -> Iterator[KeypointFrame]:
    """Frames of the people lists ``parsed`` (frame i is ``names[i]`` in errors); ``layout`` None:
    detected once from the first :data:`DETECT_FRAMES` frames holding people (``pool_name`` in errors)."""
    buffered: list[list[_RawPerson]] = []
    if layout is None:
        with_people = 0
        for people in parsed:
            buffered.append(people)
            with_people += bool(people)
            if with_people >= DETECT_FRAMES:
                break
        pool = [p.raw for b in buffered for p in b]
        if pool:
            with _source(pool_name):
                if len({len(r) for r in pool}) > 1:
                    raise KeypointError("the first frames mix people with different keypoint counts")
                layout = detect_layout(np.stack(pool))
    for index, people in enumerate(itertools.chain(buffered, parsed)):
        with _source(names[index]):
            frame = _build_frame(index, _time_s(index, fps), people, layout)
        yield frame


def _mmpose_frame(frame: object, i: int) -> list[_RawPerson]:
    with _source(f"frame {i}"):
        instances = frame.get("instances") if isinstance(frame, dict) else None
        if not isinstance(instances, list):
            raise KeypointError("no 'instances' list")
        return _raw_people(instances)


def _mmpose_people(obj: dict | list) -> list[list[_RawPerson]]:
    """Each frame's people in a parsed MMPose prediction file."""
    if isinstance(obj, dict):
        obj = obj.get("instance_info")
        if not isinstance(obj, list):
            raise KeypointError("not an MMPose prediction file (no 'instance_info' list)")
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
    _check_fps(fps)
    with _source(path):
        people = _mmpose_people(_load_json(_read_text(path)))
        names = [f"frame {i}" for i in range(len(people))]
        return list(_detected_frames(iter(people), names, _optional_layout(layout), fps, None))


def _field(obj: dict, key: str, kinds: tuple[type, ...], what: str) -> object:
    value = obj.get(key)
    if value is not None and (not isinstance(value, kinds) or isinstance(value, bool)):
        raise KeypointError(f"'{key}' must be {what}")
    return value


def parse_stream_line(line: str, default_layout: str | None = None) -> KeypointFrame:
    """One JSON-lines input frame (schema: ``data_specs/keypoint_formats.md``).

    ``{"frame": 12, "time": 0.4, "layout": "coco17", "people": [{"id": 3, "keypoints": [[x, y, c], ...]}]}``,
    an OpenPose-style object or an MMPose per-image list of instances. A missing ``frame`` gives
    index -1 (the caller numbers the frame); ``time`` is in seconds. Any bad input raises
    KeypointError with a short reason, nothing else.
    """
    obj = _load_json(line)
    if isinstance(obj, list):
        return _build_frame(-1, None, _raw_people(obj), _optional_layout(default_layout))
    index = _field(obj, "frame", (int,), "a non-negative integer")
    if index is not None and index < 0:
        raise KeypointError("'frame' must be a non-negative integer")
    time_s = _field(obj, "time", (int, float), "a number of seconds")
    if time_s is not None and not abs(time_s) < 1e300:  # NaN, infinite, or an int too big for a float
        raise KeypointError("'time' must be a finite number of seconds")
    layout = _optional_layout(obj.get("layout", default_layout))
    return _build_frame(-1 if index is None else index, None if time_s is None else float(time_s),
                        _raw_people(obj), layout)


def frames_from_arrays(keypoints: np.ndarray, layout: str | None = None,
                       fps: float | None = None) -> Iterator[KeypointFrame]:
    """Frames from a detector's array: ``[T, P, K, 3]`` or one person ``[T, K, 3]`` (x px, y px, confidence).

    ``layout`` None: detected from all people (:func:`detect_layout`). People with no keypoint at
    all (padding) are left out; array slots are not identities, so ``person_id`` is None.
    ``time_s = index / fps`` (seconds) when ``fps`` (Hz) is given. Errors are raised at once.
    """
    arr = _numeric(keypoints, "keypoint array")
    if arr.ndim == 3:
        arr = arr[:, None]
    if arr.ndim != 4 or arr.shape[-1] != 3:
        raise KeypointError(f"keypoint array of shape {np.shape(keypoints)}, expected [T, K, 3] or [T, P, K, 3]")
    _check_fps(fps)
    n_frames, n_people = arr.shape[:2]
    people = arr.reshape((-1,) + arr.shape[2:])
    points, conf = to_universal(people, detect_layout(people) if layout is None else layout)
    points = points.reshape(n_frames, n_people, N_KEYPOINTS_2D, 2)
    conf = conf.reshape(n_frames, n_people, N_KEYPOINTS_2D)
    present = (conf > 0).any(axis=-1)
    return (KeypointFrame(t, _time_s(t, fps), [Person(points[t, p], conf[t, p]) for p in np.flatnonzero(present[t])])
            for t in range(n_frames))


_NPY_HEADERS = {(1, 0): np.lib.format.read_array_header_1_0, (2, 0): np.lib.format.read_array_header_2_0}


def _read_npy(f: BinaryIO, size: int) -> np.ndarray:
    """The numeric array in ``.npy`` data ``f`` of ``size`` bytes; the header is checked against
    ``size`` before anything is allocated, and object arrays are refused (never unpickled)."""
    try:
        shape, fortran, dtype = _NPY_HEADERS[np.lib.format.read_magic(f)](f)
    except (ValueError, KeyError, SyntaxError, TokenError):
        raise KeypointError("not a .npy array (missing or damaged header)") from None
    if dtype.kind not in "iuf" or dtype.fields is not None or dtype.subdtype is not None:
        raise KeypointError(f"holds {dtype} values, not numbers")
    if min(shape, default=0) < 0:
        raise KeypointError(f"header says shape {shape}, with a negative size")
    count, data_size = math.prod(shape), size - f.tell()
    if count * dtype.itemsize != data_size:
        raise KeypointError(f"header says shape {shape} of {dtype} ({count * dtype.itemsize} bytes) "
                            f"but {data_size} bytes follow it (damaged or truncated)")
    data = f.read(data_size + 1)
    if len(data) != data_size:
        raise KeypointError(f"{len(data)} bytes of data where the header says {data_size} (damaged or truncated)")
    return np.frombuffer(data, dtype, count).reshape(shape, order="F" if fortran else "C")


def _npz_member(zf: zipfile.ZipFile, key: str, name: str) -> np.ndarray:
    info = zf.getinfo(name)
    with _source(f"array '{key}'"):
        if info.flag_bits & 0x1:
            raise KeypointError("encrypted")
        with zf.open(info) as f:
            return _read_npy(f, info.file_size)


def _npz_arrays(path: Path) -> tuple[np.ndarray, np.ndarray | None]:
    """The ``keypoints`` and (None if absent) ``scores`` arrays of an ``.npz`` file."""
    with open(path, "rb") as file:  # a missing or unreadable file raises OSError here, not below
        try:
            with zipfile.ZipFile(file) as zf:
                names = {n.removesuffix(".npy"): n for n in zf.namelist() if n.endswith(".npy")}
                if "keypoints" not in names:
                    raise KeypointError("no 'keypoints' array in the .npz file")
                scores = _npz_member(zf, "scores", names["scores"]) if "scores" in names else None
                return _npz_member(zf, "keypoints", names["keypoints"]), scores
        except (zipfile.BadZipFile, zlib.error, EOFError, NotImplementedError, OSError) as err:
            raise KeypointError(f"not a readable .npz (zip) file ({err})") from None


def _checked_keypoints(keypoints: np.ndarray, scores: np.ndarray | None) -> np.ndarray:
    """``keypoints`` (with ``scores`` when it holds positions only) as a finite float64
    ``[T, K, 3]`` or ``[T, P, K, 3]`` array, else KeypointError saying what is wrong."""
    if scores is not None and keypoints.shape[-1:] == (2,):
        keypoints = _with_scores(keypoints, scores, "scores")
    if keypoints.ndim not in (3, 4) or keypoints.shape[-1] != 3:
        raise KeypointError(f"keypoints of shape {keypoints.shape}, expected [T, K, 3] or [T, P, K, 3] "
                            f"(x, y, confidence), or positions [..., 2] with scores [...] in an .npz")
    if keypoints.size == 0:
        raise KeypointError(f"keypoints of shape {keypoints.shape} hold no values")
    finite = np.isfinite(keypoints)
    if not finite.all():
        first = tuple(int(i) for i in np.unravel_index(np.argmin(finite), finite.shape))
        raise KeypointError(f"{finite.size - np.count_nonzero(finite)} non-finite values (NaN or infinite), "
                            f"the first at index {first}; write a missing keypoint as 0, 0, 0")
    return keypoints.astype(np.float64)


def read_keypoint_array(path: str | Path) -> np.ndarray:
    """A detector's keypoint array ``[T, K, 3]`` or ``[T, P, K, 3]`` (x px, y px, confidence, float64).

    ``.npy`` (``np.save``), or ``.npz`` (``np.savez``) with ``keypoints`` ``[..., 3]``, or RTMLib's
    positions ``keypoints [..., 2]`` with ``scores [...]``. Damaged files, headers that do not match
    the file size, non-numeric (object) arrays, other shapes and NaN or infinite values raise
    KeypointError naming the file; nothing is allocated before the header is checked.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".npy", ".npz"):
        raise KeypointError(f"{path}: not a .npy or .npz keypoint file")
    with _source(path):
        if suffix == ".npz":
            return _checked_keypoints(*_npz_arrays(path))
        with open(path, "rb") as f:
            return _checked_keypoints(_read_npy(f, os.fstat(f.fileno()).st_size), None)


KEYPOINT_FILE_SUFFIXES = (".npy", ".npz", ".json")


def read_keypoint_file(path: str | Path, layout: str | None = None,
                       fps: float | None = None) -> Iterator[KeypointFrame]:
    """The frames of a keypoint file: a detector array (``.npy``, ``.npz``: :func:`read_keypoint_array`)
    or MMPose predictions (``.json``: :func:`read_mmpose_json`). Read and checked at once, so errors
    (KeypointError naming the file) come before any frame; ``layout`` None: detected."""
    path = Path(path)
    if path.suffix.lower() == ".json":
        return iter(read_mmpose_json(path, layout, fps))
    keypoints = read_keypoint_array(path)
    with _source(path):
        return frames_from_arrays(keypoints, layout, fps)
