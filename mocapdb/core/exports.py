"""Files of a motion or a track: BVH (universal or humanoid rig), TRC (OpenSim / Pose2Sim markers), CSV.

Every file is written from a :class:`~mocapdb.core.motion.Motion` (:func:`write_motion`), in its
coordinate frame (metres); a track's (:func:`write_track_files`) is its recording's, in the view
frame (x to the image's right, y up, z towards the camera, the origin at the camera). With ``floor`` the
motion is put on a floor at y = 0 (:func:`mocapdb.core.motion_ops.on_floor`): the floor the
whole-take fit found under the planted feet (``TrackRecording.floor_offset_m``; pitch and roll
taken out; the origin under the camera, so every track on that floor shares one world), or, for a
per-frame recording, one estimated from the feet, the pelvis starting above the origin.

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
from mocapdb.core.formats.bvh import format_bvh, forward_kinematics
from mocapdb.core.formats.trc import format_trc
from mocapdb.core.motion import Motion
from mocapdb.core.motion_ops import on_floor
from mocapdb.core.outputs import RIGS, TrackRecording, motion_bvh
from mocapdb.core.skeleton import FACE_MODEL_M, FACE_NAMES, KEYPOINTS

LOG = logging.getLogger("mocapdb")
FORMATS = ("bvh", "trc", "csv")
# The TRC's markers and the CSV's joints: the universal keypoints, then the face's points on the fitted head
MARKERS = KEYPOINTS + FACE_NAMES
# A track starting later than this input frame gets an unpadded BVH (its own frames only, with a
# warning): an hour at 30 fps, 45-80 MB of BVH text, keeps a numbered stream's far-off frame (or
# a long live session) from writing files of gigabytes.
MAX_BVH_PAD_FRAMES = 108_000


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


def track_motion(rec: TrackRecording, fps: float, floor: bool) -> Motion:
    """A track's motion at ``fps`` Hz (view frame), put on the floor (world frame) if asked."""
    motion = rec.motion(fps)
    if not floor:
        return motion
    plane = None if rec.floor_offset_m is None or rec.up_view is None else (rec.up_view, rec.floor_offset_m)
    return on_floor(motion, plane)


def face_points_m(motion: Motion) -> np.ndarray:
    """``[F, 6, 3]`` the face's points (:data:`~mocapdb.core.skeleton.FACE_NAMES`; the motion's frame, metres) on
    the humanoid rig's head: :data:`~mocapdb.core.skeleton.FACE_MODEL_M` scaled with the body, turned by the
    ``Head``'s global rotation about the nose where the rig puts it (``Head_End``)."""
    bvh = motion_bvh(motion, "m", "humanoid")
    positions, rotations = forward_kinematics(bvh, [bvh.names.index("Head"), bvh.names.index("Head_End")])
    model = FACE_MODEL_M * motion.scale
    return positions[:, 1, None] + np.einsum("fij,kj->fki", rotations[:, 0], model[1:] - model[0])


def csv_text(joints_m: np.ndarray, frames: np.ndarray, times_s: np.ndarray) -> str:
    """CSV with a header row: ``frame,time_s,<joint>_x,<joint>_y,<joint>_z,...`` (metres; the joints
    :data:`MARKERS`)."""
    columns = ["frame", "time_s"] + [f"{name}_{axis}" for name in MARKERS for axis in "xyz"]
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
    """Write a track's ``<stem>.<format>`` for each of ``export.formats`` (atomically); returns the
    paths. Aligned with the input (see the module's docstring): the BVH padded back to input frame 0
    (:func:`bvh_lead_frames`)."""
    lead = bvh_lead_frames(rec, export, f"{stem}.bvh")
    return write_motion(track_motion(rec, fps, export.floor), folder, stem, export, lead, rec.first_s)


def write_motion(motion: Motion, folder: str | Path, stem: str, export: TrackExport = TrackExport(),
                 lead_frames: int = 0, first_s: float | None = None) -> list[Path]:
    """Write ``<stem>.<format>`` for each of ``export.formats`` (atomically); returns the paths.
    The counterpart of :func:`mocapdb.core.clips.read_motion`.

    The BVH starts with ``lead_frames`` copies of the first pose; TRC ``Frame#`` is the motion's
    frame index (``first_frame`` on) + 1, CSV ``frame`` the index, and both give each frame's time
    (seconds): ``first_s`` at its first frame (None: ``first_frame / fps``), then ``1 / fps`` apart.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    frames = motion.first_frame + np.arange(len(motion))
    times_s = motion.times_s() if first_s is None else first_s + np.arange(len(motion)) / motion.fps
    texts = {}
    if "bvh" in export.formats:
        texts["bvh"] = format_bvh(motion_bvh(motion, export.unit, export.rig), lead_frames=lead_frames)
    if "trc" in export.formats or "csv" in export.formats:
        joints_m = np.concatenate([motion.joints_m(), face_points_m(motion)], axis=1)
        if "trc" in export.formats:
            texts["trc"] = format_trc(list(MARKERS), joints_m, motion.fps, frames + 1, times_s, f"{stem}.trc")
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
