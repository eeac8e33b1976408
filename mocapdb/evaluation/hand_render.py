"""The hand landmark model's 21 points per hand on the synthetic takes, and the fingers' bends scored against
the truth's (``data_specs/evaluation_bodies.md``, "Hands with 21 points").

**Placing** (:func:`hands_world`): each hand's 21 points in its own frame
(:attr:`~mocapdb.evaluation.end_truth.EndTruth.hand_points_m`, a 1.75 m adult's) scaled with the body's
stature, turned by the truth's hand rotation and put at the re-posed body's wrist.

**Detecting** (:func:`detected_hands`): as ``detect --hands`` writes ``Person.hands``: x, y px, z the depth
from the wrist in px at x's scale (smaller: nearer), the confidence. With noise (the scenario's
``noise_px`` > 0) every coordinate gets an independent normal error, of SD :data:`HAND_NOISE_OF_PALM` of the
hand's palm size (wrist → middle knuckle, px) over √2: each point's image error is then
:data:`HAND_NOISE_OF_PALM` of the palm (root mean square), the landmark model's own error in its own image
space, not the body's pixels. A hand drops whole (as the model's ``unsure``) with the scenario's dropout, or when
any point leaves the image; a frame whose body is swapped left/right swaps the hands too (the model's crops
follow the pose's wrists). Every draw comes after the body's and the extremities', so they stay as they were.
"""
from __future__ import annotations

import numpy as np

from mocapdb.core.fingers import FINGERS, flexion_deg
from mocapdb.core.formats.bvh import forward_kinematics
from mocapdb.core.hand_rig import SIDE_NAMES, finger_joint_names
from mocapdb.core.motion import Motion
from mocapdb.core.outputs import motion_bvh
from mocapdb.core.skeleton import END_JOINTS, KP, UNIVERSAL_HEIGHT_M

# The full hand landmark model's error: about 10 % of the palm's size (Zhang et al. 2020, "MediaPipe Hands",
# arXiv:2006.10214, Table 1: the full model's error normalised by the palm's size, about 10 %); mocapdb has
# measured none of its own (data_specs/pose_models.md, "Hands"), so the paper's figure is each point's image
# error (root mean square over x and y; the depth's as large again)
HAND_NOISE_OF_PALM = 0.10
MIDDLE_MCP = 9


def hands_world(positions_m: np.ndarray, rotations: np.ndarray, hand_points_m: np.ndarray, stature_m: float
                ) -> np.ndarray:
    """``[F, 2, 21, 3]`` the right then left hand's 21 points (world, metres) of a body ``positions_m
    [F, 15, 3]`` whose ends turn by ``rotations [F, 5, 3, 3]``, from the hands' own ``hand_points_m``."""
    local = hand_points_m * (stature_m / UNIVERSAL_HEIGHT_M)
    turns = rotations[:, [END_JOINTS.index("r_hand"), END_JOINTS.index("l_hand")]]
    wrists = positions_m[:, [KP["r_wrist"], KP["l_wrist"]]]
    return wrists[:, :, None] + np.einsum("fhij,fhkj->fhki", turns, local)


def detected_hands(px: np.ndarray, cam_points: np.ndarray, focal_px: float, noisy: bool, dropout: float,
                   swapped: np.ndarray, image_size: tuple[int, int], rng: np.random.Generator) -> np.ndarray:
    """``[F, 2, 21, 4]`` ``Person.hands`` (x px, y px, z px, confidence; a dropped hand NaN and 0) of the hands'
    pixels ``px [F, 2, 21, 2]`` and camera-aligned points ``cam_points [F, 2, 21, 3]`` (z: distance, metres)."""
    depth = focal_px * (cam_points[..., 2] - cam_points[..., :1, 2]) / cam_points[..., :1, 2]
    points = np.concatenate([px, depth[..., None]], axis=-1)
    palm = np.linalg.norm(points[..., MIDDLE_MCP, :] - points[..., 0, :], axis=-1)          # [F, 2] px
    sd = HAND_NOISE_OF_PALM / np.sqrt(2.0) * palm if noisy else np.zeros_like(palm)
    points = points + rng.normal(size=points.shape) * sd[..., None, None]
    kept = rng.random(palm.shape) >= dropout
    inside = ((points[..., :2] >= 0).all(axis=-1) & (points[..., 0] < image_size[0])
              & (points[..., 1] < image_size[1])).all(axis=-1)
    found = kept & inside & np.isfinite(points).all(axis=(-2, -1))
    out = np.concatenate([points, np.full(points.shape[:-1] + (1,), 0.9)], axis=-1)
    out[~found] = [np.nan, np.nan, np.nan, 0.0]
    out[swapped] = out[swapped][:, ::-1]
    return out


def motion_hand_points(motion: Motion) -> np.ndarray:
    """``[F, 2, 21, 3]`` the humanoid BVH's hands (right, left) as 21 points (the hand joint, then each finger's
    three joints and its end): where its forward kinematics puts them (file units)."""
    bvh = motion_bvh(motion, rig="humanoid")
    hands = []
    for side in SIDE_NAMES:
        names = [f"{side}Hand"]
        for k, joint in enumerate(finger_joint_names(side)):
            names += [joint, f"{joint}_End"] if k % 3 == 2 else [joint]
        hands.append(forward_kinematics(bvh, [bvh.names.index(n) for n in names])[0])
    return np.stack(hands, axis=1)


def bend_errors_deg(estimate: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """``[F, 2, 5, 3]`` the absolute differences (degrees) of each finger joint's flexion
    (:func:`~mocapdb.core.fingers.flexion_deg`) between two sets of hands ``[F, 2, 21, 3]`` (NaN: missing)."""
    return np.abs(flexion_deg(estimate) - flexion_deg(truth))


def finger_medians(errors: list[np.ndarray]) -> dict[str, float]:
    """Per finger (:data:`~mocapdb.core.fingers.FINGERS`) the median of ``errors`` (``[N, 2, 5, 3]`` each) over
    frames, sides and its three joints (degrees; NaN: none)."""
    stacked = np.concatenate(errors) if errors else np.full((0, 2, 5, 3), np.nan)
    out = {}
    for f, finger in enumerate(FINGERS):
        values = stacked[:, :, f]
        finite = values[np.isfinite(values)]
        out[finger] = float(np.median(finite)) if finite.size else float("nan")
    return out
