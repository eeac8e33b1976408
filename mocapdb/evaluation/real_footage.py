"""Real footage checked for what must hold on any video (issue 27): keypoint folders of real videos
(a detector's output with its ``take.json``) through the engine and the take's world as
``mocapdb reconstruct … --floor`` runs them with nothing else given; every track of at least
:data:`MIN_TRACK_S` checked from the joints its files hold, independently of the world's own
verdicts: a human stature (:data:`HUMAN_STATURE_M`), in front of the camera in every frame, and its
lower ankle within :data:`FLOOR_TOLERANCE_M` of the floor (95th percentile) in the frames it is
still (slower than :data:`PLANTED_MPS`) — or, where the world says it stands on something,
never below the floor. No truth is needed: these hold on any video.
"""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from mocapdb.core.exports import track_motion
from mocapdb.core.formats.database import MotionDatabase
from mocapdb.core.formats.openpose import read_openpose_folder
from mocapdb.core.formats.take import default_focal_px, read_take
from mocapdb.core.outputs import TrackRecording
from mocapdb.core.skeleton import ANKLE_HEIGHT_M, KP, UNIVERSAL_HEIGHT_M
from mocapdb.evaluation.engine_runs import run_sequence
from mocapdb.runtime.engine import Engine
from mocapdb.runtime.engine_config import EngineConfig
from mocapdb.runtime.world.fuse import fit_take_world
from mocapdb.runtime.world.stature import HUMAN_STATURE_M

MIN_TRACK_S = 1.0
FLOOR_TOLERANCE_M = 0.05
PLANTED_MPS = 0.2
_ANKLES = [KP["r_ankle"], KP["l_ankle"]]


def check_footage(db: MotionDatabase, folder: str | Path, engine: EngineConfig = EngineConfig()) -> dict:
    """One keypoint folder (with ``take.json``: fps, image size; the focal length or the default
    phone camera's) through the engine and the world; per track of at least :data:`MIN_TRACK_S`
    its stature (m), whether it stays in front, its planted lower ankle's height above the floor
    (m, median and 95th percentile of the absolute value), the world's kind, and the verdicts."""
    take = read_take(folder)
    if take is None or take.fps is None or take.image_size is None:
        raise ValueError(f"{folder}: no take.json with the frame rate and image size")
    focal = take.focal_px or default_focal_px(take.image_size)
    config = replace(engine, fps=take.fps, image_size=take.image_size, focal_px=focal, keep_take=True,
                     camera_height_m=None)
    run = run_sequence(Engine(db, config), list(read_openpose_folder(folder, fps=take.fps)))
    checked = {r.track for r in run.recordings if not r.static and r.duration_s(take.fps) >= MIN_TRACK_S}
    still = [r for r in run.recordings if r.static]   # evidence of the world, as in reconstruct
    tracks = []
    if checked:
        found = fit_take_world([r for r in run.recordings if r.track in checked] + still, take.fps)
        tracks = [_track_check(rec, found.world.people[rec.track].kind, take.fps)
                  for rec in found.fitted if rec.track in checked]
    return {"folder": str(folder), "fps": take.fps, "image_size": list(take.image_size), "focal_px": focal,
            "tracks": tracks, "passed": sum(t["ok"] for t in tracks)}


def _track_check(rec: TrackRecording, kind: str, fps: float) -> dict:
    """The checks of one fitted track (module docstring), from its files' joints on the floor."""
    on_the_floor = track_motion(rec, fps, floor=True)
    scale = on_the_floor.scale
    view_root = rec.motion(fps).root_m
    ankles = on_the_floor.joints_m()[:, _ANKLES]
    lower = ankles[np.arange(len(ankles)), np.argmin(ankles[..., 1], axis=1)]
    speed = np.linalg.norm(np.gradient(lower, axis=0), axis=1) * fps
    gaps = lower[speed < PLANTED_MPS, 1] - ANKLE_HEIGHT_M * scale
    stature = UNIVERSAL_HEIGHT_M * scale
    human = HUMAN_STATURE_M[0] <= stature <= HUMAN_STATURE_M[1]
    in_front = bool(np.all(view_root[:, 2] < 0.0))
    gap_p95 = float(np.percentile(np.abs(gaps), 95)) if len(gaps) else float("nan")
    on_floor = bool(len(gaps)) and gap_p95 <= FLOOR_TOLERANCE_M
    standing_on_something = kind != "floor" and bool(len(gaps)) and float(np.median(gaps)) > -FLOOR_TOLERANCE_M
    return {"track": rec.track, "frames": len(on_the_floor), "stature_m": stature, "in_front": in_front,
            "planted_frames": int(len(gaps)), "gap_median_m": float(np.median(gaps)) if len(gaps) else None,
            "gap_p95_m": gap_p95 if len(gaps) else None, "kind": kind,
            "ok": bool(human and in_front and (on_floor or standing_on_something))}


def footage_table(checks: list[dict]) -> str:
    """A markdown table of :func:`check_footage` results, one row per track."""
    rows = ["| take | track | frames | stature | in front | planted frames | lower ankle above the floor: median / p95 "
            "| world | ok |", "|---|---|---|---|---|---|---|---|---|"]
    for check in checks:
        for t in check["tracks"]:
            gap = "–" if t["gap_median_m"] is None else f"{t['gap_median_m']:+.3f} / {t['gap_p95_m']:.3f} m"
            rows.append(f"| {Path(check['folder']).name} | {t['track']} | {t['frames']} | {t['stature_m']:.2f} m "
                        f"| {'yes' if t['in_front'] else 'NO'} | {t['planted_frames']} | {gap} | {t['kind']} "
                        f"| {'yes' if t['ok'] else 'NO'} |")
    return "\n".join(rows)


def footage_check_line(checks: list[dict]) -> str:
    """The check line: every track of at least :data:`MIN_TRACK_S` passes (module docstring)."""
    tracks = [t for c in checks for t in c["tracks"]]
    passed = sum(t["ok"] for t in tracks)
    verdict = "PASS" if passed == len(tracks) else "FAIL"
    return (f"{verdict}  real footage: tracks of {MIN_TRACK_S:g} s or more with a human size, in front of the "
            f"camera, on the floor (or on something, not below it): {passed} of {len(tracks)}")
