"""`mocapdb stereo`: two uncalibrated cameras' OpenPose JSON → 3D motion (ElliPose), JSON lines and BVH.

Steps: load both folders (frame-synchronised, same frame count) → find everyone seen by both views
(:mod:`mocapdb.stereo.people`: 2D tracks per view, matched by epipolar consistency over time) →
:func:`mocapdb.stereo.ellipsoid.reconstruct` on all of them stacked along time (relative camera pose from the
bodies, ellipsoid correction) → each person triangulated with those cameras and given its own
bone-length consistency → metres → ``result.jsonl`` (runtime schema, camera-aligned
frame of camera 1, one track per person), ``cameras.json`` and one BVH per person (universal rig by
:func:`mocapdb.core.skeleton.retarget`, one levelled y-up world for all). Output contract:
``data_specs/stream_output.md``; method: ``../shared/method/ellipose_stereo.md``; decisions:
``data_specs/stereo.md``.
"""
from __future__ import annotations

import json
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mocapdb.core.cameras import CameraModel
from mocapdb.core.clips import leg_scale
from mocapdb.core.files import os_error_message, write_atomic
from mocapdb.core.formats.bvh import write_bvh
from mocapdb.core.formats.keypoints import KeypointFrame, read_openpose_folder
from mocapdb.core.geometry import matrix_to_quat, quat_to_matrix
from mocapdb.core.outputs import PersonPose, frame_line, header_line, universal_bvh
from mocapdb.core.skeleton import KP, PELVIS, head_from_torso, retarget, swing_matrices
from mocapdb.stereo.ellipsoid import (
    BEHIND_REFUSED,
    BEHIND_WARNED,
    RIGID_BONES,
    StereoConfig,
    StereoError,
    StereoResult,
    behind_cameras,
    behind_message,
    reconstruct,
    refine_bone_lengths,
    triangulate,
)
from mocapdb.stereo.people import (  # noqa: F401
    MAX_EPIPOLAR_PX,
    MIN_PERSON_FRAMES,
    MIN_SHARED_JOINTS,
    People,
    Selection,
    match_people,
    sampson_distance,
)

MAX_GAP_S = 0.5  # the BVH interpolates gaps up to this long linearly; longer ones hold the last pose

# Views (x right, y down, z forward: OpenCV camera 1) to the output frames.
CAMERA_ALIGNED = np.diag([1.0, -1.0, 1.0])  # x right, y up, z away from the camera
VIEW_FRAME = np.diag([1.0, -1.0, -1.0])     # x right, y up, z towards the camera (right-handed)

RESULT_FILE, CAMERAS_FILE, BVH_FILE = "result.jsonl", "cameras.json", "stereo.bvh"


def bvh_name(track: int) -> str:
    """The BVH of a track: ``stereo.bvh`` for the main person (track 0), ``stereo_track_<id>.bvh`` for the others."""
    return BVH_FILE if track == 0 else f"stereo_track_{track}.bvh"


@dataclass
class StereoSummary:
    """What `mocapdb stereo` did: frames, people, dropped frames and why, the camera fit, times (s)."""

    frames: int
    dropped: dict[str, list[int]]  # frames where nobody is reconstructed, by reason
    epsilons: list[float]
    kept_round: int
    rotation_deg: float
    baseline: float
    scaled: bool
    scale_source: str
    warnings: list[str]
    seconds: dict[str, float]
    outputs: list[Path]
    tracks: list[dict]             # per person: track, frames, first, last, correspondences, bvh
    unmatched: list[str]           # detections that are no person, per view

    def report(self) -> str:
        """Human-readable lines for the command line."""
        n_dropped = sum(len(v) for v in self.dropped.values())
        lines = [f"frames {self.frames}, with a person {self.frames - n_dropped}, without {n_dropped}; "
                 f"people {len(self.tracks)}"]
        lines += [f"  track {t['track']}: {t['frames']} frames ({t['first_frame']}–{t['last_frame']}), "
                  f"{t['correspondences']} joints seen by both views, BVH {t['bvh'] or 'none'}" for t in self.tracks]
        lines += [f"  no person in {len(frames)}: {why} (frames {_listed(frames)})"
                  for why, frames in self.dropped.items()]
        lines += [f"  not a person: {line}" for line in self.unmatched]
        eps = ", ".join(f"{e:.4f}" for e in self.epsilons) or "none"
        lines.append(f"ellipsoid ε per round: {eps}; kept round {self.kept_round}")
        lines.append(f"camera 2 relative to camera 1: rotation {self.rotation_deg:.2f}°, "
                     f"baseline {self.baseline:.3f} m ({self.scale_source})")
        lines += [f"warning: {w}" for w in self.warnings]
        lines += [f"  {stage:<12} {sec:8.3f} s" for stage, sec in self.seconds.items()]
        lines.append(f"  {'total':<12} {sum(self.seconds.values()):8.3f} s")
        lines.append("wrote " + ", ".join(str(p) for p in self.outputs))
        return "\n".join(lines)


def _listed(frames: list[int], most: int = 10) -> str:
    return ", ".join(map(str, frames[:most])) + (", ..." if len(frames) > most else "")


# --------------------------------------------------------------------------- loading

def load_views(view1: str | Path, view2: str | Path, layout: str | None = None,
               trim: bool = False) -> tuple[list[KeypointFrame], list[KeypointFrame], list[str]]:
    """Both folders' frames; StereoError when their frame counts differ (unless ``trim``), when
    they are the same folder, or when they hold the same keypoints (:func:`check_distinct_views`).

    ``trim`` cuts both to the shorter, assuming they start together; the warning says so.
    """
    if _same_folder(view1, view2):
        raise StereoError(f"view 1 and view 2 are the same folder ({view1}): the same view twice has no "
                          "parallax, so no depth can be recovered; give the folders of two different cameras")
    frames1, frames2 = _read_view(view1, layout), _read_view(view2, layout)
    warnings = []
    if len(frames1) != len(frames2):
        counts = f"view 1 ({view1}) has {len(frames1)} frames, view 2 ({view2}) has {len(frames2)}"
        if not trim:
            raise StereoError(f"{counts}: the views must be synchronised frame by frame (same start, same "
                              "frame rate; a different frame rate gives a different count for the same take). "
                              "--trim cuts both to the shorter if they start together")
        n = min(len(frames1), len(frames2))
        frames1, frames2 = frames1[:n], frames2[:n]
        warnings.append(f"{counts}; trimmed both to the first {n}")
    check_distinct_views(frames1, frames2, view1, view2)
    return frames1, frames2, warnings


def _same_folder(a: str | Path, b: str | Path) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:  # one is missing: reading it says so
        return Path(a).resolve() == Path(b).resolve()


def _read_view(folder: str | Path, layout: str | None) -> list[KeypointFrame]:
    try:
        return list(read_openpose_folder(folder, layout))
    except OSError as exc:
        raise StereoError(os_error_message(exc, folder, "read the keypoint folder")) from None


# Two views are the same when, in at least SAME_VIEW_FRAMES of the frames where both have people,
# every person of each view has a twin in the other whose joints (≥ 3 confident in both) lie within
# SAME_VIEW_SHARE of its box diagonal (median). Two cameras set apart never give that: parallax
# moves the joints of a body by different amounts.
SAME_VIEW_SHARE = 0.02
SAME_VIEW_FRAMES = 0.95


def same_view_frames(frames1: list[KeypointFrame], frames2: list[KeypointFrame],
                     confidence: float = 0.3) -> tuple[int, int]:
    """(frames whose people are the same in both views, frames with people in both views)."""
    same = both = 0
    for f1, f2 in zip(frames1, frames2):
        people1, people2 = _confident(f1, confidence), _confident(f2, confidence)
        if not people1 or not people2:
            continue
        both += 1
        share = np.full((len(people1), len(people2)), np.inf)
        for i, (x1, v1, diagonal) in enumerate(people1):
            for j, (x2, v2, _) in enumerate(people2):
                common = v1 & v2
                if common.sum() >= 3:
                    share[i, j] = np.median(np.linalg.norm(x1[common] - x2[common], axis=-1)) / diagonal
        twins = share <= SAME_VIEW_SHARE
        same += bool(twins.any(axis=1).all() and twins.any(axis=0).all())
    return same, both


def _confident(frame: KeypointFrame, confidence: float) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """Each person with ≥ 3 confident joints: points, confident mask, box diagonal (≥ 1 px)."""
    out = []
    for person in frame.people:
        ok = (person.confidence >= confidence) & np.isfinite(person.points_px).all(axis=-1)
        if ok.sum() >= 3:
            pts = person.points_px[ok]
            out.append((person.points_px, ok, max(float(np.linalg.norm(pts.max(axis=0) - pts.min(axis=0))), 1.0)))
    return out


def check_distinct_views(frames1: list[KeypointFrame], frames2: list[KeypointFrame], view1: str | Path = "view 1",
                         view2: str | Path = "view 2") -> None:
    """StereoError when the two views hold the same keypoints (:func:`same_view_frames`)."""
    same, both = same_view_frames(frames1, frames2)
    if both and same >= SAME_VIEW_FRAMES * both:
        raise StereoError(
            f"view 1 ({view1}) and view 2 ({view2}) hold the same keypoints: every person is at the same place "
            f"in both (within {100 * SAME_VIEW_SHARE:g} % of its size) in {same} of the {both} frames with people "
            "in both. The same view twice has no parallax, so no depth can be recovered; give the keypoints of "
            "two different cameras")


# --------------------------------------------------------------------------- people

def select_people(frames1: list[KeypointFrame], frames2: list[KeypointFrame], cam1: CameraModel,
                  cam2: CameraModel, config: StereoConfig) -> Selection:
    """The main person (track 0: the most joints seen by both views) of :func:`match_people`;
    ``dropped`` lists the frames where nobody is reconstructed."""
    return _require_people(match_people(frames1, frames2, cam1, cam2, config)).persons[0]


def _require_people(people: People) -> People:
    if not people.persons:
        raise StereoError(f"no person is seen consistently by both cameras in {MIN_PERSON_FRAMES} frames or more "
                          f"({'; '.join(people.unmatched) or 'no detections'})")
    return people


def estimate_cameras(people: People, cam1: CameraModel, cam2: CameraModel, config: StereoConfig) -> StereoResult:
    """Camera 2's pose from every person's correspondences: :func:`mocapdb.stereo.ellipsoid.reconstruct` on
    the people stacked one after the other along time (one essential matrix and one ellipsoid
    per bone type for all; each person's stage 3 is :func:`person_points`)."""
    stacked = [np.concatenate([getattr(p, name) for p in people.persons]) for name in ("x1", "c1", "x2", "c2")]
    return reconstruct(*stacked, cam1, cam2, config)


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


# --------------------------------------------------------------------------- 3D output

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


def complete_head(points_m: np.ndarray, warnings: list[str]) -> np.ndarray:
    """``points_m [T, 15, 3]`` (metres) with a head that no frame has put on the torso, and a warning."""
    if not np.isnan(points_m[:, KP["head"]]).all():
        return points_m
    warnings.append("no frame has the head in both views: the head follows the torso (rest pose)")
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
class Motion:
    """One person's reconstruction in output form (metres)."""

    track: int
    joints_aligned: np.ndarray  # [T, 15, 3] camera-aligned frame of camera 1, NaN where not measured
    present: np.ndarray         # [T] the person is written for the frame
    quats_view: np.ndarray      # [T, R, 4] local rotations, root relative to the view frame (NaN: no skeleton)
    quats_world: np.ndarray     # [T, R, 4] the same, root relative to the levelled BVH world
    pelvis_aligned: np.ndarray  # [T, 3] the (gap-filled) pelvis, camera-aligned frame
    pelvis_world: np.ndarray    # [T, 3] the same in the BVH world
    fitted: bool                # the skeleton was fitted (else: joints only, no BVH)
    warnings: list[str]         # what the inverse kinematics had to assume


def make_world(points: np.ndarray, valid: np.ndarray, filled: np.ndarray, scaled: bool) -> World:
    """Scale and levelling from the main person's 15 points (``filled``: gap-filled)."""
    scale, source = 1.0, "scaled to the given camera distance"
    if not scaled:
        scale = leg_scale(filled)
        source = "no camera distance given: metres assume the universal leg length (of track 0)"
    return World(level_rotation(points @ VIEW_FRAME, valid) @ VIEW_FRAME, scale, source)


def to_motion(points_m: np.ndarray, valid14: np.ndarray, fps: float, scaled: bool, track: int = 0,
              world: World | None = None) -> tuple[Motion, World]:
    """Metres, pelvis, gap filling, levelling and inverse kinematics on the universal rig.

    ``points_m [T, 14, 3]``, ``valid14 [T, 14]``; ``world`` None: made from this person (the main one).
    """
    points, valid = with_pelvis(points_m, valid14 & np.isfinite(points_m).all(axis=-1))
    present = valid.any(axis=1)
    if not present.any():
        raise StereoError(f"track {track}: no frame could be reconstructed")
    filled = fill_gaps(points, valid, int(round(MAX_GAP_S * fps)))
    require_joints(filled)
    world = world or make_world(points, valid, filled, scaled)
    warnings: list[str] = []
    quats_world, _ = retarget(complete_head(world.scale * filled @ world.bvh_from_camera.T, warnings))
    level = world.bvh_from_camera @ VIEW_FRAME  # VIEW_FRAME is its own inverse
    quats_view = quats_world.copy()
    quats_view[:, 0] = matrix_to_quat(level.T @ quat_to_matrix(quats_world[:, 0]))
    pelvis = world.scale * filled[:, PELVIS]
    return Motion(track, world.scale * points @ CAMERA_ALIGNED, present, quats_view, quats_world,
                  pelvis @ CAMERA_ALIGNED, pelvis @ world.bvh_from_camera.T, True, warnings), world


def joints_only(points_m: np.ndarray, valid14: np.ndarray, track: int, world: World, why: str) -> Motion:
    """A person the skeleton cannot be fitted to: measured joints only (no rotations, no BVH)."""
    points, valid = with_pelvis(points_m, valid14 & np.isfinite(points_m).all(axis=-1))
    nan_quats = np.full((len(points), 11, 4), np.nan)
    pelvis = world.scale * points[:, PELVIS]
    return Motion(track, world.scale * points @ CAMERA_ALIGNED, valid.any(axis=1), nan_quats, nan_quats,
                  pelvis @ CAMERA_ALIGNED, pelvis @ world.bvh_from_camera.T, False,
                  [f"{why}: no BVH, joints only in {RESULT_FILE}"])


def people_motions(people: People, result: StereoResult, cam1: CameraModel, cam2: CameraModel,
                   config: StereoConfig, fps: float) -> tuple[list[Motion], World]:
    """Every person's Motion in one world (the main person's: levelling, and the scale without a
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


def _result_lines(motions: list[Motion], fps: float) -> str:
    lines = [header_line(fps)]
    for t in range(len(motions[0].present)):
        poses = [PersonPose(m.track, m.joints_aligned[t], m.quats_view[t], m.pelvis_aligned[t], None)
                 for m in motions if m.present[t]]
        lines.append(frame_line(t, t / fps, poses))
    return "\n".join(lines) + "\n"


def _camera_record(cam: CameraModel, rotation: np.ndarray, translation: np.ndarray) -> dict:
    return {"name": cam.name, "size": list(cam.size), "K": np.asarray(cam.K).tolist(),
            "dist": np.asarray(cam.dist).ravel().tolist(), "R": rotation.tolist(), "t": translation.tolist()}


def rotation_angle_deg(rotation: np.ndarray) -> float:
    """Angle of a rotation matrix, degrees."""
    return float(np.degrees(np.arccos(np.clip((np.trace(rotation) - 1) / 2, -1.0, 1.0))))


def track_records(people: People, motions: list[Motion]) -> list[dict]:
    """Per person: track id, frames written, first and last, joints seen by both views, BVH file."""
    records = []
    for person, m in zip(people.persons, motions):
        frames = np.flatnonzero(m.present)
        first, last = (int(frames[0]), int(frames[-1])) if len(frames) else (None, None)
        records.append({"track": m.track, "frames": len(frames), "first_frame": first, "last_frame": last,
                        "correspondences": person.correspondences,
                        "bvh": bvh_name(m.track) if m.fitted else None})
    return records


def _cameras_json(cam1: CameraModel, cam2: CameraModel, result: StereoResult, world: World, people: People,
                  tracks: list[dict], warnings: list[str]) -> str:
    t = np.asarray(result.t, dtype=np.float64) * world.scale
    record = {
        "frame": "camera 1 (OpenCV: x right, y down, z forward), metres; x2 = R x1 + t",
        "cameras": [_camera_record(cam1, np.eye(3), np.zeros(3)), _camera_record(cam2, np.asarray(result.R), t)],
        "baseline_m": float(np.linalg.norm(t)), "scaled": bool(result.scaled), "scale_source": world.scale_source,
        "rotation_deg": rotation_angle_deg(np.asarray(result.R)),
        "camera_source": "all people's correspondences (tracks stacked along time)",
        "epsilons": [float(e) for e in result.epsilons], "kept_round": int(result.kept_round),
        "warnings": warnings, "dropped_frames": people.dropped, "tracks": tracks, "not_people": people.unmatched,
        "bvh_from_camera1": world.bvh_from_camera.tolist(),
    }
    return "{\n" + ",\n".join(f"  {json.dumps(k)}: {json.dumps(v)}" for k, v in record.items()) + "\n}\n"


def _check_out_dir(out_dir: str | Path) -> None:
    """StereoError before any work when ``out_dir`` exists and is no folder."""
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise StereoError(f"{out}: the output (--out) exists and is not a folder")


def _write_outputs(out_dir: str | Path, motions: list[Motion], world: World, cameras_json: str,
                   fps: float) -> list[Path]:
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise StereoError(os_error_message(exc, out, "create the output folder")) from None
    paths = [out / RESULT_FILE, out / CAMERAS_FILE]
    try:
        write_atomic(paths[0], _result_lines(motions, fps))
        write_atomic(paths[1], cameras_json)
        for m in motions:
            if m.fitted:
                paths.append(out / bvh_name(m.track))
                write_bvh(paths[-1], universal_bvh(m.quats_world, m.pelvis_world, fps))
    except OSError as exc:
        raise StereoError(os_error_message(exc, out, "write the output")) from None
    return paths


def run_stereo(view1_dir: str | Path, view2_dir: str | Path, cam1: CameraModel, cam2: CameraModel,
               config: StereoConfig, fps: float, out_dir: str | Path, layout: str | None = None,
               trim: bool = False) -> StereoSummary:
    """Reconstruct everyone two cameras see; writes ``result.jsonl``, ``cameras.json`` and one BVH
    per person (:func:`bvh_name`).

    ``cam1``, ``cam2``: intrinsics and distortion (their extrinsics are not used). ``fps`` (Hz)
    times the frames. Raises StereoError, CalibrationError or KeypointError with a clear message.
    """
    if not (np.isfinite(fps) and fps > 0):
        raise StereoError(f"frame rate {fps!r} is not a positive number of frames per second")
    _check_out_dir(out_dir)
    seconds: dict[str, float] = {}
    clock = time.perf_counter()

    def lap(stage: str) -> None:
        nonlocal clock
        now = time.perf_counter()
        seconds[stage], clock = now - clock, now

    frames1, frames2, warnings = load_views(view1_dir, view2_dir, layout, trim)
    lap("load")
    people = _require_people(match_people(frames1, frames2, cam1, cam2, config))
    lap("select")
    result = estimate_cameras(people, cam1, cam2, config)
    warnings += list(result.warnings)
    lap("reconstruct")
    motions, world = people_motions(people, result, cam1, cam2, config, fps)
    warnings += [w for m in motions for w in m.warnings]
    lap("ik")
    tracks = track_records(people, motions)
    paths = _write_outputs(out_dir, motions, world, _cameras_json(cam1, cam2, result, world, people, tracks,
                                                                   warnings), fps)
    lap("write")
    return StereoSummary(len(frames1), people.dropped, [float(e) for e in result.epsilons],
                         int(result.kept_round), rotation_angle_deg(np.asarray(result.R)),
                         float(np.linalg.norm(result.t)) * world.scale, bool(result.scaled),
                         world.scale_source, warnings, seconds, paths, tracks, people.unmatched)


# --------------------------------------------------------------------------- command line


