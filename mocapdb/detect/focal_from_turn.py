"""The focal length a turning camera's background shows (issue 51, item 2).

A camera that only turns moves the background by ``K R K⁻¹``. Under a wrong focal no rotation
fits a pan or a tilt exactly: the image's edges move too little or too much against its centre
(on the balancing take warped by a 6.7° turn, the rotation-only fit's median residual was 0.87 px
at the true 1681 px and 1.77 px at the 26 mm default's 1324 px). :func:`best_focal` tries focal
lengths over :data:`FOCAL_FACTORS` of the one assumed and keeps the one whose rotations leave the
least residual over the frames that turned most from their keyframe; only where the camera turned
at least :data:`MIN_TURN_DEG` and the residual fell by :data:`MIN_GAIN` (a roll, or a turn too
small, shows no focal: the assumed one stays). Its cost: a least-squares rotation per frame and
focal tried, at the end of the take.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from mocapdb.core.formats.camera_path import intrinsic_matrix, rotation_angle_deg
from mocapdb.core.geometry import kabsch

FOCAL_FACTORS = np.exp(np.linspace(np.log(0.5), np.log(2.0), 57))   # of the focal assumed, 2.5 % apart
MIN_TURN_DEG = 3.0      # the frames used turned at least this far from their keyframe
MIN_GAIN = 0.8          # the best focal's residual at most this share of the assumed one's
MAX_FRAMES = 120        # the frames that turned most from their keyframe, at most
MAX_POINTS = 40         # tracks kept per frame (the rotation's inliers, evenly spaced)


class Matches(NamedTuple):
    """One frame's background tracks: where they were in its keyframe and where they are now
    (shrunk image px; none where too few were left to fit), and the keyframe's frame (an index into
    the path's frames)."""

    key_frame: int
    key_px: np.ndarray
    now_px: np.ndarray


def kept(points_px: np.ndarray) -> np.ndarray:
    """At most :data:`MAX_POINTS` of ``points_px [N, 2]``, evenly spaced, as float32."""
    return points_px[::max(len(points_px) // MAX_POINTS, 1)][:MAX_POINTS].astype(np.float32)


def rays(points_px: np.ndarray, intrinsics: np.ndarray) -> np.ndarray:
    """Unit viewing rays ``[..., N, 3]`` (OpenCV axes) of pixels ``[..., N, 2]``."""
    out = np.concatenate([points_px, np.ones(points_px.shape[:-1] + (1,))], axis=-1) @ np.linalg.inv(intrinsics).T
    return out / np.linalg.norm(out, axis=-1, keepdims=True)


def residual_px(matches: Matches, intrinsics: np.ndarray) -> float:
    """The median distance (px) between where the best rotation under ``intrinsics`` puts a frame's
    keyframe tracks and where they are."""
    key = rays(matches.key_px.astype(np.float64), intrinsics)
    rotation = kabsch(key, rays(matches.now_px.astype(np.float64), intrinsics))
    image = key @ rotation.T @ intrinsics.T
    return float(np.median(np.linalg.norm(image[:, :2] / image[:, 2:] - matches.now_px, axis=1)))


def best_focal(matches: list[Matches | None], turns_deg: np.ndarray, focal_px: float,
               center_px: tuple[float, float]) -> float | None:
    """The focal (shrunk image px) whose rotations fit the frames that turned most from their
    keyframe best (``turns_deg [N]``: each frame's turn from it), or None when no frame turned
    :data:`MIN_TURN_DEG` or no focal beats ``focal_px`` by :data:`MIN_GAIN` (module docstring)."""
    turned = [i for i in np.argsort(-turns_deg) if turns_deg[i] >= MIN_TURN_DEG and matches[i] is not None
              and len(matches[i].key_px) >= 3]
    chosen = [matches[i] for i in turned[:MAX_FRAMES]]
    if not chosen:
        return None
    costs = np.array([np.median([residual_px(m, intrinsic_matrix(focal_px * f, center_px)) for m in chosen])
                      for f in FOCAL_FACTORS])
    best = int(np.argmin(costs))
    assumed = int(np.argmin(np.abs(FOCAL_FACTORS - 1.0)))
    return float(focal_px * FOCAL_FACTORS[best]) if costs[best] <= MIN_GAIN * costs[assumed] else None


def rotations_at(matches: list[Matches | None], focal_px: float, center_px: tuple[float, float]) -> np.ndarray:
    """``[N, 3, 3]`` every frame's rotation from the first under the focal ``focal_px`` (shrunk
    px): each frame's tracks fitted against its keyframe's, chained through the keyframes' own
    rotations (the first frame: the identity; a frame without tracks keeps its keyframe's)."""
    intrinsics = intrinsic_matrix(focal_px, center_px)
    out = np.empty((len(matches), 3, 3))
    for i, m in enumerate(matches):
        out[i] = np.eye(3) if m is None else out[m.key_frame]
        if m is not None and len(m.key_px) >= 3:
            out[i] = kabsch(rays(m.key_px.astype(np.float64), intrinsics),
                            rays(m.now_px.astype(np.float64), intrinsics)) @ out[i]
    return out


def turn_from_key_deg(rotations: np.ndarray, key_frames: np.ndarray) -> np.ndarray:
    """``[N]`` each frame's turn (degrees) from its keyframe's rotation."""
    return rotation_angle_deg(rotations @ np.transpose(rotations[key_frames], (0, 2, 1)))
