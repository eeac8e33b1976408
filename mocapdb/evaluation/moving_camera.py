"""A camera that turns, against a known path (issue 51, item 4).

Real images with a known camera path: a calibrated video's frames warped by ``K R(t) K⁻¹``
(:func:`warp_video`), the scene unchanged, as if the camera had panned, tilted and rolled about its
centre along :func:`turn_path`. What is scored:

* the camera's rotation per frame the background gives (:func:`rotation_errors_deg`) against ``R(t)``;
* the track files of the turned video against the still video's (:func:`compare_tracks`): each
  person's root (pelvis) in the one world, metres apart per frame, and its feet's height above the
  floor (the lower ankle's ``y``), centimetres apart per frame.

Synthetic takes with the truth per frame: ``eval --world``'s takes (held-out clips, several people)
filmed by a camera that turns and, optionally, walks (:func:`moving_take`), reconstructed without
the path and with the true path (:func:`seen_from_reference`), scored against the reference camera's
truth (:func:`score_moving`): roots, feet on the surface they stand on, the world's pitch and roll.

Rotations are in OpenCV's camera axes (x right, y down, z forward), reference → frame, as
:class:`~mocapdb.core.formats.camera_path.CameraPath` holds them.
"""
from __future__ import annotations

import csv
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

from mocapdb.core.formats.camera_path import CameraPath, rotation_angle_deg
from mocapdb.core.formats.database import MotionDatabase
from mocapdb.core.formats.keypoints import KeypointFrame, Person
from mocapdb.core.geometry import axis_rotation_matrices
from mocapdb.evaluation.heldout import Scenario, camera_to_world, render
from mocapdb.evaluation.metrics import planted_feet
from mocapdb.evaluation.world import run_take
from mocapdb.evaluation.world_scores import TrackFit, _sole_heights_m, match_tracks, score_person
from mocapdb.evaluation.world_takes import ANKLES, TruePerson, WorldConfig, WorldTake

# Targets (issue 51): roots in one world within 0.3 m, feet on the floor within 5 cm, the rotation within 2°
TARGET_ROOT_M = 0.3
TARGET_FEET_CM = 5.0
TARGET_TURN_DEG = 2.0


def ease(frames: int) -> np.ndarray:
    """``[frames]`` from 0 to 1, slow at both ends (a half cosine)."""
    return 0.5 - 0.5 * np.cos(np.pi * np.linspace(0.0, 1.0, frames))


def turn_path(frames: int, pan_deg: float, tilt_deg: float, roll_deg: float) -> np.ndarray:
    """``[frames, 3, 3]`` a smooth turn from the identity: the pan (about the camera's y), tilt
    (about its x) and roll (about its z) each ease in from 0 to the given angle (:func:`ease`),
    the tilt out again (a half sine: up and back), so the path is not one rotation scaled."""
    ease_in, bump = ease(frames), np.sin(np.pi * np.linspace(0.0, 1.0, frames))
    pan = axis_rotation_matrices("Y", np.radians(pan_deg * ease_in))
    tilt = axis_rotation_matrices("X", np.radians(tilt_deg * bump))
    roll = axis_rotation_matrices("Z", np.radians(roll_deg * ease_in))
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
                writer = cv2.VideoWriter(str(target), cv2.VideoWriter.fourcc(*"mp4v"), fps, (width, height))
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


# --- synthetic takes: eval --world's people filmed by a camera that turns (and walks) -----------------

OPENCV_FROM_ALIGNED = np.array([1.0, -1.0, 1.0])   # camera-aligned (x right, y up, z ahead) ↔ OpenCV axes


def filmed_moving(cam_m: np.ndarray, rotations: np.ndarray, walk_m: np.ndarray) -> np.ndarray:
    """Camera-aligned points ``[F, J, 3]`` of the reference camera as the camera of frame ``t`` sees
    them: moved to ``walk_m [F, 3]`` (reference camera-aligned, metres) and turned by ``rotations
    [F, 3, 3]`` (OpenCV axes, reference → frame)."""
    opencv = (cam_m - walk_m[:, None]) * OPENCV_FROM_ALIGNED
    return np.einsum("fij,fkj->fki", rotations, opencv) * OPENCV_FROM_ALIGNED


def moving_take(take: WorldTake, rotations: np.ndarray, walk_m: np.ndarray, config: WorldConfig,
                scenario_index: int) -> WorldTake:
    """``take``'s people filmed by the moving camera (:func:`filmed_moving`), rendered with the same
    noise draws as :func:`~mocapdb.evaluation.world_takes.build_take` (a point that leaves the image
    is lost, as a detector loses it); the truth stays the reference camera's."""
    noise = Scenario(take.scenario.name, noise_px=take.scenario.noise_px, dropout=take.scenario.dropout,
                     swap=take.scenario.swap)
    people = []
    for i, person in enumerate(take.people):
        cam = filmed_moving(person.cam_m, rotations[:len(person.cam_m)], walk_m[:len(person.cam_m)])
        rendered = render(cam, noise, config.focal_px, config.image_size,
                          np.random.default_rng((config.seed, scenario_index, take.repeat, i)))
        people.append(replace(person, points_px=np.array([f.people[0].points_px for f in rendered]),
                              confidence=np.array([f.people[0].confidence for f in rendered])))
    frames = [KeypointFrame(k, None, [Person(p.points_px[k], p.confidence[k]) for p in people])
              for k in range(len(take.frames))]
    return replace(take, people=people, frames=frames)


def true_path(rotations: np.ndarray, config: WorldConfig) -> CameraPath:
    """The camera path of ``rotations`` at ``config``'s focal and image centre, as if measured exactly."""
    n = len(rotations)
    centre = (config.image_size[0] / 2.0, config.image_size[1] / 2.0)
    return CameraPath(np.arange(n), rotations, config.focal_px, centre, np.full(n, np.nan), np.zeros(n, dtype=bool),
                      False)


def seen_from_reference(take: WorldTake, path: CameraPath) -> WorldTake:
    """``take``'s frames derotated into the reference camera, as ``reconstruct`` does with a path
    (its people's pixels too, which the tracks are matched against)."""
    frames = [path.derotate(frame) for frame in take.frames]
    people = [replace(p, points_px=np.array([f.people[i].points_px for f in frames]),
                      confidence=np.array([f.people[i].confidence for f in frames])) for i, p in enumerate(take.people)]
    return replace(take, people=people, frames=frames)


def feet_error_cm(fit: TrackFit, take: WorldTake, person: TruePerson, fps: float) -> float:
    """How far (cm, median) a track's lower sole is from the true surface the person stands on, over
    the frames its true foot is planted."""
    _, true = _sole_heights_m(fit, take.camera, person.spec.support_m)
    world = camera_to_world(person.cam_m[:, ANKLES], take.camera.height_m, 0.0, take.camera.pitch_deg)
    feet = planted_feet(world, fps)
    planted = (feet[:, 0] | feet[:, 1])[np.clip(fit.frames, 0, len(world) - 1)]
    return float(100.0 * np.median(np.abs(true[planted]))) if planted.any() else float("nan")


def score_moving(db: MotionDatabase, take: WorldTake, scored: WorldTake, config: WorldConfig,
                 camera_height_m: float | None = None) -> dict[str, list[float]]:
    """``take`` run as ``reconstruct`` runs it (the camera height given or None), scored against
    ``scored``'s people (the reference camera's truth): each person's root error (m, median over its track's frames) and
    feet error (cm), and the world's pitch and roll errors (degrees)."""
    fits, world, _, _ = run_take(db, take, camera_height_m, config)
    owners = match_tracks(fits, take.people, config.focal_px, config.image_size)
    roots, feet = [], []
    for index, person in enumerate(scored.people):
        mine = [fit for fit, owner in zip(fits, owners) if owner == index]
        if mine:
            main = max(mine, key=lambda fit: len(fit.frames))
            roots.append(score_person(person, main, scored.camera)["root_error_m"])
            feet.append(feet_error_cm(main, scored, person, config.fps))
    return {"root_m": roots, "feet_cm": feet, "pitch_deg": [abs(world.pitch_deg - scored.camera.pitch_deg)],
            "roll_deg": [abs(world.roll_deg)]}
