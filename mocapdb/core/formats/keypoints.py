"""2D body keypoints: the universal-14 types, the mapping of every input layout onto them and layout detection.

Every input layout (OpenPose BODY_25, BODY_25B, COCO-18; COCO-17, HALPE_26 and COCO-WholeBody-133
from MMPose, RTMLib or YOLO-pose; MediaPipe BlazePose 33; tables in :mod:`mocapdb.core.formats.keypoint_layouts`)
is mapped onto the 14 keypoints of :data:`mocapdb.core.skeleton.KEYPOINTS` (pixels, x right, y down).
The readers: OpenPose and MMPose JSON, folders and JSON-lines streams in
:mod:`mocapdb.core.formats.openpose`; detector arrays and ``.npy``/``.npz`` files in
:mod:`mocapdb.core.formats.keypoint_arrays`.
Orders, mapping, layout detection, file forms and the JSON-lines schema: ``data_specs/keypoint_formats.md``.
"""
from __future__ import annotations

import math
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from mocapdb.core.errors import MocapdbError
from mocapdb.core.formats.keypoint_layouts import EXTREMITY_INDEX, LAYOUT_OF_COUNT, LAYOUTS, SOURCE_INDEX
from mocapdb.core.skeleton import KP

CONFIDENCE_THRESHOLD = 0.3  # a keypoint is confident (visible) at or above this confidence

# BODY_25 / BODY_25B detection. A relation "holds" for a person when its residual is below
# LAYOUT_FIT times the person's size (diagonal of the box around the confident keypoints).
LAYOUT_FIT = 0.04
UPPER_NECK_SPAN_NOSE = (0.2, 1.0)      # BODY_25B upper neck: fraction of the way nose → mid-shoulder
UPPER_NECK_SPAN_HEAD_TOP = (0.05, 0.9)  # and of the way mid-shoulder → head top
LAYOUT_VOTE_RATIO = 3  # the winning layout needs more than this times the loser's votes
NORMALISED_EXTENT = 2.0  # a MediaPipe person whose points all lie within this of 0 is not in pixels
MAX_POSITION_PX = 1e6    # |x|, |y| of a finite keypoint at most this (30 times the largest image side)
MAX_WORLD_M = 100.0      # |x|, |y|, |z| of a finite world landmark at most this (metres from the hips)


class KeypointError(MocapdbError, ValueError):
    """Keypoint input that cannot be read; the message names the source and the problem."""


@dataclass
class Person:
    """One person's universal keypoints; a missing keypoint has confidence 0 and NaN position."""
    points_px: np.ndarray   # [14, 2] float64, pixels, x right, y down
    confidence: np.ndarray  # [14] float64 in [0, 1], 0 = missing
    person_id: int | None = None
    # [14, 3] heels, big toes, knuckles, then eyes, ears and mouth corners (EXTREMITIES order): x px, y px,
    # confidence (0 and NaN position = missing); None when the layout has none of them
    extremities: np.ndarray | None = None
    # [14, 3] the detector's own 3D of the 14 keypoints (BlazePose's world landmarks): metres, origin at
    # the hips' centre, x right and y down along the image's axes, z away from the camera; NaN where it
    # has none; None when the input carries none (data_specs/keypoint_formats.md, "World landmarks")
    world_m: np.ndarray | None = None
    # [2, 21, 4] the subject's right hand, then their left: 21 points each (wrist, thumb 1-4, index 1-4,
    # middle, ring, pinky 1-4) as x px, y px, z (depth from the wrist, px; NaN when not given), confidence
    # (0 and NaN position = missing); None when the input carries no hands (data_specs/keypoint_formats.md)
    hands: np.ndarray | None = None
    # [E, 3] the detector's own 3D of the EXTREMITIES rows (heels, toes, knuckles, face), as ``world_m``;
    # None when the input carries no world landmarks or the layout has no such rows
    extremities_world_m: np.ndarray | None = None
    # [468, 4] the face mesh (MediaPipe's face landmark model: x px, y px, z px, confidence; NaN and 0 where
    # the face is absent); None when the input carries no faces (live --face)
    face: np.ndarray | None = None


@dataclass
class KeypointFrame:
    """The people of one frame; ``index`` counts frames from 0, ``time_s`` is in seconds."""
    index: int
    time_s: float | None
    people: list[Person]
    layout: str | None = None  # the layout of its people, when they share one


class RawPerson(NamedTuple):
    raw: np.ndarray      # [K, 3] x, y, confidence in the source layout
    person_id: int | None
    layout: str | None   # the person's own layout, if the input names one
    world: np.ndarray | None = None   # [K, 3] world landmarks (metres; NaN: none) in the source layout, if given
    hands: np.ndarray | None = None   # [2, 21, 4] the person's hands (Person.hands), if given
    face: np.ndarray | None = None    # [468, 4] the person's face mesh (Person.face), if given


def visible(person: Person, threshold: float = CONFIDENCE_THRESHOLD) -> np.ndarray:
    """Which of the 14 keypoints are confident: ``bool [14]`` (confidence > 0 and >= threshold)."""
    return (person.confidence > 0) & (person.confidence >= threshold)


def shown(value: object) -> str:
    """``repr(value)``, shortened to at most 20 characters for error messages."""
    text = repr(value)
    return text if len(text) <= 20 else text[:17] + "..."


def _check_layout(layout: object) -> str:
    if not isinstance(layout, str) or layout not in LAYOUTS:
        raise KeypointError(f"unknown keypoint layout {shown(layout)} (known {', '.join(LAYOUTS)})")
    return layout


def optional_layout(layout: object) -> str | None:
    """``layout`` checked as a known layout name, or None."""
    return None if layout is None else _check_layout(layout)


def numeric(values: object, what: str) -> np.ndarray:
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
    MediaPipe positions normalised to [0, 1] instead of pixels, and finite positions beyond
    :data:`MAX_POSITION_PX`, raise KeypointError.
    """
    names = LAYOUTS[_check_layout(layout)]
    raw = numeric(raw, "keypoint array")
    if raw.ndim != 3 or raw.shape[1:] != (len(names), 3):
        raise KeypointError(f"keypoint array of shape {raw.shape} does not fit layout {layout}, "
                            f"which needs [P, {len(names)}, 3]")
    xy = raw[..., :2]
    if np.any(np.isfinite(xy) & (np.abs(xy) > MAX_POSITION_PX)):   # NaN and infinity: missing points
        raise KeypointError(f"a keypoint position is beyond {MAX_POSITION_PX:,.0f} px from the image origin")
    if layout == "mediapipe33":
        _refuse_normalised(raw)
    points, conf = _picked(raw, SOURCE_INDEX[layout])
    right, left, neck = KP["r_shoulder"], KP["l_shoulder"], KP["neck"]
    both = (conf[:, right] >= CONFIDENCE_THRESHOLD) & (conf[:, left] >= CONFIDENCE_THRESHOLD)
    points[:, neck] = np.where(both[:, None], 0.5 * (points[:, right] + points[:, left]), points[:, neck])
    conf[:, neck] = np.where(both, np.minimum(conf[:, right], conf[:, left]), conf[:, neck])
    return points, conf


def _picked(raw: np.ndarray, source: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
    """The points ``source`` (layout indices; -1: none) of ``raw [P, K, 3]``: positions ``[P, N, 2]``
    (NaN where missing) and confidences ``[P, N]`` (clipped to [0, 1]; 0 where missing)."""
    index = np.array(source)
    picked = raw[:, np.maximum(index, 0)]
    ok = np.isfinite(picked).all(axis=-1) & (picked[..., 2] > 0) & (index >= 0)
    conf = np.where(ok, np.clip(picked[..., 2], 0.0, 1.0), 0.0)
    return np.where(ok[..., None], picked[..., :2], np.nan), conf


def to_extremities(raw: np.ndarray, layout: str) -> np.ndarray | None:
    """The heels, big toes and knuckles (``keypoint_layouts.EXTREMITIES``) of ``raw [P, K, 3]``, a
    layout already checked by :func:`to_universal`: ``[P, 8, 3]`` x px, y px, confidence, missing
    points as in :func:`to_universal`; None for a layout without any of them."""
    if layout not in EXTREMITY_INDEX:
        return None
    points, conf = _picked(np.asarray(raw, dtype=np.float64), EXTREMITY_INDEX[layout])
    return np.concatenate([points, conf[..., None]], axis=-1)


def to_extremities_world(world: np.ndarray, layout: str) -> np.ndarray | None:
    """World landmarks ``[P, K, 3]`` (metres) in ``layout`` (checked) on the EXTREMITIES rows ``[P, E, 3]``
    (NaN where the layout has no such point or the value is not finite); None for a layout without any."""
    if layout not in EXTREMITY_INDEX:
        return None
    index = np.array(EXTREMITY_INDEX[layout])
    picked = np.asarray(world, dtype=np.float64)[:, np.maximum(index, 0)]
    return np.where((np.isfinite(picked).all(axis=-1) & (index >= 0))[..., None], picked, np.nan)


def to_universal_world(world: np.ndarray, layout: str) -> np.ndarray:
    """World landmarks ``[P, K, 3]`` (metres) in ``layout`` (checked) on the universal 14 ``[P, 14, 3]``:
    NaN where the layout has no such point or the value is not finite; the neck is the shoulders'
    mid-point when both are there, else the layout's own neck."""
    index = np.array(SOURCE_INDEX[layout])
    world = np.asarray(world, dtype=np.float64)
    picked = world[:, np.maximum(index, 0)]
    ok = np.isfinite(picked).all(axis=-1) & (index >= 0)
    out = np.where(ok[..., None], picked, np.nan)
    mid = 0.5 * (out[:, KP["r_shoulder"]] + out[:, KP["l_shoulder"]])
    out[:, KP["neck"]] = np.where(np.isfinite(mid).all(axis=-1, keepdims=True), mid, out[:, KP["neck"]])
    return out


def check_world(values: np.ndarray, count: int, what: str) -> np.ndarray:
    """A person's world landmarks (``[x0, y0, z0, ...]`` or ``[[x, y, z], ...]``, metres) for ``count``
    keypoints as ``[count, 3]``; non-finite values mark missing points; KeypointError when the size
    is not the keypoints' or a value lies beyond :data:`MAX_WORLD_M`."""
    if values.size != 3 * count or (values.ndim == 2 and values.shape[1] != 3) or values.ndim > 2:
        raise KeypointError(f"{what} holds {values.size} values; {count} keypoints need {3 * count} (x, y, z each)")
    if np.any(np.isfinite(values) & (np.abs(values) > MAX_WORLD_M)):
        raise KeypointError(f"{what} has a value beyond {MAX_WORLD_M:g} m from the hips")
    return values.reshape(count, 3)


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
    raw = numeric(raw, "keypoint array")
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
def error_source(name: object) -> Iterator[None]:
    """Prefix the message of any KeypointError raised inside with the source name (None: no prefix)."""
    try:
        yield
    except KeypointError as err:
        if name is None:
            raise
        raise KeypointError(f"{name}: {err}") from None


def with_scores(xy: np.ndarray, scores: np.ndarray, what: str) -> np.ndarray:
    """Positions ``[..., 2]`` and their scores ``[...]`` as ``[..., 3]`` rows (x, y, confidence)."""
    if xy.shape[-1:] != (2,) or scores.shape != xy.shape[:-1]:
        raise KeypointError(f"{what} of shape {scores.shape} do not fit positions of shape {xy.shape} "
                            f"(positions [..., 2] with scores [...])")
    return np.concatenate([xy, scores[..., None]], axis=-1)


def build_frame(index: int, time_s: float | None, people: list[RawPerson], layout: str | None,
                known: Mapping[int, str] | None = None) -> KeypointFrame:
    """Map every person onto the universal 14: own layout, else ``layout``, else ``known`` (layouts
    already decided, by keypoint count: a stream's earlier frames), else detected by count."""
    given = [p.layout or layout for p in people]
    undecided = [p.raw for p, name in zip(people, given) if name is None]
    known = known or {}
    detected = {k: known.get(k) or detect_layout(np.stack([r for r in undecided if len(r) == k]))
                for k in {len(r) for r in undecided}}
    names = [name or detected[len(p.raw)] for p, name in zip(people, given)]
    out: dict[int, Person] = {}
    for name in dict.fromkeys(names):
        members = [i for i, n in enumerate(names) if n == name]
        wrong = [i for i in members if len(people[i].raw) != len(LAYOUTS[name])]
        if wrong:
            raise KeypointError(f"person {wrong[0]} has {len(people[wrong[0]].raw)} keypoints; "
                                f"layout {name} has {len(LAYOUTS[name])}")
        raw = np.stack([people[i].raw for i in members])
        points, conf = to_universal(raw, name)
        extremities = to_extremities(raw, name)
        for j, i in enumerate(members):
            world = people[i].world
            ends_world = None if world is None else to_extremities_world(world[None], name)
            out[i] = Person(points[j], conf[j], people[i].person_id, None if extremities is None else extremities[j],
                            None if world is None else to_universal_world(world[None], name)[0], people[i].hands,
                            None if ends_world is None else ends_world[0], people[i].face)
    return KeypointFrame(index, time_s, [out[i] for i in range(len(people))],
                         names[0] if len(set(names)) == 1 else None)


def check_fps(fps: float | None) -> None:
    """KeypointError unless ``fps`` is None or a positive finite frame rate (Hz)."""
    if fps is not None and not (math.isfinite(fps) and fps > 0):
        raise KeypointError(f"frame rate {fps!r} is not a positive number of frames per second")


def frame_time(index: int, fps: float | None) -> float | None:
    """The time in seconds of frame ``index`` at ``fps`` Hz (None without a frame rate)."""
    return None if fps is None else index / fps
