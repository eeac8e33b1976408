"""The face mesh a face landmark model would give of a synthetic head (``Person.face``): the head vertices
(:func:`~mocapdb.evaluation.end_truth.face_mesh_points`) projected, their depth in pixels as the model gives it,
absent where the face looks away or is too small (``data_specs/evaluation_bodies.md``, "Head, hands and feet")."""
from __future__ import annotations

import numpy as np

from mocapdb.core.formats.face_keypoints import absent_face
from mocapdb.runtime.mesh_head import HEAD_VERTICES, LEFT, NOSE, RIGHT

MESH_NOISE_PX = 0.5     # the mesh's own jitter (Gaussian SD, px; on a noisy scenario): the every-frame mesh of a
# still photo moves 0.9 % of the eyes' distance (data_specs/head.md, "At a lower rate"), 0.3 px on a 60 px face
MAX_AWAY_DEG = 60.0     # a face turned further than this from the camera gives no mesh (the back, a profile)
MIN_BREADTH_PX = 20.0   # nor does a face narrower than this (detect/face.py's MIN_FACE_PX)
PRESENCE = 0.95         # the face flag of a mesh given


def detected_faces(px: np.ndarray, cam_points: np.ndarray, focal_px: float, noisy: bool,
                   rng: np.random.Generator) -> np.ndarray:
    """``[F, 468, 4]`` ``Person.face`` (x px, y px, z px, face flag; absent: NaN and 0) of the head vertices'
    pixels ``px [F, N_HEAD, 2]`` and camera-aligned points ``cam_points [F, N_HEAD, 3]`` (x right, y up, z the
    distance, metres): the other vertices absent (NaN, so blend shapes give none)."""
    depth = focal_px * (cam_points[..., 2] - cam_points[..., NOSE:NOSE + 1, 2]) / cam_points[..., NOSE:NOSE + 1, 2]
    points = np.concatenate([px, depth[..., None]], axis=-1)
    if noisy:
        points = points + rng.normal(0.0, MESH_NOISE_PX, points.shape)
    mid = 0.5 * (cam_points[:, LEFT] + cam_points[:, RIGHT])
    forward = cam_points[:, NOSE] - mid
    towards = -mid / np.linalg.norm(mid, axis=-1, keepdims=True)
    facing = np.sum(forward * towards, axis=-1) / np.linalg.norm(forward, axis=-1)
    breadth = np.linalg.norm(px[:, LEFT] - px[:, RIGHT], axis=-1)
    found = (facing > np.cos(np.radians(MAX_AWAY_DEG))) & (breadth >= MIN_BREADTH_PX)
    faces = np.repeat(absent_face()[None], len(px), axis=0)
    faces[:, HEAD_VERTICES, :3] = points
    faces[:, HEAD_VERTICES, 3] = PRESENCE
    faces[~found] = absent_face()
    return faces
