"""`mocapdb stereo`'s outputs: ``result.jsonl``, ``cameras.json``, one BVH per person, the summary.

``result.jsonl``: the runtime schema (``data_specs/stream_output.md``), camera-aligned frame of
camera 1, one track per person; ``cameras.json``: both cameras, the estimated relative pose, the
people; BVHs: the universal rig in the levelled y-up world (:mod:`mocapdb.stereo.motion`).
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mocapdb.core.cameras import CameraModel, format_calibration_toml
from mocapdb.core.files import os_error_message, write_atomic
from mocapdb.core.formats.bvh import write_bvh
from mocapdb.core.outputs import PersonPose, frame_line, header_line, motion_bvh, output_folder
from mocapdb.stereo.config import (
    CALIBRATION_FILE,
    CAMERAS_FILE,
    RESULT_FILE,
    STEREO_FILES,
    StereoError,
    StereoResult,
    bvh_name,
)
from mocapdb.stereo.motion import StereoPerson, World
from mocapdb.stereo.people import People, listed_frames
from mocapdb.stereo.relative_pose import rotation_angle_deg


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
    converged: bool | None = None  # the ellipsoid rounds reached their stop (None: no round ran)
    notes: list[str] = field(default_factory=list)  # what the output assumed where the views are silent

    def report(self) -> str:
        """Human-readable lines for the command line."""
        n_dropped = sum(len(v) for v in self.dropped.values())
        lines = [(f"frames {self.frames}, with a person {self.frames - n_dropped}, without {n_dropped}; "
                  f"people {len(self.tracks)}")]
        lines += [f"  track {t['track']}: {t['frames']} frames ({t['first_frame']}–{t['last_frame']}), "
                  f"{t['correspondences']} joints seen by both views, BVH {t['bvh'] or 'none'}" for t in self.tracks]
        lines += [f"  no person in {len(frames)}: {why} (frames {listed_frames(frames)})"
                  for why, frames in self.dropped.items()]
        lines += [f"  not a person: {line}" for line in self.unmatched]
        eps = ", ".join(f"{e:.4f}" for e in self.epsilons) or "none"
        state = {None: "", True: ", converged", False: ", not converged (warning below)"}[self.converged]
        lines.append(f"ellipsoid ε per round: {eps}; kept round {self.kept_round}{state}")
        lines.append(f"camera 2 relative to camera 1: rotation {self.rotation_deg:.2f}°, "
                     f"baseline {self.baseline:.3f} m ({self.scale_source})")
        lines += [f"note: {n}" for n in self.notes] + [f"warning: {w}" for w in self.warnings]
        lines += [f"  {stage:<12} {sec:8.3f} s" for stage, sec in self.seconds.items()]
        lines.append(f"  {'total':<12} {sum(self.seconds.values()):8.3f} s")
        lines.append("wrote " + ", ".join(str(p) for p in self.outputs))
        return "\n".join(lines)


def result_text(motions: list[StereoPerson], fps: float) -> str:
    """``result.jsonl``: the header line, then one line per frame with every person present."""
    lines = [header_line(fps)]
    for t in range(len(motions[0].present)):
        poses = [PersonPose(m.track, m.joints_aligned[t], m.quats_view[t], m.pelvis_aligned[t], None)
                 for m in motions if m.present[t]]
        lines.append(frame_line(t, t / fps, poses))
    return "\n".join(lines) + "\n"


def _camera_record(cam: CameraModel, rotation: np.ndarray, translation: np.ndarray) -> dict:
    """One camera of ``cameras.json``: intrinsics, distortion and pose ``x_cam = R x1 + t``."""
    return {"name": cam.name, "size": list(cam.size), "K": np.asarray(cam.K).tolist(),
            "dist": np.asarray(cam.dist).ravel().tolist(), "R": rotation.tolist(), "t": translation.tolist()}


def track_records(people: People, motions: list[StereoPerson]) -> list[dict]:
    """Per person: track id, frames written, first and last, joints seen by both views, BVH file."""
    records = []
    for person, m in zip(people.persons, motions):
        frames = np.flatnonzero(m.present)
        first, last = (int(frames[0]), int(frames[-1])) if len(frames) else (None, None)
        records.append({"track": m.track, "frames": len(frames), "first_frame": first, "last_frame": last,
                        "correspondences": person.correspondences,
                        "bvh": bvh_name(m.track) if m.fitted else None})
    return records


def cameras_text(cam1: CameraModel, cam2: CameraModel, result: StereoResult, world: World, people: People,
                 tracks: list[dict], warnings: list[str], notes: list[str]) -> str:
    """``cameras.json``: both cameras in camera 1's frame (metres), the camera fit, the people, the warnings
    and notes."""
    t = np.asarray(result.t, dtype=np.float64) * world.scale
    record = {
        "frame": "camera 1 (OpenCV: x right, y down, z forward), metres; x2 = R x1 + t",
        "cameras": [_camera_record(cam1, np.eye(3), np.zeros(3)), _camera_record(cam2, np.asarray(result.R), t)],
        "baseline_m": float(np.linalg.norm(t)), "scaled": bool(result.scaled), "scale_source": world.scale_source,
        "rotation_deg": rotation_angle_deg(np.asarray(result.R)),
        "camera_source": "all people's correspondences (tracks stacked along time)",
        "epsilons": [float(e) for e in result.epsilons], "kept_round": int(result.kept_round),
        "converged": result.converged, "warnings": warnings, "notes": notes,
        "dropped_frames": people.dropped, "tracks": tracks, "not_people": people.unmatched,
        "bvh_from_camera1": world.bvh_from_camera.tolist(),
    }
    return "{\n" + ",\n".join(f"  {json.dumps(k)}: {json.dumps(v)}" for k, v in record.items()) + "\n}\n"


ZUP_FROM_YUP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # y-up → Pose2Sim's z-up world


def calibration_text(cam1: CameraModel, cam2: CameraModel, result: StereoResult, world: World) -> str:
    """``calibration.toml``: both cameras as Pose2Sim reads them, in a z-up world (metres when
    scaled) whose origin is camera 1 and whose up is the levelled BVH world's."""
    world_from_cam1 = ZUP_FROM_YUP @ world.bvh_from_camera
    t2 = np.asarray(result.t, dtype=np.float64) * world.scale
    cameras = [CameraModel(cam1.K, cam1.dist, world_from_cam1.T, np.zeros(3), cam1.size, cam1.name or "cam_01"),
               CameraModel(cam2.K, cam2.dist, np.asarray(result.R) @ world_from_cam1.T, t2, cam2.size,
                           cam2.name or "cam_02")]
    return format_calibration_toml(cameras, "Estimated by mocapdb stereo (ElliPose) from the people seen by both "
                                            "cameras.\nWorld: z up, origin at the first camera, metres "
                                            f"({world.scale_source}).")


def write_outputs(out_dir: str | Path, motions: list[StereoPerson], world: World, cameras_json: str,
                  fps: float, calibration_toml: str) -> list[Path]:
    """Write ``result.jsonl``, ``cameras.json`` (the text ``cameras_json``), ``calibration.toml`` (the
    text ``calibration_toml``) and the BVH of every fitted person as the folder ``out_dir``; the paths
    written. The folder replaces ``out_dir`` whole once complete (:func:`mocapdb.core.outputs.output_folder`):
    an earlier stereo output is replaced, a folder holding anything else is refused. StereoError naming
    the folder on an OS error."""
    out = Path(out_dir)
    names = [RESULT_FILE, CAMERAS_FILE, CALIBRATION_FILE] + [bvh_name(m.track) for m in motions if m.fitted]
    try:
        with output_folder(out, STEREO_FILES) as tmp:
            write_atomic(tmp / RESULT_FILE, result_text(motions, fps))
            write_atomic(tmp / CAMERAS_FILE, cameras_json)
            write_atomic(tmp / CALIBRATION_FILE, calibration_toml)
            for m in motions:
                if m.motion is not None:
                    write_bvh(tmp / bvh_name(m.track), motion_bvh(m.motion))
    except OSError as exc:
        raise StereoError(os_error_message(exc, out, "write the output")) from None
    return [out / name for name in names]
