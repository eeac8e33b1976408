"""The hands from the hand landmark model's 21 points (``Person.hands``) in the whole take: each palm's
frame (its direction and its twist about it) and the 15 finger bones' local rotations of the humanoid
rig (:mod:`mocapdb.core.hand_rig`), eased to a relaxed hand where a hand is absent.

The points (x, y frame px; z px, the depth from the wrist at x's scale, smaller: nearer) become
view-frame offsets from the wrist ``(x, −y, −z)`` px. Lifted at the wrist's depth
(:func:`~mocapdb.runtime.end_joints.lift_candidates`) every offset would scale by one factor, depth /
focal, on which no direction or angle depends: the pixels are used as they are.

**Palm frame** (:func:`palm_frames`): ``u`` wrist → the index and pinky knuckles' midpoint, ``t`` pinky →
index knuckle made perpendicular to ``u``, ``n`` out of the palm. **Fingers** (:func:`finger_angles_deg`):
each finger's first bone's spread (towards the thumb's side) and flexion (towards the palm; the thumb's
across it), the thumb's metacarpal twisted about itself onto the plane its bones bend in, then the
flexion of the second and third bones about the first bone's hinge (seen across it), each angle within
:data:`~mocapdb.core.hand_rig.ANGLE_LIMITS_DEG`; the spread fades out as the first joint bends past
:data:`SPREAD_FADE_DEG` (square, it has none). The angles are sided: one set of angles is the
mirror-image pose on the two hands (:func:`finger_quaternions`). **Palm twist** (:func:`hand_twist_deg`):
about the hand's direction, from its shortest turn to the palm's plane. **Absent hands**
(:func:`eased_to_rest`).
Contract: ``data_specs/skeleton.md``, "Fingers".
"""
from __future__ import annotations

import numpy as np

from mocapdb.core.fingers import FINGERS, finger_chain
from mocapdb.core.geometry import quat_mul, quat_to_matrix
from mocapdb.core.hand_rig import ANGLE_LIMITS_DEG, FINGER_AXES, RELAXED_DEG, SIDE_NAMES, hand_basis
from mocapdb.core.outputs import TrackRecording
from mocapdb.runtime.take_params import TakeParams
from mocapdb.runtime.take_smoothing import depopped_and_smoothed

HAND_BASES = np.stack([hand_basis(side) for side in SIDE_NAMES])      # [2 (right, left), 3, 3] columns u, t, n
HANDEDNESS = np.linalg.det(HAND_BASES)                               # [2] −1 (right: left-handed basis), +1
SPREAD_FADE_DEG = 60.0    # a first joint bent beyond this loses its spread linearly, none at 90°
BEND_PLANE_MIN_DEG = 20.0  # a finger bent less than about this: its bend plane (and the twist to it) fades out
STEADY_TWIST_DEG, UNSTEADY_TWIST_DEG = 8.0, 16.0   # the knuckles' twist scattering this much a frame: kept, not
MIN_SCATTER_FRAMES = 8   # a hand's twist measured on fewer frames: its scatter is not known, nor the twist used
TWIST_LIMIT_DEG = 90.0    # the palm's twist about the hand, from the shortest turn: the forearm's
                          # pronation and supination, 80–85° each way (AAOS), with some margin
EASE_S = 0.3              # an absent hand eases to rest (and back) over this (smoothstep); a gap up to
                          # twice as long is bridged (interpolated) instead
_CHAINS = np.array([finger_chain(f) for f in FINGERS])[:, 1:]        # [5, 4] base joint to tip
_FLEX_AXES = np.cross(FINGER_AXES[:, 0], FINGER_AXES[:, 1])           # [5, 3] turn r towards p (hand basis)
_SPREAD_AXES = np.cross(FINGER_AXES[:, 0], FINGER_AXES[:, 2])         # [5, 3] turn r towards s
_RIG_FLEX_AXES = HANDEDNESS[:, None, None] * np.einsum("hij,fj->hfi", HAND_BASES, _FLEX_AXES)    # [2, 5, 3]
_RIG_SPREAD_AXES = HANDEDNESS[:, None, None] * np.einsum("hij,fj->hfi", HAND_BASES, _SPREAD_AXES)
_RIG_TWIST_AXES = HANDEDNESS[:, None, None] * np.einsum("hij,fj->hfi", HAND_BASES, FINGER_AXES[:, 0])


def hand_points_view(hands_px: np.ndarray) -> np.ndarray:
    """``hands_px [..., 21, 3]`` (x, y, z px) → offsets from the wrist ``[..., 21, 3]`` (view frame: x right,
    y up, z towards the camera; px). NaN stays NaN."""
    return (hands_px - hands_px[..., :1, :]) * np.array([1.0, -1.0, -1.0])


def palm_frames(points: np.ndarray) -> np.ndarray:
    """``[..., 2, 3, 3]`` each hand's rows ``u, t, n`` (unit; view frame) of ``points [..., 2, 21, 3]`` (rows:
    right, left hand; :func:`hand_points_view`): module docstring."""
    index, pinky = points[..., 5, :], points[..., 17, :]
    along = _unit(0.5 * (index + pinky) - points[..., 0, :])
    across = index - pinky
    across = _unit(across - np.sum(across * along, axis=-1, keepdims=True) * along)
    palmar = HANDEDNESS[:, None] * np.cross(along, across)
    return np.stack([along, across, palmar], axis=-2)


def finger_angles_deg(points: np.ndarray, palms: np.ndarray) -> np.ndarray:
    """``[..., 2, 5, 5]`` each finger's angles (degrees, :data:`~mocapdb.core.hand_rig.ANGLES`; fingers in
    :data:`~mocapdb.core.fingers.FINGERS` order) of the hands ``points [..., 2, 21, 3]`` in their
    ``palms [..., 2, 3, 3]`` (:func:`palm_frames`), within the limits; NaN where a point is missing."""
    bones = _unit(np.diff(points[..., _CHAINS, :], axis=-2))                       # [..., 2, 5, 3, 3]
    bones = np.einsum("...hij,...hfbj->...hfbi", palms, bones)                     # in the hand basis
    rest, bend, side = (FINGER_AXES[:, k] for k in range(3))                      # [5, 3] each: r, p, s
    along, bent, aside = (np.sum(bones[..., 0, :] * axis, axis=-1) for axis in (rest, bend, side))
    flex1 = _limited(np.arctan2(bent, np.copysign(np.hypot(along, aside), along)), 1)
    fade = np.clip((np.radians(90.0) - np.abs(flex1)) / np.radians(90.0 - SPREAD_FADE_DEG), 0.0, 1.0)
    spread = _limited(np.arctan2(aside, np.abs(along)) * fade, 0)
    first = (np.cos(flex1)[..., None] * (np.cos(spread)[..., None] * rest + np.sin(spread)[..., None] * side)
             + np.sin(flex1)[..., None] * bend)                                   # the first bone, turned
    untwisted = _turned(_FLEX_AXES, _SPREAD_AXES, spread)
    twist = _limited(_bend_plane_twist(first, untwisted, bones), 2)
    hinge = _turned(untwisted, first, twist)
    flex2 = _hinge_angle(first, bones[..., 1, :], hinge)
    flex3 = _hinge_angle(bones[..., 1, :], bones[..., 2, :], hinge)
    return np.degrees(np.stack([spread, flex1, twist, _limited(flex2, 3), _limited(flex3, 4)], axis=-1))


def _bend_plane_twist(first: np.ndarray, hinge: np.ndarray, bones: np.ndarray) -> np.ndarray:
    """``[...]`` radians: the twist about the ``first`` bone [..., 3] that turns its ``hinge`` onto the normal
    of the plane the finger's ``bones [..., 3, 3]`` bend in (a bend backwards is about the same hinge), less
    where they are nearly straight (none below :data:`BEND_PLANE_MIN_DEG`'s sine)."""
    normal = np.cross(bones[..., 0, :], bones[..., 1, :]) + np.cross(bones[..., 1, :], bones[..., 2, :])
    normal *= np.where(np.sum(normal * hinge, axis=-1, keepdims=True) < 0, -1.0, 1.0)
    normal -= np.sum(normal * first, axis=-1, keepdims=True) * first
    sure = np.clip(np.linalg.norm(normal, axis=-1) / np.sin(np.radians(BEND_PLANE_MIN_DEG)), 0.0, 1.0)
    return sure * np.arctan2(np.sum(np.cross(hinge, normal) * first, axis=-1), np.sum(hinge * normal, axis=-1))


def _hinge_angle(into: np.ndarray, out: np.ndarray, hinge: np.ndarray) -> np.ndarray:
    """Radians ``[...]``: the turn about unit ``hinge [..., 3]`` from bone ``into`` to bone ``out`` (both
    ``[..., 3]``), each seen in the plane across the hinge."""
    into = into - np.sum(into * hinge, axis=-1, keepdims=True) * hinge
    out = out - np.sum(out * hinge, axis=-1, keepdims=True) * hinge
    return np.arctan2(np.sum(np.cross(into, out) * hinge, axis=-1), np.sum(into * out, axis=-1))


def _limited(angles_rad: np.ndarray, column: int) -> np.ndarray:
    """``angles_rad [..., 5]`` (one per finger) within the limits of :data:`~mocapdb.core.hand_rig.ANGLES`'
    ``column``: an angle outside goes to the nearer limit round the circle (a bend a little past 180° to the
    bend's limit, not to the extension's)."""
    low, high = np.radians(ANGLE_LIMITS_DEG[:, column, 0]), np.radians(ANGLE_LIMITS_DEG[:, column, 1])
    start = low - (2.0 * np.pi - (high - low)) / 2.0           # the middle of the arc outside the limits
    return np.clip(np.mod(angles_rad - start, 2.0 * np.pi) + start, low, high)


def _turned(vectors: np.ndarray, axes: np.ndarray, angles_rad: np.ndarray) -> np.ndarray:
    """``vectors [..., 3]`` turned by ``angles_rad [...]`` about unit ``axes [..., 3]`` perpendicular to them."""
    return np.cos(angles_rad)[..., None] * vectors + np.sin(angles_rad)[..., None] * np.cross(axes, vectors)


def finger_quaternions(angles_deg: np.ndarray) -> np.ndarray:
    """``[F, 30, 4]`` the finger joints' local rotations (``hand_rig.FINGER_JOINTS`` order) of the angles
    ``[F, 2, 5, 5]`` (:func:`finger_angles_deg`): the first joint spreads, bends and twists, the others bend
    about its hinge; each hand's axes in the rig (the right hand's mirrored: its basis is left-handed)."""
    radians = np.radians(angles_deg)
    spread_flex = quat_mul(_axis_quats(_RIG_SPREAD_AXES, radians[..., 0]), _axis_quats(_RIG_FLEX_AXES, radians[..., 1]))
    first = quat_mul(spread_flex, _axis_quats(_RIG_TWIST_AXES, radians[..., 2]))
    flexes = _axis_quats(_RIG_FLEX_AXES[:, :, None], radians[..., 3:])              # [F, 2, 5, 2, 4]
    return np.concatenate([first[..., None, :], flexes], axis=-2).reshape(len(angles_deg), 30, 4)


def shortest_turn_axes(parents: np.ndarray, swings: np.ndarray) -> np.ndarray:
    """``[F, 2, 3, 2]`` each hand's direction and thumb side (columns ``u``, ``t``; view frame) when its forearm
    (``parents [F, 2, 3, 3]``, global) turns it by its shortest turn ``swings [F, 2, 4]`` (local) alone."""
    return (parents @ quat_to_matrix(swings) @ HAND_BASES)[..., :2]


def hand_twist_deg(parents: np.ndarray, swings: np.ndarray, thumb_sides: np.ndarray) -> np.ndarray:
    """``[F, 2]`` the palm's twist about the hand (degrees): the turn about the hand's direction from where its
    shortest turn puts the thumb's side to where the measured one points; NaN beyond :data:`TWIST_LIMIT_DEG`
    (a palm the forearm cannot turn to: misread, the model's or the pose's hand flipped), as where the
    hand is unseen. ``parents [F, 2, 3, 3]`` the forearms' global rotations, ``swings [F, 2, 4]`` the hands'
    local shortest turns (view frame), ``thumb_sides [F, 2, 3]`` (a palm's ``t``, :func:`palm_frames`, or the
    pose's knuckles', :func:`~mocapdb.runtime.end_joints.knuckle_thumb_sides`; NaN: unseen)."""
    along, thumb_side = np.moveaxis(shortest_turn_axes(parents, swings), -1, 0)
    measured = thumb_sides - np.sum(thumb_sides * along, axis=-1, keepdims=True) * along
    twist = np.arctan2(np.sum(np.cross(thumb_side, measured) * along, axis=-1),
                       np.sum(thumb_side * measured, axis=-1))
    twist_deg = np.degrees(twist)
    return np.where(np.abs(twist_deg) <= TWIST_LIMIT_DEG, twist_deg, np.nan)


def twisted(swings: np.ndarray, twist_deg: np.ndarray) -> np.ndarray:
    """The hands' local rotations ``[F, 2, 4]``: ``swings`` then ``twist_deg [F, 2]`` about the hand's own axis."""
    return quat_mul(swings, _axis_quats(HAND_BASES[:, :, 0], np.radians(twist_deg)))


def eased_to_rest(values: np.ndarray, seen: np.ndarray, rest: np.ndarray | float, fps: float) -> np.ndarray:
    """``values [F, ...]`` where ``seen [F]``; between seen frames up to 2 × :data:`EASE_S` apart, interpolated;
    elsewhere ``rest``, eased into from the last seen value and out to the next over :data:`EASE_S`
    (smoothstep: no step, at most 1.5 × the change / the ease's frames a frame). Never seen: ``rest``."""
    out = np.broadcast_to(rest, values.shape).astype(np.float64)
    at = np.flatnonzero(seen)
    if not len(at):
        return out
    frames = np.arange(len(values))
    prev = at[np.clip(np.searchsorted(at, frames, side="right") - 1, 0, len(at) - 1)]
    after = at[np.clip(np.searchsorted(at, frames, side="left"), 0, len(at) - 1)]
    ease_frames = max(EASE_S * fps, 1.0)
    gap = after - prev
    bridged = (frames >= at[0]) & (frames <= at[-1]) & (gap <= 2.0 * ease_frames)
    share = _expand((frames - prev) / np.maximum(gap, 1), values)
    linear = values[prev] + share * (values[after] - values[prev])
    leaving = _expand(np.where(frames >= at[0], smoothstep(1.0 - (frames - prev) / ease_frames), 0.0), values)
    coming = _expand(np.where(frames <= at[-1], smoothstep(1.0 - (after - frames) / ease_frames), 0.0), values)
    eased = out + leaving * (values[prev] - out) + coming * (values[after] - out)
    return np.where(_expand(bridged, values), linear, eased)


def finger_rotations(points: np.ndarray, palms: np.ndarray, fps: float, params: TakeParams) -> np.ndarray:
    """``[F, 30, 4]`` the finger joints' local rotations of the hands' ``points [F, 2, 21, 3]`` (view frame
    px, :func:`~mocapdb.runtime.hand_pose.hand_points_view`; NaN: absent) in their ``palms``: the angles
    (:func:`~mocapdb.runtime.hand_pose.finger_angles_deg`) eased to a relaxed hand where absent
    (:data:`~mocapdb.core.hand_rig.RELAXED_DEG`), de-popped and smoothed as the rotations."""
    angles = finger_angles_deg(points, palms)
    return finger_quaternions(eased_smoothed(angles, np.isfinite(angles).all(axis=(-2, -1)), RELAXED_DEG, fps,
                                              params))


def eased_smoothed(values: np.ndarray, seen: np.ndarray, rest: np.ndarray | float, fps: float,
                    params: TakeParams) -> np.ndarray:
    """Per hand, ``values [F, 2, ...]`` where ``seen [F, 2]`` eased to ``rest`` elsewhere
    (:func:`~mocapdb.runtime.hand_pose.eased_to_rest`), then de-popped and smoothed as the rotations."""
    eased = np.stack([eased_to_rest(values[:, h], seen[:, h], rest, fps) for h in range(2)], axis=1)
    return depopped_and_smoothed(eased, fps, params)


def steadiness(values_deg: np.ndarray, steady_deg: float = STEADY_TWIST_DEG,
               unsteady_deg: float = UNSTEADY_TWIST_DEG) -> float:
    """How much of a measure to keep, from its values ``values_deg [N]`` or ``[N, D]`` (degrees; a hand's twist
    measured from the pose's knuckles by default) over the frames it was measured on, in order (rows with a NaN
    left out): all of a steady one (a frame-to-frame scatter of ``steady_deg`` or less: per component the median
    absolute second difference over √6, as a hand's turn is smooth at video rates and a measurement's noise is
    not, root-sum-squared over the ``D`` components), none of one scattered ``unsteady_deg`` or more (for the
    twist :data:`UNSTEADY_TWIST_DEG`: its error no longer averages out: on synthetic takes, knuckles 2 px off
    scatter the twist 12–32° a frame and leave it no nearer the truth than the forearm's), linearly between;
    none on fewer than :data:`MIN_SCATTER_FRAMES` values (across a gap the hand's own turn adds to the scatter)."""
    values = values_deg[:, None] if values_deg.ndim == 1 else values_deg
    measured = values[np.isfinite(values).all(axis=1)]
    if len(measured) < MIN_SCATTER_FRAMES:
        return 0.0
    second = np.diff(measured, n=2, axis=0)
    spread_deg = 1.4826 * np.median(np.abs(second - np.median(second, axis=0)), axis=0) / np.sqrt(6.0)
    scatter_deg = np.sqrt(np.sum(spread_deg ** 2))
    return float(np.clip((unsteady_deg - scatter_deg) / (unsteady_deg - steady_deg), 0.0, 1.0))


def track_hand_points(rec: TrackRecording) -> np.ndarray | None:
    """The track's hands ``[F, 2, 21, 3]`` (view frame px from the wrist; NaN: absent), None when none was seen."""
    hands = rec.column("hands_px")
    if not len(hands) or not np.isfinite(hands).any():
        return None
    return hand_points_view(hands.astype(np.float64))


def hands_seen(points: np.ndarray) -> np.ndarray:
    """``[F, 2]`` whether each hand of ``points [F, 2, 21, 3]`` was seen (every point given)."""
    return np.isfinite(points).all(axis=(-2, -1))


def _expand(per_frame: np.ndarray, like: np.ndarray) -> np.ndarray:
    return per_frame.reshape((-1,) + (1,) * (like.ndim - 1))


def smoothstep(x: np.ndarray) -> np.ndarray:
    """3x² − 2x³ of ``x`` clipped to [0, 1]: 0 → 1 with no step and a flat start and end."""
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def _axis_quats(axes: np.ndarray, angles_rad: np.ndarray) -> np.ndarray:
    """Quaternions ``[..., 4]`` turning ``angles_rad [...]`` about unit ``axes [..., 3]`` (broadcast)."""
    half = 0.5 * np.asarray(angles_rad)[..., None]
    vector = np.sin(half) * axes
    return np.concatenate([np.broadcast_to(np.cos(half), vector.shape[:-1] + (1,)), vector], axis=-1)


def _unit(v: np.ndarray) -> np.ndarray:
    with np.errstate(invalid="ignore", divide="ignore"):
        return v / np.linalg.norm(v, axis=-1, keepdims=True)
