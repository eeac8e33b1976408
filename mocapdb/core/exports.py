"""A track's files: BVH (universal or humanoid rig), TRC (OpenSim / Pose2Sim markers) and CSV.

Coordinates are the view frame (metres, x to the image's right, y up, z towards the camera),
whose origin is the camera. With ``floor`` the motion is put on a floor at y = 0: the floor the
whole-take fit found under the planted feet (``TrackRecording.floor_offset_m``; pitch and roll
taken out; the origin under the camera, so every track on that floor shares one world), or, for a
per-frame recording, one estimated here from the feet, the pelvis starting above the origin:
the camera's pitch is taken out (the line the lowest ankle traces over depth is made level); a
person who hardly moves in depth (< :data:`MIN_DEPTH_SPREAD_M`) is only shifted, not levelled;
the roll is not estimated; the floor height is the 5th percentile of the lowest ankle minus the
ankle height.

Alignment with the input (``data_specs/stream_output.md``, "Track files"): BVH has no start-frame
field, so a track's BVH is padded at the start with its first pose (root and rotations) back to
input frame 0: BVH frame ``k`` is input frame ``k - 1``, and every BVH of a take lines up with the
video and with the others (``TrackExport.pad_to_input``; at most :data:`MAX_BVH_PAD_FRAMES`). TRC
``Frame#`` is the input frame index + 1 and ``Time`` the input's time; CSV ``frame`` is the input
frame index (from 0) and ``time_s`` the input's time. Neither is padded: their times are explicit.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mocapdb.core.files import write_atomic
from mocapdb.core.formats.bvh import format_bvh
from mocapdb.core.formats.trc import format_trc
from mocapdb.core.geometry import axis_rotation_matrices, matrix_to_quat, quat_mul
from mocapdb.core.outputs import RIGS, TrackRecording, universal_bvh
from mocapdb.core.skeleton import ANKLE_HEIGHT_M, KEYPOINTS, KP, pose_from_rotations, swing_matrices

LOG = logging.getLogger("mocapdb")
FORMATS = ("bvh", "trc", "csv")
# A track starting later than this input frame gets an unpadded BVH (its own frames only, with a
# warning): an hour at 30 fps, 45-80 MB of BVH text, keeps a numbered stream's far-off frame (or
# a long live session) from writing files of gigabytes.
MAX_BVH_PAD_FRAMES = 108_000
MIN_DEPTH_SPREAD_M = 0.5   # the feet must cover this much depth for the camera pitch to be measured
FLOOR_PERCENTILE = 5.0     # of the lowest ankle's height, for the floor
LEVEL_INLIER_M = 0.05      # ankle points this close to the first line fit the second


@dataclass(frozen=True)
class TrackExport:
    """Which files a track gets and how: ``formats`` (of :data:`FORMATS`), the BVH ``unit``
    ("m" or "cm") and ``rig`` (:data:`~mocapdb.core.outputs.RIGS`), ``floor``, and
    ``pad_to_input``: the BVH starts at input frame 0, the track's first pose held until the track
    starts (False: at the track's first frame; `--bvh-start`)."""

    formats: tuple[str, ...] = ("bvh",)
    unit: str = "m"
    rig: str = "universal"
    floor: bool = False
    pad_to_input: bool = True

    def __post_init__(self) -> None:
        unknown = [f for f in self.formats if f not in FORMATS]
        if unknown or not self.formats:
            raise ValueError(f"unknown output format {', '.join(unknown) or '(none)'}: "
                             f"choose from {', '.join(FORMATS)}")
        if self.rig not in RIGS:
            raise ValueError(f"unknown rig {self.rig!r}: choose from {', '.join(RIGS)}")
        if self.unit not in ("m", "cm"):
            raise ValueError(f"unknown BVH unit {self.unit!r}: m or cm")


def on_floor(quats: np.ndarray, root_m: np.ndarray, scale: float, offsets_m: np.ndarray | None = None,
             floor: tuple[np.ndarray, float] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``quats [F, R, 4]`` and ``root_m [F, 3]`` of a body (rest ``offsets_m``, default universal,
    times ``scale``) turned level and moved onto a floor at y = 0. ``floor``: the plane ``normal · p
    = offset`` (view frame) found by the whole-take fit, turned to y = 0 (pitch and roll), the origin
    on it under the camera (so tracks on one floor share one world); else a floor estimated here,
    the first frame's pelvis above the origin (see the module's docstring)."""
    if floor is not None:
        normal, floor_y = np.asarray(floor[0], dtype=np.float64), float(floor[1])
        level = swing_matrices(normal / np.linalg.norm(normal), np.array([0.0, 1.0, 0.0]))
    else:
        lowest = _lowest_ankle(quats, root_m, scale, offsets_m)
        level = axis_rotation_matrices("X", np.float64(_floor_pitch(lowest)))
        floor_y = np.percentile((lowest @ level.T)[:, 1], FLOOR_PERCENTILE) - ANKLE_HEIGHT_M * scale
    quats = quats.copy()
    quats[:, 0] = quat_mul(matrix_to_quat(level), quats[:, 0])
    root = root_m @ level.T
    if floor is not None:  # one world for every track on that floor: the origin under the camera
        return quats, root - [0.0, floor_y, 0.0]
    return quats, root - [root[0, 0], floor_y, root[0, 2]]


def _lowest_ankle(quats: np.ndarray, root_m: np.ndarray, scale: float, offsets_m: np.ndarray | None) -> np.ndarray:
    """Per frame, the position of the lower ankle ``[F, 3]``."""
    ankles = pose_from_rotations(quats, root_m, scale, offsets_m)[:, [KP["r_ankle"], KP["l_ankle"]]]
    return ankles[np.arange(len(ankles)), np.argmin(ankles[..., 1], axis=1)]


def _floor_pitch(lowest: np.ndarray) -> float:
    """The rotation about x (radians) that makes the line of ``lowest`` over depth level; 0 when
    the depth spread is under :data:`MIN_DEPTH_SPREAD_M`. Two fits: all points, then those within
    :data:`LEVEL_INLIER_M` of the first line (steps and jumps lift the foot off the floor)."""
    depth, height = lowest[:, 2], lowest[:, 1]
    if np.ptp(depth) < MIN_DEPTH_SPREAD_M:
        return 0.0
    slope, offset = np.polyfit(depth, height, 1)
    near = np.abs(height - (slope * depth + offset)) < LEVEL_INLIER_M
    if np.ptp(depth[near]) >= MIN_DEPTH_SPREAD_M:
        slope, offset = np.polyfit(depth[near], height[near], 1)
    return float(np.arctan(slope))


def track_motion(rec: TrackRecording, floor: bool) -> tuple[np.ndarray, np.ndarray, float]:
    """Rotations ``[F, R, 4]``, root ``[F, 3]`` (metres) and body scale of a track, on the floor if asked."""
    quats, root_m, scale = rec.motion()
    if floor:
        floor = None if rec.floor_offset_m is None else (rec.up_view, rec.floor_offset_m)
        quats, root_m = on_floor(quats, root_m, scale, rec.offsets_m(), floor)
    return quats, root_m, scale


def csv_text(joints_m: np.ndarray, frames: np.ndarray, times_s: np.ndarray) -> str:
    """CSV with a header row: ``frame,time_s,<joint>_x,<joint>_y,<joint>_z,...`` (metres)."""
    columns = ["frame", "time_s"] + [f"{name}_{axis}" for name in KEYPOINTS for axis in "xyz"]
    values = np.char.mod("%.5f", np.round(joints_m.reshape(len(joints_m), -1), 5) + 0.0)
    rows = [f"{f},{t:.6f}," + ",".join(v) for f, t, v in zip(frames, times_s, values)]
    return "\n".join([",".join(columns), *rows]) + "\n"


def bvh_lead_frames(rec: TrackRecording, export: TrackExport, name: str = "") -> int:
    """How many copies of its first pose a track's BVH starts with: its first input frame's index
    (BVH frame 1 = input frame 0), 0 without ``export.pad_to_input`` or past
    :data:`MAX_BVH_PAD_FRAMES` (then logged once per process, naming file ``name``)."""
    global _WARNED_UNPADDED
    if not export.pad_to_input:
        return 0
    if rec.first_frame <= MAX_BVH_PAD_FRAMES:
        return rec.first_frame
    if not _WARNED_UNPADDED:
        _WARNED_UNPADDED = True
        LOG.warning("%s starts at input frame %d, past the %d frames a BVH is padded back to frame 0: its BVH "
                    "starts at the track's first frame (its TRC and CSV give the input's frame numbers; "
                    "further such files are not logged)", name or f"track {rec.track}", rec.first_frame,
                    MAX_BVH_PAD_FRAMES)
    return 0


_WARNED_UNPADDED = False


def write_track_files(rec: TrackRecording, folder: str | Path, stem: str, fps: float,
                      export: TrackExport = TrackExport()) -> list[Path]:
    """Write ``<stem>.<format>`` for each of ``export.formats`` (atomically); returns the paths.

    Aligned with the input (see the module's docstring): the BVH padded back to input frame 0
    (:func:`bvh_lead_frames`), TRC ``Frame#`` the input frame index + 1, CSV ``frame`` the index,
    and both the input's times (seconds) from the track's first frame on.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    quats, root_m, scale = track_motion(rec, export.floor)
    frames = rec.first_frame + np.arange(len(quats))
    times_s = rec.first_s + np.arange(len(quats)) / fps
    texts = {}
    if "bvh" in export.formats:
        bvh = universal_bvh(quats, root_m, fps, export.unit, scale, export.rig, rec.proportions_m, rec.end_quaternions)
        texts["bvh"] = format_bvh(bvh, lead_frames=bvh_lead_frames(rec, export, f"{stem}.bvh"))
    if "trc" in export.formats or "csv" in export.formats:
        joints_m = pose_from_rotations(quats, root_m, scale, rec.offsets_m())
        if "trc" in export.formats:
            texts["trc"] = format_trc(list(KEYPOINTS), joints_m, fps, frames + 1, times_s, f"{stem}.trc")
        if "csv" in export.formats:
            texts["csv"] = csv_text(joints_m, frames, times_s)
    paths = []
    for suffix in export.formats:
        path = folder / f"{stem}.{suffix}"
        write_atomic(path, texts[suffix])
        paths.append(path)
    return paths


def write_tracks(recordings: list[TrackRecording], out_dir: str | Path, fps: float,
                 export: TrackExport = TrackExport(), keep_static: bool = False) -> list[Path]:
    """Write ``track_<id>.<format>`` files for each recording; returns the paths. Static tracks (a
    poster, a false detection that never moves: ``TrackRecording.static``) get none unless
    ``keep_static``, as in `reconstruct`."""
    return [path for rec in recordings if keep_static or not rec.static
            for path in write_track_files(rec, out_dir, f"track_{rec.track}", fps, export)]
