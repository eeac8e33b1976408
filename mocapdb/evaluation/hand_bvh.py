"""A hand's measured finger rotations through the humanoid BVH, for checking them against the points they
came from (not used at run time): the BVH's forward kinematics gives the hand's 21 points back."""
from __future__ import annotations

import numpy as np

from mocapdb.core.formats.bvh import format_bvh, forward_kinematics, parse_bvh
from mocapdb.core.geometry import matrix_to_quat
from mocapdb.core.hand_rig import FINGER_NAMES, SIDE_NAMES, hand_basis
from mocapdb.core.motion import Motion
from mocapdb.core.outputs import motion_bvh
from mocapdb.core.skeleton import N_RIG_JOINTS
from mocapdb.runtime.hand_pose import finger_angles_deg, finger_quaternions, hand_points_view, palm_frames

IMAGE_FROM_VIEW = np.array([1.0, -1.0, -1.0])   # view frame (y up, z towards the camera) ↔ image (y, z down/away)


def both_hands(side: str, points: np.ndarray) -> np.ndarray:
    """``[1, 2, 21, 3]`` one hand's ``points [21, 3]`` (x, y, z image px) in the view frame on ``side``'s row
    ("Right", "Left"), the other hand absent (NaN)."""
    view = np.full((1, 2, 21, 3), np.nan)
    view[0, SIDE_NAMES.index(side)] = hand_points_view(np.asarray(points, dtype=np.float64))
    return view


def side_of(points: np.ndarray) -> str:
    """The side ("Right", "Left") on whose palm the fingers of ``points [21, 3]`` bend the more: a hand's side
    from its own points, where no pose gives it (the two sides' palms face opposite ways)."""
    bends = [np.nansum(finger_angles_deg(view, palm_frames(view))[0, SIDE_NAMES.index(side), :, 1:])
             for side in SIDE_NAMES for view in [both_hands(side, points)]]
    return SIDE_NAMES[int(np.argmax(bends))]


def bvh_hand_points(side: str, points: np.ndarray) -> np.ndarray:
    """The 21 points (image convention, metres from the wrist) the humanoid BVH's forward kinematics gives the
    ``side`` hand measured from ``points [21, 3]``: the arm at rest, the hand turned by its palm's frame, the
    fingers by their measured rotations (the other hand's straight)."""
    view = both_hands(side, points)
    palms = palm_frames(view)
    row = SIDE_NAMES.index(side)
    ends = np.tile([1.0, 0.0, 0.0, 0.0], (1, 5, 1))
    ends[0, 2 + row] = matrix_to_quat(palms[0, row].T @ hand_basis(side).T)   # rest basis → the palm's
    fingers = finger_quaternions(np.nan_to_num(finger_angles_deg(view, palms)))
    motion = Motion(np.tile([1.0, 0.0, 0.0, 0.0], (1, N_RIG_JOINTS, 1)), np.zeros((1, 3)), 30.0,
                    end_rotations=ends, finger_rotations=fingers)
    bvh = parse_bvh(format_bvh(motion_bvh(motion, rig="humanoid")))
    positions = forward_kinematics(bvh)[0][0]
    names = [f"{side}Hand"] + [f"{side}Hand{f}{k}" for f in FINGER_NAMES for k in ("1", "2", "3", "3_End")]
    return (positions[[bvh.index(name) for name in names]] - positions[bvh.index(f"{side}Hand")]) * IMAGE_FROM_VIEW
