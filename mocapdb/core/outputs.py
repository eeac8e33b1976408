"""Runtime outputs: the JSON-lines result stream and one BVH per track (``data_specs/stream_output.md``)."""
from __future__ import annotations

import json
import os
import shutil
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from fnmatch import fnmatchcase
from pathlib import Path

import numpy as np

from mocapdb.core.errors import MocapdbError
from mocapdb.core.face_shapes import BLEND_SHAPES
from mocapdb.core.files import recover_interrupted, replace_folder, sibling
from mocapdb.core.formats.bvh import Bvh, motion_from_rotations
from mocapdb.core.geometry import quat_to_matrix
from mocapdb.core.hand_rig import FINGER_JOINTS
from mocapdb.core.motion import FrameRecorder, Motion
from mocapdb.core.skeleton import (
    END_JOINTS,
    END_SITES,
    HUMANOID_BONE_AXES,
    HUMANOID_NODES,
    HUMANOID_NODES_WITH_FINGERS,
    KEYPOINTS,
    MEASURED_BONE_NAMES,
    NODE_NAMES,
    NODE_PARENTS,
    RIG_JOINTS,
    RIG_NODES,
    UNIVERSAL_HEIGHT_M,
    body_offsets_m,
    rig_offsets_m,
    universal_bone_lengths_m,
)

CAMERA_FROM_VIEW = np.array([1.0, 1.0, -1.0])  # view frame ↔ camera-aligned frame (z negated), either way


@dataclass
class Match:
    """The database projection a pose was retrieved from."""

    clip: str
    frame: int          # frame index within the clip (database frame rate)
    yaw_deg: float
    distance_2d: float  # Eq. 1 distance to the normalised input


@dataclass
class PersonPose:
    """One person's output for one frame."""

    track: int
    joints_m: np.ndarray     # [15, 3] camera-aligned frame, metres (KEYPOINTS order)
    quaternions: np.ndarray  # [R, 4] local rotations; the root's is relative to the view frame
    root_m: np.ndarray       # [3] pelvis, camera-aligned frame, metres
    match: Match | None      # None: no database match (stereo)
    height_m: float = UNIVERSAL_HEIGHT_M  # the body's standing height (the skeleton's scale)
    bones_m: np.ndarray | None = None     # [8] its MEASURED_BONE_NAMES lengths (None: the universal body's)
    up_view: np.ndarray | None = None     # [3] the world's up in the view frame, unit (None: not estimated)
    floor_offset_m: float | None = None   # the floor under the person: up_view · p = this (view frame, metres)
    contacts: tuple[bool, bool] | None = None  # (right, left) foot planted (None: not estimated)
    keypoints_px: np.ndarray | None = None     # [14, 3] the keypoints it was fitted to (x, y px, confidence)
    extremities_px: np.ndarray | None = None   # [E, 3] its heels, toes, knuckles, face (x, y px, confidence; 0: unseen)
    # [5, 4] the humanoid rig's feet, hands and head (END_JOINTS): local rotations (None: not estimated)
    end_quaternions: np.ndarray | None = None
    end_seen: tuple[bool, ...] | None = None  # [5] each measured in this frame (else held, or easing to rest)
    face_world_m: np.ndarray | None = None    # [11, 3] the detector's face world landmarks (head_pose.face_world)
    hands_px: np.ndarray | None = None        # [2, 21, 3] its hands' points (x, y, z px; NaN: absent; None: no hands)
    # [30, 4] the finger joints' local rotations (hand_rig.FINGER_JOINTS order; None: the input has no hands)
    finger_quaternions: np.ndarray | None = None
    fingers_seen: tuple[bool, bool] | None = None  # (right, left) hand measured in this frame
    # [3] the face's blend shapes (face_shapes.BLEND_SHAPES, 0-1; NaN: no face this frame; None: no faces)
    blend_shapes: np.ndarray | None = None
    # [N_HEAD, 3] the face mesh's head vertices (runtime/mesh_head.head_vertices: x, y, z px; NaN: no mesh
    # this frame; None: the input has no faces)
    mesh_px: np.ndarray | None = None


MOTION_COLUMNS = ("quaternions", "root_view_m", "scales")  # every recorded frame's (TrackRecording.frames)
FIT_COLUMNS = ("fit_quaternions", "fit_root_view_m", "keypoints", "extremities",  # with EngineConfig.keep_take
               "world_bones", "face_world_m", "hands_px", "mesh_px")


@dataclass
class TrackRecording:
    """What a track produced, for its files: one row per frame from its first to its last.

    ``frames`` (:class:`~mocapdb.core.motion.FrameRecorder`) holds per frame the rotations
    ``quaternions [R, 4]`` (view frame), ``root_view_m [3]`` and the body scale ``scales`` (height /
    1.75 m) estimated so far; with ``EngineConfig.keep_take`` also what the whole-take fit needs:
    the unfiltered per-frame fit ``fit_quaternions``/``fit_root_view_m``, the input ``keypoints
    [14, 3]`` and ``extremities [8, 3]`` (heels, toes, knuckles; x, y px, confidence), and the
    detector's world bones the fit was turned towards ``world_bones [B, 4]`` (unit direction in the
    view frame, weight; weight 0: none; ``runtime/world/detector_prior.py``) and its world landmarks of the face,
    shoulders and hips ``face_world_m [11, 3]`` (NaN: none; ``runtime/head_pose.face_world``) and the hands'
    points ``hands_px [2, 21, 3]`` (x, y, z px, float32; NaN: absent; ``runtime/frame_people.hand_points``) and
    the face mesh's head vertices ``mesh_px [N_HEAD, 3]`` (x, y, z px, float32; NaN: absent;
    ``runtime/mesh_head.head_vertices``).
    :meth:`motion` gives the track as a :class:`~mocapdb.core.motion.Motion`.
    """

    track: int
    first_frame: int
    frames: FrameRecorder = field(default_factory=FrameRecorder)
    proportions_m: np.ndarray | None = None  # [8] its bone lengths at 1.75 m stature (None: universal)
    camera_px: tuple[float, float, float] | None = None  # the pinhole they were fitted with: focal, cx, cy (px)
    up_view: np.ndarray | None = None  # the world's up in the view frame (the camera's tilt estimate)
    up_sd_deg: float | None = None     # that estimate's error (degrees; runtime.world.body_size.CameraTilt.sd_deg)
    floor_offset_m: float | None = None  # the floor found under the feet: up_view · p = this (view frame)
    # [F, 5, 4] the feet's, hands' and head's local rotations (END_JOINTS order) found by the whole-take fit
    # from heels, toes, knuckles and face points; None: they do not turn
    end_quaternions: np.ndarray | None = None
    # [F, 30, 4] the finger joints' local rotations (hand_rig.FINGER_JOINTS order) from the hands' points and
    # [F, 2] the frames whose hand (right, left) was measured (else interpolated or eased to a relaxed hand);
    # None: the fingers do not turn
    finger_quaternions: np.ndarray | None = None
    hands_seen: np.ndarray | None = None
    static: bool = False  # its keypoints never moved (see StillnessCheck): a poster, not a person
    part: int = 0         # earlier parts of the track cut off (Engine.cut_recordings)
    first_s: float = 0.0  # input time of the first and the last recorded frame
    last_s: float = 0.0

    def __len__(self) -> int:
        return len(self.frames)

    def column(self, name: str) -> np.ndarray:
        """The recorded values of ``name`` (:data:`MOTION_COLUMNS`, :data:`FIT_COLUMNS`) frame by frame;
        empty when not recorded (no frame yet, or the fits without ``keep_take``); KeyError for
        another name."""
        if name not in MOTION_COLUMNS + FIT_COLUMNS:
            raise KeyError(f"a track records no {name!r}: one of {', '.join(MOTION_COLUMNS + FIT_COLUMNS)}")
        return self.frames[name] if name in self.frames else np.zeros(0)

    @property
    def quaternions(self) -> np.ndarray:
        """``[F, R, 4]`` the rotations as streamed (view frame)."""
        return self.column("quaternions")

    @property
    def root_view_m(self) -> np.ndarray:
        """``[F, 3]`` the root as streamed (view frame, metres)."""
        return self.column("root_view_m")

    @property
    def scales(self) -> np.ndarray:
        """``[F]`` the body scale estimated at each frame."""
        return self.column("scales")

    def with_motion(self, motion: Motion) -> TrackRecording:
        """This track with ``motion`` (view frame) as its frames; the per-frame fits (consumed by the
        whole-take fit) are not carried over."""
        scales = np.full(len(motion), motion.scale)
        frames = FrameRecorder.of(quaternions=motion.rotations, root_view_m=motion.root_m, scales=scales)
        return replace(self, frames=frames, end_quaternions=motion.end_rotations,
                       finger_quaternions=motion.finger_rotations)

    def snapshot(self) -> TrackRecording:
        """A copy whose frames stay as they are now while the track records on (for a thread that
        writes the track's files meanwhile); the recorded arrays are shared, not copied."""
        return replace(self, frames=self.frames.snapshot())

    def duration_s(self, fps: float) -> float:
        """Input time from the first recorded frame to the last, plus one frame (``1 / fps``)."""
        return self.last_s - self.first_s + 1.0 / fps

    def motion(self, fps: float) -> Motion:
        """The track as a motion in the view frame at ``fps`` Hz, with one body: the last scale.

        The image fixes a body only up to a scale about the camera centre, so where the scale
        estimate changed during the track (``--camera-height``) each frame's root is moved to
        the track's final scale: the BVH keeps one skeleton and still matches the image.
        """
        scales = self.scales
        final = float(scales[-1])
        return Motion(self.quaternions, self.root_view_m * (final / scales)[:, None], fps, "view", self.first_frame,
                      final, self.proportions_m, self.end_quaternions, self.finger_quaternions)


BVH_ROTATION_CHANNELS = ["Zrotation", "Yrotation", "Xrotation"]
BVH_UNITS = {"m": 1.0, "cm": 100.0}


RIGS = ("universal", "humanoid")  # BVH rigs: mocapdb's 11 joints, or with the bones character set-ups expect


def _rig_table(rig: str, proportions_m: np.ndarray | None = None, fingers: bool = False
               ) -> tuple[list[str], np.ndarray, np.ndarray, list[str | None], np.ndarray]:
    """Names, parents, rest offsets (metres, for a body of bone lengths ``proportions_m`` at 1.75 m;
    None: the universal body), the universal joint, end joint (:data:`END_JOINTS`) or finger joint
    (:data:`FINGER_JOINTS`) each node turns with (None: identity) and the End Site mask of a BVH rig
    (:data:`RIGS`); ``fingers``: the humanoid rig's hands end in 15 finger joints each, not an End Site."""
    proportions = universal_bone_lengths_m() if proportions_m is None else proportions_m
    if rig == "universal":
        names = [n if n not in END_SITES else f"{RIG_NODES[NODE_NAMES.index(n)][1]}_End" for n in NODE_NAMES]
        sources = [n if n in RIG_JOINTS else None for n in NODE_NAMES]
        end_site = np.array([n in END_SITES for n in NODE_NAMES])
        return names, NODE_PARENTS.copy(), body_offsets_m(proportions), sources, end_site
    if rig == "humanoid":
        nodes = HUMANOID_NODES_WITH_FINGERS if fingers else HUMANOID_NODES
        names = [n[0] for n in nodes]
        parents = np.array([-1 if n[1] is None else names.index(n[1]) for n in nodes])
        offsets = rig_offsets_m(np.array([n[2] for n in nodes]), names, HUMANOID_BONE_AXES, proportions)
        return names, parents, offsets, [n[3] for n in nodes], np.array([n.endswith("_End") for n in names])
    raise ValueError(f"unknown rig {rig!r}: one of {', '.join(RIGS)}")


ROOT_TAIL_M = np.array([0.0, 0.10, 0.0])  # the root's End Site: up from the pelvis, for a 1.75 m body


def _with_root_tail(names: list[str], parents: np.ndarray, offsets_m: np.ndarray, sources: list[str | None],
                    end_site: np.ndarray) -> tuple[list[str], np.ndarray, np.ndarray, list[str | None], np.ndarray]:
    """A rig table (:func:`_rig_table`) with an End Site on the root, :data:`ROOT_TAIL_M` from it, listed
    last. Importers that end a bone at the mean of its children's offsets (Blender) otherwise give the
    root no length (the hips lie either side of the pelvis, the spine starts at it: "zero length node
    found"); an End Site sets the root bone's end instead. It turns nothing: no joint moves."""
    return (names + [f"{names[0]}_End"], np.append(parents, 0), np.vstack([offsets_m, ROOT_TAIL_M]),
            sources + [None], np.append(end_site, True))


def motion_bvh(motion: Motion, unit: str = "m", rig: str = "universal") -> Bvh:
    """A motion as a BVH: the root's position and every joint's rotation per frame.

    ``unit`` is the BVH's length unit (``"m"`` or ``"cm"``); every bone is the motion's body's
    (its proportions times its scale). ``rig="humanoid"`` adds head, clavicle, hand, foot and toe
    bones and 15 finger joints a hand under Mixamo's names (:data:`HUMANOID_NODES_WITH_FINGERS`); the
    joints of both rigs are at the same places, and its feet and hands turn by the motion's
    ``end_rotations``, its fingers by its ``finger_rotations`` (None: they do not turn);
    the universal rig has no such joints.
    """
    scale = BVH_UNITS[unit]
    names, parents, offsets_m, sources, end_site = _with_root_tail(*_rig_table(rig, motion.proportions_m, True))
    channels = [([] if end else BVH_ROTATION_CHANNELS.copy()) for end in end_site]
    channels[0] = ["Xposition", "Yposition", "Zposition"] + BVH_ROTATION_CHANNELS
    skeleton = Bvh(names, parents, offsets_m * (scale * motion.scale), channels, end_site, 1.0 / motion.fps,
                   np.zeros((len(motion), 0)))
    local = np.broadcast_to(np.eye(3), (len(motion), len(names), 3, 3)).copy()
    for joints, rotations in ((RIG_JOINTS, motion.rotations), (END_JOINTS, motion.end_rotations),
                              (FINGER_JOINTS, motion.finger_rotations)):
        nodes = [i for i, source in enumerate(sources) if source in joints]
        if rotations is not None and nodes:
            local[:, nodes] = quat_to_matrix(rotations[:, [joints.index(str(sources[i])) for i in nodes]])
    skeleton.motion = motion_from_rotations(skeleton, local, motion.root_m * scale)
    return skeleton


class OutputFolderError(MocapdbError, ValueError):
    """An output (folder or file) that cannot be (re)placed; the message says why."""


@dataclass(frozen=True)
class OutputFiles:
    """What one command writes in its output folder, to tell an earlier output of it from anything
    else: every file matches one of ``patterns`` (names, ``*`` wildcards) and one matches ``marker``
    (a file the command always writes)."""

    command: str
    patterns: tuple[str, ...]
    marker: str

    def matches(self, name: str) -> bool:
        """Whether a file named ``name`` is one the command writes."""
        return any(fnmatchcase(name, pattern) for pattern in self.patterns)


@dataclass(frozen=True)
class OutputFile:
    """A single file one command writes, told from anyone else's by its first bytes: ``signature``
    at byte ``offset`` (a PNG's, an MP4's, a report's first line). ``what``: its kind in words."""

    command: str
    what: str
    signature: bytes
    offset: int = 0


RECONSTRUCT_FILES = OutputFiles("reconstruct", ("result.jsonl", "track_*.bvh", "track_*.trc", "track_*.csv",
                                                "preview.png", "world.json"), "result.jsonl")


STREAM_FORMAT = "mocapdb-stream"
STREAM_VERSION = 2  # 2: the header's coordinate frame is "coordinate_frame" (was "frame")


def _rounded(values: np.ndarray, decimals: int) -> list:
    """Nested lists of rounded values; NaN (a value not measured) becomes null."""
    values = np.asarray(values, dtype=np.float64)
    rounded = np.round(values, decimals)
    missing = np.isnan(values)
    if missing.any():
        with_nulls = rounded.astype(object)
        with_nulls[missing] = None
        return with_nulls.tolist()
    return rounded.tolist()


def person_record(pose: PersonPose) -> dict:
    """One person of a frame as the stream schema writes it (``match`` null without a database match)."""
    match = None if pose.match is None else {
        "clip": pose.match.clip, "frame": pose.match.frame, "yaw_deg": pose.match.yaw_deg,
        "distance_2d": round(pose.match.distance_2d, 5)}
    return {
        "track": pose.track,
        "joints": _rounded(pose.joints_m, 4),
        "quaternions": _rounded(pose.quaternions, 5),
        "root": _rounded(pose.root_m, 4),
        "height": round(pose.height_m, 3),
        "bones": dict(zip(MEASURED_BONE_NAMES, _rounded(_bones_m(pose), 4))),
        "match": match,
        **_online_fields(pose),
    }


def _online_fields(pose: PersonPose) -> dict:
    """What the online whole take adds to a person's record: the feet planted, the world's up and the
    floor (view frame), the end joints' and fingers' rotations and which were seen, where known."""
    fields: dict = {}
    if pose.contacts is not None:
        fields["contacts"] = [bool(c) for c in pose.contacts]
    if pose.end_quaternions is not None:
        fields["end_quaternions"] = _rounded(pose.end_quaternions, 5)
        fields["end_seen"] = [bool(s) for s in (pose.end_seen or (False,) * len(END_JOINTS))]
    if pose.finger_quaternions is not None:
        fields["finger_quaternions"] = _rounded(pose.finger_quaternions.reshape(2, -1, 4), 5)
        fields["fingers_seen"] = [bool(s) for s in (pose.fingers_seen or (False, False))]
    if pose.blend_shapes is not None:
        fields["blend_shapes"] = {name: round(float(v), 3) if np.isfinite(v) else None
                                  for name, v in zip(BLEND_SHAPES, pose.blend_shapes)}
    if pose.up_view is not None:
        fields["up"] = _rounded(pose.up_view, 5)
    if pose.floor_offset_m is not None:
        fields["floor"] = round(float(pose.floor_offset_m), 4)
    return fields


def _bones_m(pose: PersonPose) -> np.ndarray:
    """The pose's bone lengths (metres), the universal body's at its height when not estimated."""
    if pose.bones_m is not None:
        return pose.bones_m
    return universal_bone_lengths_m() * (pose.height_m / UNIVERSAL_HEIGHT_M)


def frame_line(frame_index: int, time_s: float, poses: list[PersonPose]) -> str:
    """The JSON line of one frame (no trailing newline)."""
    return json.dumps({"frame": frame_index, "time": round(time_s, 6),
                       "people": [person_record(p) for p in poses]}, separators=(",", ":"))


def header_line(fps: float, image_size: tuple[int, int] | None = None, focal_px: float | None = None,
                sources: dict[str, str] | None = None, lag_frames: int | None = None) -> str:
    """The first line of a result stream: format, version, joint and rotation orders, units, the
    camera the run assumed (fps, image size, focal length in pixels, and where each came from:
    given, read from the take description, or default) and, for a stream through the online whole
    take, its lag (frames; None: the per-frame stream)."""
    body = {"format": STREAM_FORMAT, "version": STREAM_VERSION, "fps": fps,
            "joints": list(KEYPOINTS), "rotations": list(RIG_JOINTS), "units": "m",
            "coordinate_frame": "camera-aligned: x right, y up, z away from the camera"}
    if image_size is not None:
        body["image_size"] = [int(image_size[0]), int(image_size[1])]
    if focal_px is not None:
        body["focal_px"] = float(focal_px)
    if sources:
        body["camera_sources"] = dict(sources)
    body["stream"] = "per-frame" if lag_frames is None else "online-take"
    if lag_frames is not None:
        body["lag_frames"] = int(lag_frames)
        body["lag_s"] = round(lag_frames / fps, 6)
        body["end_joints"] = list(END_JOINTS)
    return json.dumps(body, separators=(",", ":"))


def _why_not_output(folder: Path, files: OutputFiles) -> str | None:
    """Why the folder ``folder`` is no earlier output of ``files.command``; None when it is one or empty."""
    names = []
    with os.scandir(folder) as entries:
        for entry in entries:
            if not (entry.is_file(follow_symlinks=False) and files.matches(entry.name)):
                return f"it holds {entry.name}, which `mocapdb {files.command}` does not write"
            names.append(entry.name)
    if names and not any(fnmatchcase(name, files.marker) for name in names):
        return f"it holds {names[0]} but no {files.marker}"
    return None


def check_output_folder(out: str | Path, files: OutputFiles = RECONSTRUCT_FILES) -> Path:
    """``out`` as a Path when a run of ``files.command`` may replace it: missing, an empty folder or an
    earlier output of that command (:class:`OutputFiles`); else OutputFolderError naming a file that
    is not the command's. Cheap: commands run it before any work."""
    out = Path(out)
    if not os.path.lexists(out):
        return out
    if out.is_symlink() or not out.is_dir():
        kind = "a symbolic link: give the folder itself" if out.is_symlink() else "not a folder"
        raise OutputFolderError(f"{out}: the output (--out) exists and is {kind}")
    why = _why_not_output(out, files)
    if why is not None:
        raise OutputFolderError(f"{out}: the output (--out) is not an output folder of `mocapdb {files.command}`: "
                                f"{why}; choose another --out (nothing was written)")
    return out


@contextmanager
def output_folder(out: str | Path, files: OutputFiles = RECONSTRUCT_FILES) -> Iterator[Path]:
    """A fresh temporary folder beside ``out`` that replaces ``out`` when the block ends normally.

    ``out`` is checked before the block (:func:`check_output_folder`: anything but an earlier output
    of ``files.command`` is refused before work starts) and again before the swap, so an earlier
    output is removed only once the new one is complete: a failing run leaves it as it was, a new
    run never mixes with an old one's files. On an exception the temporary folder is deleted.
    """
    out = check_output_folder(out, files)
    out.parent.mkdir(parents=True, exist_ok=True)
    recover_interrupted(out)
    tmp = sibling(out, "tmp", os.getpid())
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir()
    try:
        yield tmp
        check_output_folder(out, files)  # nothing else appeared there during the run
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    replace_folder(tmp, out)


def clear_output_folder(out: str | Path, files: OutputFiles) -> Path:
    """``out`` made ready for a run that writes its files in place as it goes (``mocapdb detect``,
    whose folder ``live`` may read meanwhile): refused as :func:`check_output_folder` refuses, an
    earlier output's files deleted, the folder created. A file the command does not write is never
    deleted."""
    out = check_output_folder(out, files)
    out.mkdir(parents=True, exist_ok=True)
    for path in out.iterdir():
        if files.matches(path.name):
            path.unlink()
    return out


def check_output_file(path: str | Path, kind: OutputFile) -> Path:
    """``path`` as a Path when a run of ``kind.command`` may write it: missing, or a file of the kind
    the command writes (:class:`OutputFile`); else OutputFolderError naming it. Cheap: commands run
    it before any work."""
    path = Path(path)
    if not os.path.lexists(path):
        return path
    if not path.is_file():
        raise OutputFolderError(f"{path}: the output (--out) exists and is not a file")
    with open(path, "rb") as file:
        head = file.read(kind.offset + len(kind.signature))
    if head[kind.offset:] != kind.signature:
        raise OutputFolderError(f"{path}: the output (--out) exists and is not {kind.what} (what `mocapdb "
                                f"{kind.command}` writes): choose another --out (nothing was written)")
    return path


@contextmanager
def output_file(path: str | Path, kind: OutputFile) -> Iterator[Path]:
    """A temporary path beside ``path`` (same suffix: writers choose the format by it) that replaces
    ``path`` when the block ends normally; ``path`` is checked (:func:`check_output_file`) before the
    block and again before it is replaced. On an exception the temporary file is deleted."""
    path = check_output_file(path, kind)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.stem}.tmp{os.getpid()}{path.suffix}")
    try:
        yield tmp
        os.replace(tmp, check_output_file(path, kind))
    finally:
        tmp.unlink(missing_ok=True)


TRACK_FILES = OutputFiles("live", ("track_*.bvh", "track_*.trc", "track_*.csv"), "track_*")


def check_no_track_files(folder: str | Path, option: str = "--bvh-dir") -> None:
    """Refuse (OutputFolderError) a folder that already holds track files (``track_*.bvh/trc/csv``):
    a run that adds its track files to a folder as tracks end (``live --bvh-dir``) never writes over
    an earlier run's, and touches no other file there. A missing folder passes (it is created)."""
    folder = Path(folder)
    if not os.path.lexists(folder):
        return
    if not folder.is_dir():
        raise OutputFolderError(f"{folder}: {option} exists and is not a folder")
    with os.scandir(folder) as entries:
        earlier = sorted(e.name for e in entries if TRACK_FILES.matches(e.name))
    if earlier:
        raise OutputFolderError(f"{folder}: {option} already holds track files ({', '.join(earlier[:3])}"
                                f"{', …' if len(earlier) > 3 else ''}) that this run would write over: choose "
                                "another folder or move them (nothing was written)")
