"""The engine over evaluation frames: one sequence's run (:class:`EngineRun`), its whole take, the
whole take as ``reconstruct`` writes it (:func:`track_files_take`), the default stream at its lags
(:func:`stream_runs`), and the peer: the detector's own 3D as a run (:func:`world_landmarks_run`)."""
from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np

from mocapdb.core.formats.database import MotionDatabase
from mocapdb.core.formats.keypoints import KeypointFrame
from mocapdb.core.outputs import CAMERA_FROM_VIEW, PersonPose, TrackRecording
from mocapdb.core.skeleton import N_POINTS, PELVIS, pose_from_rotations
from mocapdb.runtime.engine import Engine
from mocapdb.runtime.engine_config import EngineConfig
from mocapdb.runtime.online_take import OnlineParams, OnlineTake
from mocapdb.runtime.take import take_joints
from mocapdb.runtime.world.detector_prior import view_joints
from mocapdb.runtime.world.fuse import fit_takes


@dataclass
class EngineRun:
    """One sequence through the engine; NaN where the engine gave no output."""

    joints: np.ndarray  # [F, 15, 3] camera-aligned frame (absolute)
    root: np.ndarray    # [F, 3] camera-aligned frame
    local: np.ndarray   # [F, 15, 3] root rotation and translation removed
    seconds: float
    recordings: list[TrackRecording] = field(default_factory=list)  # the engine's tracks (Engine.finish)

    @property
    def ok(self) -> np.ndarray:
        return ~np.isnan(self.joints[:, PELVIS, 0])


def run_sequence(engine: Engine, frames: list[KeypointFrame]) -> EngineRun:
    """Every frame through ``engine`` (one person per frame), then :meth:`Engine.finish`."""
    joints = np.full((len(frames), N_POINTS, 3), np.nan)
    root = np.full((len(frames), 3), np.nan)
    local = np.full_like(joints, np.nan)
    t0 = time.perf_counter()
    for i, frame in enumerate(frames):
        for pose in engine.step(frame):
            joints[i], root[i] = pose.joints_m, pose.root_m
            local[i] = _root_frame(pose.quaternions)
    elapsed = time.perf_counter() - t0
    return EngineRun(joints, root, local, elapsed, engine.finish())


def whole_take_run(run: EngineRun, n_frames: int, fps: float, camera_height_m: float | None = None) -> EngineRun:
    """The tracks of a refined run (made with ``keep_take``) through the whole-take fit on one floor
    (``camera_height_m`` below the camera when known), as a run of
    ``n_frames`` frames (frame index = position; ``local`` left NaN: the two-view test uses the
    per-frame engine); ``seconds``: the fit's time."""
    joints = np.full((n_frames, N_POINTS, 3), np.nan)
    root = np.full((n_frames, 3), np.nan)
    t0 = time.perf_counter()
    for rec in fit_takes(run.recordings, fps, camera_height_m=camera_height_m):
        frames, rec_joints, rec_root = take_joints(rec, fps)
        keep = (frames >= 0) & (frames < n_frames)
        joints[frames[keep]], root[frames[keep]] = rec_joints[keep], rec_root[keep]
    return EngineRun(joints, root, np.full_like(joints, np.nan), time.perf_counter() - t0, run.recordings)


def _root_frame(quats: np.ndarray) -> np.ndarray:
    """The pose with root rotation and translation removed (joints in the pelvis frame)."""
    q = quats.copy()
    q[0] = [1.0, 0.0, 0.0, 0.0]
    return pose_from_rotations(q[None], np.zeros((1, 3)))[0]


def track_files_take(db: MotionDatabase, engine: EngineConfig, frames: list[KeypointFrame], fps: float,
                     camera_height_m: float | None = None) -> EngineRun:
    """The whole take as ``reconstruct`` writes it: ``frames`` through an engine run as it runs one
    (:meth:`EngineConfig.for_track_files`: the fits kept, no 2D clean-up, no per-frame smoothing),
    then the whole-take fit (:func:`whole_take_run`)."""
    run = run_sequence(Engine(db, engine.for_track_files()), frames)
    return whole_take_run(run, len(frames), fps, camera_height_m)


def world_landmarks_run(frames: list[KeypointFrame], true_root_m: np.ndarray, focal_px: float,
                        center_px: tuple[float, float]) -> EngineRun:
    """The frames' world landmarks (the detector's own 3D, one person per frame) as a run, read as the
    engine reads them (:func:`~mocapdb.runtime.world.detector_prior.view_joints`) and placed at the true root
    ``true_root_m [F, 3]`` (camera-aligned; they have none of their own); NaN where a frame has none."""
    joints = np.full((len(frames), N_POINTS, 3), np.nan)
    for i, frame in enumerate(frames):
        person = frame.people[0] if frame.people else None
        if person is not None and person.world_m is not None:
            view, _ = view_joints(person.world_m, person.points_px, person.confidence, focal_px, center_px)
            joints[i] = view * CAMERA_FROM_VIEW + true_root_m[i]
    root = np.where(np.isnan(joints[:, PELVIS]), np.nan, true_root_m)
    return EngineRun(joints, root, np.full_like(joints, np.nan), 0.0)


def stream_config(engine: EngineConfig) -> EngineConfig:
    """``engine`` as ``reconstruct`` and ``live`` run it under their default stream, the online take:
    the per-frame fits unsmoothed (no 1€ filters, no 2D clean-up; the online take smooths them)."""
    return replace(engine, smoothing=False, keypoint_filter=None, keep_take=False)


def stream_runs(db: MotionDatabase, engine: EngineConfig, frames: list[KeypointFrame], lags: tuple[int, ...],
                params: OnlineParams | None = None) -> dict[int, EngineRun]:
    """The default stream of ``frames`` (one person per frame) at each of ``lags`` (frames): one engine run
    as the stream runs it (:func:`stream_config`), its poses through an
    :class:`~mocapdb.runtime.online_take.OnlineTake` per lag, each as a run (frame index = position;
    ``local`` left NaN; ``seconds``: the engine's time and that take's)."""
    config = stream_config(engine)
    run = Engine(db, config)
    t0 = time.perf_counter()
    poses = [run.step(frame) for frame in frames]
    engine_s = time.perf_counter() - t0
    return {lag: _online_run(poses, config, replace(params or OnlineParams(), lag_frames=lag), engine_s)
            for lag in lags}


def _online_run(poses: list[list[PersonPose]], config: EngineConfig, params: OnlineParams, engine_s: float
                ) -> EngineRun:
    """Each frame's engine ``poses`` through an online take with ``params`` as a run (``engine_s``: the
    engine's seconds, added to the take's)."""
    online = OnlineTake(config.fps, params, (config.focal_px, *config.center_px))
    joints = np.full((len(poses), N_POINTS, 3), np.nan)
    root = np.full((len(poses), 3), np.nan)
    t0 = time.perf_counter()
    due = [frame for i, people in enumerate(poses) for frame in online.push(i, i / config.fps, people)]
    for index, _, people in due + online.flush():
        for pose in people:
            joints[index], root[index] = pose.joints_m, pose.root_m
    return EngineRun(joints, root, np.full_like(joints, np.nan), engine_s + time.perf_counter() - t0)
