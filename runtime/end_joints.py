"""The feet's and hands' directions as one camera sees them (heel → big toe, wrist → mid-knuckles) and
the humanoid end joints' local rotations that turn them there: shared by the whole take
(:func:`mocapdb.runtime.take.end_rotations`) and the online take (:mod:`mocapdb.runtime.online_ends`).

Each end joint (:data:`~mocapdb.core.skeleton.END_JOINTS`' feet and hands) hangs from a rig joint
(:data:`END_PARENTS`) that points it along :data:`END_REST_DIRECTIONS` (its rest direction in the
parent's frame); the measured direction turns it by the shortest turn (no twist about it). Heel and big toe
fix a foot's direction, not its roll about it: a foot is then rolled about its direction until its lateral
axis lies level (:func:`levelled_feet`), as a sole on the floor has it, rather than left at its shank's twist.
Contract: ``data_specs/stream_output.md`` (``--rig``).
"""
from __future__ import annotations

import numpy as np
from numba import njit

from mocapdb.core.geometry import matrix_to_quat, quat_to_matrix
from mocapdb.core.hand_rig import KNUCKLE_ACROSS_M
from mocapdb.core.kernels import quat_mul_into
from mocapdb.core.skeleton import (
    HAND_LENGTH_M,
    HEEL_TO_TOE_M,
    HEEL_TO_TOE_SLOPE_DEG,
    KP,
    RIG_JOINTS,
    global_rotations,
    pose_from_rotations,
    swing_matrices,
)
from mocapdb.runtime.foot_contacts import ANKLES, HEELS, INDEX_KNUCKLES, PINKY_KNUCKLES, TOES

WRISTS = (KP["r_wrist"], KP["l_wrist"])
# Each end joint: the rig joint it hangs from, and its direction at rest (heel → toe forwards, sloping
# down as on a standing foot; wrist → knuckles along the forearm, as the humanoid rig's hand bones)
END_PARENTS = ("r_knee", "l_knee", "r_elbow", "l_elbow")
_PARENT_ROWS = [RIG_JOINTS.index(j) for j in END_PARENTS]
_SLOPE = np.radians(HEEL_TO_TOE_SLOPE_DEG)
_FOOT_REST = [0.0, -np.sin(_SLOPE), np.cos(_SLOPE)]
END_REST_DIRECTIONS = np.array([_FOOT_REST, _FOOT_REST, [-1.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
END_LENGTHS_M = np.array([HEEL_TO_TOE_M, HEEL_TO_TOE_M, HAND_LENGTH_M, HAND_LENGTH_M])  # of a 1.75 m body
# A foot's lateral axis is laid level in full where its heel → toe is this far from the vertical (the sine of
# that angle, 30 deg) or further, in proportion nearer it (along the vertical every roll is level: none)
LEVEL_FULL_SIN = 0.5
KNUCKLES_APART_M = KNUCKLE_ACROSS_M[1] - KNUCKLE_ACROSS_M[4]   # index to little finger knuckle of a 1.75 m body
# a palm whose knuckles lie closer in the image than this share of their width is seen from its edge: its thumb
# side is not measured (the line's direction in the image is then mostly the points' scatter)
MIN_ACROSS_SHARE = 0.4
# the index knuckle lies this much further along the hand than the little finger's, per unit across (the rig's hand)
KNUCKLE_SLANT = 0.34
# choosing between a knuckle line's two thumb sides: the knuckles' depth's error (log: the body's depth and the
# hand's length), and the twist's from the shortest turn (the forearm's pronation and supination, ±85°)
KNUCKLE_DEPTH_LOG_SD, KNUCKLE_TWIST_SD_DEG = 0.1, 45.0


def lift_candidates(start_px: np.ndarray, end_px: np.ndarray, depth_m: np.ndarray, length_m: np.ndarray,
                    camera_px: tuple[float, float, float]) -> np.ndarray:
    """``[..., 2, 3]`` the two unit directions (view frame: x right, y up, z towards the camera) a segment
    of ``length_m [...]`` seen from ``start_px`` to ``end_px`` (``[..., 2]``, pixels, y down) by the pinhole
    ``camera_px`` (focal, cx, cy: pixels) may have, its start ``depth_m [...]`` metres in front of the
    camera: its end where that pixel's ray meets the sphere of that length about the start (perspective,
    exact), the farther meeting first, then the nearer; where the ray passes outside the sphere (an image
    longer than the length), its point nearest the start, twice."""
    start = _ray(start_px, camera_px) * depth_m[..., None]
    ray = _unit(_ray(end_px, camera_px))
    along = np.sum(ray * start, axis=-1)                          # the ray's point nearest the start
    half = np.sqrt(np.maximum(along ** 2 - np.sum(start ** 2, axis=-1) + length_m ** 2, 0.0))
    meetings = (along[..., None] + half[..., None] * [1.0, -1.0])[..., None] * ray[..., None, :]
    return _unit(meetings - start[..., None, :])


def nearest_candidate(candidates: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """``[..., 3]`` of each pair ``candidates [..., 2, 3]`` the one nearer ``reference [..., 3]``."""
    nearer = np.sum(candidates * reference[..., None, :], axis=-1).argmax(axis=-1)
    return np.take_along_axis(candidates, nearer[..., None, None], axis=-2)[..., 0, :]


def _ray(px: np.ndarray, camera_px: tuple[float, float, float]) -> np.ndarray:
    """``[..., 3]`` the view-frame ray (z = −1: one metre in front of the camera) through pixels ``px [..., 2]``."""
    focal, cx, cy = camera_px
    return np.stack([(px[..., 0] - cx) / focal, (cy - px[..., 1]) / focal, -np.ones(px.shape[:-1])], axis=-1)


def end_frames(quats: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The parents' global rotations ``[F, 4, 3, 3]`` (view frame) of the rig rotations ``quats [F, R, 4]``
    and where they point the feet and hands at rest ``[F, 4, 3]`` (unit)."""
    parents = global_rotations(quats)[:, _PARENT_ROWS]
    return parents, np.einsum("fkij,kj->fki", parents, END_REST_DIRECTIONS)


def measured_candidates(quats: np.ndarray, root_m: np.ndarray, scale: float, offsets_m: np.ndarray | None,
                        keypoints: np.ndarray, extremities: np.ndarray, camera_px: tuple[float, float, float]
                        ) -> np.ndarray:
    """``[F, 4, 2, 3]`` the feet's heel → big toe and the hands' wrist → mid-knuckles directions (view
    frame, unit; NaN where a point is unseen), each both ways :func:`lift_candidates` leaves it, of a motion
    (``quats [F, R, 4]``, ``root_m [F, 3]`` view frame, body ``scale``, ``offsets_m``) seen as ``keypoints
    [F, 14, 3]`` and ``extremities [F, E, 3]`` (x px, y px, confidence; 0: unseen) by the pinhole
    ``camera_px`` (focal, cx, cy): from the ankle's or wrist's depth, lengths :data:`END_LENGTHS_M` × ``scale``."""
    joints = pose_from_rotations(quats, root_m, scale, offsets_m)
    xy = np.where(extremities[..., 2:] > 0, extremities[..., :2], np.nan)
    wrists = np.where(keypoints[:, WRISTS, 2:] > 0, keypoints[:, WRISTS, :2], np.nan)
    starts = np.concatenate([xy[:, HEELS], wrists], axis=1)
    ends = np.concatenate([xy[:, TOES], 0.5 * (xy[:, INDEX_KNUCKLES] + xy[:, PINKY_KNUCKLES])], axis=1)
    depth = -joints[:, list(ANKLES) + list(WRISTS), 2]
    return lift_candidates(starts, ends, depth, END_LENGTHS_M * scale, camera_px)


def knuckle_thumb_sides(hand_directions: np.ndarray, extremities: np.ndarray, camera_px: tuple[float, float, float],
                        wrists_depth_m: np.ndarray, scale: float, untwisted: np.ndarray) -> np.ndarray:
    """``[F, 2, 3]`` each hand's thumb side (view frame, unit: square to the hand, towards the index) from the
    pose's knuckle points ``extremities [F, E, 3]`` (x px, y px, confidence) and the hands' directions
    ``hand_directions [F, 2, 3]`` (wrist → mid-knuckles). The knuckles' line (:data:`KNUCKLE_SLANT` along the
    hand per unit across it, :data:`KNUCKLES_APART_M` × ``scale`` across) lies in the plane of their two rays
    through the camera ``camera_px`` (focal, cx, cy): of the two thumb sides that put it there, the one whose
    line puts the knuckles in front of the camera, the index the one seen as such, at the depth the hand gives
    them (the wrist's, ``wrists_depth_m [F, 2]``, plus the hand's length along its direction; error
    :data:`KNUCKLE_DEPTH_LOG_SD`), the less twisted from the thumb side of the hand's shortest turn ``untwisted
    [F, 2, 3]`` (:data:`KNUCKLE_TWIST_SD_DEG`; the two can lie at one depth, the palm turned to the camera or
    away): exact in perspective. NaN where a point is unseen or the knuckles lie closer in the image than
    :data:`MIN_ACROSS_SHARE` of the palm's width at the wrist's depth: a palm seen from its edge, whose line the
    image cannot turn."""
    index, pinky = extremities[:, INDEX_KNUCKLES], extremities[:, PINKY_KNUCKLES]
    seen = (index[..., 2] > 0) & (pinky[..., 2] > 0)
    return _knuckle_sides(np.ascontiguousarray(hand_directions, dtype=np.float64).reshape(-1, 3),
                          np.ascontiguousarray(index[..., :2], dtype=np.float64).reshape(-1, 2),
                          np.ascontiguousarray(pinky[..., :2], dtype=np.float64).reshape(-1, 2), seen.reshape(-1),
                          np.ascontiguousarray(wrists_depth_m, dtype=np.float64).reshape(-1),
                          np.ascontiguousarray(untwisted, dtype=np.float64).reshape(-1, 3),
                          np.asarray(camera_px, dtype=np.float64), float(scale)).reshape(hand_directions.shape)


@njit(cache=True)
def _knuckle_sides(directions: np.ndarray, index_px: np.ndarray, pinky_px: np.ndarray, seen: np.ndarray,
                   wrists_depth_m: np.ndarray, untwisted: np.ndarray, camera_px: np.ndarray, scale: float
                   ) -> np.ndarray:
    """:func:`knuckle_thumb_sides` of ``N`` hands (rows): ``[N, 3]``."""
    focal, cx, cy = camera_px[0], camera_px[1], camera_px[2]
    apart_m = KNUCKLES_APART_M * scale
    out = np.full((len(directions), 3), np.nan)
    index_ray, pinky_ray, about = np.empty(3), np.empty(3), np.empty(3)
    for h in range(len(directions)):
        d = directions[h]
        if not seen[h] or not np.isfinite(d).all():
            continue
        full_px = apart_m * focal / max(wrists_depth_m[h], 1e-6)
        if np.hypot(index_px[h, 0] - pinky_px[h, 0], index_px[h, 1] - pinky_px[h, 1]) < MIN_ACROSS_SHARE * full_px:
            continue   # a palm seen from its edge
        for ray, px in ((index_ray, index_px[h]), (pinky_ray, pinky_px[h])):
            ray[0], ray[1], ray[2] = (px[0] - cx) / focal, (cy - px[1]) / focal, -1.0
        normal = np.cross(index_ray, pinky_ray)
        normal /= max(float(np.linalg.norm(normal)), 1e-12)
        towards = normal @ d
        square = normal - towards * d                                  # the normal's part square to the hand
        reach = max(square @ square, 1e-12)
        share = -KNUCKLE_SLANT * towards / reach                         # t · normal = −slant × direction · normal
        beside = np.sqrt(max(1.0 - share ** 2 * reach, 0.0) / reach)
        about[:] = np.cross(d, square)
        expected = wrists_depth_m[h] - HAND_LENGTH_M * scale * d[2]      # the mid-knuckles' depth
        ff, ss, fs = index_ray @ index_ray, pinky_ray @ pinky_ray, index_ray @ pinky_ray
        gram = max(ff * ss - fs ** 2, 1e-18)
        best = np.inf
        for sign in (1.0, -1.0):
            side = share * square + sign * beside * about
            side /= max(float(np.linalg.norm(side)), 1e-12)
            line = apart_m * (KNUCKLE_SLANT * d + side)
            fl, sl = index_ray @ line, pinky_ray @ line
            depth_index, depth_pinky = (ss * fl - fs * sl) / gram, -(ff * sl - fs * fl) / gram
            if depth_index <= 0.0 or depth_pinky <= 0.0:
                continue   # a knuckle behind the camera, or the index seen as the pinky
            mean = max(0.5 * (depth_index + depth_pinky), 1e-9)
            turned = np.arccos(min(max(side @ untwisted[h], -1.0), 1.0))
            misfit = (abs(np.log(mean / max(expected, 1e-9))) / KNUCKLE_DEPTH_LOG_SD
                      + turned / np.radians(KNUCKLE_TWIST_SD_DEG))
            if misfit < best:
                best, out[h] = misfit, side
    return out


def wrist_depths_m(quats: np.ndarray, root_m: np.ndarray, scale: float, offsets_m: np.ndarray | None) -> np.ndarray:
    """``[F, 2]`` the wrists' depths (metres in front of the camera) of a motion (``quats [F, R, 4]``, ``root_m
    [F, 3]`` view frame, body ``scale`` and ``offsets_m``)."""
    return -pose_from_rotations(quats, root_m, scale, offsets_m)[:, list(WRISTS), 2]


def sign_references(quats: np.ndarray) -> np.ndarray:
    """``[F, 4, 3]`` the side priors of a measured segment's two depths (:func:`lift_candidates`; weighed by
    :mod:`mocapdb.runtime.end_branches`) for the rig rotations ``quats [F, R, 4]``: for the feet the pelvis's
    forward (a foot points about where the hips face; the knee's twist, which the rest direction follows, is
    the rig's least sure: on synthetic takes of the database's clips it chose right 92 % of the ambiguous
    frames, the pelvis 98 %), for the hands where their forearms point them."""
    reference = end_frames(quats)[1]
    forward = global_rotations(quats)[:, RIG_JOINTS.index("pelvis"), :, 2]
    reference[:, :2] = forward[:, None]
    return reference


def standing_directions(directions: np.ndarray, up: np.ndarray) -> np.ndarray:
    """``directions [..., 3]`` laid on a floor of normal ``up`` ([3], view frame): their heading kept, sloping
    down by a standing foot's :data:`~mocapdb.core.skeleton.HEEL_TO_TOE_SLOPE_DEG`."""
    up = up / np.linalg.norm(up)
    forwards = _unit(directions - (directions @ up)[..., None] * up)
    return np.cos(_SLOPE) * forwards - np.sin(_SLOPE) * up


def end_locals(parents: np.ndarray, reference: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """``[F, 4, 4]`` the feet's and hands' local rotations (relative to their ``parents [F, 4, 3, 3]``)
    that turn them from ``reference [F, 4, 3]`` (:func:`end_frames`) to ``directions [F, 4, 3]`` by the
    shortest turn."""
    turn = swing_matrices(_unit(reference), _unit(directions))
    return matrix_to_quat(np.swapaxes(parents, -1, -2) @ turn @ parents)


def levelled_feet(parents: np.ndarray, locals_: np.ndarray, up: np.ndarray) -> np.ndarray:
    """``locals_ [F, 4, 4]`` (:func:`end_locals` on ``parents [F, 4, 3, 3]``) with each foot rolled about its
    heel → toe until its lateral axis (the humanoid foot's x) is perpendicular to ``up`` ([3] or [F, 3], view
    frame), by the smaller of the two rolls that do, scaled by :data:`LEVEL_FULL_SIN` near the vertical; the
    hands as given. The truth's feet lie so within a median 2–6 deg (the CMU clips' own rig); on synthetic takes
    of the database's own clips (``tools/eval_ends.py --bvh`` 002_02, 002_07, 006_10) the whole take's feet
    went from 9.6 to 5.0 deg (median geodesic, exact 2D; 14.7 to 10.3 noisy): their direction was within
    2.8 deg, the rest had been the roll the shank gave them."""
    up = _unit(np.broadcast_to(np.asarray(up, dtype=np.float64), parents.shape[:1] + (3,)))
    feet = (parents[:, :2] @ quat_to_matrix(locals_[:, :2])).reshape(-1, 3, 3)     # global, [F · 2, 3, 3]
    out = np.array(locals_, dtype=np.float64)
    rolled = np.empty((len(feet), 4))
    _levelled_into(feet, np.ascontiguousarray(out[:, :2].reshape(-1, 4)), np.repeat(up, 2, axis=0),
                   END_REST_DIRECTIONS[0], LEVEL_FULL_SIN, rolled)
    out[:, :2] = rolled.reshape(-1, 2, 4)
    return out


@njit(cache=True)
def _levelled_into(feet, locals_, up, rest, full_sin, out) -> None:  # pragma: no cover - numba
    """Per foot ``n``: its global rotation ``feet [N, 3, 3]``, local ``locals_ [N, 4]``, the unit ``up [N, 3]`` and
    its rest direction ``rest [3]``: into ``out [N, 4]`` the local rolled about ``rest`` (its own heel → toe) by
    the smaller roll that lays its x perpendicular to up, times min(1, |up × direction| / ``full_sin``)."""
    d, level, turn = np.empty(3), np.empty(3), np.empty(4)
    for n in range(feet.shape[0]):
        for i in range(3):
            d[i] = feet[n, i, 0] * rest[0] + feet[n, i, 1] * rest[1] + feet[n, i, 2] * rest[2]
        level[0] = up[n, 1] * d[2] - up[n, 2] * d[1]
        level[1] = up[n, 2] * d[0] - up[n, 0] * d[2]
        level[2] = up[n, 0] * d[1] - up[n, 1] * d[0]
        sine = np.sqrt(level[0] ** 2 + level[1] ** 2 + level[2] ** 2)
        x0, x1, x2 = feet[n, 0, 0], feet[n, 1, 0], feet[n, 2, 0]
        if level[0] * x0 + level[1] * x1 + level[2] * x2 < 0:
            for i in range(3):
                level[i] = -level[i]
        across = ((x1 * level[2] - x2 * level[1]) * d[0] + (x2 * level[0] - x0 * level[2]) * d[1]
                  + (x0 * level[1] - x1 * level[0]) * d[2])
        roll = np.arctan2(across, x0 * level[0] + x1 * level[1] + x2 * level[2])
        half = 0.5 * roll * min(max(sine / full_sin, 0.0), 1.0)
        turn[0] = np.cos(half)
        for i in range(3):
            turn[i + 1] = np.sin(half) * rest[i]
        quat_mul_into(locals_[n], turn, out[n])


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-12)
