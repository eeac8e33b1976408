"""`mocapdb stereo`'s people in 3D: triangulation under the estimated cameras, then motion.

Each person is triangulated with the cameras of the reconstruction and given its own bone-length
consistency (:func:`person_points`), checked to be in front of the cameras (:func:`in_front_check`),
then turned into output form (:func:`to_motion`): pelvis, gaps filled, metres, one levelled y-up
world for everyone (the main person's, :class:`World`), inverse kinematics on the universal rig
(:func:`mocapdb.core.motion_ops.from_points`): a :class:`~mocapdb.core.motion.Motion` in that world.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from mocapdb.core.cameras import CameraModel
from mocapdb.core.clips import leg_scale
from mocapdb.core.geometry import matrix_to_quat, quat_to_matrix
from mocapdb.core.motion import Motion
from mocapdb.core.motion_ops import from_points
from mocapdb.core.skeleton import KP, N_RIG_JOINTS, PELVIS, head_from_torso, swing_matrices
from mocapdb.stereo.bone_lengths import RIGID_BONES, refine_bone_lengths
from mocapdb.stereo.checks import BEHIND_REFUSED, BEHIND_WARNED, behind_cameras, behind_message
from mocapdb.stereo.config import RESULT_FILE, StereoConfig, StereoError, StereoResult
from mocapdb.stereo.people import People, Selection
from mocapdb.stereo.relative_pose import triangulate

MAX_GAP_S = 0.5  # the BVH interpolates gaps up to this long linearly; longer ones hold the last pose

# Views (x right, y down, z forward: OpenCV camera 1) to the output frames.
CAMERA_ALIGNED = np.diag([1.0, -1.0, 1.0])  # x right, y up, z away from the camera
VIEW_FRAME = np.diag([1.0, -1.0, -1.0])     # x right, y up, z towards the camera (right-handed)


def person_points(result: StereoResult, person: Selection, cam1: CameraModel, cam2: CameraModel,
                  config: StereoConfig) -> tuple[np.ndarray, np.ndarray]:
    """A person's joints ``[T, 14, 3]`` and validity ``[T, 14]`` under the cameras of ``result``:
    DLT triangulation, then stage 3 (bone-length consistency) with the person's own bone lengths.
    A joint is valid exactly when both views see it (confidence ≥ threshold) in a kept frame."""
    valid = ((person.c1 >= config.confidence) & (person.c2 >= config.confidence) & person.kept[:, None]
             & np.isfinite(person.x1).all(axis=-1) & np.isfinite(person.x2).all(axis=-1))
    n1, n2 = np.zeros(person.x1.shape), np.zeros(person.x2.shape)
    if valid.any():
        n1[valid], n2[valid] = cam1.undistort_normalized(person.x1[valid]), cam2.undistort_normalized(person.x2[valid])
    scale = config.camera_distance_m or 1.0
    P1, P2 = np.hstack([np.eye(3), np.zeros((3, 1))]), np.hstack([result.R, result.t.reshape(3, 1) / scale])
    points = np.zeros(valid.shape + (3,))
    if valid.any():
        points[valid] = triangulate(P1, P2, n1[valid], n2[valid])
    final = refine_bone_lengths(points, P1, P2, n1, n2, valid, RIGID_BONES, config.alpha, config.bone_rounds)
    return final * scale, valid


def with_pelvis(points: np.ndarray, valid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``[T, 14, 3]`` keypoints and validity → the 15 universal points, pelvis = mid-hip."""
    pelvis = 0.5 * (points[:, KP["r_hip"]] + points[:, KP["l_hip"]])
    ok = valid[:, KP["r_hip"]] & valid[:, KP["l_hip"]]
    valid15 = np.concatenate([valid, ok[:, None]], axis=1)
    points15 = np.concatenate([points, pelvis[:, None]], axis=1)
    return np.where(valid15[..., None], points15, np.nan), valid15


def fill_gaps(points: np.ndarray, valid: np.ndarray, max_gap: int) -> np.ndarray:
    """Every joint's invalid frames filled: linearly across gaps of at most ``max_gap`` frames,
    else the last valid value (the first one before it). ``points [T, J, 3]``, ``valid [T, J]``.
    A joint that is never valid stays NaN.
    """
    n = len(points)
    t = np.arange(n)[:, None]
    prev = np.maximum.accumulate(np.where(valid, t, -1), axis=0)
    nxt = np.minimum.accumulate(np.where(valid, t, n)[::-1], axis=0)[::-1]
    joint = np.arange(points.shape[1])[None]
    p_prev = points[np.clip(prev, 0, n - 1), joint]
    p_next = points[np.clip(nxt, 0, n - 1), joint]
    short = (prev >= 0) & (nxt < n) & (nxt - prev <= max_gap + 1)
    w = np.where(short, (t - prev) / np.maximum(nxt - prev, 1), 0.0)[..., None]
    held = np.where((prev >= 0)[..., None], p_prev, p_next)
    return np.where(short[..., None], (1 - w) * p_prev + w * p_next, held)


def require_joints(points: np.ndarray) -> None:
    """StereoError naming the joints (other than the head) that no frame of ``points [T, 15, 3]`` has."""
    never = [name for name, k in KP.items() if name != "head" and np.isnan(points[:, k]).all()]
    if never:
        raise StereoError(f"no frame reconstructs {', '.join(never)}: cannot fit the skeleton")


def complete_head(points_m: np.ndarray, notes: list[str]) -> np.ndarray:
    """``points_m [T, 15, 3]`` (metres) with a head that no frame has put on the torso, and a note: the
    output is whole, only the head's own turn is not measured (a view of the back of the head)."""
    if not np.isnan(points_m[:, KP["head"]]).all():
        return points_m
    notes.append("no frame has the head (nose) in both views: the head follows the torso (rest pose)")
    out = points_m.copy()
    out[:, KP["head"]] = head_from_torso(out)
    return out


def level_rotation(points_view: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Smallest rotation ``[3, 3]`` turning the median pelvis → neck direction to +y.

    ``points_view [T, 15, 3]`` in the view frame (y up, so x stays close to the image's right).
    """
    ok = valid[:, PELVIS] & valid[:, KP["neck"]]
    if not ok.any():
        raise StereoError("no frame has both the neck and the hips: cannot tell which way is up")
    up = points_view[ok, KP["neck"]] - points_view[ok, PELVIS]
    up = np.median(up / np.linalg.norm(up, axis=-1, keepdims=True), axis=0)
    return swing_matrices(up / np.linalg.norm(up), np.array([0.0, 1.0, 0.0]))


@dataclass
class World:
    """The output world every person shares: metres and the levelled BVH axes (from the main person)."""

    bvh_from_camera: np.ndarray  # [3, 3] OpenCV camera-1 axes → BVH world axes (y up)
    scale: float                 # metres per reconstruction unit
    scale_source: str


@dataclass
class StereoPerson:
    """One person's reconstruction in output form (metres): its motion in the levelled world (what
    its BVH holds) and what the stream writes per frame, in camera 1's camera-aligned frame."""

    track: int
    motion: Motion | None       # world frame (levelled, y up); None: no skeleton fitted (joints only, no BVH)
    joints_aligned: np.ndarray  # [T, 15, 3] camera-aligned frame of camera 1, NaN where not measured
    present: np.ndarray         # [T] the person is written for the frame
    quats_view: np.ndarray      # [T, R, 4] the motion's rotations, the root's relative to the view frame
    #                             (NaN: no skeleton)
    pelvis_aligned: np.ndarray  # [T, 3] the (gap-filled) pelvis, camera-aligned frame
    warnings: list[str]         # what may make the result wrong
    notes: list[str] = field(default_factory=list)  # what the inverse kinematics assumed where the views are silent

    @property
    def fitted(self) -> bool:
        """Whether the skeleton was fitted (else: joints only, no BVH)."""
        return self.motion is not None


def make_world(points: np.ndarray, valid: np.ndarray, filled: np.ndarray, scaled: bool) -> World:
    """Scale and levelling from the main person's 15 points (``filled``: gap-filled)."""
    scale, source = 1.0, "scaled to the given camera distance"
    if not scaled:
        scale = leg_scale(filled)
        source = "no camera distance given: metres assume the universal leg length (of track 0)"
    return World(level_rotation(points @ VIEW_FRAME, valid) @ VIEW_FRAME, scale, source)


def to_motion(points_m: np.ndarray, valid14: np.ndarray, fps: float, scaled: bool, track: int = 0,
              world: World | None = None) -> tuple[StereoPerson, World]:
    """Metres, pelvis, gap filling, levelling and inverse kinematics on the universal rig.

    ``points_m [T, 14, 3]``, ``valid14 [T, 14]``; ``world`` None: made from this person (the main one).
    """
    points, valid = with_pelvis(points_m, valid14 & np.isfinite(points_m).all(axis=-1))
    present = np.asarray(valid.any(axis=1))
    if not present.any():
        raise StereoError(f"track {track}: no frame could be reconstructed")
    filled = fill_gaps(points, valid, round(MAX_GAP_S * fps))
    require_joints(filled)
    world = world or make_world(points, valid, filled, scaled)
    notes: list[str] = []
    motion, _ = from_points(complete_head(world.scale * filled @ world.bvh_from_camera.T, notes), fps)
    level = world.bvh_from_camera @ VIEW_FRAME  # VIEW_FRAME is its own inverse
    quats_view = motion.rotations.copy()
    quats_view[:, 0] = matrix_to_quat(level.T @ quat_to_matrix(motion.rotations[:, 0]))
    pelvis = world.scale * filled[:, PELVIS]
    motion.root_m = pelvis @ world.bvh_from_camera.T
    return StereoPerson(track, motion, world.scale * points @ CAMERA_ALIGNED, present, quats_view,
                        pelvis @ CAMERA_ALIGNED, [], notes), world


def joints_only(points_m: np.ndarray, valid14: np.ndarray, track: int, world: World, why: str) -> StereoPerson:
    """A person the skeleton cannot be fitted to: measured joints only (no rotations, no BVH)."""
    points, valid = with_pelvis(points_m, valid14 & np.isfinite(points_m).all(axis=-1))
    nan_quats = np.full((len(points), N_RIG_JOINTS, 4), np.nan)
    pelvis = world.scale * points[:, PELVIS]
    return StereoPerson(track, None, world.scale * points @ CAMERA_ALIGNED, np.asarray(valid.any(axis=1)), nan_quats,
                        pelvis @ CAMERA_ALIGNED, [f"{why}: no BVH, joints only in {RESULT_FILE}"])


def people_motions(people: People, result: StereoResult, cam1: CameraModel, cam2: CameraModel,
                   config: StereoConfig, fps: float) -> tuple[list[StereoPerson], World]:
    """Every person's reconstruction in one world (the main person's: levelling, and the scale without a
    camera distance), each triangulated with the cameras of ``result``. A person other than the
    main one whose skeleton cannot be fitted keeps its joints (warning)."""
    main_points, main_valid = person_points(result, people.persons[0], cam1, cam2, config)
    behind = in_front_check(main_points, main_valid, result, people.persons[0].track)
    motion, world = to_motion(main_points, main_valid, fps, bool(result.scaled))
    motion.warnings[:0] = behind
    motions = [motion]
    for person in people.persons[1:]:
        points, valid = person_points(result, person, cam1, cam2, config)
        behind = in_front_check(points, valid, result, person.track)
        try:
            motions.append(to_motion(points, valid, fps, bool(result.scaled), person.track, world)[0])
        except StereoError as exc:
            motions.append(joints_only(points, valid, person.track, world, str(exc)))
        motions[-1].warnings[:0] = behind
    for m in motions:
        m.warnings = [w if m.track == 0 else f"track {m.track}: {w}" for w in m.warnings]
        m.notes = [w if m.track == 0 else f"track {m.track}: {w}" for w in m.notes]
    return motions, world


def in_front_check(points: np.ndarray, valid: np.ndarray, result: StereoResult, track: int) -> list[str]:
    """Warnings when a person's median joint is behind a camera in more than BEHIND_WARNED of its
    frames; for the main person (track 0) StereoError beyond BEHIND_REFUSED (no other person is
    refused: it is written with the warning)."""
    *shares, frames = behind_cameras(points, valid, np.asarray(result.R), np.asarray(result.t))
    warnings = []
    for camera, share in enumerate(shares, start=1):
        if track == 0 and share > BEHIND_REFUSED:
            raise StereoError(behind_message("the main person (track 0)", camera, share, frames,
                                             np.asarray(result.R), np.asarray(result.t)))
        if share > BEHIND_WARNED:
            who = "track 0 (the main person) is behind" if track == 0 else "behind"  # others get "track k: "
            warnings.append(f"{who} camera {camera} in {round(share * frames)} of its {frames} frames: not a person "
                            "both cameras see (a false match?), or a wrong camera estimate")
    return warnings
