"""The live stream against the whole take on a real video (issue 35): what ``mocapdb live`` sends,
frame by frame, scored beside the track files, at several lags.

The reference is the same detector's keypoints on every camera of a calibrated take, triangulated
(:mod:`mocapdb.evaluation.detector_quality`: the main person, DLT over the views that see a joint).
The first camera is run alone through the engine as ``live`` runs it (:class:`~mocapdb.runtime.engine.Engine`
unsmoothed, :func:`~mocapdb.evaluation.engine_runs.stream_config`, then
:class:`~mocapdb.runtime.online_take.OnlineTake`, frame by frame), its output taken to the
calibration's world by that camera's extrinsics. Variants: the per-frame stream (before the online
take: the engine's causal 1€ output), the online take at each lag ``L``, and the whole take (the
track files: :func:`~mocapdb.runtime.world.fuse.fit_takes`). When the keypoints carry the detector's own 3D
(BlazePose's world landmarks, ``data_specs/keypoint_formats.md``), they are scored too as a peer
(:data:`WORLD_LANDMARKS`): per frame, those of the person the main track follows (the nearest in the
image to its keypoints), hips-centred and without a root, so only MPJPE and PA are given for them.

Figures, over the main track (the longest that is not static), beside the published method (the
per-frame engine without its 2D refinement) and the database floor (:func:`floor_cm`):

- **acceleration**: ``|p[t+1] − 2 p[t] + p[t−1]|`` of the 15 output joints in the world (mm/frame²),
  mean and 95th percentile;
- **fastest joint**: the largest frame-to-frame speed of any joint (m/s);
- **planted feet**: where the triangulation's ankles are planted (low-passed at
  :data:`~mocapdb.evaluation.detector_quality.LOW_PASS_HZ`, :func:`~mocapdb.evaluation.metrics.planted_feet`),
  the output ankles' horizontal speed (cm/s, mean) and their 3D displacement per frame (mm/frame,
  mean: the foot sliding WHAM and GVHMR report, on the reference's contact frames);
- **MPJPE** and **PA-MPJPE** (cm) over the 12 joints from shoulders to ankles, pelvis-centred (the
  hips' midpoint) in the world (the camera's extrinsics align them; PA: per frame);
- **latency added**: the lag (``L / fps``) plus the engine's and the online take's compute per frame
  (the detector's not included), p50 and p99 (ms).
"""
from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from mocapdb.core.cameras import CameraModel, read_calibration_toml
from mocapdb.core.errors import UsageError
from mocapdb.core.formats.database import MotionDatabase
from mocapdb.core.formats.keypoints import CONFIDENCE_THRESHOLD, KeypointFrame
from mocapdb.core.formats.openpose import read_openpose_folder
from mocapdb.core.skeleton import KP, N_KEYPOINTS_2D, N_POINTS
from mocapdb.evaluation.detector_quality import low_pass, read_detections, residuals
from mocapdb.evaluation.engine_runs import stream_config
from mocapdb.evaluation.floor import FloorIndex, database_floor
from mocapdb.evaluation.metrics import pa_mpjpe, planted_feet
from mocapdb.evaluation.real_take import Y_DOWN, focal_px, world_to_trc
from mocapdb.runtime.engine import Engine
from mocapdb.runtime.engine_config import EngineConfig
from mocapdb.runtime.online_take import OnlineParams, OnlineTake
from mocapdb.runtime.take import take_joints
from mocapdb.runtime.world.fuse import fit_takes

SCORED = ("r_shoulder", "l_shoulder", "r_elbow", "l_elbow", "r_wrist", "l_wrist",
          "r_hip", "l_hip", "r_knee", "l_knee", "r_ankle", "l_ankle")
PER_FRAME, WHOLE_TAKE = "per-frame stream (before)", "whole take (track files)"
PUBLISHED = "published method (per-frame, no refinement)"
WORLD_LANDMARKS = "BlazePose world landmarks (raw)"
MOTION_FIGURES = ("acceleration_mm_per_frame2", "acceleration_p95_mm_per_frame2", "fastest_joint_mps",
                  "planted_feet_cm_per_s", "foot_sliding_mm_per_frame")   # not given for a pose without a root
LAGS = (0, 3, 6)
# The targets (on the balancing take, camera 1): lag → (acceleration mm/frame², fastest m/s,
# planted cm/s, MPJPE over the whole take's in cm (None: not set))
TARGETS = {6: (4.0, 8.0, 10.0, 1.0), 0: (10.0, 12.0, 25.0, None)}


def reference_joints(folders: list[Path], cams: list[CameraModel], confidence: float = CONFIDENCE_THRESHOLD
                     ) -> tuple[np.ndarray, tuple[str, ...]]:
    """The main person's joints ``[T, J, 3]`` (world, metres; NaN where fewer than two views saw one)
    triangulated from one keypoint folder per camera, and their names."""
    det = read_detections(folders, cams, confidence)
    joints_m, _, _ = residuals(det, cams, confidence)
    return joints_m, det.joints


def camera_to_world(points_m: np.ndarray, cam: CameraModel) -> np.ndarray:
    """Camera-aligned points ``[..., 3]`` (x right, y up, z away, metres) in the calibration's world."""
    return (np.asarray(points_m, dtype=np.float64) * Y_DOWN - cam.t) @ cam.R


def run_variants(db: MotionDatabase, frames: list[KeypointFrame], config: EngineConfig, lags: tuple[int, ...],
                 params: OnlineParams | None = None) -> dict[str, dict]:
    """Each variant's main-track joints ``[T, 15, 3]`` (camera-aligned, NaN where none) and per-frame
    compute times (s): the published method (the per-frame engine without its 2D refinement), the
    per-frame stream and the whole take from one run, the online take at each lag; the detector's
    world landmarks (:func:`world_landmark_joints`) when the frames carry them."""
    out: dict[str, dict] = {}
    published, times, recordings, _ = _run(db, frames, replace(config, refine=False), None)
    out[PUBLISHED] = {"joints": _track_joints(published, _main_track(published, recordings), len(frames)),
                      "compute_s": times, "lag": 0}
    per_frame, times, recordings, keypoints = _run(db, frames, config, None)
    track = _main_track(per_frame, recordings)
    if any(p.world_m is not None for frame in frames for p in frame.people):
        followed = keypoints[track] if track in keypoints else np.full((len(frames), N_KEYPOINTS_2D, 3), np.nan)
        out[WORLD_LANDMARKS] = {"joints": world_landmark_joints(frames, followed), "compute_s": None, "lag": None,
                                "root": False}
    out[PER_FRAME] = {"joints": _track_joints(per_frame, track, len(frames)), "compute_s": times, "lag": 0}
    kept, _, recordings, _ = _run(db, frames, config.for_track_files(), None)   # as reconstruct runs it
    track = _main_track(kept, recordings)
    whole = _empty(len(frames))
    if track is not None:
        fitted = fit_takes([recordings[track]], config.fps)[0]
        index, take_joints_m, _ = take_joints(fitted, config.fps)
        keep = (index >= 0) & (index < len(frames))
        whole[index[keep]] = take_joints_m[keep]
    out[WHOLE_TAKE] = {"joints": whole, "compute_s": None, "lag": None}
    for lag in lags:
        online = OnlineTake(config.fps, replace(params or OnlineParams(), lag_frames=lag),
                            (config.focal_px, *config.center_px))
        joints, times, _, _ = _run(db, frames, stream_config(config), online)
        out[f"online take, L = {lag}"] = {"joints": _track_joints(joints, track, len(frames)), "compute_s": times,
                                          "lag": lag}
    return out


def _run(db: MotionDatabase, frames: list[KeypointFrame], config: EngineConfig, online: OnlineTake | None
         ) -> tuple[dict[int, np.ndarray], np.ndarray, dict, dict[int, np.ndarray]]:
    """Every frame through the engine (and ``online``): each track's joints, each frame's compute
    time (s), the recordings and each track's keypoints ``[T, 14, 3]`` (x px, y px, confidence)."""
    engine = Engine(db, config)
    joints: dict[int, np.ndarray] = {}
    keypoints: dict[int, np.ndarray] = {}
    times = np.zeros(len(frames))
    position = {frame.index: i for i, frame in enumerate(frames)}
    for i, frame in enumerate(frames):
        start = time.perf_counter()
        poses = engine.step(frame)
        due = [(frame.index, 0.0, poses)] if online is None else online.push(frame.index, 0.0, poses)
        times[i] = time.perf_counter() - start
        _store(joints, keypoints, due, position, len(frames))
    if online is not None:
        _store(joints, keypoints, online.flush(), position, len(frames))
    recordings = {r.track: r for r in engine.finish()}
    return joints, times, recordings, keypoints


def _track_joints(joints: dict[int, np.ndarray], track: int | None, n: int) -> np.ndarray:
    """``track``'s joints ``[n, 15, 3]`` (all NaN without it)."""
    return joints[track] if track is not None and track in joints else _empty(n)


def _store(joints: dict[int, np.ndarray], keypoints: dict[int, np.ndarray], due: list, position: dict[int, int],
           n: int) -> None:
    for index, _, people in due:
        for pose in people:
            joints.setdefault(pose.track, _empty(n))[position[index]] = pose.joints_m
            keypoints.setdefault(pose.track, np.full((n, N_KEYPOINTS_2D, 3), np.nan))[position[index]] = \
                pose.keypoints_px


def world_landmark_joints(frames: list[KeypointFrame], followed_px: np.ndarray) -> np.ndarray:
    """The detector's world landmarks of the followed person as output joints ``[T, 15, 3]``
    (camera-aligned: x right, y up, z away; hips-centred, the pelvis the hips' mid-point; NaN where
    none): per frame, the person of ``frames[t]`` nearest in the image (median over the keypoints
    both have) to ``followed_px [T, 14, 3]`` (the track's keypoints, x px, y px, confidence)."""
    out = _empty(len(frames))
    for t, frame in enumerate(frames):
        track = followed_px[t, :, :2]
        people = [p for p in frame.people if p.world_m is not None]
        if not people or not np.isfinite(track).any():
            continue
        gaps = [np.nanmedian(np.linalg.norm(p.points_px - track, axis=-1)) if
                (np.isfinite(p.points_px) & np.isfinite(track)).all(axis=-1).any() else np.inf for p in people]
        if not np.isfinite(min(gaps)):
            continue
        world = people[int(np.argmin(gaps))].world_m
        out[t, :N_KEYPOINTS_2D] = world * Y_DOWN
        out[t, KP["pelvis"]] = (out[t, KP["r_hip"]] + out[t, KP["l_hip"]]) / 2.0
    return out


def _main_track(joints: dict[int, np.ndarray], recordings: dict) -> int | None:
    """The longest track that is not static."""
    moving = [t for t in joints if t in recordings and not recordings[t].static]
    return max(moving, key=lambda t: int(np.isfinite(joints[t][:, 0, 0]).sum())) if moving else None


def _empty(n: int) -> np.ndarray:
    return np.full((n, N_POINTS, 3), np.nan)


def score(pred_world: np.ndarray, truth: np.ndarray, names: tuple[str, ...], planted: np.ndarray, fps: float) -> dict:
    """Figures (module docstring) of ``pred_world [T, 15, 3]`` against ``truth [T, J, 3]`` (world,
    metres; joints ``names``) with the reference's ``planted [T, 2]`` ankles."""
    acc = 1000 * np.linalg.norm(pred_world[2:] - 2 * pred_world[1:-1] + pred_world[:-2], axis=-1)
    speed = np.linalg.norm(np.diff(pred_world, axis=0), axis=-1) * fps
    ankles = pred_world[:, [KP["r_ankle"], KP["l_ankle"]]]
    step = np.diff(ankles, axis=0)
    both = planted[1:] & planted[:-1] & np.isfinite(step).all(axis=-1)
    horizontal = np.linalg.norm(step[..., [0, 1]], axis=-1)[both] * fps   # the world is z-up
    pred = pred_world[:, [KP[j] for j in SCORED]]
    true = truth[:, [names.index(j) for j in SCORED]]
    hips = [SCORED.index("r_hip"), SCORED.index("l_hip")]
    ok = np.isfinite(pred).all(axis=(1, 2)) & np.isfinite(true).all(axis=(1, 2))
    p = pred[ok] - pred[ok][:, hips].mean(axis=1, keepdims=True)
    t = true[ok] - true[ok][:, hips].mean(axis=1, keepdims=True)
    return {"frames_with_output": int(np.isfinite(pred_world).all(axis=(1, 2)).sum()),
            "acceleration_mm_per_frame2": _finite_mean(acc), "acceleration_p95_mm_per_frame2": _finite_pct(acc, 95),
            "fastest_joint_mps": float(np.nanmax(speed)) if np.isfinite(speed).any() else float("nan"),
            "planted_feet_cm_per_s": _finite_mean(100 * horizontal),
            "foot_sliding_mm_per_frame": _finite_mean(1000 * np.linalg.norm(step, axis=-1)[both]),
            "planted_ankle_frames": int(both.sum()),
            "mpjpe_cm": _finite_mean(100 * np.linalg.norm(p - t, axis=-1)),
            "pa_mpjpe_cm": _finite_mean(100 * pa_mpjpe(p, t)) if len(p) else float("nan")}


def floor_cm(db: MotionDatabase, truth: np.ndarray, names: tuple[str, ...]) -> float:
    """The database floor (:mod:`~mocapdb.evaluation.floor`) of the scored joints, hips-centred, mean
    over the frames where the reference has them all (cm): the best database pose under the best
    vertical turn, at the database's size (the engine's 1.75 m). ``truth [T, J, 3]``: world, metres.

    The floor's 15 keypoints are the 12 scored ones and, in the pelvis, neck and head slots, the
    hips' midpoint (on both sides: the centre, and no distance), so its mean over 15 joints is 12/15
    of the mean over the scored ones."""
    true = world_to_trc(truth[:, [names.index(j) for j in SCORED]])            # y up
    true = true[np.isfinite(true).all(axis=(1, 2))]
    if not len(true):
        return float("nan")
    truth15 = _scored_as_keypoints(true)
    base = _scored_as_keypoints(db.positions[:, [KP[j] for j in SCORED]])
    floor = database_floor(FloorIndex.from_positions(base), truth15).mpjpe_m
    return float(100 * floor.mean() * N_POINTS / len(SCORED))


def _scored_as_keypoints(scored: np.ndarray) -> np.ndarray:
    """``[T, 12, 3]`` scored joints as ``[T, 15, 3]`` keypoints, the hips' midpoint in the others' slots."""
    out = np.repeat(scored[:, [SCORED.index("r_hip")]] * 0.5 + scored[:, [SCORED.index("l_hip")]] * 0.5,
                    N_POINTS, axis=1)
    out[:, [KP[j] for j in SCORED]] = scored
    return out


def _finite_mean(values: np.ndarray) -> float:
    v = values[np.isfinite(values)]
    return float(v.mean()) if v.size else float("nan")


def _finite_pct(values: np.ndarray, q: float) -> float:
    v = values[np.isfinite(values)]
    return float(np.percentile(v, q)) if v.size else float("nan")


def evaluate_live(db: MotionDatabase, folders: list[Path], calibration: Path, lags: tuple[int, ...] = LAGS,
                  base: EngineConfig | None = None, names: list[str] | None = None, fps: float | None = None,
                  params: OnlineParams | None = None) -> dict:
    """The live evaluation (module docstring) of ``folders`` (one keypoint folder per camera: the
    calibration's cameras ``names``, default its first ones by name; the first is run) against their
    triangulation: a JSON-able dict. ``fps``: the frame rate where the first folder has no take.json;
    ``params``: the online take's settings (its lag set to each of ``lags``)."""
    cams_by_name = read_calibration_toml(calibration)
    names = list(names or sorted(cams_by_name)[:len(folders)])
    if len(folders) < 2:
        raise UsageError("--live needs at least two cameras' keypoint folders: the first is run, all are triangulated")
    if len(names) != len(folders) or any(n not in cams_by_name for n in names):
        raise UsageError(f"{len(folders)} keypoint folders need as many cameras of {calibration} "
                         f"({', '.join(sorted(cams_by_name))}); got {', '.join(names) or 'none'}")
    cams = [cams_by_name[name] for name in names]
    fps = _fps(folders[0], fps)
    frames = list(read_openpose_folder(folders[0], fps=fps))
    if not frames:
        raise UsageError(f"{folders[0]}: no frames")
    truth, joint_names = reference_joints(folders, cams)
    ankles = [joint_names.index("r_ankle"), joint_names.index("l_ankle")]
    planted = planted_feet(low_pass(world_to_trc(truth[:, ankles]), fps), fps)  # it takes y up
    cam = cams[0]
    config = replace(base or EngineConfig(), fps=fps, focal_px=focal_px(cam), image_size=(cam.size[0], cam.size[1]))
    report: dict = {"camera": cam.name, "fps": fps, "frames": len(frames), "cameras_triangulated": len(cams),
                    "planted_ankle_frames": int(planted.sum()), "variants": {},
                    "database_floor_mpjpe_cm": floor_cm(db, truth, joint_names)}
    for name, run in run_variants(db, frames, config, lags, params).items():
        figures = score(camera_to_world(run["joints"], cam), truth, joint_names, planted, fps)
        if not run.get("root", True):
            figures |= dict.fromkeys(MOTION_FIGURES, float("nan"))
        if run["compute_s"] is not None:
            added = 1000 * (run["lag"] / fps + run["compute_s"])
            figures |= {"lag_frames": run["lag"], "latency_p50_ms": float(np.percentile(added, 50)),
                        "latency_p99_ms": float(np.percentile(added, 99))}
        report["variants"][name] = figures
    return report


def _fps(folder: Path, given: float | None) -> float:
    """The frame rate (Hz): ``given``, else the folder's take.json's."""
    from mocapdb.core.formats.take import read_take

    take = read_take(folder)
    if given is not None:
        return float(given)
    if take is None or take.fps is None:
        raise UsageError(f"{folder}: no take.json with the frame rate: give --fps")
    return float(take.fps)


def format_table(report: dict) -> str:
    """The report as a markdown table, a row per variant."""
    header = ("| variant | acceleration mm/frame² (p95) | fastest joint m/s | planted feet cm/s "
              "| foot sliding mm/frame | MPJPE cm | PA cm | latency added p50 / p99 ms |")
    lines = [header, "|---|---|---|---|---|---|---|---|"]
    for name, r in report["variants"].items():
        latency = "–" if "latency_p50_ms" not in r else f"{r['latency_p50_ms']:.1f} / {r['latency_p99_ms']:.1f}"
        acceleration = "–" if not np.isfinite(r["acceleration_mm_per_frame2"]) else \
            f"{r['acceleration_mm_per_frame2']:.1f} ({r['acceleration_p95_mm_per_frame2']:.1f})"
        lines.append(f"| {name} | {acceleration} | {_cell(r['fastest_joint_mps'])} | "
                     f"{_cell(r['planted_feet_cm_per_s'])} | {_cell(r['foot_sliding_mm_per_frame'], 2)} | "
                     f"{_cell(r['mpjpe_cm'])} | {_cell(r['pa_mpjpe_cm'])} | {latency} |")
    lines += ["", (f"{report['camera']} alone ({report['frames']} frames at {report['fps']:g} fps) against the "
                   f"{report['cameras_triangulated']}-camera triangulation of the same detector; "
                   f"{report['planted_ankle_frames']} planted ankle-frames in the reference. Database floor "
                   f"(the best database pose under the best vertical turn, same joints, hips-centred): MPJPE "
                   f"{report['database_floor_mpjpe_cm']:.1f} cm.")]
    return "\n".join(lines)


def _cell(value: float, digits: int = 1) -> str:
    return f"{value:.{digits}f}" if np.isfinite(value) else "–"


def check_lines(report: dict) -> list[str]:
    """PASS/FAIL per target of :data:`TARGETS` for the lags evaluated."""
    variants = report["variants"]
    whole = variants[WHOLE_TAKE]["mpjpe_cm"]
    lines = []
    for lag, (acc, fastest, planted, mpjpe_over) in TARGETS.items():
        r = variants.get(f"online take, L = {lag}")
        if r is None:
            continue
        checks = [("acceleration", r["acceleration_mm_per_frame2"], acc, "mm/frame²"),
                  ("fastest joint", r["fastest_joint_mps"], fastest, "m/s"),
                  ("planted feet", r["planted_feet_cm_per_s"], planted, "cm/s")]
        if mpjpe_over is not None:
            checks.append(("MPJPE", r["mpjpe_cm"], whole + mpjpe_over, "cm (the whole take's + 1)"))
        for label, value, target, unit in checks:
            ok = bool(np.isfinite(value) and value <= target)
            lines.append(f"{'PASS' if ok else 'FAIL'}  L = {lag}: {label} {value:.2f} ≤ {target:.2f} {unit}")
    return lines
