"""2D body keypoints in: OpenPose JSON, JSON-lines streams and detector arrays, on the universal 14.

Every input layout (OpenPose BODY_25, BODY_25B, COCO-18; COCO-17 from MMPose, RTMLib or
YOLO-pose) is mapped onto the 14 keypoints of :data:`mocapdb.skeleton.KEYPOINTS` (pixels, x right,
y down). Orders, mapping, layout detection and the JSON-lines schema: ``data_specs/keypoint_formats.md``.
"""
from __future__ import annotations

import itertools
import json
import math
import re
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np

from .skeleton import KP, N_KEYPOINTS_2D

_COCO17 = (
    "nose", "left_eye", "right_eye", "left_ear", "right_ear", "left_shoulder", "right_shoulder",
    "left_elbow", "right_elbow", "left_wrist", "right_wrist", "left_hip", "right_hip",
    "left_knee", "right_knee", "left_ankle", "right_ankle")
_OPENPOSE_BODY = (
    "Nose", "Neck", "RShoulder", "RElbow", "RWrist", "LShoulder", "LElbow", "LWrist")
_OPENPOSE_FEET = ("LBigToe", "LSmallToe", "LHeel", "RBigToe", "RSmallToe", "RHeel")
_OPENPOSE_FACE = ("REye", "LEye", "REar", "LEar")
_OPENPOSE_LEGS = ("RHip", "RKnee", "RAnkle", "LHip", "LKnee", "LAnkle")

# Keypoint names of each input layout, in the layout's index order.
LAYOUTS: dict[str, tuple[str, ...]] = {
    "body25": _OPENPOSE_BODY + ("MidHip",) + _OPENPOSE_LEGS + _OPENPOSE_FACE + _OPENPOSE_FEET,
    "body25b": _COCO17 + (
        "upper_neck", "head_top", "left_big_toe", "left_small_toe", "left_heel",
        "right_big_toe", "right_small_toe", "right_heel"),
    "coco18": _OPENPOSE_BODY + _OPENPOSE_LEGS + _OPENPOSE_FACE,
    "coco17": _COCO17,
}
# The layout keypoint giving each universal keypoint (KEYPOINTS[:14] order); None: no such point
# (the neck then comes from the shoulders only; BODY_25B's "upper_neck" is not the mid-shoulder).
_OPENPOSE_SOURCES = _OPENPOSE_BODY + _OPENPOSE_LEGS
_COCO_SOURCES = (
    "nose", None, "right_shoulder", "right_elbow", "right_wrist", "left_shoulder", "left_elbow",
    "left_wrist", "right_hip", "right_knee", "right_ankle", "left_hip", "left_knee", "left_ankle")
_SOURCES: dict[str, tuple[str | None, ...]] = {
    "body25": _OPENPOSE_SOURCES, "body25b": _COCO_SOURCES,
    "coco18": _OPENPOSE_SOURCES, "coco17": _COCO_SOURCES}
_SOURCE_INDEX = {name: np.array([LAYOUTS[name].index(s) if s else -1 for s in sources])
                 for name, sources in _SOURCES.items()}
_LAYOUT_OF_COUNT = {17: "coco17", 18: "coco18"}
LAYOUT_HINT = "give the layout with --keypoints body25|body25b|coco18|coco17"

CONFIDENCE_THRESHOLD = 0.3  # a keypoint is confident (visible) at or above this confidence

# BODY_25 / BODY_25B detection. A relation "holds" for a person when its residual is below
# LAYOUT_FIT times the person's size (diagonal of the box around the confident keypoints).
LAYOUT_FIT = 0.04
UPPER_NECK_SPAN_NOSE = (0.2, 1.0)      # BODY_25B upper neck: fraction of the way nose → mid-shoulder
UPPER_NECK_SPAN_HEAD_TOP = (0.05, 0.9)  # and of the way mid-shoulder → head top
LAYOUT_VOTE_RATIO = 3  # the winning layout needs more than this times the loser's votes
DETECT_FRAMES = 10     # a folder's layout is detected from its first frames holding people


class KeypointError(ValueError):
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


def _check_layout(layout: object) -> str:
    if not isinstance(layout, str) or layout not in LAYOUTS:
        raise KeypointError(f"unknown keypoint layout {layout!r} (known: {', '.join(LAYOUTS)})")
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
    """
    names = LAYOUTS[_check_layout(layout)]
    raw = _numeric(raw, "keypoint array")
    if raw.ndim != 3 or raw.shape[1:] != (len(names), 3):
        raise KeypointError(f"keypoint array of shape {raw.shape}: layout {layout} needs [P, {len(names)}, 3]")
    source = _SOURCE_INDEX[layout]
    picked = raw[:, np.maximum(source, 0)]
    ok = np.isfinite(picked).all(axis=-1) & (picked[..., 2] > 0) & (source >= 0)
    conf = np.where(ok, np.clip(picked[..., 2], 0.0, 1.0), 0.0)
    points = np.where(ok[..., None], picked[..., :2], np.nan)
    r, l, neck = KP["r_shoulder"], KP["l_shoulder"], KP["neck"]
    both = (conf[:, r] >= CONFIDENCE_THRESHOLD) & (conf[:, l] >= CONFIDENCE_THRESHOLD)
    points[:, neck] = np.where(both[:, None], 0.5 * (points[:, r] + points[:, l]), points[:, neck])
    conf[:, neck] = np.where(both, np.minimum(conf[:, r], conf[:, l]), conf[:, neck])
    return points, conf


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

    17 keypoints: coco17, 18: coco18. 25: BODY_25 or BODY_25B, told apart by geometry: each person
    votes for the layout whose relations hold while the other's do not (BODY_25: neck at the
    mid-shoulder and MidHip at the mid-hip; BODY_25B: upper neck between the mid-shoulder and both
    the nose and the head top). KeypointError when the votes do not settle it.
    """
    raw = _numeric(raw, "keypoint array")
    if raw.ndim != 3 or raw.shape[-1] != 3:
        raise KeypointError(f"keypoint array of shape {raw.shape}: expected [P, K, 3]")
    count = raw.shape[1]
    if count in _LAYOUT_OF_COUNT:
        return _LAYOUT_OF_COUNT[count]
    if count != len(LAYOUTS["body25"]):
        raise KeypointError(f"{count} keypoints per person match no layout (17: coco17, 18: coco18, "
                            f"25: body25 or body25b)")
    e25, e25b = _layout_residuals(raw)
    votes = {"body25": int(np.sum((e25 < LAYOUT_FIT) & ~(e25b < LAYOUT_FIT))),
             "body25b": int(np.sum((e25b < LAYOUT_FIT) & ~(e25 < LAYOUT_FIT)))}
    (winner, won), (_, lost) = sorted(votes.items(), key=lambda kv: -kv[1])
    if won > LAYOUT_VOTE_RATIO * lost:
        return winner
    raise KeypointError(f"25 keypoints, but BODY_25 and BODY_25B cannot be told apart ({votes['body25']} of "
                        f"{len(raw)} people look like body25, {votes['body25b']} like body25b); {LAYOUT_HINT}")


@contextmanager
def _source(name: object) -> Iterator[None]:
    """Prefix the message of any KeypointError raised inside with the source name."""
    try:
        yield
    except KeypointError as err:
        raise KeypointError(f"{name}: {err}") from None


def _load_object(text: str) -> dict:
    try:
        obj = json.loads(text)
    except (ValueError, RecursionError) as err:
        raise KeypointError(f"not JSON ({err})") from None
    if not isinstance(obj, dict):
        raise KeypointError("not a JSON object")
    return obj


def _person_id(value: object) -> int | None:
    """``id`` or OpenPose ``person_id`` (an int, or a list holding one); -1 means none."""
    if isinstance(value, list) and len(value) == 1:
        value = value[0]
    if value is None:
        return None
    if not isinstance(value, int) or isinstance(value, bool):
        raise KeypointError(f"person id {value!r} is not an integer")
    return None if value == -1 else value


def _raw_person(obj: object, i: int) -> _RawPerson:
    """A person entry: ``keypoints`` [[x, y, c], ...] or OpenPose ``pose_keypoints_2d`` [x, y, c, ...]."""
    if not isinstance(obj, dict):
        raise KeypointError(f"person {i} is not a JSON object")
    if "keypoints" in obj:
        raw = _numeric(obj["keypoints"], f"person {i} keypoints")
        if raw.ndim != 2 or raw.shape[1] != 3:
            raise KeypointError(f"person {i} keypoints must be [[x, y, confidence], ...]")
    elif "pose_keypoints_2d" in obj:
        flat = _numeric(obj["pose_keypoints_2d"], f"person {i} pose_keypoints_2d")
        if flat.ndim != 1 or flat.size % 3:
            raise KeypointError(f"person {i} pose_keypoints_2d holds {flat.size} values, not a multiple of 3")
        raw = flat.reshape(-1, 3)
    else:
        raise KeypointError(f"person {i} has neither 'keypoints' nor 'pose_keypoints_2d'")
    return _RawPerson(raw, _person_id(obj.get("id", obj.get("person_id"))), _optional_layout(obj.get("layout")))


def _raw_people(obj: dict) -> list[_RawPerson]:
    people = obj.get("people")
    if not isinstance(people, list):
        raise KeypointError("no 'people' list")
    return [_raw_person(p, i) for i, p in enumerate(people)]


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
    """One OpenPose ``--write_json`` frame (``{"people": [{"pose_keypoints_2d": [x, y, c, ...]}]}``).

    ``layout`` None: detected from this frame's people. Errors: KeypointError naming ``source``.
    """
    with _source(source or "<OpenPose JSON>"):
        return _build_frame(index, None, _raw_people(_load_object(text)), _optional_layout(layout))


_OPENPOSE_NAME = re.compile(r"_(\d+)_keypoints\.json$")


def _frame_key(path: Path) -> tuple[int, int, list[object]]:
    """OpenPose-named files (``<name>_<frame>_keypoints.json``) by frame number first, then the
    others; ties and the others in natural order (case-insensitive, ``f2`` before ``f10``)."""
    natural = [int(s) if s.isdigit() else s.lower() for s in re.split(r"(\d+)", path.name)]
    match = _OPENPOSE_NAME.search(path.name)
    return (0, int(match[1]), natural) if match else (1, 0, natural)


def _frame_files(folder: Path) -> list[Path]:
    """The folder's .json files in frame order (:func:`_frame_key`)."""
    if not folder.is_dir():
        raise KeypointError(f"{folder}: not a folder")
    files = [p for p in folder.iterdir() if p.suffix.lower() == ".json" and p.is_file()]
    if not files:
        raise KeypointError(f"{folder}: no .json keypoint files")
    return sorted(files, key=_frame_key)


def _check_fps(fps: float | None) -> None:
    if fps is not None and not (math.isfinite(fps) and fps > 0):
        raise KeypointError(f"frame rate {fps!r} is not a positive number of frames per second")


def _time_s(index: int, fps: float | None) -> float | None:
    return None if fps is None else index / fps


def _read_people(path: Path) -> list[_RawPerson]:
    with _source(path):
        try:
            text = path.read_text(encoding="utf-8")
        except UnicodeDecodeError:
            raise KeypointError("not UTF-8 text") from None
        return _raw_people(_load_object(text))


def read_openpose_folder(folder: str | Path, layout: str | None = None,
                         fps: float | None = None) -> Iterator[KeypointFrame]:
    """The frames of an OpenPose ``--write_json`` folder, in frame-number order.

    ``index`` is the position in that order; ``time_s = index / fps`` (seconds) when ``fps`` (Hz)
    is given. ``layout`` None: detected once from the first :data:`DETECT_FRAMES` frames holding
    people, then fixed. Folder errors are raised at once, file errors when the file is reached.
    """
    files = _frame_files(Path(folder))
    _check_fps(fps)
    return _folder_frames(files, _optional_layout(layout), fps)


def _folder_frames(files: list[Path], layout: str | None, fps: float | None) -> Iterator[KeypointFrame]:
    parsed: Iterable[list[_RawPerson]] = (_read_people(p) for p in files)
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
            with _source(files[0].parent):
                if len({len(r) for r in pool}) > 1:
                    raise KeypointError("the first frames mix people with different keypoint counts")
                layout = detect_layout(np.stack(pool))
    for index, people in enumerate(itertools.chain(buffered, parsed)):
        with _source(files[index]):
            frame = _build_frame(index, _time_s(index, fps), people, layout)
        yield frame


def _field(obj: dict, key: str, kinds: tuple[type, ...], what: str) -> object:
    value = obj.get(key)
    if value is not None and (not isinstance(value, kinds) or isinstance(value, bool)):
        raise KeypointError(f"'{key}' must be {what}")
    return value


def parse_stream_line(line: str, default_layout: str | None = None) -> KeypointFrame:
    """One JSON-lines input frame (schema: ``data_specs/keypoint_formats.md``).

    ``{"frame": 12, "time": 0.4, "layout": "coco17", "people": [{"id": 3, "keypoints": [[x, y, c], ...]}]}``
    or an OpenPose-style object. A missing ``frame`` gives index -1 (the caller numbers the frame);
    ``time`` is in seconds. Any bad input raises KeypointError with a short reason, nothing else.
    """
    obj = _load_object(line)
    index = _field(obj, "frame", (int,), "a non-negative integer")
    if index is not None and index < 0:
        raise KeypointError("'frame' must be a non-negative integer")
    time_s = _field(obj, "time", (int, float), "a number of seconds")
    if time_s is not None and not abs(time_s) < 1e300:  # NaN, infinite, or an int too big for a float
        raise KeypointError("'time' must be a finite number of seconds")
    layout = _optional_layout(obj.get("layout", default_layout))
    return _build_frame(-1 if index is None else index, None if time_s is None else float(time_s),
                        _raw_people(obj), layout)


def frames_from_arrays(keypoints: np.ndarray, layout: str = "coco17",
                       fps: float | None = None) -> Iterator[KeypointFrame]:
    """Frames from a detector's array: ``[T, P, K, 3]`` or one person ``[T, K, 3]`` (x px, y px, confidence).

    People with no keypoint at all (padding) are left out; array slots are not identities, so
    ``person_id`` is None. ``time_s = index / fps`` (seconds) when ``fps`` (Hz) is given.
    """
    arr = _numeric(keypoints, "keypoint array")
    if arr.ndim == 3:
        arr = arr[:, None]
    if arr.ndim != 4 or arr.shape[-1] != 3:
        raise KeypointError(f"keypoint array of shape {np.shape(keypoints)}: expected [T, K, 3] or [T, P, K, 3]")
    _check_fps(fps)
    n_frames, n_people = arr.shape[:2]
    points, conf = to_universal(arr.reshape((-1,) + arr.shape[2:]), layout)
    points = points.reshape(n_frames, n_people, N_KEYPOINTS_2D, 2)
    conf = conf.reshape(n_frames, n_people, N_KEYPOINTS_2D)
    present = (conf > 0).any(axis=-1)
    return (KeypointFrame(t, _time_s(t, fps), [Person(points[t, p], conf[t, p]) for p in np.flatnonzero(present[t])])
            for t in range(n_frames))


def read_keypoint_array(path: str | Path) -> np.ndarray:
    """A keypoint array saved with ``np.save`` (``.npy``) or ``np.savez`` (``.npz``, key ``keypoints``)."""
    path = Path(path)
    if path.suffix.lower() not in (".npy", ".npz"):
        raise KeypointError(f"{path}: not a .npy or .npz keypoint file")
    with _source(path):
        try:
            loaded = np.load(path, allow_pickle=False)
            if isinstance(loaded, np.ndarray):
                return loaded
            with loaded:
                return loaded["keypoints"]
        except KeyError:
            raise KeypointError("no 'keypoints' array in the .npz file") from None
        except (ValueError, EOFError) as err:
            raise KeypointError(f"not a readable numpy file ({err})") from None
