"""The face mesh in keypoint JSON: mocapdb's ``face_mesh`` field (MediaPipe's 468 face points: x px, y px, z px).

OpenPose's own ``face_keypoints_2d`` holds its 70-point face and stays empty: the mesh is another model's
468 points, in a field of its own, ``{"state": …, "presence": …, "points": [[x, y, z], …]}`` (``state``:
"found" or why the face is absent, :data:`FACE_STATES`; ``presence``: the model's face flag; ``points``:
468 triples, pixels to 0.01, ``[]`` when absent). A person's mesh is read into ``[468, 4]`` (x, y, z px,
confidence: the face flag; NaN and 0 when absent). Schema: ``data_specs/keypoint_formats.md``, "Face mesh".
"""
from __future__ import annotations

import numpy as np

from mocapdb.core.formats.keypoints import MAX_POSITION_PX, KeypointError, numeric

N_FACE_POINTS = 468
FACE_FIELD = "face_mesh"
FACE_STATES = ("found", "hidden", "small", "unsure")   # a face's state: found, or why it is absent


def absent_face() -> np.ndarray:
    """``[468, 4]`` an absent face: positions NaN, confidence 0."""
    face = np.full((N_FACE_POINTS, 4), np.nan)
    face[:, 3] = 0.0
    return face


def read_face(person: dict, what: str) -> np.ndarray | None:
    """A person object's face mesh ``[468, 4]`` (module docstring), or None when it has no :data:`FACE_FIELD`;
    KeypointError naming ``what`` for a field that is not an object, a state not in :data:`FACE_STATES`,
    points that are not 468 triples or a position beyond :data:`MAX_POSITION_PX`."""
    given = person.get(FACE_FIELD)
    if given is None:
        return None
    label = f"{what} {FACE_FIELD}"
    if not isinstance(given, dict) or given.get("state") not in FACE_STATES:
        raise KeypointError(f"{label} must be an object whose state is one of {', '.join(FACE_STATES)}")
    face = absent_face()
    if given["state"] != "found":
        return face
    points = numeric(given.get("points"), f"{label} points")
    if points.shape != (N_FACE_POINTS, 3) or not np.isfinite(points).all():
        raise KeypointError(f"{label} points must be 468 finite [x, y, z] triples (pixels)")
    if np.abs(points).max() > MAX_POSITION_PX:
        raise KeypointError(f"{label} has a position beyond {MAX_POSITION_PX:,.0f} px")
    face[:, :3] = points
    face[:, 3] = float(np.clip(numeric(given.get("presence", 1.0), f"{label} presence"), 0.0, 1.0))
    return face


def face_field(points: np.ndarray, presence: float, state: str) -> dict:
    """One person's :data:`FACE_FIELD` as `mocapdb detect --face` writes it: ``points [468, ≥3]`` (x, y, z
    px), the model's face flag and the state ("" or "found" for found, else why absent)."""
    state = state or "found"
    rows = np.round(points[:, :3], 2).tolist() if state == "found" else []
    return {FACE_FIELD: {"state": state, "presence": round(float(presence), 4), "points": rows}}
