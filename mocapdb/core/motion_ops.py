"""Stateless operations on a :class:`~mocapdb.core.motion.Motion`: each takes motions (or points)
and returns new ones, never changing its inputs.

* :func:`from_points`: inverse kinematics (retargeting) of 15 keypoints onto the universal rig;
* :func:`resample` and :func:`mirror_keypoints`: a source's keypoints before retargeting;
* :func:`on_floor`: a motion in the view frame put level on a floor at y = 0 (the world frame);
* :func:`scaled_about_origin`: the same image, a body ``k`` times as large and far (one camera
  fixes a body only up to this scale);
* forward kinematics is :meth:`Motion.joints_m`.

The whole take's smoothing and foot planting are the runtime's (``mocapdb.runtime.take``): they
need the input's keypoints, not the motion alone.

The floor without a whole-take fit (:func:`on_floor` with no plane): the camera's pitch is taken
out (the line the lowest ankle traces over depth is made level); a person who hardly moves in
depth (< :data:`MIN_DEPTH_SPREAD_M`) is only shifted, not levelled; the roll is not estimated; the
floor height is the :data:`FLOOR_PERCENTILE` th percentile of the lowest ankle minus the ankle
height, and the first frame's pelvis is put above the origin.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from mocapdb.core.geometry import axis_rotation_matrices, matrix_to_quat, quat_mul
from mocapdb.core.motion import Motion
from mocapdb.core.skeleton import ANKLE_HEIGHT_M, KP, MIRROR_SOURCE, PELVIS, retarget, swing_matrices

MIN_DEPTH_SPREAD_M = 0.5   # the feet must cover this much depth for the camera pitch to be measured
FLOOR_PERCENTILE = 5.0     # of the lowest ankle's height, for the floor
LEVEL_INLIER_M = 0.05      # ankle points this close to the first line fit the second
UP = np.array([0.0, 1.0, 0.0])


def from_points(points_m: np.ndarray, fps: float, coordinate_frame: str = "world", first_frame: int = 0
                ) -> tuple[Motion, np.ndarray]:
    """The universal body's motion that best follows keypoints ``points_m [F, 15, 3]`` (metres,
    y up), and its own joints ``[F, 15, 3]`` (forward kinematics of that motion)."""
    rotations, joints_m = retarget(points_m)
    return Motion(rotations, joints_m[:, PELVIS].copy(), fps, coordinate_frame, first_frame), joints_m


def mirror_keypoints(points: np.ndarray) -> np.ndarray:
    """The left-right mirror image of keypoints ``[..., 15, 3]`` (KEYPOINTS order): x negated
    (reflection in the y-z plane) and every :data:`MIRROR_PAIRS` pair swapped. Its own inverse."""
    mirrored = points[..., MIRROR_SOURCE, :].copy()
    mirrored[..., 0] *= -1
    return mirrored


def resample(points: np.ndarray, source_fps: float, target_fps: float) -> np.ndarray:
    """Linear resampling of ``[F, ...]`` samples from ``source_fps`` to ``target_fps`` (Hz).

    Sample k sits at time k / target_fps; samples past the last source frame are not made.
    """
    n_src = points.shape[0]
    duration = (n_src - 1) / source_fps
    t = np.arange(int(np.floor(duration * target_fps + 1e-9)) + 1) * (source_fps / target_fps)
    i0 = np.minimum(np.floor(t).astype(np.int64), n_src - 1)
    i1 = np.minimum(i0 + 1, n_src - 1)
    w = (t - i0).reshape((-1,) + (1,) * (points.ndim - 1))
    return points[i0] * (1.0 - w) + points[i1] * w


def scaled_about_origin(motion: Motion, factor: float) -> Motion:
    """The body ``factor`` times as tall and its root ``factor`` times as far from the origin (the
    camera, in the view frame): the same image from a single camera."""
    return replace(motion, root_m=motion.root_m * factor, scale=motion.scale * factor)


def on_floor(motion: Motion, floor: tuple[np.ndarray, float] | None = None) -> Motion:
    """A view-frame motion turned level and moved onto a floor at y = 0 (the world frame).

    ``floor``: the plane ``normal · p = offset`` (view frame) the whole-take fit found, turned to
    y = 0 (pitch and roll), the origin on it under the camera (so tracks on one floor share one
    world); None: a floor estimated from the feet (see the module's docstring).
    """
    if floor is not None:
        normal, floor_y = np.asarray(floor[0], dtype=np.float64), float(floor[1])
        level = swing_matrices(normal / np.linalg.norm(normal), UP)
    else:
        lowest = _lowest_ankle(motion)
        level = axis_rotation_matrices("X", np.asarray(_floor_pitch(lowest)))
        floor_y = np.percentile((lowest @ level.T)[:, 1], FLOOR_PERCENTILE) - ANKLE_HEIGHT_M * motion.scale
    rotations = motion.rotations.copy()
    rotations[:, 0] = quat_mul(matrix_to_quat(level), rotations[:, 0])
    root = motion.root_m @ level.T
    if floor is not None:  # one world for every track on that floor: the origin under the camera
        root = root - [0.0, floor_y, 0.0]
    else:
        root = root - [root[0, 0], floor_y, root[0, 2]]
    return replace(motion, rotations=rotations, root_m=root, coordinate_frame="world")


def _lowest_ankle(motion: Motion) -> np.ndarray:
    """Per frame, the position of the lower ankle ``[F, 3]``."""
    ankles = motion.joints_m()[:, [KP["r_ankle"], KP["l_ankle"]]]
    return ankles[np.arange(len(ankles)), np.argmin(ankles[..., 1], axis=1)]


def _floor_pitch(lowest: np.ndarray) -> float:
    """The rotation about x (radians) that makes the line of ``lowest`` over depth level; 0 when
    the depth spread is under :data:`MIN_DEPTH_SPREAD_M`. Two fits: all points, then those within
    :data:`LEVEL_INLIER_M` of the first line (steps and jumps lift the foot off the floor)."""
    depth, height = lowest[:, 2], lowest[:, 1]
    if np.ptp(depth) < MIN_DEPTH_SPREAD_M:
        return 0.0
    slope, offset = np.polyfit(depth, height, 1)
    near = np.abs(height - (slope * depth + offset)) < LEVEL_INLIER_M
    if np.ptp(depth[near]) >= MIN_DEPTH_SPREAD_M:
        slope, offset = np.polyfit(depth[near], height[near], 1)
    return float(np.arctan(slope))
