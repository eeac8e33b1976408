"""Finger flexion angles from a hand's 21 points (MediaPipe's and OpenPose's hand order).

The 21 points: 0 the wrist, then four per finger from the palm out: thumb 1–4 (CMC, MCP, IP, tip),
index 5–8, middle 9–12, ring 13–16, pinky 17–20 (MCP, PIP, DIP, tip). A joint's **flexion** is the
angle between the bone into it and the bone out of it (degrees; 0 = straight, 90 = bent square); a
finger's MCP uses the bone from the wrist to its knuckle as the bone in. Points are x, y in pixels
and z the depth from the wrist in the same unit (``data_specs/keypoint_formats.md``, "Hands"), so
the angles are 3D; a hand of 2D points only (z = 0) gives their projections.
"""
from __future__ import annotations

import numpy as np

N_HAND_POINTS = 21
FINGERS = ("thumb", "index", "middle", "ring", "pinky")
JOINTS = {"thumb": ("cmc", "mcp", "ip"), "index": ("mcp", "pip", "dip"), "middle": ("mcp", "pip", "dip"),
          "ring": ("mcp", "pip", "dip"), "pinky": ("mcp", "pip", "dip")}


def finger_chain(finger: str) -> list[int]:
    """The points of ``finger`` from the wrist out: ``[0, base, 2nd, 3rd, tip]``."""
    first = 1 + 4 * FINGERS.index(finger)
    return [0, first, first + 1, first + 2, first + 3]


def flexion_deg(points: np.ndarray) -> np.ndarray:
    """``points [..., 21, 3]`` (x, y, z; any one unit) → flexion ``[..., 5, 3]`` in degrees, fingers in
    :data:`FINGERS` order, joints in :data:`JOINTS` order (thumb CMC, MCP, IP; others MCP, PIP, DIP).
    NaN where a bone has no length or a point is missing (NaN)."""
    points = np.asarray(points, dtype=np.float64)
    if points.shape[-2:] != (N_HAND_POINTS, 3):
        raise ValueError(f"a hand is [21, 3] points (x, y, z), not {list(points.shape[-2:])}")
    chains = np.array([finger_chain(f) for f in FINGERS])                 # [5, 5]
    bones = np.diff(points[..., chains, :], axis=-2)                      # [..., 5, 4, 3]
    into, out = bones[..., :-1, :], bones[..., 1:, :]
    lengths = np.linalg.norm(into, axis=-1) * np.linalg.norm(out, axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        cosine = np.sum(into * out, axis=-1) / np.where(lengths > 0, lengths, np.nan)
    return np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0)))


def curl_deg(flexion: np.ndarray) -> np.ndarray:
    """Each finger's curl ``[..., 5]``: the sum of its three flexions (degrees; 0 = straight)."""
    return np.asarray(flexion).sum(axis=-1)
