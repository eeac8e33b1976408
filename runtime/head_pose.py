"""The head's own rotation from the face points one camera sees (nose, eyes, ears, mouth corners).

A rigid face model (:data:`FACE_MODEL_M`, in the head's frame: x to the subject's left, y up, z
forwards, origin the ears' mid-point; scaled with the body) is turned and moved across the view so
that its points project onto the detected ones (:func:`fit_head`: Gauss-Newton on the confidence-
weighted re-projection error, robust (Huber) weights, its depth held where the body's nose is). A
weak prior holds it near ``prior`` (the chest's frame: the head at rest on the trunk) where the face
says little. Layouts give what they have: BlazePose all seven points, COCO-17 and OpenPose nose,
eyes and ears; fewer than :data:`MIN_POINTS` seen points (nose included) leave the frame unknown.

Contract and decisions: ``data_specs/head.md``.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from mocapdb.core.formats.keypoint_layouts import EXTREMITIES
from mocapdb.core.geometry import matrix_to_quat, quat_to_matrix
from mocapdb.core.skeleton import KP, RIG_JOINTS, global_rotations, pose_from_rotations

# The face points after the nose, as rows of the extremities array (keypoint_layouts.EXTREMITIES)
FACE_NAMES = ("r_eye", "l_eye", "r_ear", "l_ear", "r_mouth", "l_mouth")
FACE_ROWS = tuple(EXTREMITIES.index(n) for n in FACE_NAMES)
# The face model of a 1.75 m adult (metres; head frame: x left, y up, z forwards; origin between the
# ears), rows: nose, then FACE_NAMES. Rounded adult means of craniofacial anthropometry, not fitted to
# any take: bitragion breadth about 15 cm (ears ±7.5 cm); interpupillary distance about 6.3 cm (eyes
# ±3.2 cm), the pupils about 2 cm above the ear-eye (Frankfort) plane and 8.5 cm ahead of the tragion;
# the nose tip 10.5 cm ahead of the tragion and 1.5 cm below it; mouth width about 5 cm (corners
# ±2.5 cm), 5.5 cm below the tragion and 8 cm ahead of it.
FACE_MODEL_M = np.array([
    [0.0, -0.015, 0.105],
    [-0.032, 0.02, 0.085], [0.032, 0.02, 0.085],
    [-0.075, 0.0, 0.0], [0.075, 0.0, 0.0],
    [-0.025, -0.055, 0.08], [0.025, -0.055, 0.08]])
MIN_POINTS = 3            # seen face points (the nose one of them) a frame needs
POINT_SD_M = 0.01         # a face point's detection noise, metres at the head (1 cm)
HUBER_SD = 2.0            # residuals beyond this many SDs weigh less (Huber)
PRIOR_SD_DEG = 40.0       # the prior's pull: the head within about this of it
DEPTH_SD = 0.3            # the head's depth: free to within this share of the body's (the model's size is a guess)
ITERATIONS = 12


def face_points(keypoints: np.ndarray, extremities: np.ndarray) -> np.ndarray:
    """``[F, 7, 3]`` nose then :data:`FACE_NAMES` (x px, y px, confidence; 0: unseen) of ``keypoints
    [F, 14, 3]`` and ``extremities [F, E, 3]``."""
    return np.concatenate([keypoints[:, :1], extremities[:, list(FACE_ROWS)]], axis=1)


def _project(points_view: np.ndarray, camera_px: tuple[float, float, float]) -> np.ndarray:
    """View-frame points ``[..., 3]`` (z towards the camera) in pixels ``[..., 2]`` (y down)."""
    focal, cx, cy = camera_px
    depth = -points_view[..., 2]
    return np.stack([cx + focal * points_view[..., 0] / depth, cy - focal * points_view[..., 1] / depth], axis=-1)


def _jacobian(points_view: np.ndarray, offsets: np.ndarray, focal: float) -> np.ndarray:
    """``[F, P, 2, 6]``: pixels of points ``[F, P, 3]`` = centre + ``offsets`` (the turned model) by a
    small turn (rotation vector, left-multiplied) and a move of the centre (x, y, z)."""
    depth = -points_view[..., 2]
    d_uv = np.zeros(points_view.shape[:-1] + (2, 3))        # d(u, v) / d(point)
    d_uv[..., 0, 0] = focal / depth
    d_uv[..., 0, 2] = focal * points_view[..., 0] / depth ** 2
    d_uv[..., 1, 1] = -focal / depth
    d_uv[..., 1, 2] = -focal * points_view[..., 1] / depth ** 2
    skew = np.zeros(offsets.shape + (3,))                    # d(offset) / d(turn) = −[offset]×
    ox, oy, oz = offsets[..., 0], offsets[..., 1], offsets[..., 2]
    skew[..., 0, 1], skew[..., 0, 2] = oz, -oy
    skew[..., 1, 0], skew[..., 1, 2] = -oz, ox
    skew[..., 2, 0], skew[..., 2, 1] = oy, -ox
    return np.concatenate([d_uv @ skew, d_uv], axis=-1)


def fit_head(face_px: np.ndarray, nose_view_m: np.ndarray, prior: np.ndarray, scale: float,
             camera_px: tuple[float, float, float]) -> tuple[np.ndarray, np.ndarray]:
    """The head's global rotations ``[F, 3, 3]`` (view frame; identity: facing +z upright) and which
    frames the face fixed ``[F]`` (the others: ``prior``). ``face_px [F, 7, 3]``: :func:`face_points`;
    ``nose_view_m [F, 3]``: the body's nose (view frame, metres; its depth is the model's);
    ``prior [F, 3, 3]``: where the head would be without the face (the start, weakly held);
    ``scale``: the body's (height / 1.75 m); ``camera_px``: focal, cx, cy (pixels)."""
    model = FACE_MODEL_M * scale
    seen = (face_px[..., 2] > 0) & np.isfinite(face_px[..., :2]).all(axis=-1)
    fixed = seen[:, 0] & (seen.sum(axis=1) >= MIN_POINTS)
    rotation = prior.copy()
    if not fixed.any():
        return rotation, fixed
    rot, base = prior[fixed], prior[fixed]
    nose = nose_view_m[fixed]
    centre = nose - np.einsum("fij,j->fi", rot, model[0])
    observed = np.nan_to_num(face_px[fixed, :, :2])
    weight = np.where(seen[fixed], face_px[fixed, :, 2], 0.0)
    pixel_sd = camera_px[0] * POINT_SD_M * scale / -nose[:, 2]                  # [n]
    prior_weight = 1.0 / np.radians(PRIOR_SD_DEG)
    start_depth = centre[:, 2].copy()
    depth_weight = 1.0 / (DEPTH_SD * -start_depth)                                # [n]
    for _ in range(ITERATIONS):
        offsets = np.einsum("fij,pj->fpi", rot, model)
        points = centre[:, None] + offsets
        residual = (_project(points, camera_px) - observed) / pixel_sd[:, None, None]   # [n, P, 2] in SDs
        size = np.linalg.norm(residual, axis=-1)
        w = weight * np.minimum(1.0, HUBER_SD / np.maximum(size, 1e-12))
        jac = _jacobian(points, offsets, camera_px[0]) / pixel_sd[:, None, None, None]
        normal = np.einsum("fp,fpki,fpkj->fij", w, jac, jac)
        gradient = np.einsum("fp,fpki,fpk->fi", w, jac, residual)
        away = Rotation.from_matrix(rot @ np.swapaxes(base, -1, -2)).as_rotvec()    # the prior's residual
        normal[:, :3, :3] += prior_weight ** 2 * np.eye(3)
        gradient[:, :3] += prior_weight ** 2 * away
        normal[:, 5, 5] += depth_weight ** 2
        gradient[:, 5] += depth_weight ** 2 * (centre[:, 2] - start_depth)
        step = -np.linalg.solve(normal + 1e-9 * np.eye(6), gradient[..., None])[..., 0]
        rot = Rotation.from_rotvec(step[:, :3]).as_matrix() @ rot
        centre += step[:, 3:]
    rotation[fixed] = rot
    return rotation, fixed


def chest_relative_head(quats: np.ndarray, root_m: np.ndarray, scale: float, offsets_m: np.ndarray | None,
                        face_px: np.ndarray, camera_px: tuple[float, float, float]) -> np.ndarray:
    """``[F, 4]`` the head's rotation relative to the chest (the ``spine`` joint's frame; w ≥ 0, NaN
    where the face does not fix it) of a motion (``quats [F, R, 4]``, ``root_m [F, 3]`` view frame,
    body ``scale`` and ``offsets_m``) seen as ``face_px [F, 7, 3]`` (:func:`face_points`)."""
    chest = global_rotations(quats)[:, RIG_JOINTS.index("spine")]
    nose = pose_from_rotations(quats, root_m, scale, offsets_m)[:, KP["head"]]
    head, fixed = fit_head(face_px, nose, chest, scale, camera_px)
    relative = matrix_to_quat(np.swapaxes(chest, -1, -2) @ head)
    relative *= np.where(relative[:, :1] < 0, -1.0, 1.0)
    return np.where(fixed[:, None], relative, np.nan)


def head_local(quats: np.ndarray, chest_relative: np.ndarray) -> np.ndarray:
    """``[F, 4]`` the humanoid ``Head``'s local rotation (relative to the ``Neck``, which carries the
    universal ``neck`` joint) that puts the head at ``chest_relative [F, 4]`` from the chest."""
    rotations = global_rotations(quats)
    chest, neck = rotations[:, RIG_JOINTS.index("spine")], rotations[:, RIG_JOINTS.index("neck")]
    return matrix_to_quat(np.swapaxes(neck, -1, -2) @ chest @ quat_to_matrix(chest_relative))
