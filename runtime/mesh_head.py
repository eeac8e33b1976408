"""The head's rotation from the face mesh (MediaPipe's face landmark model, 468 points: ``detect/face.py``).

Only the mesh's rigid part is used (:data:`HEAD_VERTICES`: the forehead, the temples and the face's contour at
the ears, the cheekbones, the nose's bridge, tip and wings, the eyes' corners): the lids, lips and jaw move
with blinks, speech and smiles and would turn a rigid fit. :func:`head_vertices` picks them out of a mesh,
the nose tip first.

The pinned wheel carries no canonical face model (its ``face_geometry/data`` holds none), so the model is
the person's own (:func:`mesh_model`, online :class:`MeshModel`): each frame's head vertices in 3D (x, y px
and the model's z, scaled like x), put in the head frame of :data:`~mocapdb.runtime.head_pose.FACE_MODEL_M`
(x: the subject's right → left cheek contour at the ears' height, vertices 234 → 454; z: from their
mid-point towards the nose tip, vertex 1; y = z × x), divided by its breadth (234 ↔ 454), the median over
the take's frames, then scaled to :data:`MESH_BREADTH_M` × the body's scale. The rotation
(:func:`fit_mesh_head`) is the same Gauss-Newton re-projection fit as the face points'
(:func:`~mocapdb.runtime.head_pose.fit_head`: rotation and centre, Huber weights, the prior, the depth near
the body's nose); the mesh has no left-right swap to undo. Contract and figures: ``data_specs/head.md``,
"Face mesh".
"""
from __future__ import annotations

import numpy as np
from scipy.ndimage import binary_closing, binary_erosion, uniform_filter1d

from mocapdb.runtime.head_pose import PRIOR_SD_DEG, fit_head, frames_along

MESH_NOSE, MESH_RIGHT, MESH_LEFT = 1, 234, 454   # mesh vertices: the nose tip, the cheek contours at the ears
MESH_BREADTH_M = 0.14    # 234 ↔ 454 of a 1.75 m adult: about the bizygomatic breadth (rounded mean, 14 cm)
N_MESH = 468
# The rigid vertices (module docstring), the nose tip first: the nose's bridge, tip and wings (4, 5, 6, 195,
# 197, 168, 98, 327), the forehead's middle (8, 9, 151, 10), the eyes' outer and inner corners (33, 263, 133,
# 362), the contour at the ears and up the temples to the forehead (234, 454, 93, 323, 127, 356, 162, 389, 21,
# 251, 54, 284, 103, 332, 67, 297, 109, 338), the cheekbones (116, 345); pairs the subject's right, left
HEAD_VERTICES = (MESH_NOSE, 4, 5, 6, 195, 197, 168, 98, 327, 8, 9, 151, 10, 33, 263, 133, 362, MESH_RIGHT,
                 MESH_LEFT, 93, 323, 127, 356, 162, 389, 21, 251, 54, 284, 103, 332, 67, 297, 109, 338, 116, 345)
N_HEAD = len(HEAD_VERTICES)
NOSE, RIGHT, LEFT = (HEAD_VERTICES.index(v) for v in (MESH_NOSE, MESH_RIGHT, MESH_LEFT))   # their rows there
NO_HEAD_POINTS = np.full((N_HEAD, 3), np.nan, dtype=np.float32)
MODEL_MESHES = 30        # the online model: the median of the first this many meshes, then kept
HOLD_S = 0.5   # a mesh missing this long or less keeps the head on the mesh's rotation (the stream: held)
EASE_S = 0.3   # the head eases between the mesh's rotation and the face points' over this long (seconds)


def head_vertices(mesh_px: np.ndarray) -> np.ndarray:
    """``[..., N_HEAD, 3]`` the :data:`HEAD_VERTICES` (x, y, z px; float32) of meshes ``[..., 468, 4]`` (x, y,
    z px, confidence), NaN where the mesh is absent (confidence 0)."""
    points = mesh_px[..., HEAD_VERTICES, :3]
    present = mesh_px[..., HEAD_VERTICES[:1], 3] > 0
    return np.where(present[..., None], points, np.nan).astype(np.float32)


def mesh_3d(points_px: np.ndarray) -> np.ndarray:
    """``[..., 3]`` mesh points (x, y, z px; z smaller: nearer) in a right-handed frame with y up and z
    towards the camera, as the view frame: (x, −y, −z)."""
    return points_px[..., :3] * np.array([1.0, -1.0, -1.0])


def mesh_shapes(points_px: np.ndarray) -> np.ndarray:
    """``[n, N_HEAD, 3]`` the face of each present frame of head vertices ``[F, N_HEAD, ≥3]`` (frame px; NaN:
    absent) in its head frame (module docstring), in units of its breadth (234 ↔ 454)."""
    points = mesh_3d(np.asarray(points_px, dtype=np.float64))
    points = points[np.isfinite(points).all(axis=(1, 2))]
    centre = 0.5 * (points[:, LEFT] + points[:, RIGHT])
    breadth = np.linalg.norm(points[:, LEFT] - points[:, RIGHT], axis=-1)
    frames = frames_along(points[:, LEFT] - points[:, RIGHT], points[:, NOSE] - centre, 2)
    return np.einsum("fji,fpj->fpi", frames, points - centre[:, None]) / breadth[:, None, None]


def mesh_model(points_px: np.ndarray, scale: float) -> np.ndarray | None:
    """``[N_HEAD, 3]`` the person's face (metres, the head frame; module docstring) from the head vertices
    ``[F, N_HEAD, ≥3]`` (frame px; NaN where absent) at the body's ``scale`` (height / 1.75 m); None without a
    mesh (one mesh is a whole face; the median of more takes its jitter out)."""
    shapes = mesh_shapes(points_px)
    return None if not len(shapes) else np.median(shapes, axis=0) * MESH_BREADTH_M * scale


class MeshModel:
    """The person's face as a stream builds it: the median shape (:func:`mesh_shapes`) of the first
    :data:`MODEL_MESHES` meshes, then kept."""

    def __init__(self) -> None:
        self.shapes: list[np.ndarray] = []
        self.shape: np.ndarray | None = None     # [N_HEAD, 3] in units of the breadth

    def add(self, points_px: np.ndarray) -> None:
        """One frame's head vertices ``[N_HEAD, 3]`` (px; NaN: absent)."""
        if len(self.shapes) >= MODEL_MESHES or not np.isfinite(points_px).all():
            return
        self.shapes.extend(mesh_shapes(points_px[None]))
        self.shape = np.median(np.array(self.shapes), axis=0)

    def model(self, scale: float) -> np.ndarray | None:
        """``[N_HEAD, 3]`` metres at the body's ``scale`` (as :func:`mesh_model`); None before the first mesh."""
        return None if self.shape is None else self.shape * MESH_BREADTH_M * scale


def fit_mesh_head(points_px: np.ndarray, nose_view_m: np.ndarray, prior: np.ndarray, scale: float,
                  camera_px: tuple[float, float, float], model_m: np.ndarray,
                  prior_sd_deg: float | np.ndarray = PRIOR_SD_DEG) -> tuple[np.ndarray, np.ndarray]:
    """The head's global rotations ``[F, 3, 3]`` (view frame) and the frames a mesh fixed ``[F]`` (the
    others: ``prior``) of head vertices ``points_px [F, N_HEAD, ≥2]`` (x, y px; NaN: absent) with the face
    ``model_m [N_HEAD, 3]`` (:func:`mesh_model`); the rest as :func:`~mocapdb.runtime.head_pose.fit_head`."""
    return fit_head(mesh_observations(points_px), nose_view_m, prior, scale, camera_px, prior_sd_deg, model_m,
                    swapped=None)


def mesh_observations(points_px: np.ndarray) -> np.ndarray:
    """``[F, N_HEAD, 3]`` head vertices as :func:`~mocapdb.runtime.head_pose.fit_head` reads points (x, y px,
    confidence: 1 where present, 0 where NaN)."""
    xy = np.asarray(points_px[..., :2], dtype=np.float64)
    present = np.isfinite(xy).all(axis=-1, keepdims=True)
    return np.concatenate([np.nan_to_num(xy), present.astype(np.float64)], axis=-1)


def eased_presence(present: np.ndarray, fps: float) -> np.ndarray:
    """``[F]`` the whole take's weight of the mesh's rotation (0-1) where a mesh was ``present [F]``: gaps of up
    to :data:`HOLD_S` closed, eased in and out over :data:`EASE_S` inside the runs (linear, then smoothstep)."""
    hold, ease = max(int(round(HOLD_S * fps)), 1), max(int(round(EASE_S * fps)), 1)
    padded = np.pad(present, hold)                    # a run at the take's ends is not cut by the closing
    closed = np.asarray(binary_closing(padded, np.ones(hold + 1, dtype=bool)))[hold:-hold] | present
    inner = np.asarray(binary_erosion(closed, np.ones(ease, dtype=bool), border_value=1)) if ease > 1 else closed
    ramp = np.clip(uniform_filter1d(inner.astype(np.float64), ease, mode="nearest") * closed, 0.0, 1.0)
    return ramp * ramp * (3.0 - 2.0 * ramp)
