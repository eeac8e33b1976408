"""`mocapdb stereo`: two uncalibrated cameras' OpenPose JSON → 3D motion (ElliPose), JSON lines and BVH.

Steps: load both folders (frame-synchronised, same frame count) → choose per frame the person pair
that agrees across the views (epipolar test) → :func:`mocapdb.stereo.reconstruct` (relative camera
pose from the body, ellipsoid correction, bone-length consistency) → metres → ``result.jsonl``
(runtime schema, camera-aligned frame of camera 1), ``cameras.json`` and ``stereo.bvh`` (universal
rig by :func:`mocapdb.skeleton.retarget`, levelled y-up world). Output contract:
``data_specs/stream_output.md``; method: ``../shared/method/ellipose_stereo.md``.
"""
from __future__ import annotations

import argparse
import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from runtime.engine import PersonPose
from runtime.output import frame_line, header_line

from .builder import _leg_scale
from .bvh import write_atomic, write_bvh
from .cameras import CameraModel, camera_from_intrinsics, read_calibration_toml
from .geometry import matrix_to_quat, quat_to_matrix
from .keypoints import LAYOUTS, KeypointFrame, read_openpose_folder
from .skeleton import KP, N_KEYPOINTS_2D, PELVIS, head_from_torso, retarget, swing_matrices, universal_bvh
from .stereo import ESSENTIAL_METHOD, StereoConfig, StereoError, StereoResult, reconstruct

# Person selection. A pair (person in view 1, person in view 2) is consistent when at least
# MIN_SHARED_JOINTS joints are confident in both and the median of their first-order epipolar
# (Sampson) distances is at most MAX_EPIPOLAR_PX. Distances are measured in undistorted normalised
# coordinates and multiplied by the mean focal length of the two cameras (≈ pixels). On the
# Pose2Sim take (f ≈ 1680 px) the true pairs' medians are 2-17 px (median 4-6 px), while a false
# person paired with the true one in the other view lies 18-300 px off.
MIN_SHARED_JOINTS = 6
MAX_EPIPOLAR_PX = 20.0
MAX_GAP_S = 0.5  # the BVH interpolates gaps up to this long linearly; longer ones hold the last pose

# Views (x right, y down, z forward: OpenCV camera 1) to the output frames.
CAMERA_ALIGNED = np.diag([1.0, -1.0, 1.0])  # x right, y up, z away from the camera
VIEW_FRAME = np.diag([1.0, -1.0, -1.0])     # x right, y up, z towards the camera (right-handed)

RESULT_FILE, CAMERAS_FILE, BVH_FILE = "result.jsonl", "cameras.json", "stereo.bvh"


@dataclass
class Selection:
    """One person per view and frame: ``x [T, 14, 2]`` pixels (NaN when missing), ``c [T, 14]``."""

    x1: np.ndarray
    c1: np.ndarray
    x2: np.ndarray
    c2: np.ndarray
    kept: np.ndarray         # [T] bool: a consistent pair was found
    distance_px: np.ndarray  # [T] median epipolar distance of the chosen pair (NaN when dropped)
    dropped: dict[str, list[int]] = field(default_factory=dict)  # reason → frame indices


@dataclass
class StereoSummary:
    """What `mocapdb stereo` did: frames, dropped frames and why, the camera fit, times (s)."""

    frames: int
    dropped: dict[str, list[int]]
    epsilons: list[float]
    kept_round: int
    rotation_deg: float
    baseline: float
    scaled: bool
    scale_source: str
    warnings: list[str]
    seconds: dict[str, float]
    outputs: list[Path]

    def report(self) -> str:
        """Human-readable lines for the command line."""
        n_dropped = sum(len(v) for v in self.dropped.values())
        lines = [f"frames {self.frames}, reconstructed {self.frames - n_dropped}, dropped {n_dropped}"]
        lines += [f"  dropped {len(frames)}: {why} (frames {_listed(frames)})" for why, frames in self.dropped.items()]
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
    """Both folders' frames; StereoError when their frame counts differ (unless ``trim``).

    ``trim`` cuts both to the shorter, assuming they start together; the warning says so.
    """
    frames1 = list(read_openpose_folder(view1, layout))
    frames2 = list(read_openpose_folder(view2, layout))
    if len(frames1) == len(frames2):
        return frames1, frames2, []
    counts = f"view 1 ({view1}) has {len(frames1)} frames, view 2 ({view2}) has {len(frames2)}"
    if not trim:
        raise StereoError(f"{counts}: the views must be synchronised frame by frame (same start, same "
                          "frame rate; a different frame rate gives a different count for the same take). "
                          "--trim cuts both to the shorter if they start together")
    n = min(len(frames1), len(frames2))
    return frames1[:n], frames2[:n], [f"{counts}; trimmed both to the first {n}"]


# --------------------------------------------------------------------------- person selection

def _candidates(frames: list[KeypointFrame], threshold: float) -> tuple[np.ndarray, ...]:
    """Every person with a confident joint, flattened: frame ``[N]``, points ``[N, 14, 2]``,
    visibility ``[N, 14]``, confidence ``[N, 14]`` and prominence ``[N]``."""
    people = [(t, p) for t, f in enumerate(frames) for p in f.people]
    frame = np.array([i for i, _ in people], dtype=np.int64)
    points = np.array([p.points_px for _, p in people]).reshape(-1, N_KEYPOINTS_2D, 2)
    conf = np.array([p.confidence for _, p in people]).reshape(-1, N_KEYPOINTS_2D)
    vis = (conf >= threshold) & (conf > 0) & np.isfinite(points).all(axis=-1)
    keep = vis.any(axis=1)
    frame, points, conf, vis = frame[keep], points[keep], conf[keep], vis[keep]
    return frame, points, vis, conf, _prominence(points, vis, conf)


def _prominence(points: np.ndarray, vis: np.ndarray, conf: np.ndarray) -> np.ndarray:
    """Sum of confident confidences times the diagonal of their box (px): big, clear people first."""
    xy = np.where(vis[..., None], points, np.nan)
    diag = np.linalg.norm(np.fmax.reduce(xy, axis=1) - np.fmin.reduce(xy, axis=1), axis=-1)
    return np.where(vis, conf, 0.0).sum(axis=1) * np.nan_to_num(diag)


def _first_per_frame(frame: np.ndarray, *keys: np.ndarray) -> np.ndarray:
    """Index of the entry sorting first by ``keys`` (first key first, ascending) in each frame present."""
    order = np.lexsort(tuple(reversed(keys)) + (frame,))
    _, first = np.unique(frame[order], return_index=True)
    return order[first]


def _normalised(cam: CameraModel, points: np.ndarray) -> np.ndarray:
    """Undistorted normalised coordinates of ``[N, 14, 2]`` pixels (NaN stays NaN)."""
    flat = points.reshape(-1, 2)
    ok = np.isfinite(flat).all(axis=1)
    out = np.full_like(flat, np.nan)
    if ok.any():
        out[ok] = np.asarray(cam.undistort_normalized(flat[ok])).reshape(-1, 2)
    return out.reshape(points.shape)


def _essential_guess(n1: np.ndarray, n2: np.ndarray, config: StereoConfig) -> np.ndarray:
    """Essential matrix by RANSAC from normalised correspondences ``[N, 2]``."""
    if len(n1) < max(8, config.min_correspondences):
        raise StereoError(f"only {len(n1)} keypoint correspondences between the views' most prominent "
                          f"people (need {max(8, config.min_correspondences)}): too few frames or joints "
                          "seen by both cameras")
    essential, _ = cv2.findEssentialMat(n1, n2, np.eye(3), method=ESSENTIAL_METHOD, prob=config.ransac_prob,
                                        threshold=config.ransac_threshold)
    if essential is None or essential.shape[0] < 3:
        raise StereoError("no essential matrix fits the two views' keypoints: are both folders the same take?")
    return essential[:3]


def sampson_distance(essential: np.ndarray, n1: np.ndarray, n2: np.ndarray) -> np.ndarray:
    """First-order geometric (Sampson) distance ``[...]`` of normalised correspondences ``[..., 2]``."""
    h1 = np.concatenate([n1, np.ones(n1.shape[:-1] + (1,))], axis=-1)
    h2 = np.concatenate([n2, np.ones(n2.shape[:-1] + (1,))], axis=-1)
    e1 = h1 @ essential.T          # E x1
    e2 = h2 @ essential            # Eᵀ x2
    num = np.sum(h2 * e1, axis=-1)
    den = e1[..., 0] ** 2 + e1[..., 1] ** 2 + e2[..., 0] ** 2 + e2[..., 1] ** 2
    return np.abs(num) / np.sqrt(np.maximum(den, 1e-30))


def _pairs(frame1: np.ndarray, frame2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every (view-1 person, view-2 person) index pair of the same frame."""
    by_frame2: dict[int, list[int]] = {}
    for j, f in enumerate(frame2.tolist()):
        by_frame2.setdefault(f, []).append(j)
    pairs = [(i, j) for i, f in enumerate(frame1.tolist()) for j in by_frame2.get(f, [])]
    arr = np.array(pairs, dtype=np.int64).reshape(-1, 2)
    return arr[:, 0], arr[:, 1]


def select_people(frames1: list[KeypointFrame], frames2: list[KeypointFrame], cam1: CameraModel,
                  cam2: CameraModel, config: StereoConfig) -> Selection:
    """Per frame, the person pair that agrees across the views (see :data:`MAX_EPIPOLAR_PX`).

    An essential matrix is first fitted by RANSAC to the most prominent person of each view in
    every frame. A pair is consistent when the median Sampson distance over its shared confident
    joints is small; each frame keeps its most prominent consistent pair (a static false person
    seen by both cameras is consistent too, so the smallest distance alone is not the rule).
    Frames with no consistent pair are dropped (NaN, confidence 0) and listed by reason; frame
    indices are kept.
    """
    n_frames = len(frames1)
    f1, p1, v1, c1, prom1 = _candidates(frames1, config.confidence)
    f2, p2, v2, c2, prom2 = _candidates(frames2, config.confidence)
    n1, n2 = _normalised(cam1, p1), _normalised(cam2, p2)
    main1, main2 = _first_per_frame(f1, -prom1), _first_per_frame(f2, -prom2)
    both = np.intersect1d(f1[main1], f2[main2])
    a, b = main1[np.isin(f1[main1], both)], main2[np.isin(f2[main2], both)]
    shared = v1[a] & v2[b]
    essential = _essential_guess(n1[a][shared], n2[b][shared], config)

    i, j = _pairs(f1, f2)
    shared = v1[i] & v2[j]
    focal = float(np.mean([cam1.K[0, 0], cam1.K[1, 1], cam2.K[0, 0], cam2.K[1, 1]]))
    dist = np.where(shared, sampson_distance(essential, np.nan_to_num(n1[i]), np.nan_to_num(n2[j])) * focal, np.nan)
    enough = shared.sum(axis=1) >= MIN_SHARED_JOINTS
    median = np.full(len(i), np.inf)
    if enough.any():
        median[enough] = np.nanmedian(dist[enough], axis=1)
    rank = np.where(median <= MAX_EPIPOLAR_PX, -(prom1[i] + prom2[j]), np.inf)
    best = _first_per_frame(f1[i], rank, median)
    return _selection(n_frames, (f1, f2), (i[best], j[best]), median[best], (p1, p2), (c1, c2))


def _selection(n_frames: int, frames: tuple[np.ndarray, np.ndarray], chosen: tuple[np.ndarray, np.ndarray],
               median: np.ndarray, points: tuple[np.ndarray, np.ndarray],
               conf: tuple[np.ndarray, np.ndarray]) -> Selection:
    """Arrays of the chosen pairs, and the dropped frames by reason."""
    (f1, f2), (i, j) = frames, chosen
    ok = median <= MAX_EPIPOLAR_PX
    t = f1[i]
    x1 = np.full((n_frames, N_KEYPOINTS_2D, 2), np.nan)
    x2 = x1.copy()
    cc1, cc2 = np.zeros((n_frames, N_KEYPOINTS_2D)), np.zeros((n_frames, N_KEYPOINTS_2D))
    x1[t[ok]], cc1[t[ok]] = points[0][i[ok]], conf[0][i[ok]]
    x2[t[ok]], cc2[t[ok]] = points[1][j[ok]], conf[1][j[ok]]
    kept = np.zeros(n_frames, dtype=bool)
    kept[t[ok]] = True
    distance = np.full(n_frames, np.nan)
    distance[t[ok]] = median[ok]
    everyone = np.arange(n_frames)
    reasons = {
        "no person in view 1": np.setdiff1d(everyone, f1),
        "no person in view 2": np.setdiff1d(np.intersect1d(everyone, f1), f2),
        f"no pair with {MIN_SHARED_JOINTS} joints confident in both views": t[np.isinf(median)],
        f"no pair within {MAX_EPIPOLAR_PX:g} px of the epipolar geometry": t[np.isfinite(median) & ~ok],
    }
    dropped = {why: sorted(int(f) for f in frames_) for why, frames_ in reasons.items() if len(frames_)}
    return Selection(x1, np.where(np.isfinite(x1).all(-1), cc1, 0.0), x2,
                     np.where(np.isfinite(x2).all(-1), cc2, 0.0), kept, distance, dropped)


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
class Motion:
    """The reconstruction in output form (metres)."""

    joints_aligned: np.ndarray  # [T, 15, 3] camera-aligned frame of camera 1, NaN where not measured
    present: np.ndarray         # [T] a person is written for the frame
    quats_view: np.ndarray      # [T, R, 4] local rotations, root relative to the view frame
    quats_world: np.ndarray     # [T, R, 4] the same, root relative to the levelled BVH world
    pelvis_aligned: np.ndarray  # [T, 3] the (gap-filled) pelvis, camera-aligned frame
    pelvis_world: np.ndarray    # [T, 3] the same in the BVH world
    bvh_from_camera: np.ndarray  # [3, 3] OpenCV camera-1 axes → BVH world axes
    scale: float                # metres per reconstruction unit
    scale_source: str
    warnings: list[str]         # what the inverse kinematics had to assume


def to_motion(result: StereoResult, kept: np.ndarray, fps: float) -> Motion:
    """Metres, pelvis, gap filling, levelling and inverse kinematics on the universal rig."""
    valid14 = result.valid & kept[:, None] & np.isfinite(result.points_m).all(axis=-1)
    points, valid = with_pelvis(result.points_m, valid14)
    present = valid.any(axis=1)
    if not present.any():
        raise StereoError("no frame could be reconstructed")
    filled = fill_gaps(points, valid, int(round(MAX_GAP_S * fps)))
    require_joints(filled)
    scale, source = 1.0, "scaled to the given camera distance"
    if not result.scaled:
        scale = _leg_scale(filled)
        source = "no camera distance given: metres assume the universal leg length"
    level = level_rotation(points @ VIEW_FRAME, valid)
    bvh_from_camera = level @ VIEW_FRAME
    warnings: list[str] = []
    quats_world, _ = retarget(complete_head(scale * filled @ bvh_from_camera.T, warnings))
    root = level.T @ quat_to_matrix(quats_world[:, 0])
    quats_view = quats_world.copy()
    quats_view[:, 0] = matrix_to_quat(root)
    return Motion(scale * points @ CAMERA_ALIGNED, present, quats_view, quats_world,
                  scale * filled[:, PELVIS] @ CAMERA_ALIGNED, scale * filled[:, PELVIS] @ bvh_from_camera.T,
                  bvh_from_camera, scale, source, warnings)


def _result_lines(motion: Motion, fps: float) -> str:
    lines = [header_line(fps)]
    for t in range(len(motion.present)):
        poses = [PersonPose(0, motion.joints_aligned[t], motion.quats_view[t], motion.pelvis_aligned[t], None)] \
            if motion.present[t] else []
        lines.append(frame_line(t, t / fps, poses))
    return "\n".join(lines) + "\n"


def _camera_record(cam: CameraModel, rotation: np.ndarray, translation: np.ndarray) -> dict:
    return {"name": cam.name, "size": list(cam.size), "K": np.asarray(cam.K).tolist(),
            "dist": np.asarray(cam.dist).ravel().tolist(), "R": rotation.tolist(), "t": translation.tolist()}


def rotation_angle_deg(rotation: np.ndarray) -> float:
    """Angle of a rotation matrix, degrees."""
    return float(np.degrees(np.arccos(np.clip((np.trace(rotation) - 1) / 2, -1.0, 1.0))))


def _cameras_json(cam1: CameraModel, cam2: CameraModel, result: StereoResult, motion: Motion,
                  selection: Selection, warnings: list[str]) -> str:
    t = np.asarray(result.t, dtype=np.float64) * motion.scale
    record = {
        "frame": "camera 1 (OpenCV: x right, y down, z forward), metres; x2 = R x1 + t",
        "cameras": [_camera_record(cam1, np.eye(3), np.zeros(3)), _camera_record(cam2, np.asarray(result.R), t)],
        "baseline_m": float(np.linalg.norm(t)), "scaled": bool(result.scaled), "scale_source": motion.scale_source,
        "rotation_deg": rotation_angle_deg(np.asarray(result.R)),
        "epsilons": [float(e) for e in result.epsilons], "kept_round": int(result.kept_round),
        "warnings": warnings, "dropped_frames": selection.dropped,
        "bvh_from_camera1": motion.bvh_from_camera.tolist(),
    }
    return "{\n" + ",\n".join(f"  {json.dumps(k)}: {json.dumps(v)}" for k, v in record.items()) + "\n}\n"


def run_stereo(view1_dir: str | Path, view2_dir: str | Path, cam1: CameraModel, cam2: CameraModel,
               config: StereoConfig, fps: float, out_dir: str | Path, layout: str | None = None,
               trim: bool = False) -> StereoSummary:
    """Reconstruct a take seen by two cameras; writes ``result.jsonl``, ``cameras.json``, ``stereo.bvh``.

    ``cam1``, ``cam2``: intrinsics and distortion (their extrinsics are not used). ``fps`` (Hz)
    times the frames. Raises StereoError, CalibrationError or KeypointError with a clear message.
    """
    if not (np.isfinite(fps) and fps > 0):
        raise StereoError(f"frame rate {fps!r} is not a positive number of frames per second")
    seconds: dict[str, float] = {}
    clock = time.perf_counter()

    def lap(stage: str) -> None:
        nonlocal clock
        now = time.perf_counter()
        seconds[stage], clock = now - clock, now

    frames1, frames2, warnings = load_views(view1_dir, view2_dir, layout, trim)
    lap("load")
    selection = select_people(frames1, frames2, cam1, cam2, config)
    lap("select")
    result = reconstruct(selection.x1, selection.c1, selection.x2, selection.c2, cam1, cam2, config)
    warnings += list(result.warnings)
    lap("reconstruct")
    motion = to_motion(result, selection.kept, fps)
    warnings += motion.warnings
    lap("ik")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / RESULT_FILE, out / CAMERAS_FILE, out / BVH_FILE]
    write_atomic(paths[0], _result_lines(motion, fps))
    write_atomic(paths[1], _cameras_json(cam1, cam2, result, motion, selection, warnings))
    write_bvh(paths[2], universal_bvh(motion.quats_world, motion.pelvis_world, fps))
    lap("write")
    return StereoSummary(len(frames1), selection.dropped, [float(e) for e in result.epsilons],
                         int(result.kept_round), rotation_angle_deg(np.asarray(result.R)),
                         float(np.linalg.norm(result.t)) * motion.scale, bool(result.scaled),
                         motion.scale_source, warnings, seconds, paths)


# --------------------------------------------------------------------------- command line

def intrinsics_only(cam: CameraModel) -> CameraModel:
    """``cam`` with its extrinsics dropped (identity pose): the stereo fit estimates them."""
    return CameraModel(np.asarray(cam.K), np.asarray(cam.dist), np.eye(3), np.zeros(3), tuple(cam.size), cam.name)


def cameras_from_args(args: argparse.Namespace) -> tuple[CameraModel, CameraModel]:
    """The two cameras' intrinsics from ``--calibration``/``--cameras`` or ``--focal``/``--size``."""
    if args.calibration:
        cams = read_calibration_toml(args.calibration)
        names = args.cameras or (list(cams) if len(cams) == 2 else None)
        if names is None:
            raise StereoError(f"{args.calibration} holds {len(cams)} cameras ({', '.join(cams)}): "
                              "name two with --cameras")
        missing = [n for n in names if n not in cams]
        if missing:
            raise StereoError(f"{args.calibration} has no camera {', '.join(missing)} (it has {', '.join(cams)})")
        return intrinsics_only(cams[names[0]]), intrinsics_only(cams[names[1]])
    if args.focal is None or args.size is None:
        raise StereoError("give the intrinsics: --calibration FILE.toml --cameras NAME1 NAME2, "
                          "or --focal F --size W H [--center CX CY]")
    size = (int(args.size[0]), int(args.size[1]))
    center = tuple(args.center) if args.center else (size[0] / 2, size[1] / 2)
    return tuple(camera_from_intrinsics(args.focal, center, size) for _ in range(2))  # type: ignore[return-value]


def add_stereo_parser(sub: argparse._SubParsersAction) -> None:
    """Add the ``stereo`` subcommand (``run`` returns the exit code)."""
    p = sub.add_parser(
        "stereo", help="two uncalibrated cameras' 2D keypoints → 3D motion (ElliPose), JSON lines and BVH",
        description="Reconstruct one person filmed by two synchronised cameras whose relative pose is unknown: "
                    "the camera pose is estimated from the body itself (ElliPose: triangulation, ellipsoid "
                    "correction, bone-length consistency). Writes OUT/result.jsonl (camera-aligned frame of "
                    "camera 1), OUT/cameras.json (both cameras, the estimated relative pose) and OUT/stereo.bvh "
                    "(universal rig, y up). Intrinsics are needed; with --calibration only the intrinsics and "
                    "distortion of the two named cameras are used, never their extrinsics.")
    p.add_argument("view1", help="folder of OpenPose JSON frames from camera 1 (the output's reference)")
    p.add_argument("view2", help="folder of OpenPose JSON frames from camera 2 (same frames, same rate)")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--calibration", help="Pose2Sim calibration TOML: intrinsics and distortion of --cameras")
    p.add_argument("--cameras", nargs=2, metavar=("NAME1", "NAME2"),
                   help="section names of the two cameras in --calibration, e.g. cam_01 cam_02")
    p.add_argument("--focal", type=float, help="focal length in pixels (both cameras, no distortion)")
    p.add_argument("--center", type=float, nargs=2, metavar=("CX", "CY"),
                   help="principal point in pixels (default: the image centre)")
    p.add_argument("--size", type=int, nargs=2, metavar=("W", "H"), help="image size in pixels")
    p.add_argument("--camera-distance", type=float, metavar="M",
                   help="distance between the cameras in metres, for metric output (default: metres from the "
                        "universal skeleton's leg length)")
    p.add_argument("--fps", type=float, default=30.0, help="frame rate of both views in Hz (default 30)")
    p.add_argument("--keypoints", choices=tuple(LAYOUTS), help="keypoint layout of the JSON (default: detected)")
    p.add_argument("--trim", action="store_true",
                   help="when the views' frame counts differ, cut both to the shorter (they must start together)")
    p.set_defaults(run=run_stereo_command)


def run_stereo_command(args: argparse.Namespace) -> int:
    """``mocapdb stereo``: run and print the summary (user errors are reported by the CLI, exit 2)."""
    cam1, cam2 = cameras_from_args(args)
    config = StereoConfig(camera_distance_m=args.camera_distance)
    summary = run_stereo(args.view1, args.view2, cam1, cam2, config, args.fps, args.out, args.keypoints, args.trim)
    print(summary.report())
    return 0
