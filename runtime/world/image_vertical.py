"""The camera's tilt as the image shows it (issue 36, item 1: "the image direction of each person's
vertical"). A person standing or walking keeps the centre of mass above what carries it, so the
image line from the support (the lower ankle) to the body's centre of mass is the image of a
vertical line, and the plane through the camera and that line holds the world's up.

Per frame, :func:`vertical_planes` gives that plane's unit normal (view frame). Each keypoint is
put on its ray at the person's depth, which makes the body a flat picture of itself: its centre of
mass the mass-weighted mid-points (:func:`~mocapdb.runtime.world.detector_prior.centre_of_mass`), its support
chosen along the track's up (:func:`~mocapdb.runtime.world.detector_prior.support_points`).

:func:`plane_angles_deg` gives a candidate up's angle out of the planes, :func:`vertical_misfit` a
track's cost of a candidate up and :func:`vertical_sd_deg` its error. A lean along the viewing ray
leaves a plane unchanged, so the planes fix the roll; the pitch they show only through the
perspective of people off the image's centre, where a sideways lean of 1° moves it by several, so
the world counts them on the roll alone (:mod:`~mocapdb.runtime.world.fuse`). ``data_specs/world.md``
gives the decisions.
"""
from __future__ import annotations

import numpy as np

from mocapdb.core.skeleton import KP
from mocapdb.runtime.world.detector_prior import centre_of_mass, support_points, unit
from mocapdb.runtime.world.tilt import tilted_normals

MASS_KEYPOINTS = ("head", "r_shoulder", "l_shoulder", "r_elbow", "l_elbow", "r_wrist", "l_wrist",
                  "r_hip", "l_hip", "r_knee", "l_knee", "r_ankle", "l_ankle")
_MASS_INDEX = np.array([KP[name] for name in MASS_KEYPOINTS])
MAX_PLANES = 256   # frames kept per track (evenly spaced): the cost is a median over them


def vertical_planes(keypoints: np.ndarray, camera_px: tuple[float, float, float], depth_m: float,
                    up: np.ndarray) -> np.ndarray:
    """Unit plane normals ``[N, 3]`` (view frame) through the camera and each frame's image line
    support → centre of mass, for the frames of ``keypoints [F, 14, 3]`` (x px, y px, confidence)
    that see every one of :data:`MASS_KEYPOINTS` (the nose may be missing: :func:`_head_or_shoulders`;
    at most :data:`MAX_PLANES`, evenly spaced).
    ``camera_px``: focal length and principal point (pixels); ``depth_m``: the person's distance
    along the optical axis (metres); ``up``: the track's estimate of the world's up (view frame): the
    support is chosen along it, then along it rolled into the planes found (:data:`SUPPORT_PASSES`)."""
    keypoints = _head_or_shoulders(keypoints)
    seen = (keypoints[:, _MASS_INDEX, 2] > 0).all(axis=1)
    points = keypoints[seen][:, :, :2]
    points = points[::max(len(points) // MAX_PLANES, 1)]
    focal, cx, cy = camera_px
    rays = np.stack([(points[..., 0] - cx) / focal, -(points[..., 1] - cy) / focal,
                     -np.ones(points.shape[:2])], axis=-1) * depth_m                  # [N, 14, 3] view frame
    body = {name: rays[:, KP[name]] for name in MASS_KEYPOINTS}
    com = centre_of_mass(body)
    up = np.asarray(up, dtype=np.float64)
    for _ in range(SUPPORT_PASSES):
        normals = unit(np.cross(support_points(body, up), com))
        normals = normals[np.isfinite(normals).all(axis=1)]
        if not len(normals):
            break
        up = _rolled_into(normals, up)
    return normals


def _head_or_shoulders(keypoints: np.ndarray) -> np.ndarray:
    """``keypoints [F, 14, 3]`` with an unseen nose put at the shoulders' mid-point where both are
    seen: a detector that drops the nose (or the engine that doubts it) leaves the head's 8 % of the
    mass a few centimetres off, a fraction of a degree, instead of the frame."""
    head, right, left = KP["head"], KP["r_shoulder"], KP["l_shoulder"]
    missing = (keypoints[:, head, 2] <= 0) & (keypoints[:, right, 2] > 0) & (keypoints[:, left, 2] > 0)
    if not missing.any():
        return keypoints
    out = keypoints.copy()
    out[missing, head, :2] = 0.5 * (keypoints[missing, right, :2] + keypoints[missing, left, :2])
    out[missing, head, 2] = 1.0
    return out


SUPPORT_PASSES = 3   # the support chosen along the up, that up rolled into the planes, this many times
_ROLLS_DEG = np.arange(-20.0, 20.01, 0.25)


def _rolled_into(planes: np.ndarray, up: np.ndarray) -> np.ndarray:
    """``up`` rolled about the optical axis (within ±20°) to where its median angle out of ``planes``
    is least: an up that reads the roll wrong picks the wrong ankle as the support, which leans each
    line towards that wrong roll."""
    ups = tilted_normals(up, np.column_stack([np.zeros_like(_ROLLS_DEG), _ROLLS_DEG]))
    return ups[np.argmin(np.abs(np.median(plane_angles_deg(planes, ups), axis=0)))]


def plane_angles_deg(planes: np.ndarray, ups: np.ndarray) -> np.ndarray:
    """The signed angle (degrees) of each candidate up ``ups [T, 3]`` (unit) out of each plane of
    ``planes [N, 3]`` (unit normals): ``[N, T]``."""
    return np.degrees(np.arcsin(np.clip(planes @ ups.T, -1.0, 1.0)))


POSTURE_SD_DEG = 2.0    # how far a take's median body line may lean off the vertical (degrees)
DECORRELATION_S = 0.5   # frames this far apart count as independent draws of a body's sway


def vertical_sd_deg(planes: np.ndarray, up: np.ndarray, duration_s: float) -> float:
    """The error (degrees) of a track's median angle out of its ``planes`` at its own ``up``:
    :data:`POSTURE_SD_DEG` and the frames' spread (1.4826 MAD) over the independent draws among
    ``duration_s`` seconds (one every :data:`DECORRELATION_S`, at most one a plane)."""
    angles = plane_angles_deg(planes, np.asarray(up, dtype=np.float64)[None])[:, 0]
    spread = 1.4826 * float(np.median(np.abs(angles - np.median(angles))))
    draws = max(min(len(planes), duration_s / DECORRELATION_S), 1.0)
    return float(np.hypot(POSTURE_SD_DEG, 1.2533 * spread / np.sqrt(draws)))


def vertical_misfit(planes: np.ndarray, sd_deg: float, ups: np.ndarray) -> np.ndarray:
    """``−log`` likelihood ``[T]`` (up to a constant) of each candidate up ``ups [T, 3]`` given a
    track's ``planes``: its median angle out of them over ``sd_deg``, a Cauchy error (a person
    leaning on something, or an odd support, costs little)."""
    median = np.median(plane_angles_deg(planes, ups), axis=0)
    return np.log1p(0.5 * (median / sd_deg) ** 2)
