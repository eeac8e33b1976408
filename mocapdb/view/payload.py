"""The JSON the viewer's page reads, shared by a recorded take and a live stream (``data_specs/viewer.md``).

Scene coordinates are right-handed, y up, metres: the track files' own frame (on the floor: y = 0
the floor, the origin under the camera; else the camera's view frame: x right, y up, z towards
the camera). Pixels are the input image's (x right, y down). Unknown values are ``null``.
"""
from __future__ import annotations

import math
from itertools import pairwise

import numpy as np

from mocapdb.core.fingers import FINGERS, finger_chain
from mocapdb.core.geometry import quat_to_matrix
from mocapdb.core.skeleton import DRAWING_LINES, END_JOINTS, KEYPOINTS, RIG_JOINTS, global_rotations
from mocapdb.render.draw import track_colour

INPUT_THRESHOLD = 0.3   # input keypoints below this confidence are not drawn (as `mocapdb render`)
VIEW_AXES = np.diag([1.0, -1.0, -1.0])   # rows: a camera's right, down and forward in its view frame
HAND_LINES = [[a, b] for finger in FINGERS for a, b in pairwise(finger_chain(finger))]   # the 21 hand points
FACE_REST = np.array([0.0, 0.0, 1.0])    # where the face points in the rest pose (view frame: at the camera)
HAND_REST = np.array([[-1.0, 0.0, 0.0], [1.0, 0.0, 0.0]])   # right, left hand bones at rest: out along the forearm
_NECK = RIG_JOINTS.index("neck")
_ELBOWS = [RIG_JOINTS.index("r_elbow"), RIG_JOINTS.index("l_elbow")]
_HEAD_END = END_JOINTS.index("head")
_HAND_ENDS = [END_JOINTS.index("r_hand"), END_JOINTS.index("l_hand")]


def numbers(values: np.ndarray, decimals: int) -> list:
    """``values`` as nested lists rounded to ``decimals``, non-finite values as None (JSON null)."""
    a = np.round(np.asarray(values, dtype=np.float64), decimals).astype(object)
    a[~np.isfinite(np.asarray(values, dtype=np.float64))] = None
    return a.tolist()


def colour(track: int) -> str:
    """A track's colour as CSS ``#rrggbb`` (the colours of ``mocapdb render``)."""
    b, g, r = track_colour(track)
    return f"#{r:02x}{g:02x}{b:02x}"


def skeleton() -> dict:
    """The joints' names and the lines drawn between them (indices), and a hand's lines (its 21 points)."""
    return {"joints": list(KEYPOINTS), "lines": [list(line) for line in DRAWING_LINES], "hand_lines": HAND_LINES}


def image(focal_px: float, size: tuple[int, int], principal: tuple[float, float] | None = None) -> dict:
    """The pinhole camera the re-projection used: focal and principal point (pixels), image size."""
    cx, cy = principal or (size[0] / 2, size[1] / 2)
    return {"width": int(size[0]), "height": int(size[1]), "focal": float(focal_px), "cx": float(cx), "cy": float(cy)}


def camera(name: str, position: np.ndarray, axes: np.ndarray, fov: tuple[float, float] | None, label: str) -> dict:
    """A camera in the scene: its centre, rows ``axes`` its right, down and forward directions,
    ``fov`` the tangents of half its horizontal and vertical field of view, a label."""
    return {"name": name, "position": numbers(position, 4), "axes": numbers(axes, 6),
            "fov": None if fov is None else [float(v) for v in fov], "label": label}


def fov(image_info: dict) -> tuple[float, float]:
    """Tangents of half the horizontal and vertical field of view of :func:`image`'s camera."""
    return image_info["width"] / 2 / image_info["focal"], image_info["height"] / 2 / image_info["focal"]


def input_people(people: list) -> list:
    """Input keypoints (:class:`~mocapdb.core.formats.keypoints.Person` or ``[14, 3]`` x, y,
    confidence arrays) as per-person lists of ``[x, y]`` or null below :data:`INPUT_THRESHOLD`."""
    out = []
    for p in people:
        if isinstance(p, np.ndarray):
            pts, conf = p[:, :2], p[:, 2]
        else:
            pts, conf = p.points_px, p.confidence
        seen = np.asarray(conf) >= INPUT_THRESHOLD
        out.append(numbers(np.where(seen[:, None], pts, np.nan), 1))
    return out


def _hand(points: np.ndarray) -> list | None:
    """One hand ``[21, 4]`` (x, y, z px, confidence) as 21 ``[x, y]`` or null below :data:`INPUT_THRESHOLD`;
    None when no point is seen."""
    seen = points[:, 3] >= INPUT_THRESHOLD
    return numbers(np.where(seen[:, None], points[:, :2], np.nan), 1) if seen.any() else None


def input_hands(people: list) -> list | None:
    """The input people's hands (``Person.hands [2, 21, 4]``), in :func:`input_people`'s order: per
    person ``[right, left]`` (each :func:`_hand`), or null for a person without hands; None when no
    person carries hands (the frame then says nothing of them)."""
    out = [None if getattr(p, "hands", None) is None else [_hand(h) for h in p.hands] for p in people]
    return out if any(h is not None for h in out) else None


def scene_from_view(axes: np.ndarray) -> np.ndarray:
    """``[3, 3]`` the rotation taking view-frame directions to the scene, of a camera whose rows
    ``axes`` are its right, down and forward in the scene (:func:`camera`)."""
    return np.asarray(axes, dtype=np.float64).T @ VIEW_AXES


def end_directions(quaternions: np.ndarray, end_quaternions: np.ndarray, to_scene: np.ndarray) -> dict:
    """Where one person-frame's face and hands point (unit, scene frame; 4 decimals): the head's global
    rotation (the neck's, the product of the rig's ``quaternions [11, 4]`` from the pelvis down, times
    the head's of ``end_quaternions [5, 4]``, view frame) on :data:`FACE_REST`, each hand's (its elbow's
    times its own) on :data:`HAND_REST`; ``to_scene`` the view frame's rotation into the scene."""
    rig = global_rotations(np.asarray(quaternions, dtype=np.float64)[None])[0]
    ends = quat_to_matrix(end_quaternions)
    face = to_scene @ rig[_NECK] @ ends[_HEAD_END] @ FACE_REST
    hands = [to_scene @ rig[e] @ ends[h] @ rest for e, h, rest in zip(_ELBOWS, _HAND_ENDS, HAND_REST)]
    return {"face": numbers(face / np.linalg.norm(face), 4),
            "hands": numbers(hands / np.linalg.norm(hands, axis=1, keepdims=True), 4)}


def spread_text(log_sd: float | None) -> str:
    """`` ±13 %`` for an SD of log stature (empty when unknown)."""
    return f" ±{100 * (math.exp(log_sd) - 1):.0f} %" if isinstance(log_sd, (int, float)) else ""
