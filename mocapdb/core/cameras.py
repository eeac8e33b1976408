"""Cameras: pinhole models with OpenCV lens distortion (:class:`CameraModel`; Pose2Sim's calibrations:
its TOML and Qualisys's ``.qca.txt``, :func:`read_calibration`) and the database's virtual camera
(:class:`DatabaseCamera`)."""
from __future__ import annotations

import math
import re
import tomllib
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from mocapdb.core import domains as D
from mocapdb.core.errors import MocapdbError
from mocapdb.core.files import MIB, read_input_bytes, read_input_text


class CalibrationError(MocapdbError, ValueError):
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


@dataclass(frozen=True)
class DatabaseCamera:
    """Where the database's virtual camera stands relative to the subject, and its pinhole image.

    The camera stands ``distance_m`` in front of the subject's pelvis, ``height_m`` above the
    floor, with a horizontal optical axis looking along the world's ``-z`` (so at yaw 0 it sees
    a subject whose facing is ``+z`` from the front); no lens distortion. ``focal_px`` and the
    image size ``width_px`` × ``height_px`` are pixels. ``geometry.project_views`` projects with it.
    """

    height_m: float = D.DATABASE_CAMERA_HEIGHT_M.default
    distance_m: float = D.DATABASE_CAMERA_DISTANCE_M.default
    focal_px: float = D.DATABASE_FOCAL_PX.default
    width_px: int = 1920
    height_px: int = 1080

    @property
    def center_px(self) -> tuple[float, float]:
        """The principal point (pixels): the image centre."""
        return (self.width_px / 2.0, self.height_px / 2.0)

    def model(self) -> CameraModel:
        """Its pinhole intrinsics as a :class:`CameraModel`: ``K`` with ``focal_px`` and the principal
        point at the image centre, no distortion, identity pose, size ``(width_px, height_px)``."""
        cx, cy = self.center_px
        k = np.array([[self.focal_px, 0.0, cx], [0.0, self.focal_px, cy], [0.0, 0.0, 1.0]], dtype=np.float64)
        return CameraModel(k, np.zeros(4), np.eye(3), np.zeros(3), (int(self.width_px), int(self.height_px)),
                           "database")


# The principal point may lie outside the image (a crop), but not by more than this share of the
# image's width or height beyond its border: further out, the matrix or the size is wrong.
MAX_CENTER_OUTSIDE = 0.5
MAX_CALIBRATION_BYTES = MIB  # a calibration of dozens of cameras takes a few kB


def check_intrinsics(k: np.ndarray, size: tuple[float, float], where: str) -> None:
    """CalibrationError (prefixed ``where``) unless ``k`` is a usable pinhole matrix for an image
    of ``size`` (width, height) px: finite, not singular, bottom row [0, 0, 1], positive focal
    lengths, the principal point within :data:`MAX_CENTER_OUTSIDE` image sizes of the image."""
    k = np.asarray(k, dtype=np.float64)
    width, height = (float(v) for v in size)
    if not (math.isfinite(width) and math.isfinite(height) and width > 0 and height > 0):
        raise CalibrationError(f"{where}: image size {width:g} × {height:g} px is not two positive numbers")
    if k.shape != (3, 3) or not np.all(np.isfinite(k)):
        raise CalibrationError(f"{where}: the camera matrix is not 3×3 finite numbers")
    with np.errstate(divide="ignore", invalid="ignore"):
        singular = abs(np.linalg.det(k)) <= 1e-12 * float(np.abs(k).max()) ** 2 or not np.linalg.cond(k) < 1e12
    if singular:
        raise CalibrationError(f"{where}: the camera matrix {_numbers(k)} is singular (no inverse)")
    if not np.allclose(k[2], [0.0, 0.0, 1.0], atol=1e-6):
        raise CalibrationError(f"{where}: the camera matrix's last row is {_numbers(k[2])}, not [0, 0, 1]")
    if k[0, 0] <= 0 or k[1, 1] <= 0:
        raise CalibrationError(f"{where}: focal lengths fx = {k[0, 0]:g}, fy = {k[1, 1]:g} px must be positive")
    cx, cy = k[0, 2], k[1, 2]
    if not (-MAX_CENTER_OUTSIDE * width <= cx <= (1 + MAX_CENTER_OUTSIDE) * width
            and -MAX_CENTER_OUTSIDE * height <= cy <= (1 + MAX_CENTER_OUTSIDE) * height):
        raise CalibrationError(f"{where}: principal point ({cx:g}, {cy:g}) px is far outside the "
                               f"{width:g} × {height:g} px image (wrong matrix or size?)")


def _numbers(a: np.ndarray) -> str:
    return np.array2string(np.asarray(a), separator=", ", precision=6, suppress_small=True).replace("\n", "")


def camera_from_intrinsics(focal_px: float, center_px: tuple[float, float], size: tuple[int, int]) -> CameraModel:
    """A distortion-free camera at the world origin (for ``--focal/--center``); CalibrationError when
    the values cannot be a camera (:func:`check_intrinsics`)."""
    k = np.array([[focal_px, 0.0, center_px[0]], [0.0, focal_px, center_px[1]], [0.0, 0.0, 1.0]], dtype=np.float64)
    check_intrinsics(k, size, "intrinsics (--focal, --center, --image-size)")
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
    check_intrinsics(k, (size[0], size[1]), where)
    rot, _ = cv2.Rodrigues(rvec)
    return CameraModel(k, dist, rot, t, (int(size[0]), int(size[1])), str(section.get("name", key)))


def _toml_array(values: np.ndarray) -> str:
    """A TOML array (nested for 2D) of full-precision floats."""
    values = np.asarray(values, dtype=np.float64)
    if values.ndim > 1:
        return "[ " + ", ".join(_toml_array(row) for row in values) + "]"
    return "[ " + ", ".join(repr(float(v)) for v in values) + "]"


def format_calibration_toml(cameras: list[CameraModel], note: str = "") -> str:
    """Pose2Sim's calibration TOML of ``cameras`` (what :func:`read_calibration_toml` reads): one
    section per camera named after it (``matrix``, ``distortions`` (4), ``rotation`` (Rodrigues,
    world → camera), ``translation`` (metres), ``size``, ``fisheye``), then ``[metadata]``."""
    sections = []
    for i, cam in enumerate(cameras):
        name = cam.name or f"cam_{i + 1:02d}"
        rvec, _ = cv2.Rodrigues(np.asarray(cam.R, dtype=np.float64))
        dist = np.zeros(4) if cam.dist is None else np.resize(np.asarray(cam.dist, dtype=np.float64).ravel(), 4)
        sections.append("\n".join([
            f"[{name}]", f'name = "{name}"', f"size = {_toml_array(np.asarray(cam.size, dtype=np.float64))}",
            f"matrix = {_toml_array(cam.K)}", f"distortions = {_toml_array(dist)}",
            f"rotation = {_toml_array(rvec.ravel())}", f"translation = {_toml_array(np.ravel(cam.t))}",
            "fisheye = false"]))
    comment = "".join(f"# {line}\n" for line in note.splitlines())
    return comment + "\n\n".join(sections) + "\n\n[metadata]\nadjusted = false\nerror = 0.0\n"


def read_calibration_toml(path: str | Path) -> dict[str, CameraModel]:
    """Cameras of a Pose2Sim/OpenCV calibration TOML, by section name (``[metadata]`` is skipped).

    Each section: ``matrix`` (3×3 px), ``distortions`` (k1, k2, p1, p2), ``rotation`` (Rodrigues,
    world→camera), ``translation`` (metres), ``size`` (width, height px), ``fisheye`` (false).
    Every error is a CalibrationError naming the file (and the line, or the section and field).
    """
    path = Path(path)
    raw = read_input_bytes(path, MAX_CALIBRATION_BYTES, CalibrationError, "calibration file")
    if b"\0" in raw:
        raise CalibrationError(f"{path}: a binary file, not a calibration TOML (text)")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = raw[:exc.start].count(b"\n") + 1
        raise CalibrationError(f"{path}, line {line}: not UTF-8 text: not a calibration TOML") from None
    try:
        data = tomllib.loads(text)
    except (tomllib.TOMLDecodeError, RecursionError) as exc:
        raise CalibrationError(_toml_message(path, str(exc))) from None
    cams = {key: _camera(key, sec, f"{path} [{key}]") for key, sec in data.items()
            if isinstance(sec, dict) and key != "metadata"}
    if not cams:
        raise CalibrationError(f"{path}: no camera section")
    return cams


def _toml_message(path: Path, message: str) -> str:
    """``<file>, line L, column C: not valid TOML (<reason>)`` from tomllib's message."""
    at = re.search(r"\s*\(at line (\d+), column (\d+)\)$", message)
    if at:
        return f"{path}, line {at[1]}, column {at[2]}: not valid TOML ({message[:at.start()]})"
    end = re.search(r"\s*\(at end of document\)$", message)
    if end:
        return f"{path}, at its end: not valid TOML ({message[:end.start()]})"
    return f"{path}: not valid TOML ({message})"


# Qualisys QTM's calibration (.qca.txt, XML; data_specs/stereo.md): sensor coordinates are in
# subpixels, QCA_SUBPIXELS to a pixel; the camera's axes are y up, looking along -z (OpenGL's), so
# OpenCV's are QTM's turned 180° about x; positions are millimetres; a `video_resolution` of "720p"
# scales the sensor's QCA_VIDEO_LINES lines to 720.
QCA_SUBPIXELS = 64.0
QTM_TO_OPENCV = np.diag([1.0, -1.0, -1.0])
QCA_VIDEO_LINES = 1080.0
QCA_ROTATION_TOLERANCE = 1e-3  # |RᵀR − I| and |det R − 1| of the transform, at most


def read_calibration(path: str | Path) -> dict[str, CameraModel]:
    """Cameras of a Pose2Sim calibration by name: a Qualisys ``*.qca.txt`` (:func:`read_calibration_qca`),
    any other file a calibration TOML (:func:`read_calibration_toml`)."""
    if Path(path).name.lower().endswith(".qca.txt"):
        return read_calibration_qca(path)
    return read_calibration_toml(path)


def read_calibration_qca(path: str | Path) -> dict[str, CameraModel]:
    """Active cameras of a Qualisys QTM calibration ``.qca.txt`` by serial, as Pose2Sim reads them:
    per ``<camera>``, ``<fov_video>`` (the image: a crop of the sensor, pixels, bounds included),
    ``<intrinsic>`` (focal lengths, principal point and distortion in subpixels of the sensor) and
    ``<transform>`` (the camera's position in mm and its world → QTM-camera rotation ``r11``…``r33``).
    Every error is a CalibrationError naming the file (and the camera and attribute)."""
    from xml.etree import ElementTree

    path = Path(path)
    text = read_input_text(path, MAX_CALIBRATION_BYTES, CalibrationError, "calibration file")
    if "<!DOCTYPE" in text or "<!ENTITY" in text:
        raise CalibrationError(f"{path}: a document type or entity declaration: not a Qualisys calibration")
    try:
        root = ElementTree.fromstring(text)
    except ElementTree.ParseError as exc:
        line, column = exc.position
        raise CalibrationError(f"{path}, line {line}, column {column + 1}: not valid XML, not a Qualisys "
                               f"calibration ({str(exc).split(':')[0]})") from None
    elements = root.findall("cameras/camera") if root.tag == "calibration" else []
    if not elements:
        raise CalibrationError(f"{path}: no <calibration><cameras><camera>: not a Qualisys calibration")
    cams: dict[str, CameraModel] = {}
    for k, element in enumerate(elements, start=1):
        name = element.get("serial") or f"#{k}"
        if name in cams:
            raise CalibrationError(f"{path}: two cameras with serial {name!r}")
        if element.get("active", "1").strip() != "0":
            cams[name] = _qca_camera(element, name, f'{path} <camera serial="{name}">')
    if not cams:
        raise CalibrationError(f"{path}: every camera is inactive (active=\"0\")")
    return cams


def _qca_camera(element, name: str, where: str) -> CameraModel:
    """One ``<camera>`` of a QCA file as an OpenCV camera (``x_cam = R x_world + t``, metres, pixels)."""
    fov, intrinsic, transform = (_qca_child(element, tag, where) for tag in ("fov_video", "intrinsic", "transform"))
    left, top, right, bottom = (_qca_number(fov, key, where) for key in ("left", "top", "right", "bottom"))
    scale = _qca_video_scale(element, where)
    size = ((right - left + 1) * scale, (bottom - top + 1) * scale)
    fu, fv, cu, cv = (_qca_number(intrinsic, key, where) / QCA_SUBPIXELS
                      for key in ("focalLengthU", "focalLengthV", "centerPointU", "centerPointV"))
    if _qca_number(intrinsic, "skew", where, 0.0) != 0.0:
        raise CalibrationError(f"{where}: <intrinsic skew=...> is not 0: a skewed sensor is not supported "
                               "(OpenCV's camera model has no skew)")
    k = np.array([[fu * scale, 0.0, (cu - left) * scale], [0.0, fv * scale, (cv - top) * scale], [0.0, 0.0, 1.0]])
    check_intrinsics(k, size, where)
    dist = np.array([_qca_number(intrinsic, key, where, 0.0) for key in
                     ("radialDistortion1", "radialDistortion2", "tangentalDistortion1", "tangentalDistortion2",
                      "radialDistortion3")]) / QCA_SUBPIXELS
    rotation = QTM_TO_OPENCV @ _qca_rotation(transform, where)
    centre_m = np.array([_qca_number(transform, key, where) for key in "xyz"]) / 1000.0
    return CameraModel(k, dist, rotation, -rotation @ centre_m, (round(size[0]), round(size[1])), name)


def _qca_child(element, tag: str, where: str):
    child = element.find(tag)
    if child is None:
        raise CalibrationError(f"{where}: no <{tag}>")
    return child


# QTM writes "tangentalDistortion1"; the other spelling is read too.
_QCA_SPELLINGS = {"tangentalDistortion1": "tangentialDistortion1", "tangentalDistortion2": "tangentialDistortion2"}


def _qca_number(element, key: str, where: str, default: float | None = None) -> float:
    """Attribute ``key`` of ``element`` as a finite number (``default`` when it is missing and one is given)."""
    text = element.get(key, element.get(_QCA_SPELLINGS.get(key, key)))
    if text is None and default is not None:
        return default
    try:
        value = float(text)
    except (TypeError, ValueError):
        raise CalibrationError(f"{where}: <{element.tag} {key}=...> is "
                               + ("missing" if text is None else f"{text[:40]!r}, not a number")) from None
    if not math.isfinite(value):
        raise CalibrationError(f"{where}: <{element.tag} {key}=...> is not a finite number")
    return value


def _qca_video_scale(element, where: str) -> float:
    """Image pixels per sensor pixel: ``video_resolution`` "720p" → 720 / 1080 (1 when absent)."""
    text = element.get("video_resolution")
    if text is None:
        return 1.0
    lines = text.strip().lower().removesuffix("p")
    if not lines.isdigit() or not 0 < int(lines) <= QCA_VIDEO_LINES * 4:
        raise CalibrationError(f"{where}: video_resolution {text[:40]!r} is not a video resolution like \"1080p\"")
    return int(lines) / QCA_VIDEO_LINES


def _qca_rotation(transform, where: str) -> np.ndarray:
    """``r11``…``r33`` (row by row) of ``<transform>``; CalibrationError unless a rotation matrix."""
    m = np.array([[_qca_number(transform, f"r{i}{j}", where) for j in (1, 2, 3)] for i in (1, 2, 3)])
    if (np.abs(m.T @ m - np.eye(3)).max() > QCA_ROTATION_TOLERANCE
            or abs(np.linalg.det(m) - 1.0) > QCA_ROTATION_TOLERANCE):
        raise CalibrationError(f"{where}: <transform r11..r33> {_numbers(m)} is no rotation matrix")
    return m


def intrinsics_only(cam: CameraModel) -> CameraModel:
    """``cam`` with its extrinsics dropped (identity pose): the stereo fit estimates them."""
    width, height = cam.size
    return CameraModel(np.asarray(cam.K), np.asarray(cam.dist), np.eye(3), np.zeros(3), (width, height), cam.name)
