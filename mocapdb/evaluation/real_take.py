"""The one-camera engine on a real body: each camera of a calibrated Pose2Sim take run alone and
scored against the take's multi-camera triangulation (its TRC).

A take is a folder holding ``calibration.toml`` (Pose2Sim/OpenCV, z-up world, metres),
``triangulated_4cam.trc`` (the reference, metres) and ``openpose_body25b/camNN_json`` (OpenPose
frames of camera ``cam_NN``). Per camera the engine runs refined (the default) and as published
(``--no-refine``), each with nothing given (a 1.75 m body assumed) and, refined only (the floor
needs the tilt estimate), with the camera's height above the floor given; refined with nothing given
also as the default stream sends it (the online take at lag 0: ``stream, lag 0``).

Frames. The engine's output is in the camera-aligned frame (x right, y up, z away from the
camera, origin the camera centre); the OpenCV camera frame has y down; the calibration's
extrinsics take it to the world (z up); Pose2Sim writes the TRC y-up with its axes turned:
TRC (X, Y, Z) = world (Y, Z, X) (:data:`TRC_FROM_WORLD`, found by projecting the TRC through
every camera onto its OpenPose keypoints: this map lands within about 10 px, every other
proper axis permutation 300 px or more away; ``tests/test_real_take.py`` checks it).

Floor. TRC y is the world's vertical; the floor is taken level (the planted ankles of the three
stances of the balancing take lie within 2 cm of one height over 0.9 m) at the median height of
the lowest foot keypoint (big toe, small toe or heel) of each foot while the TRC's ankle is
planted (:func:`mocapdb.evaluation.metrics.planted_feet`): the keypoints' own height above the
sole (a centimetre or two) is not taken off. A camera's height is its centre's TRC y above it.

The engine models each camera as a pinhole with the principal point at the image centre, focal
length the mean of fx and fy, and no lens distortion; the calibration's own principal point and
distortion are not given to it. :func:`pinhole_offset` measures the offset per camera (on this
take 6-31 px, nearly all the principal point: 1-6 cm at the body). It does not matter here:
remapping the keypoints onto the engine's pinhole (undistorted, principal point moved to the
centre) changed MPJPE by at most 0.3 cm, PA-MPJPE by 0.1 cm and the root by at most 2 cm.
"""
from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from mocapdb.core.cameras import CameraModel, camera_from_intrinsics, read_calibration_toml
from mocapdb.core.errors import UsageError
from mocapdb.core.formats.database import MotionDatabase
from mocapdb.core.formats.keypoints import KeypointFrame
from mocapdb.core.formats.openpose import read_openpose_folder
from mocapdb.core.formats.take import TAKE_FILE, read_take, resolve_camera
from mocapdb.core.formats.trc import Trc, read_trc, trc_keypoints
from mocapdb.core.outputs import TrackRecording
from mocapdb.core.skeleton import MEASURED_BONE_NAMES, N_KEYPOINTS_2D, N_POINTS, PELVIS, bone_lengths_m
from mocapdb.evaluation.engine_runs import stream_config
from mocapdb.evaluation.metrics import foot_height_error_m, foot_skating_mps, pa_mpjpe, planted_feet
from mocapdb.evaluation.reconstruction import (
    ANKLES,
    BELOW_HEAD,
    BODY_BONES,
    TAKE_VARIANT,
    stream_variant,
    variant_config,
)
from mocapdb.evaluation.world_camera import camera_checks, format_rows, score_camera, summary_lines
from mocapdb.runtime.engine import Engine
from mocapdb.runtime.engine_config import EngineConfig
from mocapdb.runtime.online_take import OnlineParams, OnlineTake
from mocapdb.runtime.take import take_joints
from mocapdb.runtime.world.fuse import fit_take_world, fit_takes

TRC_FROM_WORLD = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])  # trc = TRC_FROM_WORLD @ world
Y_DOWN = np.array([1.0, -1.0, 1.0])  # camera-aligned (y up) ↔ OpenCV camera (y down), either way
FOOT_MARKERS = ("BigToe", "SmallToe", "Heel")  # Pose2Sim's foot markers, after "R" or "L"
# (variant, size mode, EngineConfig.refine, camera height given)
RUNS = (("refined", "nothing_given", True, False), ("refined", "camera_height_given", True, True),
        ("published", "nothing_given", False, False))
TARGET_PA_MPJPE_CM = 7.0
TARGET_MPJPE_CM = 10.0
TARGET_BONE_CM = 2.0
TARGET_ROOT_M = 0.3        # with the camera height given
TARGET_ROOT_PCT = 10.0     # of the camera-to-pelvis distance, nothing given


@dataclass
class Take:
    """A calibrated take: cameras, the reference keypoints ``truth [F, 15, 3]`` (TRC frame, metres),
    each camera's OpenPose frames, the frame rate (Hz) and the floor's TRC y (metres)."""

    cameras: dict[str, CameraModel]
    truth: np.ndarray
    frames: dict[str, list[KeypointFrame]]
    fps: float
    floor_y_m: float


def world_to_trc(points_m: np.ndarray) -> np.ndarray:
    """Calibration-world points ``[..., 3]`` (z up, metres) in the TRC's axes (y up)."""
    return np.asarray(points_m, dtype=np.float64) @ TRC_FROM_WORLD.T


def trc_to_world(points_m: np.ndarray) -> np.ndarray:
    """TRC points ``[..., 3]`` (y up, metres) in the calibration world's axes (z up)."""
    return np.asarray(points_m, dtype=np.float64) @ TRC_FROM_WORLD


def camera_to_trc(points_m: np.ndarray, cam: CameraModel) -> np.ndarray:
    """Camera-aligned points ``[..., 3]`` (x right, y up, z away from ``cam``, metres) in the TRC frame."""
    return world_to_trc((np.asarray(points_m, dtype=np.float64) * Y_DOWN - cam.t) @ cam.R)


def floor_height_m(trc: Trc) -> float:
    """The floor's TRC y (metres): median of the lowest foot marker of each planted foot (above)."""
    missing = [s + m for s in "RL" for m in FOOT_MARKERS if s + m not in trc.markers]
    if missing:
        raise UsageError(f"{trc.source}: no foot marker {', '.join(missing)}: cannot find the floor")
    feet = trc.positions[:, [[trc.markers.index(s + m) for m in FOOT_MARKERS] for s in "RL"], 1]  # [F, 2, 3]
    planted = planted_feet(trc_keypoints(trc)[:, ANKLES], trc.rate_hz)
    if not planted.any():
        raise UsageError(f"{trc.source}: no planted foot: cannot find the floor")
    return float(np.median(np.nanmin(feet, axis=-1)[planted]))


def camera_height_m(cam: CameraModel, floor_y_m: float) -> float:
    """Height (metres) of the camera centre above the floor at TRC y ``floor_y_m``."""
    return float(world_to_trc(cam.center_m)[1] - floor_y_m)


def focal_px(cam: CameraModel) -> float:
    """The engine's focal length for ``cam``: the mean of fx and fy (pixels)."""
    return float((cam.K[0, 0] + cam.K[1, 1]) / 2.0)


def load_take(folder: str | Path, names: Sequence[str] | None = None) -> Take:
    """The take in ``folder`` (cameras ``names``, default all); UsageError naming what is missing, or
    a camera folder's ``take.json`` whose frame rate or image size contradicts the TRC's rate or the
    calibration's size (the calibration and the TRC are what is used; a take's focal is not)."""
    folder = Path(folder)
    files = [folder / "calibration.toml", folder / "triangulated_4cam.trc"]
    for path in files:
        if not path.is_file():
            raise UsageError(f"{folder}: no {path.name} (a Pose2Sim take: calibration.toml, "
                             f"triangulated_4cam.trc, openpose_body25b/camNN_json)")
    cameras = read_calibration_toml(files[0])
    unknown = sorted(set(names or ()) - set(cameras))
    if unknown:
        raise UsageError(f"camera {', '.join(unknown)} is not in {files[0]} ({', '.join(cameras)})")
    cameras = {n: cameras[n] for n in (names or sorted(cameras))}
    folders = {n: folder / "openpose_body25b" / f"cam{n[-2:]}_json" for n in cameras}
    for n, path in folders.items():
        if not path.is_dir():
            raise UsageError(f"{folder}: no OpenPose folder {path.relative_to(folder)} for camera {n}")
    trc = read_trc(files[1])
    for n, path in folders.items():  # a take.json (when `mocapdb detect` wrote the folder) must agree
        resolve_camera(read_take(path), str(path / TAKE_FILE), trc.rate_hz, cameras[n].size, None,
                       {"fps": f"the rate of {files[1]}", "image_size": f"the image size of {n} in {files[0]}"})
    frames = {n: list(read_openpose_folder(path, fps=trc.rate_hz)) for n, path in folders.items()}
    for n, camera_frames in frames.items():
        if len(camera_frames) != len(trc.positions):
            raise UsageError(f"{folders[n]}: {len(camera_frames)} frames, but {files[1].name} has "
                             f"{len(trc.positions)}: the take's frames must correspond one to one")
    return Take(cameras, trc_keypoints(trc), frames, trc.rate_hz, floor_height_m(trc))


def engine_config(base: EngineConfig, cam: CameraModel, fps: float, refine: bool,
                  camera_height: float | None = None) -> EngineConfig:
    """``base`` for ``cam`` (its focal length and image size, ``fps`` Hz) as variant ``refine``
    (:func:`~mocapdb.evaluation.reconstruction.variant_config`), with ``camera_height`` (metres) or
    not; the refined variant keeps its per-frame fits for the whole take."""
    cfg = replace(base, fps=fps, focal_px=focal_px(cam), image_size=(cam.size[0], cam.size[1]),
                  camera_height_m=None)
    return replace(variant_config(cfg, refine), camera_height_m=camera_height, keep_take=refine)


def run_camera(db: MotionDatabase, frames: list[KeypointFrame], config: EngineConfig, lag: int | None = None
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, list[TrackRecording]]:
    """The person's joints ``[F, 15, 3]`` (camera-aligned, metres; NaN where it has no output), body
    heights ``[F]`` (metres) and, when ``config.keep_take``, the whole-take fit's joints ``[F, 15, 3]``
    (else None): the longest track that is not static (a false detection that never moves is); all
    NaN when there is none. Last, every track's recording (for the take's world). ``lag``: the
    engine's poses through the online take at that lag (frames; the default stream), else as they come."""
    engine = Engine(db, config)
    online = None if lag is None else OnlineTake(config.fps, OnlineParams(lag_frames=lag),
                                                 (config.focal_px, *config.center_px))
    joints: dict[int, np.ndarray] = {}
    heights: dict[int, np.ndarray] = {}
    due: list = []
    for i, frame in enumerate(frames):
        poses = engine.step(frame)
        due += [(i, 0.0, poses)] if online is None else online.push(i, 0.0, poses)
    for i, _, poses in due + ([] if online is None else online.flush()):
        for pose in poses:
            if pose.track not in joints:
                joints[pose.track] = np.full((len(frames), N_POINTS, 3), np.nan)
                heights[pose.track] = np.full(len(frames), np.nan)
            joints[pose.track][i], heights[pose.track][i] = pose.joints_m, pose.height_m
    finished = engine.finish()
    recordings = {r.track: r for r in finished}
    moving = [t for t in joints if not recordings[t].static]
    empty = np.full((len(frames), N_POINTS, 3), np.nan)
    if not moving:
        return empty, np.full(len(frames), np.nan), empty if config.keep_take else None, finished
    track = max(moving, key=lambda t: np.isfinite(heights[t]).sum())
    whole = None
    if config.keep_take:
        fitted = fit_takes([recordings[track]], config.fps, camera_height_m=config.camera_height_m)[0]
        index, take_joints_m, _ = take_joints(fitted, config.fps)
        keep = (index >= 0) & (index < len(frames))
        whole = empty.copy()
        whole[index[keep]] = take_joints_m[keep]
    return joints[track], heights[track], whole, finished


def score(pred: np.ndarray, truth: np.ndarray, camera_centre: np.ndarray, fps: float) -> dict:
    """Figures of ``pred`` against ``truth`` (both ``[F, 15, 3]`` TRC frame, metres, y up; ``pred`` NaN
    where it has no output), the camera centre ``[3]`` (TRC frame) and the rate ``fps`` (Hz):
    MPJPE (pelvis-aligned) and PA-MPJPE over the 13 joints below the head (cm), root error (m, % of
    the camera-to-pelvis distance), bone lengths (medians over the frames scored, cm), foot skating where
    the truth's ankles are planted (cm/s) and planted-foot height error (cm; negative: too low)."""
    ok = np.isfinite(pred).all(axis=(1, 2)) & np.isfinite(truth).all(axis=(1, 2))
    p, t = pred[ok], truth[ok]
    rel_p, rel_t = p - p[:, PELVIS:PELVIS + 1], t - t[:, PELVIS:PELVIS + 1]
    root = np.linalg.norm(p[:, PELVIS] - t[:, PELVIS], axis=-1)
    distance = np.linalg.norm(t[:, PELVIS] - camera_centre, axis=-1)
    bones_p, bones_t = (np.median(bone_lengths_m(x), axis=0) if len(x) else np.full(len(MEASURED_BONE_NAMES), np.nan)
                        for x in (p, t))
    bone_err = dict(zip(MEASURED_BONE_NAMES, 100 * np.abs(bones_p - bones_t)))
    planted = planted_feet(truth[:, ANKLES], fps)
    skate = foot_skating_mps(pred[:, ANKLES], planted, fps)
    height = foot_height_error_m(pred[:, ANKLES], truth[:, ANKLES], planted)
    return {
        "frames": len(pred), "frames_with_output": int(ok.sum()),
        "mpjpe_cm": _mean(100 * np.linalg.norm(rel_p - rel_t, axis=-1)[:, BELOW_HEAD]),
        "pa_mpjpe_cm": _mean(100 * pa_mpjpe(p[:, BELOW_HEAD], t[:, BELOW_HEAD])) if len(p) else np.nan,
        "root_error_m": _mean(root), "root_error_pct_distance": _mean(100 * root / distance),
        "camera_to_pelvis_m": _mean(distance),
        "bone_length_cm": {"output": dict(zip(MEASURED_BONE_NAMES, 100 * bones_p)),
                           "truth": dict(zip(MEASURED_BONE_NAMES, 100 * bones_t)), "error": bone_err,
                           "mean_error_7": float(np.mean([bone_err[MEASURED_BONE_NAMES[b]] for b in BODY_BONES]))},
        "foot_skating_cm_per_s": {"mean": _mean(100 * skate), "median": _median(100 * skate)},
        "planted_foot_height_error_cm": {"mean": _mean(100 * height), "mean_abs": _mean(100 * np.abs(height))},
    }


def _mean(values: np.ndarray) -> float:
    return float(np.mean(values)) if np.size(values) else float("nan")


def _median(values: np.ndarray) -> float:
    return float(np.median(values)) if np.size(values) else float("nan")


def pinhole_offset(cam: CameraModel, points_world: np.ndarray) -> dict[str, float]:
    """How far the engine's camera model (principal point at the image centre, :func:`focal_px`, no
    distortion) puts world points ``[..., 3]`` (metres) from where the calibrated ``cam`` sees them:
    median and largest distance (px), the distortion's share alone (median px), and the median
    distance as a shift at each point's depth (cm)."""
    w = np.asarray(points_world, dtype=np.float64).reshape(-1, 3)
    engine_cam = replace(camera_from_intrinsics(focal_px(cam), (cam.size[0] / 2, cam.size[1] / 2), cam.size),
                         R=cam.R, t=cam.t)
    px = cam.project(w)
    offset = np.linalg.norm(engine_cam.project(w) - px, axis=-1)
    distortion = np.linalg.norm(replace(cam, dist=np.zeros(4)).project(w) - px, axis=-1)
    depth = (w @ cam.R.T + cam.t)[:, 2]
    return {"median_px": _median(offset), "max_px": float(offset.max()), "distortion_median_px": _median(distortion),
            "median_cm_at_depth": _median(100 * offset * depth / focal_px(cam))}


def evaluate_real_take(db: MotionDatabase, folder: str | Path, base: EngineConfig | None = None,
                       cameras: Sequence[str] | None = None) -> dict:
    """Every camera (``cameras``, default all) of the take in ``folder`` alone through the engine
    (``base`` settings) in each of :data:`RUNS`, scored against the TRC: a JSON-able dict, per camera
    its height (m), focal length (px), :func:`pinhole_offset` and ``runs[variant][size mode]``."""
    take = load_take(folder, cameras)
    base = base or EngineConfig()
    per_camera: dict[str, dict] = {}
    report = {"take": str(folder), "frames": len(take.truth), "fps": take.fps, "floor_y_m": take.floor_y_m,
              "axes": "TRC (X, Y, Z) = calibration world (Y, Z, X): y up", "cameras": per_camera}
    for name, cam in take.cameras.items():
        height = camera_height_m(cam, take.floor_y_m)
        runs: dict[str, dict[str, dict]] = {}  # variant: size mode: figures
        per_camera[name] = {
            "camera_height_m": height, "focal_px": focal_px(cam),
            "pinhole_offset": pinhole_offset(cam, trc_to_world(take.truth[:, :N_KEYPOINTS_2D])), "runs": runs}
        centre = world_to_trc(cam.center_m)
        for variant, mode, refine, given in RUNS:
            config = engine_config(base, cam, take.fps, refine, height if given else None)
            joints, heights, _, recordings = run_camera(db, take.frames[name], replace(config, keep_take=False))
            whole = None
            if refine:   # the track files as reconstruct writes them
                _, _, whole, recordings = run_camera(db, take.frames[name], config.for_track_files())
            if refine and not given:   # the world's camera, as reconstruct finds it with nothing given
                per_camera[name]["world_camera"] = score_camera(fit_take_world(recordings, take.fps).world, cam)
                # the default stream, as live sends it
                stream, sizes, _, _ = run_camera(db, take.frames[name], stream_config(config), lag=0)
                result = score(camera_to_trc(stream, cam), take.truth, centre, take.fps)
                result["body_height_m"] = _median(sizes[np.isfinite(sizes)])
                runs.setdefault(stream_variant(0), {})[mode] = result
            body_height = _median(heights[np.isfinite(heights)])
            outputs = [(variant, joints)] + ([(TAKE_VARIANT, whole)] if whole is not None else [])
            for label, points in outputs:
                result = score(camera_to_trc(points, cam), take.truth, centre, take.fps)
                result["body_height_m"] = body_height
                runs.setdefault(label, {})[mode] = result
    return report


def _runs(report: dict) -> Iterator[tuple[str, str, str, dict]]:
    """(camera, variant, size mode, figures) of every run of ``report``."""
    for camera, entry in report["cameras"].items():
        for variant, modes in entry["runs"].items():
            for mode, r in modes.items():
                yield camera, variant, mode, r


def _cell(value: float, digits: int = 1) -> str:
    return "–" if value is None or not np.isfinite(value) else f"{value:.{digits}f}"


def format_table(report: dict) -> str:
    """A markdown table of ``report`` (:func:`evaluate_real_take`): a row per camera, variant and size mode."""
    lines = [("| camera | variant | size | height used | frames | MPJPE | PA-MPJPE | root error | root / distance | "
              "bone error (7) | skating mean / median | planted-foot height |"),
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for camera, variant, mode, r in _runs(report):
        size = "camera height " + _cell(report["cameras"][camera]["camera_height_m"], 2) + " m" \
            if mode == "camera_height_given" else "nothing (1.75 m)"
        skate = r["foot_skating_cm_per_s"]
        lines.append(
            f"| {camera} | {variant} | {size} | {_cell(r['body_height_m'], 2)} m | "
            f"{r['frames_with_output']}/{r['frames']} | "
            f"{_cell(r['mpjpe_cm'])} cm | {_cell(r['pa_mpjpe_cm'])} cm | {_cell(r['root_error_m'], 2)} m | "
            f"{_cell(r['root_error_pct_distance'])} % | {_cell(r['bone_length_cm']['mean_error_7'])} cm | "
            f"{_cell(skate['mean'])} / {_cell(skate['median'])} cm/s | "
            f"{_cell(r['planted_foot_height_error_cm']['mean'])} cm |")
    offsets = ", ".join(f"{c} {_cell(e['pinhole_offset']['median_px'])} px ≈ "
                        f"{_cell(e['pinhole_offset']['median_cm_at_depth'])} cm"
                        for c, e in report["cameras"].items())
    lines += ["", (f"Floor at TRC y = {report['floor_y_m']:.3f} m. The engine's pinhole (centred principal point, "
                   f"no distortion) against the calibration, median over the TRC keypoints: {offsets}.")]
    cameras = {c: e["world_camera"] for c, e in report["cameras"].items()}
    lines += ["", "The world's camera (nothing given; truth: the calibration, floor z = 0):", ""]
    return "\n".join(lines + format_rows(cameras) + [""] + summary_lines(cameras))


def check_lines(report: dict) -> list[str]:
    """A PASS/FAIL line per target and variant/size mode: the mean over the cameras (worst camera named)."""
    targets = [("PA-MPJPE", "cm", TARGET_PA_MPJPE_CM, lambda r: r["pa_mpjpe_cm"], None),
               ("MPJPE", "cm", TARGET_MPJPE_CM, lambda r: r["mpjpe_cm"], None),
               ("bone length error (mean of 7 bones)", "cm", TARGET_BONE_CM,
                lambda r: r["bone_length_cm"]["mean_error_7"], None),
               ("root error", "m", TARGET_ROOT_M, lambda r: r["root_error_m"], "camera_height_given"),
               ("root error", "% of the distance", TARGET_ROOT_PCT, lambda r: r["root_error_pct_distance"],
                "nothing_given")]
    lines = []
    variants = [(v, m) for v, m, _, _ in RUNS] + [(TAKE_VARIANT, m) for v, m, refine, _ in RUNS if refine]
    for variant, mode in variants:
        runs = [(c, r) for c, v, m, r in _runs(report) if (v, m) == (variant, mode)]
        for label, unit, target, value, only in targets:
            if only not in (None, mode) or not runs:
                continue
            values = np.array([value(r) for _, r in runs], dtype=np.float64)
            worst = int(np.argmax(np.where(np.isnan(values), np.inf, values)))
            mean = float(np.mean(values))
            ok = bool(np.isfinite(mean) and mean <= target)
            lines.append(f"{'PASS' if ok else 'FAIL'}  {variant}, {mode.replace('_', ' ')}: {label} {_cell(mean, 2)} "
                         f"{unit} ≤ {target:g} {unit} (mean of {len(runs)} cameras; worst {runs[worst][0]} "
                         f"{_cell(values[worst], 2)})")
    return lines + camera_checks({c: e["world_camera"] for c, e in report["cameras"].items()})
