"""A moving camera's path: each frame's rotation from the take's reference camera, written by
`mocapdb detect` beside the keypoints (``camera_path.json``) and read by every command that reads
the folder, so that the engine, the whole take and the world see one still camera.

Rotations are in OpenCV's camera axes (x right, y down, z forward): a point ``X`` in the reference
camera's frame is ``R_t X`` in frame ``t``'s, so a pixel moves by the homography ``K R_t K⁻¹`` (``K``:
the path's focal and principal point). :meth:`CameraPath.derotate` maps a frame's keypoints back
into the reference camera through their rays (``K R_tᵀ K⁻¹``): it holds for any turn that keeps the
rays in front of the reference camera (a point whose ray turns behind it is dropped, not mirrored).
The format: ``data_specs/take_description.md``, "The camera's path".
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from mocapdb.core.errors import MocapdbError
from mocapdb.core.files import read_sidecar, write_atomic
from mocapdb.core.formats.keypoints import KeypointFrame, Person
from mocapdb.core.geometry import matrix_to_quat, quat_to_matrix

CAMERA_PATH_FILE = "camera_path.json"
CAMERA_PATH_FORMAT = "mocapdb-camera-path"
CAMERA_PATH_VERSION = 1
MAX_PATH_BYTES = 200_000_000   # ~100 bytes a frame: a day at 60 fps
MIN_RAY_Z = 1e-6               # a derotated ray must point this far in front of the reference camera


class CameraPathError(MocapdbError, ValueError):
    """A camera path that cannot be used (names the file and the field)."""


@dataclass(frozen=True)
class CameraPath:
    """Each frame's camera rotation from the reference frame's (module docstring).

    ``frames [N]``: the frames' numbers (the keypoint files' ``frame``), increasing;
    ``rotations [N, 3, 3]``: ``R_t`` (OpenCV axes, reference → frame); ``focal_px`` and ``center_px``:
    the camera's intrinsics the rotations were measured with (pixels); ``residual_px [N]``: the
    rotation-only fit's RMS residual on the background (pixels; NaN where unmeasured); ``moved``
    ``[N]``: frames whose background showed parallax, a camera that moved (its translation is not
    compensated); ``still``: no frame turned beyond the measurement's noise (every rotation is the
    identity)."""

    frames: np.ndarray
    rotations: np.ndarray
    focal_px: float
    center_px: tuple[float, float]
    residual_px: np.ndarray
    moved: np.ndarray
    still: bool
    _by_frame: dict[int, int] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        frames = np.asarray(self.frames, dtype=np.int64)
        if frames.ndim != 1 or len(frames) == 0 or np.any(np.diff(frames) <= 0):
            raise ValueError("frames must be increasing frame numbers, at least one")
        shape = (len(frames), 3, 3)
        if np.shape(self.rotations) != shape or not np.isfinite(self.rotations).all():
            raise ValueError(f"rotations must be {shape} finite rotation matrices")
        if not np.allclose(np.einsum("nij,nkj->nik", self.rotations, self.rotations), np.eye(3), atol=1e-4):
            raise ValueError("rotations must be rotation matrices (orthonormal)")
        if not (math.isfinite(self.focal_px) and self.focal_px > 0):
            raise ValueError(f"focal_px must be a positive number of pixels, not {self.focal_px!r}")
        if len(self.residual_px) != len(frames) or len(self.moved) != len(frames):
            raise ValueError("residual_px and moved need one value per frame")
        object.__setattr__(self, "frames", frames)
        object.__setattr__(self, "_by_frame", {int(f): i for i, f in enumerate(frames)})

    @property
    def intrinsics(self) -> np.ndarray:
        """``K [3, 3]``: the focal and principal point the rotations were measured with."""
        return intrinsic_matrix(self.focal_px, self.center_px)

    def rotation(self, frame: int) -> np.ndarray:
        """``R_t`` of frame number ``frame``; a frame the path does not hold takes the nearest earlier
        one's (the first one's before it starts): the camera is taken to stay where it was seen last."""
        at = self._by_frame.get(int(frame))
        if at is None:
            at = max(int(np.searchsorted(self.frames, frame, side="right")) - 1, 0)
        return self.rotations[at]

    def turn_deg(self) -> np.ndarray:
        """``[N]`` each frame's rotation angle from the reference (degrees)."""
        return rotation_angle_deg(self.rotations)

    def derotate(self, frame: KeypointFrame) -> KeypointFrame:
        """``frame``'s people seen from the reference camera (:func:`derotate_points`; the detector's
        3D turned by ``R_tᵀ``); the frame itself when the camera was still."""
        return frame if self.still else derotate_frame(frame, self.rotation(frame.index), self.intrinsics)


def intrinsic_matrix(focal_px: float, center_px: tuple[float, float]) -> np.ndarray:
    """``K``: a pinhole's focal (pixels, square pixels) and principal point (pixels)."""
    return np.array([[focal_px, 0.0, center_px[0]], [0.0, focal_px, center_px[1]], [0.0, 0.0, 1.0]])


def derotate_frame(frame: KeypointFrame, rotation: np.ndarray, intrinsics: np.ndarray) -> KeypointFrame:
    """``frame``'s people as the reference camera sees them, the frame's camera turned by ``rotation``
    (reference → it, OpenCV axes) through ``intrinsics`` (``K``): :func:`derotate_points` on every
    pixel, the detector's 3D turned by ``Rᵀ``."""
    return replace(frame, people=[_derotated_person(p, rotation, intrinsics) for p in frame.people])


def rotation_angle_deg(rotations: np.ndarray) -> np.ndarray:
    """The angle (degrees) of rotation matrices ``[..., 3, 3]``."""
    cos = (np.trace(rotations, axis1=-2, axis2=-1) - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def derotate_points(points_px: np.ndarray, rotation: np.ndarray, intrinsics: np.ndarray) -> np.ndarray:
    """Pixels ``[..., 2]`` of a camera turned by ``rotation`` (reference → it, OpenCV axes) as the
    reference camera sees them: each pixel's ray ``K⁻¹ x`` turned back by ``Rᵀ`` and projected by ``K``.
    NaN where the ray would lie behind the reference camera (or the pixel is NaN)."""
    points = np.asarray(points_px, dtype=np.float64)
    rays = np.concatenate([points, np.ones(points.shape[:-1] + (1,))], axis=-1) @ np.linalg.inv(intrinsics).T
    turned = rays @ rotation                       # Rᵀ r for every row r
    image = turned @ intrinsics.T
    with np.errstate(invalid="ignore", divide="ignore"):
        out = image[..., :2] / image[..., 2:]
    return np.where(turned[..., 2:] > MIN_RAY_Z, out, np.nan)


def _derotated_rows(rows: np.ndarray, turn: np.ndarray, intrinsics: np.ndarray, xy: slice = slice(0, 2),
                    confidence: int = -1) -> np.ndarray:
    """Rows ``[..., C]`` whose columns ``xy`` are pixels: those derotated; a point whose ray turned
    behind the camera gets NaN and confidence 0 (column ``confidence``)."""
    out = np.array(rows, dtype=np.float64)
    out[..., xy] = derotate_points(out[..., xy], turn, intrinsics)
    lost = ~np.isfinite(out[..., xy]).all(axis=-1) & np.isfinite(rows[..., xy]).all(axis=-1)
    out[..., confidence] = np.where(lost, 0.0, out[..., confidence])
    return out


def local_roll(point_px: np.ndarray, rotation: np.ndarray, intrinsics: np.ndarray) -> np.ndarray:
    """``[3, 3]`` the turn about the optical axis (image axes: x right, y down, z away) by which
    :func:`derotate_points` turns the image about the pixel ``point_px [2]``: the rotation part of
    its Jacobian there (finite differences of 1 px). The identity where the pixel is unknown."""
    if not np.isfinite(point_px).all():
        return np.eye(3)
    moved = derotate_points(point_px + np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]), rotation, intrinsics)
    jacobian = (moved[1:] - moved[0]).T                           # columns: d/dx, d/dy
    angle = np.arctan2(jacobian[1, 0] - jacobian[0, 1], jacobian[0, 0] + jacobian[1, 1])
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _derotated_person(person: Person, turn: np.ndarray, intrinsics: np.ndarray) -> Person:
    """One person's keypoints, extremities, hands and face mesh derotated (pixels). The detector's 3D
    (image axes) is turned by the image's turn about the person (:func:`local_roll` at its keypoints'
    centre), not by ``Rᵀ``: the detector sees a crop about the person, whose look a pan or a tilt
    barely changes; measured on the balancing take warped by a 15.8° turn (true path): the pelvis
    0.29 → 0.09 m from the still video's, the feet 24 → 0.2 cm (``Rᵀ`` → the 3D kept as it was)."""
    points = derotate_points(person.points_px, turn, intrinsics)
    lost = ~np.isfinite(points).all(axis=-1)
    seen = person.points_px[np.isfinite(person.points_px).all(axis=-1) & (person.confidence > 0)]
    roll = local_roll(seen.mean(axis=0) if len(seen) else np.full(2, np.nan), turn, intrinsics)
    return replace(
        person, points_px=points, confidence=np.where(lost, 0.0, person.confidence),
        extremities=None if person.extremities is None else _derotated_rows(person.extremities, turn, intrinsics),
        hands=None if person.hands is None else _derotated_rows(person.hands, turn, intrinsics),
        face=None if person.face is None else _derotated_rows(person.face, turn, intrinsics),
        world_m=None if person.world_m is None else person.world_m @ roll.T,
        extremities_world_m=None if person.extremities_world_m is None else person.extremities_world_m @ roll.T)


def path_record(path: CameraPath) -> dict:
    """``camera_path.json``'s content (data_specs/take_description.md, "The camera's path")."""
    return {"format": CAMERA_PATH_FORMAT, "version": CAMERA_PATH_VERSION, "still": path.still,
            "focal_px": round(path.focal_px, 3), "center_px": [round(float(c), 3) for c in path.center_px],
            "axes": "opencv: x right, y down, z forward; rotation reference -> frame",
            "frames": path.frames.tolist(),
            "quaternions_wxyz": np.round(matrix_to_quat(path.rotations), 7).tolist(),
            "residual_px": [None if not np.isfinite(r) else round(float(r), 3) for r in path.residual_px],
            "moved": [int(m) for m in path.moved]}


def write_camera_path(folder: str | Path, path: CameraPath) -> Path:
    """``folder/camera_path.json`` (atomically); returns its path."""
    target = Path(folder) / CAMERA_PATH_FILE
    write_atomic(target, json.dumps(path_record(path)) + "\n")
    return target


def read_camera_path(folder: str | Path) -> CameraPath | None:
    """The camera path in ``folder`` (None when there is none); CameraPathError naming the file and
    the field when it is broken."""
    found = read_sidecar(folder, CAMERA_PATH_FILE, MAX_PATH_BYTES, CameraPathError, "camera path",
                         CAMERA_PATH_FORMAT, CAMERA_PATH_VERSION)
    if found is None:
        return None
    target, body = found
    try:
        quats = np.asarray(body["quaternions_wxyz"], dtype=np.float64)
        if quats.ndim != 2 or quats.shape[1] != 4 or not np.allclose(np.linalg.norm(quats, axis=1), 1.0, atol=1e-5):
            raise ValueError("quaternions_wxyz must be unit quaternions [w, x, y, z], one per frame")
        residual = np.array([np.nan if r is None else r for r in body["residual_px"]], dtype=np.float64)
        return CameraPath(np.asarray(body["frames"]), quat_to_matrix(quats), float(body["focal_px"]),
                          (float(body["center_px"][0]), float(body["center_px"][1])), residual,
                          np.asarray(body["moved"], dtype=bool), bool(body["still"]))
    except (KeyError, TypeError, IndexError, ValueError) as exc:
        raise CameraPathError(f"{target}: {exc}") from None
