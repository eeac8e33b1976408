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
