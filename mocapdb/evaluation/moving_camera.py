"""A camera that turns, against a known path (issue 51, item 4).

Real images with a known camera path: a calibrated video's frames warped by ``K R(t) K⁻¹``
(:func:`warp_video`), the scene unchanged, as if the camera had panned, tilted and rolled about its
centre along :func:`turn_path`. What is scored:

* the camera's rotation per frame the background gives (:func:`rotation_errors_deg`) against ``R(t)``;
* the track files of the turned video against the still video's (:func:`compare_tracks`): each
  person's root (pelvis) in the one world, metres apart per frame, and its feet's height above the
  floor (the lower ankle's ``y``), centimetres apart per frame.

Rotations are in OpenCV's camera axes (x right, y down, z forward), reference → frame, as
:class:`~mocapdb.core.formats.camera_path.CameraPath` holds them.
"""
from __future__ import annotations

import csv
from pathlib import Path

import cv2
import numpy as np

from mocapdb.core.formats.camera_path import CameraPath, rotation_angle_deg
from mocapdb.core.geometry import axis_rotation_matrices

# Targets (issue 51): roots in one world within 0.3 m, feet on the floor within 5 cm, the rotation within 2°
TARGET_ROOT_M = 0.3
TARGET_FEET_CM = 5.0
TARGET_TURN_DEG = 2.0


def turn_path(frames: int, pan_deg: float, tilt_deg: float, roll_deg: float) -> np.ndarray:
    """``[frames, 3, 3]`` a smooth turn from the identity: the pan (about the camera's y), tilt
    (about its x) and roll (about its z) each ease in from 0 to the given angle (a half cosine),
    the tilt out again (a half sine: up and back), so the path is not one rotation scaled."""
    t = np.linspace(0.0, 1.0, frames)
    ease, bump = 0.5 - 0.5 * np.cos(np.pi * t), np.sin(np.pi * t)
    pan = axis_rotation_matrices("Y", np.radians(pan_deg * ease))
    tilt = axis_rotation_matrices("X", np.radians(tilt_deg * bump))
    roll = axis_rotation_matrices("Z", np.radians(roll_deg * ease))
    return roll @ tilt @ pan


def warp_video(source: str | Path, target: str | Path, intrinsics: np.ndarray, rotations: np.ndarray) -> int:
    """``source``'s frames, frame ``t`` warped by ``K R_t K⁻¹`` (the view of the camera turned by
    ``R_t`` about its centre; the uncovered border black), written to ``target`` (MPEG-4 part 2, the
    source's frame rate). Returns the frames written; ValueError when the video has more frames than
    ``rotations`` or cannot be read or written."""
    reader = cv2.VideoCapture(str(source))
    fps = reader.get(cv2.CAP_PROP_FPS)
    writer = None
    count = 0
    try:
        while True:
            ok, image = reader.read()
            if not ok:
                break
            if count >= len(rotations):
                raise ValueError(f"{source}: more frames than the {len(rotations)} rotations given")
            height, width = image.shape[:2]
            if writer is None:
                writer = cv2.VideoWriter(str(target), cv2.VideoWriter_fourcc(*"mp4v"), fps, (width, height))
                if not writer.isOpened():
                    raise ValueError(f"{target}: cannot be written")
            homography = intrinsics @ rotations[count] @ np.linalg.inv(intrinsics)
            writer.write(cv2.warpPerspective(image, homography, (width, height), flags=cv2.INTER_LINEAR))
            count += 1
    finally:
        reader.release()
        if writer is not None:
            writer.release()
    if count == 0:
        raise ValueError(f"{source}: no frame could be read")
    return count


def rotation_errors_deg(path: CameraPath, truth: np.ndarray) -> np.ndarray:
    """``[N]`` the angle (degrees) between each frame's measured rotation and the true one (frames
    numbered from 0, as ``truth [T, 3, 3]``)."""
    return rotation_angle_deg(path.rotations @ np.transpose(truth[path.frames], (0, 2, 1)))


def read_joints_csv(path: str | Path) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """A track's CSV file (``reconstruct --format csv``): its frame numbers and each joint's ``[F, 3]``
    positions (metres)."""
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    header, values = rows[0], np.array(rows[1:], dtype=np.float64)
    joints = {name[:-2]: values[:, i:i + 3] for i, name in enumerate(header) if name.endswith("_x")}
    return values[:, 0].astype(np.int64), joints


def compare_tracks(moving: str | Path, still: str | Path) -> dict[str, float]:
    """Every track CSV of the turned video's output folder against the still video's file of the
    same name (frames in common): roots (pelvis) apart (m) and the lower ankle's height apart (cm),
    median and largest over the frames."""
    roots, feet = [], []
    for path in sorted(Path(moving).glob("track_*.csv")):
        other = Path(still) / path.name
        if not other.exists():
            continue
        frames_a, a = read_joints_csv(path)
        frames_b, b = read_joints_csv(other)
        common, ia, ib = np.intersect1d(frames_a, frames_b, return_indices=True)
        roots.append(np.linalg.norm(a["pelvis"][ia] - b["pelvis"][ib], axis=1))
        lower_a = np.minimum(a["r_ankle"][ia, 1], a["l_ankle"][ia, 1])
        lower_b = np.minimum(b["r_ankle"][ib, 1], b["l_ankle"][ib, 1])
        feet.append(100.0 * np.abs(lower_a - lower_b))
    if not roots:
        return {"tracks": 0}
    root, foot = np.concatenate(roots), np.concatenate(feet)
    return {"tracks": len(roots), "root_median_m": float(np.median(root)), "root_max_m": float(root.max()),
            "feet_median_cm": float(np.median(foot)), "feet_p95_cm": float(np.percentile(foot, 95))}
