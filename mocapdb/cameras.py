"""Pinhole cameras with OpenCV lens distortion, and the Pose2Sim/OpenCV calibration TOML."""
from __future__ import annotations

import tomllib
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np


class CalibrationError(ValueError):
    """A calibration file that cannot be used; the message names the section and field."""


@dataclass(frozen=True)
class CameraModel:
    """A camera: ``x_cam = R x_world + t`` (metres), then pinhole ``K`` (pixels) and distortion.

    ``dist`` holds OpenCV's (k1, k2, p1, p2[, k3]); zeros mean none. ``size`` is (width, height) px.
    """

    K: np.ndarray
    dist: np.ndarray
    R: np.ndarray
    t: np.ndarray
    size: tuple[int, int]
    name: str = ""

    @property
    def P(self) -> np.ndarray:
        """The 3×4 projection matrix ``K [R | t]`` (pixels, no distortion)."""
        return self.K @ np.hstack([self.R, self.t.reshape(3, 1)])

    @property
    def center_m(self) -> np.ndarray:
        """The camera centre in world coordinates (metres)."""
        return -self.R.T @ self.t

    def project(self, points_world: np.ndarray) -> np.ndarray:
        """Pixels ``[..., 2]`` of world points ``[..., 3]`` (metres), lens distortion applied."""
        pts = np.asarray(points_world, dtype=np.float64)
        rvec, _ = cv2.Rodrigues(self.R)
        px, _ = cv2.projectPoints(pts.reshape(-1, 1, 3), rvec, self.t.astype(np.float64), self.K, self.dist)
        return px.reshape(pts.shape[:-1] + (2,))

    def undistort_normalized(self, px: np.ndarray) -> np.ndarray:
        """Normalised image coordinates ``[..., 2]`` (x/z, y/z) of pixels ``[..., 2]``, distortion removed."""
        pts = np.asarray(px, dtype=np.float64)
        out = cv2.undistortPoints(pts.reshape(-1, 1, 2), self.K, self.dist)
        return out.reshape(pts.shape)


def camera_from_intrinsics(focal_px: float, center_px: tuple[float, float], size: tuple[int, int]) -> CameraModel:
    """A distortion-free camera at the world origin (for ``--focal/--center``)."""
    k = np.array([[focal_px, 0.0, center_px[0]], [0.0, focal_px, center_px[1]], [0.0, 0.0, 1.0]])
    return CameraModel(k, np.zeros(4), np.eye(3), np.zeros(3), (int(size[0]), int(size[1])))


def _field(section: dict, name: str, where: str, shape: tuple[int, ...] | None) -> np.ndarray:
    if name not in section:
        raise CalibrationError(f"{where}: missing '{name}'")
    try:
        value = np.asarray(section[name], dtype=np.float64)
    except (TypeError, ValueError):
        raise CalibrationError(f"{where}: '{name}' is not an array of numbers") from None
    if shape is not None and value.shape != shape:
        raise CalibrationError(f"{where}: '{name}' has shape {value.shape}, expected {shape}")
    if not np.all(np.isfinite(value)):
        raise CalibrationError(f"{where}: '{name}' holds a non-finite value")
    return value


def _camera(key: str, section: dict, where: str) -> CameraModel:
    if section.get("fisheye", False):
        raise CalibrationError(f"{where}: fisheye cameras are not supported")
    k = _field(section, "matrix", where, (3, 3))
    dist = _field(section, "distortions", where, None).ravel()
    if len(dist) not in (4, 5):
        raise CalibrationError(f"{where}: 'distortions' needs 4 or 5 values (k1, k2, p1, p2[, k3])")
    rvec = _field(section, "rotation", where, (3,))
    t = _field(section, "translation", where, (3,))
    size = _field(section, "size", where, (2,))
    rot, _ = cv2.Rodrigues(rvec)
    return CameraModel(k, dist, rot, t, (int(size[0]), int(size[1])), str(section.get("name", key)))


def read_calibration_toml(path: str | Path) -> dict[str, CameraModel]:
    """Cameras of a Pose2Sim/OpenCV calibration TOML, by section name (``[metadata]`` is skipped).

    Each section: ``matrix`` (3×3 px), ``distortions`` (k1, k2, p1, p2), ``rotation`` (Rodrigues,
    world→camera), ``translation`` (metres), ``size`` (width, height px), ``fisheye`` (false).
    """
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise CalibrationError(f"{path}: cannot read ({exc.strerror})") from None
    except tomllib.TOMLDecodeError as exc:
        raise CalibrationError(f"{path}: not valid TOML ({exc})") from None
    cams = {key: _camera(key, sec, f"{path} [{key}]") for key, sec in data.items()
            if isinstance(sec, dict) and key != "metadata"}
    if not cams:
        raise CalibrationError(f"{path}: no camera section")
    return cams
