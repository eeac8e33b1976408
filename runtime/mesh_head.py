"""The head's rotation from the face mesh (MediaPipe's face landmark model, 468 points: ``detect/face.py``).

The pinned wheel carries no canonical face model (its ``face_geometry/data`` holds none), so the model is
the person's own (:func:`mesh_model`): each frame's mesh in 3D (x, y px and the model's z, scaled like x),
put in the head frame of :data:`~mocapdb.runtime.head_pose.FACE_MODEL_M` (x: the subject's right → left
cheek contour at the ears' height, vertices 234 → 454; z: from their mid-point towards the nose tip,
vertex 1; y = z × x), divided by its breadth (234 ↔ 454), the median over the take's frames, then scaled
to :data:`MESH_BREADTH_M` × the body's scale. The rotation (:func:`fit_mesh_head`) is the same Gauss-Newton
re-projection fit as the face points' (:func:`~mocapdb.runtime.head_pose.fit_head`: rotation and centre,
confidence and Huber weights, the prior, the depth near the body's nose), on all 468 points, the nose tip
first; the mesh has no left-right swap to undo. Contract and figures: ``data_specs/head.md``, "Face mesh".
"""
from __future__ import annotations

import numpy as np

from mocapdb.runtime.head_pose import MIN_MODEL_FRAMES, PRIOR_SD_DEG, fit_head, frames_along

MESH_NOSE, MESH_RIGHT, MESH_LEFT = 1, 234, 454   # mesh vertices: the nose tip, the cheek contours at the ears
MESH_BREADTH_M = 0.14    # 234 ↔ 454 of a 1.75 m adult: about the bizygomatic breadth (rounded mean, 14 cm)
N_MESH = 468
# the mesh's rows with the nose tip first (fit_head holds the model's first row at the body's nose)
NOSE_FIRST = np.array([MESH_NOSE] + [i for i in range(N_MESH) if i != MESH_NOSE])


def mesh_3d(mesh_px: np.ndarray) -> np.ndarray:
    """``[..., 468, 3]`` a mesh's points (x, y, z px; z smaller: nearer) in a right-handed frame with y up
    and z towards the camera, as the view frame: (x, −y, −z)."""
    return mesh_px[..., :3] * np.array([1.0, -1.0, -1.0])


def _head_frames(points: np.ndarray) -> np.ndarray:
    """``[F, 3, 3]`` the head frames (columns x, y, z; module docstring) of meshes ``[F, 468, 3]`` (:func:`mesh_3d`)."""
    forward = points[:, MESH_NOSE] - 0.5 * (points[:, MESH_LEFT] + points[:, MESH_RIGHT])
    return frames_along(points[:, MESH_LEFT] - points[:, MESH_RIGHT], forward, 2)


def mesh_model(mesh_px: np.ndarray, scale: float) -> np.ndarray | None:
    """``[468, 3]`` the person's face (metres, the head frame; module docstring) from the meshes ``[F, 468,
    ≥3]`` (frame px; NaN where absent) at the body's ``scale`` (height / 1.75 m); None with fewer than
    :data:`~mocapdb.runtime.head_pose.MIN_MODEL_FRAMES` meshes."""
    points = mesh_3d(mesh_px[np.isfinite(mesh_px[..., :3]).all(axis=(1, 2))])
    if len(points) < MIN_MODEL_FRAMES:
        return None
    centre = 0.5 * (points[:, MESH_LEFT] + points[:, MESH_RIGHT])
    breadth = np.linalg.norm(points[:, MESH_LEFT] - points[:, MESH_RIGHT], axis=-1)
    local = np.einsum("fji,fpj->fpi", _head_frames(points), points - centre[:, None]) / breadth[:, None, None]
    return np.median(local, axis=0) * MESH_BREADTH_M * scale


def fit_mesh_head(mesh_px: np.ndarray, nose_view_m: np.ndarray, prior: np.ndarray, scale: float,
                  camera_px: tuple[float, float, float], model_m: np.ndarray,
                  prior_sd_deg: float | np.ndarray = PRIOR_SD_DEG) -> tuple[np.ndarray, np.ndarray]:
    """The head's global rotations ``[F, 3, 3]`` (view frame) and the frames a mesh fixed ``[F]`` (the
    others: ``prior``) of meshes ``mesh_px [F, 468, 4]`` (x, y, z px, confidence; 0 or NaN: absent) with
    the face ``model_m [468, 3]`` (:func:`mesh_model`); the rest as :func:`~mocapdb.runtime.head_pose.fit_head`."""
    observed = mesh_px[:, NOSE_FIRST][..., [0, 1, 3]]
    return fit_head(observed, nose_view_m, prior, scale, camera_px, prior_sd_deg, model_m[NOSE_FIRST], swapped=None)
