"""Hands in keypoint JSON: OpenPose's ``hand_right_keypoints_2d`` / ``hand_left_keypoints_2d`` (21 points
each, x px, y px, confidence) and mocapdb's ``hands`` details (depth, presence, handedness, state).

OpenPose's 21 hand points and MediaPipe's are in the same order: 0 the wrist, then four per finger
from the palm out: thumb 1–4 (CMC, MCP, IP, tip), index 5–8 (MCP, PIP, DIP, tip), middle 9–12, ring
13–16, pinky 17–20. A person's hands are read into ``[2, 21, 4]`` (x px, y px, z px, confidence;
rows :data:`HAND_SIDES`: the subject's right hand, then their left); a missing point has confidence 0
and NaN position; z (depth from the wrist, px, smaller: nearer) is NaN unless ``hands`` gives it.
Schema: ``data_specs/keypoint_formats.md``, "Hands".
"""
from __future__ import annotations

import numpy as np

from mocapdb.core.formats.keypoints import MAX_POSITION_PX, KeypointError, numeric

N_HAND_POINTS = 21
HAND_SIDES = ("right", "left")
HAND_FIELDS = {side: f"hand_{side}_keypoints_2d" for side in HAND_SIDES}   # OpenPose's own keys
DETAILS_FIELD = "hands"   # mocapdb's: {"right": {"state", "presence", "handedness", "depth_px"}, "left": {...}}
HAND_STATES = ("found", "hidden", "small", "unsure")   # a hand's state: found, or why it is absent


def read_hands(person: dict, what: str) -> np.ndarray | None:
    """A person object's hands ``[2, 21, 4]`` (module docstring), or None when neither hand field holds
    points (absent, null or ``[]``, as OpenPose writes without hands); KeypointError naming ``what``
    for a field that is not 21 points or holds a position beyond :data:`MAX_POSITION_PX`."""
    given = {side: person.get(field) for side, field in HAND_FIELDS.items()}
    if all(value is None or value == [] for value in given.values()):
        return None
    hands = np.full((len(HAND_SIDES), N_HAND_POINTS, 4), np.nan)
    hands[..., 3] = 0.0
    details = person.get(DETAILS_FIELD)
    for row, side in enumerate(HAND_SIDES):
        if given[side] is None or given[side] == []:
            continue
        label = f"{what} {HAND_FIELDS[side]}"
        flat = numeric(given[side], label)
        if flat.size != 3 * N_HAND_POINTS:
            raise KeypointError(f"{label} holds {flat.size} values; a hand is 21 points (x, y, confidence)")
        points = flat.reshape(N_HAND_POINTS, 3)
        if np.any(np.isfinite(points[:, :2]) & (np.abs(points[:, :2]) > MAX_POSITION_PX)):
            raise KeypointError(f"{label} has a position beyond {MAX_POSITION_PX:,.0f} px")
        found = np.isfinite(points).all(axis=1) & (points[:, 2] > 0)
        hands[row, found, :2] = points[found, :2]
        hands[row, found, 3] = np.clip(points[found, 2], 0.0, 1.0)
        hands[row, found, 2] = _depth(details, side, f"{what} {DETAILS_FIELD}")[found]
    return hands


def _depth(details: object, side: str, what: str) -> np.ndarray:
    """The ``depth_px`` of one hand in a ``hands`` details object: ``[21]`` (NaN when not given)."""
    entry = details.get(side) if isinstance(details, dict) else None
    depth = entry.get("depth_px") if isinstance(entry, dict) else None
    if depth is None or depth == []:
        return np.full(N_HAND_POINTS, np.nan)
    values = numeric(depth, f"{what} {side} depth_px")
    if values.shape != (N_HAND_POINTS,) or np.any(np.abs(values[np.isfinite(values)]) > MAX_POSITION_PX):
        raise KeypointError(f"{what} {side} depth_px must be 21 numbers of pixels")
    return values


def hand_fields(points: np.ndarray, presence: np.ndarray, handedness: np.ndarray,
                states: tuple[str, str]) -> dict:
    """One person's hand fields as `mocapdb detect` writes them: ``points [2, 21, 4]`` (x, y, z px,
    confidence; rows :data:`HAND_SIDES`), the model's hand flags ``[2]`` and handedness ``[2]`` (NaN:
    not run) and each hand's state (:data:`HAND_STATES`; "" for found). An absent hand's points are
    OpenPose's "not found" (0, 0, 0) and its depth ``[]``; values rounded to 0.01 px and 1e-4."""
    fields: dict = {}
    details = {}
    for row, side in enumerate(HAND_SIDES):
        state = states[row] or "found"
        hand = points[row] if state == "found" else np.zeros((N_HAND_POINTS, 4))
        rows = np.concatenate([np.round(hand[:, :2], 2), np.round(hand[:, 3:], 4)], axis=1)
        fields[HAND_FIELDS[side]] = rows.ravel().tolist()
        details[side] = {"state": state, "presence": round(float(presence[row]), 4),
                         "handedness": None if not np.isfinite(handedness[row]) else round(float(handedness[row]), 4),
                         "depth_px": np.round(hand[:, 2], 2).tolist() if state == "found" else []}
    fields[DETAILS_FIELD] = details
    return fields
