"""The world's camera against a calibration (issue 36): the height, pitch and roll the one-camera
world (:func:`~mocapdb.runtime.world.fuse.fit_world`) reports, scored against the calibrated camera.

Truth. A Pose2Sim calibration's world is z up, metres, its floor the plane ``z = 0`` where the
people stand. The camera's height is its centre's ``z``; its pitch and roll are those of the
floor's normal seen from the camera, with the same definitions as :class:`~mocapdb.runtime.world.fuse.World`
(the normal in the view frame, x right, y up, z towards the camera: pitch ``atan2(n_z, n_y)``,
positive looking down; roll ``atan2(−n_x, n_y)``, positive when the world's up leans to the
image's left).

Scores per camera: the height's error (% of the truth), the pitch's and roll's errors (degrees),
and for each whether the truth lies inside the world's reported ±2 SD.
"""
from __future__ import annotations

import numpy as np

from mocapdb.core.cameras import CameraModel
from mocapdb.core.formats.database import MotionDatabase
from mocapdb.core.formats.keypoints import KeypointFrame
from mocapdb.core.outputs import TrackRecording
from mocapdb.runtime.engine import Engine
from mocapdb.runtime.engine_config import EngineConfig
from mocapdb.runtime.world.fuse import World, fit_take_world
from mocapdb.runtime.world.scene_lines import SceneEvidence, SceneTilt

VIEW_FROM_OPENCV = np.array([1.0, -1.0, -1.0])  # OpenCV camera axes (x right, y down, z forward) → view frame
# Issue 36's targets over the cameras of a take, each run alone: height off (% of the truth) and pitch
# off (degrees), median and worst; and every true height inside the reported ±2 SD
TARGET_HEIGHT_PCT = (10.0, 25.0)
TARGET_PITCH_DEG = (3.0, 8.0)


def true_camera(cam: CameraModel, floor_z_m: float = 0.0) -> dict[str, float]:
    """The calibrated camera's height above the floor ``z = floor_z_m`` (metres), pitch and roll
    (degrees; module docstring)."""
    normal = cam.R[:, 2] * VIEW_FROM_OPENCV         # the world's up (+z) in the view frame
    return {"height_m": float(cam.center_m[2] - floor_z_m),
            "pitch_deg": float(np.degrees(np.arctan2(normal[2], normal[1]))),
            "roll_deg": float(np.degrees(np.arctan2(-normal[0], normal[1])))}


def world_of_frames(db: MotionDatabase, frames: list[KeypointFrame], config: EngineConfig,
                    scene: SceneEvidence | None = None) -> World:
    """The world one camera's ``frames`` give, every track of them, as ``reconstruct`` finds it: its
    per-frame fits kept unsmoothed (the online and whole takes smooth them); ``scene``: the room's
    vanishing points, if any."""
    return world_of_tracks(tracks_of_frames(db, frames, config), config, scene)


def tracks_of_frames(db: MotionDatabase, frames: list[KeypointFrame], config: EngineConfig) -> list[TrackRecording]:
    """The engine's tracks of one camera's ``frames``, run as ``reconstruct`` runs it."""
    engine = Engine(db, config.for_track_files())
    for frame in frames:
        engine.step(frame)
    return engine.finish()


def world_of_tracks(tracks: list[TrackRecording], config: EngineConfig, scene: SceneEvidence | None = None) -> World:
    """The take's world of the engine's ``tracks`` (:func:`tracks_of_frames`), with the scene's lines if given."""
    return fit_take_world(tracks, config.fps, camera_height_m=config.camera_height_m, scene=scene).world


def scene_world(tilt: SceneTilt) -> World:
    """The scene's up alone as a :class:`World` (no floor, no height) for :func:`score_world_camera`."""
    return World(tilt.up, float("nan"), float("inf"), False, pitch_sd_deg=tilt.pitch_sd_deg,
                 roll_sd_deg=tilt.roll_sd_deg, tilt_from="scene", scene_share=1.0, scene=tilt)


def score_camera(world: World, cam: CameraModel, floor_z_m: float = 0.0) -> dict:
    """The world's camera against ``cam``'s (module docstring): a JSON-able dict."""
    return score_world_camera(world, true_camera(cam, floor_z_m))


def score_world_camera(world: World, truth: dict[str, float]) -> dict:
    """The world's camera against a true one (``height_m``, ``pitch_deg``, ``roll_deg``): its errors
    and whether the truth lies inside the reported ±2 SD of each."""
    sd = float(world.camera_height_log_sd)
    low, high = (world.camera_height_m * np.exp(-2 * sd), world.camera_height_m * np.exp(2 * sd)) \
        if np.isfinite(sd) else (float("nan"), float("nan"))
    return {"truth": truth,
            "world": {"height_m": float(world.camera_height_m), "height_log_sd": sd,
                      "height_2sd_m": [float(low), float(high)], "pitch_deg": world.pitch_deg,
                      "pitch_sd_deg": world.pitch_sd_deg, "roll_deg": world.roll_deg,
                      "roll_sd_deg": world.roll_sd_deg, "floor_found": world.floor_known},
            "height_error_pct": float(100 * (world.camera_height_m / truth["height_m"] - 1)),
            "height_inside_2sd": bool(low <= truth["height_m"] <= high),
            "pitch_error_deg": float(world.pitch_deg - truth["pitch_deg"]),
            "pitch_inside_2sd": bool(abs(world.pitch_deg - truth["pitch_deg"]) <= 2 * world.pitch_sd_deg),
            "roll_error_deg": float(world.roll_deg - truth["roll_deg"]),
            "roll_inside_2sd": bool(abs(world.roll_deg - truth["roll_deg"]) <= 2 * world.roll_sd_deg)}


def summary_lines(scores: dict[str, dict]) -> list[str]:
    """Median and worst of the cameras' errors, and how many truths lie inside the ±2 SD."""
    if not scores:
        return []
    height = np.abs([s["height_error_pct"] for s in scores.values()])
    pitch = np.abs([s["pitch_error_deg"] for s in scores.values()])
    roll = np.abs([s["roll_error_deg"] for s in scores.values()])
    inside = [sum(s[f"{what}_inside_2sd"] for s in scores.values()) for what in ("height", "pitch", "roll")]
    return [f"World camera over {len(scores)} cameras (takes): height off {np.median(height):.0f} % (median; worst "
            f"{height.max():.0f} %), pitch off {np.median(pitch):.1f}° (worst {pitch.max():.1f}°), roll off "
            f"{np.median(roll):.1f}° (worst {roll.max():.1f}°); the truth inside the reported ±2 SD: height "
            f"{inside[0]}, pitch {inside[1]}, roll {inside[2]} of {len(scores)}."]


def tilt_lines(label: str, scores: dict[str, dict]) -> list[str]:
    """One line of a mode's pitch and roll errors (median, worst) and how many truths lie inside ±2 SD,
    over the cameras it found a tilt on (``scores``: camera → :func:`score_world_camera`, None where it found none)."""
    found = {k: s for k, s in scores.items() if s is not None}
    if not found:
        return [f"{label}: no tilt on any of {len(scores)} cameras"]
    pitch = np.abs([s["pitch_error_deg"] for s in found.values()])
    roll = np.abs([s["roll_error_deg"] for s in found.values()])
    inside = [sum(s[f"{what}_inside_2sd"] for s in found.values()) for what in ("pitch", "roll")]
    return [f"{label}: {len(found)} of {len(scores)} cameras; pitch off {np.median(pitch):.1f}° (median; worst "
            f"{pitch.max():.1f}°), roll off {np.median(roll):.1f}° (worst {roll.max():.1f}°); truth inside ±2 SD: "
            f"pitch {inside[0]}, roll {inside[1]} of {len(found)}"]


def format_rows(scores: dict[str, dict]) -> list[str]:
    """A markdown table, a row per camera."""
    lines = ["| camera | height: world (±2 SD) / truth | off | pitch: world ± SD / truth | roll: world ± SD / truth |",
             "|---|---|---|---|---|"]
    for name, s in scores.items():
        w, t = s["world"], s["truth"]
        lo, hi = w["height_2sd_m"]
        lines.append(f"| {name} | {w['height_m']:.2f} m ({lo:.2f}–{hi:.2f}) / {t['height_m']:.2f} m | "
                     f"{s['height_error_pct']:+.0f} % | {w['pitch_deg']:.1f}° ± {w['pitch_sd_deg']:.1f} / "
                     f"{t['pitch_deg']:.1f}° | {w['roll_deg']:.1f}° ± {w['roll_sd_deg']:.1f} / {t['roll_deg']:.1f}° |")
    return lines


def camera_checks(scores: dict[str, dict]) -> list[str]:
    """PASS/FAIL lines of the targets (:data:`TARGET_HEIGHT_PCT`, :data:`TARGET_PITCH_DEG`, the ±2 SD)."""
    if not scores:
        return []
    lines = []
    for label, key, unit, (median_max, worst_max) in (("height off", "height_error_pct", "%", TARGET_HEIGHT_PCT),
                                                      ("pitch off", "pitch_error_deg", "°", TARGET_PITCH_DEG)):
        errors = np.abs([s[key] for s in scores.values()])
        for what, value, target in (("median", np.median(errors), median_max), ("worst", errors.max(), worst_max)):
            lines.append(f"{'PASS' if value <= target else 'FAIL'}  world camera: {label} {value:.1f}{unit} ≤ "
                         f"{target:g}{unit} ({what} of {len(errors)} cameras)")
    inside = sum(s["height_inside_2sd"] for s in scores.values())
    lines.append(f"{'PASS' if inside == len(scores) else 'FAIL'}  world camera: true height inside the reported "
                 f"±2 SD on {inside} of {len(scores)} cameras")
    return lines
